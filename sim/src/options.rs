//! The options of [`simulate`](super::simulate) and
//! `corrupt`, and the ranges they are checked against.
//!
//! Every number written by `pgo simulate` or `pgo corrupt` must read back:
//! finite, with positive-definite information. The ranges below are derived
//! from that and from the memory a simulation takes.

use super::SimulationError;
use super::counts::InlierModel;
use super::world::World;
use super::wrong::{
    AliasOffsets, AliasPlace, DEFAULT_LOCAL_WINDOW, DEFAULT_OUTLIER_ROTATION,
    DEFAULT_OUTLIER_TRANSLATION, OutlierPolicy,
};
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

/// Largest accepted rotation noise σᵣ (radians); see the module
/// documentation on truncation.
pub const MAX_ROTATION_NOISE: f64 = 0.5;

/// Smallest accepted noise σ (translation in metres, rotation in radians).
/// The information of the noise is `1/σ²` (`4/σᵣ²` for SE(3) rotations);
/// with `σ ≥ 10⁻⁴⁹` it is at most `4·10⁹⁸`, inside the range the library
/// accepts ([`pgo::INFORMATION_RANGE`], up to `10¹⁰⁰`).
pub const MIN_NOISE: f64 = 1e-49;

/// Largest accepted length (metres): the translation noise σₜ and the
/// translation scale of wrong measurements. The information `1/σₜ²` of the
/// largest noise is `10⁻⁹⁸`, inside the range the library accepts
/// ([`pgo::INFORMATION_RANGE`], down to `10⁻¹⁰⁰`); the squared norms of
/// such lengths (`10⁹⁸`) stay finite too.
pub const MAX_LENGTH: f64 = 1e49;

/// Most poses of a simulation, and most wrong candidates of a simulation or
/// corruption. A simulated SE(3) pose with a loop closure takes about 2 KB
/// (two graphs with their edges and 6×6 information matrices, the planned
/// edges and the loop search's hash) and about 800 bytes of g2o text, so a
/// million poses take about 2 GB while simulated and 0.8 GB on disk: within
/// reach of every machine the project builds on, with room for `pgo
/// optimize` to read the result back. A wrong candidate costs less than a
/// pose.
pub const MAX_POSES: usize = 1_000_000;

/// Options of [`simulate_planar`](super::simulate_planar),
/// [`simulate_spatial`](super::simulate_spatial) and [`simulate`](super::simulate).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct SimulationOptions {
    /// The trajectory's shape (default [`World::Grid2d`]).
    pub world: World,
    /// Number of poses, in `[2, MAX_POSES]` (default 1000). Vertex ids
    /// are `0..poses`.
    pub poses: usize,
    /// Standard deviation of the translation noise per axis, metres, in
    /// `[MIN_NOISE, MAX_LENGTH]` (default 0.05).
    pub translation_noise: f64,
    /// Standard deviation of the rotation noise per axis, radians, in
    /// `[MIN_NOISE, MAX_ROTATION_NOISE]` (default 0.01).
    pub rotation_noise: f64,
    /// Largest number of true loop closures, any (default 300): at most one
    /// per pose is made, fewer when the trajectory has fewer poses with a
    /// loop partner.
    pub loops: usize,
    /// Seed of the random generator, any
    /// ([`StdRng::seed_from_u64`](rand::SeedableRng::seed_from_u64); default 0).
    pub seed: u64,
    /// Number of wrong loop candidates, at most [`MAX_POSES`] (default 0).
    pub outliers: usize,
    /// How wrong loop candidates are placed (default
    /// [`OutlierPolicy::Random`]).
    pub outlier_policy: OutlierPolicy,
    /// Size of the groups of [`OutlierPolicy::Grouped`] and
    /// [`OutlierPolicy::Aliased`], in `[1, MAX_POSES]` (default 10); the
    /// last group is smaller when it does not divide `outliers`.
    pub group_size: usize,
    /// The offsets of [`OutlierPolicy::Aliased`] candidates (default
    /// [`AliasOffsets::default`]).
    pub alias_offsets: AliasOffsets,
    /// Where [`OutlierPolicy::Aliased`] groups fall (default
    /// [`AliasPlace::Revisited`]).
    pub alias_place: AliasPlace,
    /// Share of the wrong candidates whose inlier counts are drawn from the
    /// true-loop model instead of the wrong one, in `[0, 1]` (default 0):
    /// each wrong candidate independently with this probability. Needs an
    /// inlier model when positive.
    pub true_like_share: f64,
    /// Whether a group of [`OutlierPolicy::Grouped`] or
    /// [`OutlierPolicy::Aliased`] candidates draws `true_like_share` once
    /// for all its members (default `false`: each candidate draws its own).
    pub true_like_by_group: bool,
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
            alias_offsets: AliasOffsets::default(),
            alias_place: AliasPlace::Revisited,
            true_like_share: 0.0,
            true_like_by_group: false,
            inliers: None,
        }
    }
}

impl SimulationOptions {
    /// Checks every option against its range (see the fields), and the
    /// inlier model; the world's room for wrong loops is checked when they
    /// are placed.
    pub fn validate(&self) -> Result<(), SimulationError> {
        if self.poses < 2 {
            return Err(SimulationError::TooFewPoses(self.poses));
        }
        within_count("poses", self.poses, 2, MAX_POSES)?;
        within(
            "translation_noise",
            self.translation_noise,
            MIN_NOISE,
            MAX_LENGTH,
        )?;
        within(
            "rotation_noise",
            self.rotation_noise,
            MIN_NOISE,
            MAX_ROTATION_NOISE,
        )?;
        within_count("outliers", self.outliers, 0, MAX_POSES)?;
        if self.group_size == 0 {
            return Err(SimulationError::ZeroGroupSize);
        }
        within_count("group_size", self.group_size, 1, MAX_POSES)?;
        self.alias_offsets.validate()?;
        validate_counts(self.inliers.as_ref(), self.true_like_share)
    }
}

