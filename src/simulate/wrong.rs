//! Where wrong loop candidates go and what they measure: the placement
//! policies and the random wrong measurements.

use super::SimulationError;
use crate::geometry::Pose;
use nalgebra::SVector;
use rand::Rng;
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

/// Default half-width (metres) of the uniform translation part of the
/// tangent vector of a wrong measurement.
pub const DEFAULT_OUTLIER_TRANSLATION: f64 = 3.0;

/// Default half-width (radians) of the uniform rotation part of the tangent
/// vector of a wrong measurement.
pub const DEFAULT_OUTLIER_ROTATION: f64 = PI;

/// Default largest index distance of a [`OutlierPolicy::Local`] wrong loop.
pub const DEFAULT_LOCAL_WINDOW: usize = 20;

/// Draws of a vertex pair before giving up on placing a wrong loop; only
/// graphs with almost no non-consecutive pairs come near it.
const MAX_PAIR_ATTEMPTS: usize = 10_000;

/// How wrong loop candidates are placed.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum OutlierPolicy {
    /// A random pair of non-consecutive vertices.
    Random,
    /// A pair at most a few steps apart (but not consecutive).
    Local,
    /// Groups of consecutive pairs `(i+k, j+k)` that all carry the same wrong
    /// relative transform: mutually consistent wrong loops, the hard case.
    Grouped,
}

/// What is needed to place wrong loops, shared by simulation and
/// corruption.
#[derive(Clone, Copy)]
pub(super) struct WrongLoopPlan {
    pub(super) count: usize,
    pub(super) policy: OutlierPolicy,
    pub(super) group_size: usize,
    pub(super) local_window: usize,
    pub(super) translation_scale: f64,
    pub(super) rotation_scale: f64,
}

/// Vertex pairs `(from, to)`, `from < to`, of the wrong loops, in groups
/// sharing one measurement (groups of one unless the policy is
/// [`OutlierPolicy::Grouped`]). `consecutive(i, j)` says whether a pair is
/// already joined by odometry and must be avoided.
pub(super) fn wrong_pairs<R: Rng + ?Sized>(
    plan: &WrongLoopPlan,
    vertices: usize,
    consecutive: impl Fn(usize, usize) -> bool,
    rng: &mut R,
) -> Result<Vec<Vec<(usize, usize)>>, SimulationError> {
    let no_room = || SimulationError::NoRoomForOutliers {
        policy: plan.policy,
        vertices,
    };
    if plan.count == 0 {
        return Ok(Vec::new());
    }
    let group = match plan.policy {
        OutlierPolicy::Grouped => plan.group_size.max(1),
        OutlierPolicy::Random | OutlierPolicy::Local => 1,
    };
    // The largest group still needs two non-adjacent start vertices.
    if vertices < group.min(plan.count) + 2 {
        return Err(no_room());
    }
    let acceptable = |i: usize, j: usize| i.abs_diff(j) >= 2 && !consecutive(i, j);
    let mut groups = Vec::with_capacity(plan.count.div_ceil(group));
    let mut left = plan.count;
    while left > 0 {
        let len = group.min(left);
        let mut placed = None;
        for _ in 0..MAX_PAIR_ATTEMPTS {
            let (i, j) = match plan.policy {
                OutlierPolicy::Random | OutlierPolicy::Grouped => (
                    rng.random_range(0..=vertices - len),
                    rng.random_range(0..=vertices - len),
                ),
                OutlierPolicy::Local => {
                    let d = rng.random_range(2..=plan.local_window.min(vertices - 1));
                    let i = rng.random_range(0..vertices - d);
                    (i, i + d)
                }
            };
            let (i, j) = (i.min(j), i.max(j));
            if (0..len).all(|k| acceptable(i + k, j + k)) {
                placed = Some((i, j));
                break;
            }
        }
        let (i, j) = placed.ok_or_else(no_room)?;
        groups.push((0..len).map(|k| (i + k, j + k)).collect());
        left -= len;
    }
    Ok(groups)
}

/// A random pose `P::exp(ξ)`, the translation components of `ξ` uniform in
/// `±translation_scale` and the rotation components in `±rotation_scale`.
pub(super) fn random_measurement<P: Pose<D>, const D: usize, R: Rng + ?Sized>(
    plan: &WrongLoopPlan,
    rng: &mut R,
) -> Result<P, SimulationError> {
    let translation_dims = translation_dims(D)?;
    let xi = SVector::<f64, D>::from_fn(|k, _| {
        let scale = if k < translation_dims {
            plan.translation_scale
        } else {
            plan.rotation_scale
        };
        scale * (2.0 * rng.random::<f64>() - 1.0)
    });
    Ok(P::exp(&xi))
}

/// The number `n` of translation components of SE(n), whose dimension is
/// `n(n+1)/2` (translation first, by the convention of [`Pose::exp`]).
pub(super) fn translation_dims(dimension: usize) -> Result<usize, SimulationError> {
    (1..=dimension)
        .find(|n| n * (n + 1) / 2 == dimension)
        .ok_or(SimulationError::UnsupportedDimension(dimension))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn translation_dims_are_those_of_se_n() {
        assert_eq!(translation_dims(3), Ok(2));
        assert_eq!(translation_dims(6), Ok(3));
        assert_eq!(
            translation_dims(4),
            Err(SimulationError::UnsupportedDimension(4))
        );
    }
}
