//! The options of [`simulate`](super::simulate) and
//! [`corrupt`](super::corrupt), and the ranges they are checked against.

use super::SimulationError;
use super::counts::InlierModel;
use super::world::World;
use super::wrong::{
    DEFAULT_LOCAL_WINDOW, DEFAULT_OUTLIER_ROTATION, DEFAULT_OUTLIER_TRANSLATION, OutlierPolicy,
};
use serde::{Deserialize, Serialize};

/// Largest accepted rotation noise σᵣ (radians); see the module
/// documentation on truncation.
pub const MAX_ROTATION_NOISE: f64 = 0.5;

/// Options of [`simulate_planar`](super::simulate_planar),
/// [`simulate_spatial`](super::simulate_spatial) and [`simulate`](super::simulate).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct SimulationOptions {
    /// The trajectory's shape (default [`World::Grid2d`]).
    pub world: World,
    /// Number of poses, at least 2 (default 1000). Vertex ids are
    /// `0..poses`.
    pub poses: usize,
    /// Standard deviation of the translation noise per axis, metres
    /// (default 0.05).
    pub translation_noise: f64,
    /// Standard deviation of the rotation noise per axis, radians, at most
    /// [`MAX_ROTATION_NOISE`] (default 0.01).
    pub rotation_noise: f64,
    /// Largest number of true loop closures (default 300); fewer are made
    /// when the trajectory has fewer poses with a loop partner.
    pub loops: usize,
    /// Seed of the random generator, [`StdRng::seed_from_u64`](rand::SeedableRng::seed_from_u64) (default 0).
    pub seed: u64,
    /// Number of wrong loop candidates (default 0).
    pub outliers: usize,
    /// How wrong loop candidates are placed (default
    /// [`OutlierPolicy::Random`]).
    pub outlier_policy: OutlierPolicy,
    /// Size of the groups of [`OutlierPolicy::Grouped`], at least 1
    /// (default 10); the last group is smaller when it does not divide
    /// `outliers`.
    pub group_size: usize,
    /// Inlier-count model of the loop candidates (default `None`: no
    /// counts). With a model, true loops are candidates with counts; see
    /// the module documentation for which edges are candidates.
    pub inliers: Option<InlierModel>,
}

impl Default for SimulationOptions {
    fn default() -> Self {
        Self {
            world: World::Grid2d,
            poses: 1000,
            translation_noise: 0.05,
            rotation_noise: 0.01,
            loops: 300,
            seed: 0,
            outliers: 0,
            outlier_policy: OutlierPolicy::Random,
            group_size: 10,
            inliers: None,
        }
    }
}

impl SimulationOptions {
    /// Checks the options that do not depend on the world: at least two
    /// poses, positive finite noise (rotation noise at most
    /// [`MAX_ROTATION_NOISE`]), a positive group size and a valid inlier
    /// model.
    pub fn validate(&self) -> Result<(), SimulationError> {
        if self.poses < 2 {
            return Err(SimulationError::TooFewPoses(self.poses));
        }
        positive("translation_noise", self.translation_noise)?;
        positive("rotation_noise", self.rotation_noise)?;
        if self.rotation_noise > MAX_ROTATION_NOISE {
            return Err(SimulationError::InvalidOption {
                name: "rotation_noise",
                value: self.rotation_noise,
                requirement: "at most MAX_ROTATION_NOISE (0.5 rad)",
            });
        }
        if self.group_size == 0 {
            return Err(SimulationError::ZeroGroupSize);
        }
        self.inliers.as_ref().map_or(Ok(()), InlierModel::validate)
    }
}

/// Options of [`corrupt`](super::corrupt).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct CorruptionOptions {
    /// Number of wrong loop candidates to append (default 100).
    pub outliers: usize,
    /// How they are placed (default [`OutlierPolicy::Random`]).
    pub policy: OutlierPolicy,
    /// Size of the groups of [`OutlierPolicy::Grouped`], at least 1
    /// (default 10).
    pub group_size: usize,
    /// Largest index distance of [`OutlierPolicy::Local`] pairs, at least 2
    /// (default [`DEFAULT_LOCAL_WINDOW`]).
    pub local_window: usize,
    /// Half-width (metres) of the uniform translation components of the
    /// tangent vector of a wrong measurement (default
    /// [`DEFAULT_OUTLIER_TRANSLATION`]).
    pub translation_scale: f64,
    /// Half-width (radians) of its uniform rotation components (default
    /// [`DEFAULT_OUTLIER_ROTATION`]).
    pub rotation_scale: f64,
    /// Inlier-count model (default `Some(InlierModel::default())`); `None`
    /// leaves the counts of existing candidates alone and gives wrong
    /// candidates no count.
    pub inliers: Option<InlierModel>,
    /// The last this many existing non-sequential edges (in file order) are
    /// known to be wrong, as in the max-mixture outlier files whose last
    /// 1000 mixture edges are the injected outliers (default 0): they are
    /// labelled wrong and get counts from the wrong-loop model.
    pub known_wrong_last: usize,
}

impl Default for CorruptionOptions {
    fn default() -> Self {
        Self {
            outliers: 100,
            policy: OutlierPolicy::Random,
            group_size: 10,
            local_window: DEFAULT_LOCAL_WINDOW,
            translation_scale: DEFAULT_OUTLIER_TRANSLATION,
            rotation_scale: DEFAULT_OUTLIER_ROTATION,
            inliers: Some(InlierModel::default()),
            known_wrong_last: 0,
        }
    }
}

impl CorruptionOptions {
    /// Checks the group size, the local window, the scales and the inlier
    /// model.
    pub fn validate(&self) -> Result<(), SimulationError> {
        if self.group_size == 0 {
            return Err(SimulationError::ZeroGroupSize);
        }
        if self.local_window < 2 {
            return Err(SimulationError::InvalidOption {
                name: "local_window",
                value: self.local_window as f64,
                requirement: "at least 2",
            });
        }
        non_negative("translation_scale", self.translation_scale)?;
        non_negative("rotation_scale", self.rotation_scale)?;
        self.inliers.as_ref().map_or(Ok(()), InlierModel::validate)
    }
}
pub(super) fn positive(name: &'static str, value: f64) -> Result<(), SimulationError> {
    if value.is_finite() && value > 0.0 {
        Ok(())
    } else {
        Err(SimulationError::InvalidOption {
            name,
            value,
            requirement: "finite and positive",
        })
    }
}

pub(super) fn non_negative(name: &'static str, value: f64) -> Result<(), SimulationError> {
    if value.is_finite() && value >= 0.0 {
        Ok(())
    } else {
        Err(SimulationError::InvalidOption {
            name,
            value,
            requirement: "finite and non-negative",
        })
    }
}