/// Options of `corrupt`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct CorruptionOptions {
    /// Number of wrong loop candidates to append, at most [`MAX_POSES`]
    /// (default 100).
    pub outliers: usize,
    /// How they are placed (default [`OutlierPolicy::Random`]).
    pub policy: OutlierPolicy,
    /// Size of the groups of [`OutlierPolicy::Grouped`] and
    /// [`OutlierPolicy::Aliased`], in `[1, MAX_POSES]` (default 10).
    pub group_size: usize,
    /// The offsets of [`OutlierPolicy::Aliased`] candidates (default
    /// [`AliasOffsets::default`]).
    pub alias_offsets: AliasOffsets,
    /// Where [`OutlierPolicy::Aliased`] groups fall (default
    /// [`AliasPlace::Revisited`]).
    pub alias_place: AliasPlace,
    /// Largest index distance of [`OutlierPolicy::Local`] pairs, in
    /// `[2, MAX_POSES]` (default [`DEFAULT_LOCAL_WINDOW`]).
    pub local_window: usize,
    /// Half-width (metres) of the uniform translation components of the
    /// tangent vector of a random wrong measurement, in `[0, MAX_LENGTH]`
    /// (default [`DEFAULT_OUTLIER_TRANSLATION`]).
    pub translation_scale: f64,
    /// Half-width (radians) of its uniform rotation components, in
    /// `[0, π]`: wider components only repeat rotations already drawn
    /// (default [`DEFAULT_OUTLIER_ROTATION`]).
    pub rotation_scale: f64,
    /// Inlier-count model (default `Some(InlierModel::default())`); `None`
    /// leaves the counts of existing candidates alone and gives wrong
    /// candidates no count.
    pub inliers: Option<InlierModel>,
    /// The last this many existing non-sequential edges (in file order) are
    /// known to be wrong, as in the max-mixture outlier files whose last
    /// 1000 mixture edges are the injected outliers (default 0): they are
    /// labelled wrong and get counts like the appended wrong candidates.
    /// At most the number of non-sequential edges, checked by
    /// `corrupt`.
    pub known_wrong_last: usize,
    /// Share of the wrong candidates (appended and known-wrong) whose
    /// counts are drawn from the true-loop model, in `[0, 1]` (default 0),
    /// as [`SimulationOptions::true_like_share`].
    pub true_like_share: f64,
    /// As [`SimulationOptions::true_like_by_group`], for the appended
    /// groups.
    pub true_like_by_group: bool,
}

impl Default for CorruptionOptions {
    fn default() -> Self {
        Self {
            outliers: 100,
            policy: OutlierPolicy::Random,
            group_size: 10,
            alias_offsets: AliasOffsets::default(),
            alias_place: AliasPlace::Revisited,
            local_window: DEFAULT_LOCAL_WINDOW,
            translation_scale: DEFAULT_OUTLIER_TRANSLATION,
            rotation_scale: DEFAULT_OUTLIER_ROTATION,
            inliers: Some(InlierModel::default()),
            known_wrong_last: 0,
            true_like_share: 0.0,
            true_like_by_group: false,
        }
    }
}

impl CorruptionOptions {
    /// Checks every option against its range (see the fields), and the
    /// inlier model; `known_wrong_last` and the graph's room for wrong
    /// loops are checked against the graph by `corrupt`.
    pub fn validate(&self) -> Result<(), SimulationError> {
        within_count("outliers", self.outliers, 0, MAX_POSES)?;
        if self.group_size == 0 {
            return Err(SimulationError::ZeroGroupSize);
        }
        within_count("group_size", self.group_size, 1, MAX_POSES)?;
        self.alias_offsets.validate()?;
        within_count("local_window", self.local_window, 2, MAX_POSES)?;
        within("translation_scale", self.translation_scale, 0.0, MAX_LENGTH)?;
        within("rotation_scale", self.rotation_scale, 0.0, PI)?;
        validate_counts(self.inliers.as_ref(), self.true_like_share)
    }
}

/// Checks the inlier model and the share of true-like counts, which needs
/// a model to draw from.
fn validate_counts(
    model: Option<&InlierModel>,
    true_like_share: f64,
) -> Result<(), SimulationError> {
    within("true_like_share", true_like_share, 0.0, 1.0)?;
    match model {
        Some(model) => model.validate(),
        None if true_like_share > 0.0 => Err(SimulationError::InvalidOption {
            name: "true_like_share",
            value: true_like_share,
            requirement: "0 without an inlier model",
        }),
        None => Ok(()),
    }
}

/// `value` in `[min, max]` (so not NaN).
pub(super) fn within(
    name: &'static str,
    value: f64,
    min: f64,
    max: f64,
) -> Result<(), SimulationError> {
    if (min..=max).contains(&value) {
        Ok(())
    } else {
        Err(SimulationError::OutOfRange {
            name,
            value,
            min,
            max,
        })
    }
}

/// A count in `[min, max]`; the bounds are exact in `f64` (at most
/// [`MAX_POSES`]), and so is every value that the message shows in full.
pub(super) fn within_count(
    name: &'static str,
    value: usize,
    min: usize,
    max: usize,
) -> Result<(), SimulationError> {
    if (min..=max).contains(&value) {
        Ok(())
    } else {
        Err(SimulationError::OutOfRange {
            name,
            value: value as f64,
            min: min as f64,
            max: max as f64,
        })
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
