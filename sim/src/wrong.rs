//! Where wrong loop candidates go and what they measure: the placement
//! policies, the random wrong measurements and the offsets of aliases.

use super::SimulationError;
use super::options::{MAX_POSES, within_count};
use nalgebra::SVector;
use pgo::Pose;
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

/// Default smallest `|s|` of [`AliasOffsets`], in steps: several times the
/// loop radius of every world (1.5 steps on the grid), so that pose `j + s`
/// is another place than pose `j`, yet near enough along the path to look
/// alike.
pub const DEFAULT_ALIAS_OFFSET_MIN: usize = 5;

/// Default largest `|s|` of [`AliasOffsets`], in steps: a repeated
/// structure of tens of metres (a corridor, a row of parked cars) at the
/// 1 m steps of the grid world.
pub const DEFAULT_ALIAS_OFFSET_MAX: usize = 40;

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
    /// Perceptual aliasing: groups of consecutive pairs `(i+k, j+k)` whose
    /// measurements say that two places are one, one offset `s` per group
    /// (see [`AliasOffsets`]); where the groups fall is [`AliasPlace`].
    /// Groups of one are scattered aliases; longer groups are repeated
    /// structures (a corridor, a parking row).
    Aliased,
}

/// Where [`OutlierPolicy::Aliased`] groups fall.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum AliasPlace {
    /// Where a place was revisited: `(i, j)` a true loop of the graph,
    /// drawn at random (any pair when it has none); pair `k` measures the
    /// relative pose `Xᵢ₊ₖ⁻¹·Xⱼ₊ₖ₊ₛ` of the reference poses (plus the usual
    /// measurement noise): verification matched the repeated structure a
    /// few poses off, so the pose is correct for a place `s` steps away
    /// from `j + k`. A true loop beside every alias speaks against it.
    #[default]
    Revisited,
    /// Between any two places, most of them never revisited (two identical
    /// corridors on different floors, the same shop front on two streets):
    /// `(i, j)` any pair of distinct places, and the whole group says that
    /// the stretch from `j` is the stretch from `i + s`, moved rigidly:
    /// pair `k` measures `Xᵢ₊ₖ⁻¹·T·Xⱼ₊ₖ` with `T = Xᵢ₊ₛ·Xⱼ⁻¹`. The members
    /// agree with one another and with the odometry along the stretch;
    /// only the odometry joining `i` to `j` the long way speaks against
    /// them.
    Anywhere,
}

/// The offsets `s` of [`OutlierPolicy::Aliased`] candidates: `|s|` uniform
/// in `[min, max]` steps, either sign with probability ½.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct AliasOffsets {
    /// Smallest `|s|`, in `[1, max]` (default [`DEFAULT_ALIAS_OFFSET_MIN`]).
    pub min: usize,
    /// Largest `|s|`, in `[min, MAX_POSES]` (default
    /// [`DEFAULT_ALIAS_OFFSET_MAX`]).
    pub max: usize,
}

impl Default for AliasOffsets {
    fn default() -> Self {
        Self {
            min: DEFAULT_ALIAS_OFFSET_MIN,
            max: DEFAULT_ALIAS_OFFSET_MAX,
        }
    }
}

impl AliasOffsets {
    /// Checks `1 ≤ min ≤ max ≤ MAX_POSES` (an offset of zero would be a true
    /// loop).
    pub fn validate(&self) -> Result<(), SimulationError> {
        within_count("alias_offsets.min", self.min, 1, MAX_POSES)?;
        within_count("alias_offsets.max", self.max, self.min, MAX_POSES)
    }

    /// Draws an offset: `|s|`, then its sign.
    fn sample<R: Rng + ?Sized>(&self, rng: &mut R) -> isize {
        // Both bounds are at most MAX_POSES, far below isize::MAX.
        let magnitude = rng.random_range(self.min..=self.max) as isize;
        if rng.random_bool(0.5) {
            magnitude
        } else {
            -magnitude
        }
    }
}

/// What is needed to place wrong loops, shared by simulation and
/// corruption.
#[derive(Clone, Copy)]
pub(super) struct WrongLoopPlan {
    pub(super) count: usize,
    pub(super) policy: OutlierPolicy,
    pub(super) group_size: usize,
    pub(super) local_window: usize,
    pub(super) alias_offsets: AliasOffsets,
    pub(super) alias_place: AliasPlace,
    pub(super) translation_scale: f64,
    pub(super) rotation_scale: f64,
}

/// Consecutive wrong loops placed together.
#[derive(Clone, Debug, PartialEq, Eq)]
pub(super) struct WrongGroup {
    /// Vertex pairs `(i+k, j+k)`, `i < j`, `k = 0, 1, …`.
    pub(super) pairs: Vec<(usize, usize)>,
    /// The aliasing of an [`OutlierPolicy::Aliased`] group; `None` for the
    /// other policies, whose group shares one random measurement.
    pub(super) alias: Option<Alias>,
}

/// Where the candidates of an aliased group look.
#[derive(Clone, Debug, PartialEq, Eq)]
pub(super) struct Alias {
    /// The group's offset `s`.
    pub(super) offset: isize,
    /// What its pairs measure.
    pub(super) frame: AliasFrame,
}

/// What the pairs `(a, b)` of an aliased group measure.
#[derive(Clone, Debug, PartialEq, Eq)]
pub(super) enum AliasFrame {
    /// [`AliasPlace::Revisited`]: `targets[k] = j + k + s`, pair `k`
    /// measures the pose of this vertex from `i + k`.
    Targets(Vec<usize>),
    /// [`AliasPlace::Anywhere`]: every pair measures `Xₐ⁻¹·T·X_b` with
    /// `T = X_anchor·X_start⁻¹` (`anchor = i + s`, `start = j`).
    Rigid { anchor: usize, start: usize },
}

impl Alias {
    /// The exact measurement of the group's `k`-th pair `(a, b)` on the
    /// reference poses `poses`.
    pub(super) fn exact<P: Pose<D>, const D: usize>(
        &self,
        poses: &[P],
        k: usize,
        (a, b): (usize, usize),
    ) -> P {
        let from = poses[a].inverse();
        match &self.frame {
            AliasFrame::Targets(targets) => from.compose(&poses[targets[k]]),
            AliasFrame::Rigid { anchor, start } => from
                .compose(&poses[*anchor])
                .compose(&poses[*start].inverse())
                .compose(&poses[b]),
        }
    }
}

/// The vertex `j + s` when there is one among `vertices`.
pub(super) fn aliased_vertex(j: usize, s: isize, vertices: usize) -> Option<usize> {
    j.checked_add_signed(s).filter(|&t| t < vertices)
}

/// The groups of wrong loops of the plan (groups of one unless the policy
/// is [`OutlierPolicy::Grouped`] or [`OutlierPolicy::Aliased`]); aliased
/// groups start at one of the `revisits` (vertex pairs of true loops) when
/// there are any.
/// `consecutive(i, j)` says whether a pair is already joined by odometry
/// and must be avoided; `distinct(j, t)` whether vertex `t` is another
/// place than vertex `j`, which every aliased target `j + s` must be (and
/// it must not be `i`).
pub(super) fn wrong_groups<R: Rng + ?Sized>(
    plan: &WrongLoopPlan,
    vertices: usize,
    revisits: &[(usize, usize)],
    consecutive: impl Fn(usize, usize) -> bool,
    distinct: impl Fn(usize, usize) -> bool,
    rng: &mut R,
) -> Result<Vec<WrongGroup>, SimulationError> {
    let no_room = || SimulationError::NoRoomForOutliers {
        policy: plan.policy,
        vertices,
    };
    if plan.count == 0 {
        return Ok(Vec::new());
    }
    let group = match plan.policy {
        OutlierPolicy::Grouped | OutlierPolicy::Aliased => plan.group_size.max(1),
        OutlierPolicy::Random | OutlierPolicy::Local => 1,
    };
    // The largest group still needs two non-adjacent start vertices.
    if vertices < group.min(plan.count) + 2 {
        return Err(no_room());
    }
    let fits = |i: usize, j: usize, alias: Option<isize>, k: usize| {
        let (a, b) = (i + k, j + k);
        let aliased = |s: isize| match plan.alias_place {
            // The vertex b stands in for is another place than b, and not a.
            AliasPlace::Revisited => {
                aliased_vertex(b, s, vertices).is_some_and(|t| t != a && distinct(b, t))
            }
            // The stretch from j moves onto the one from i + s: j and i + s
            // are other places, and so are the pair's ends.
            AliasPlace::Anywhere => aliased_vertex(i, s, vertices)
                .is_some_and(|t| t != j && distinct(j, t) && distinct(a, b)),
        };
        b < vertices && a.abs_diff(b) >= 2 && !consecutive(a, b) && alias.is_none_or(aliased)
    };
    let mut groups = Vec::with_capacity(plan.count.div_ceil(group));
    let mut left = plan.count;
    while left > 0 {
        let len = group.min(left);
        let (i, j, alias) = (0..MAX_PAIR_ATTEMPTS)
            .map(|_| draw_group(plan, vertices, revisits, len, rng))
            .find(|&(i, j, alias)| (0..len).all(|k| fits(i, j, alias, k)))
            .ok_or_else(no_room)?;
        let pairs: Vec<(usize, usize)> = (0..len).map(|k| (i + k, j + k)).collect();
        let alias = alias.map(|offset| Alias {
            offset,
            frame: match plan.alias_place {
                AliasPlace::Revisited => AliasFrame::Targets(
                    (pairs.iter())
                        .filter_map(|&(_, b)| aliased_vertex(b, offset, vertices))
                        .collect(),
                ),
                AliasPlace::Anywhere => AliasFrame::Rigid {
                    anchor: i.saturating_add_signed(offset),
                    start: j,
                },
            },
        });
        groups.push(WrongGroup { pairs, alias });
        left -= len;
    }
    Ok(groups)
}

/// One draw of the first pair `(i, j)`, `i ≤ j`, of a group of `len` (and
/// of the offset of an aliased group, drawn first). `vertices ≥ len + 2`.
fn draw_group<R: Rng + ?Sized>(
    plan: &WrongLoopPlan,
    vertices: usize,
    revisits: &[(usize, usize)],
    len: usize,
    rng: &mut R,
) -> (usize, usize, Option<isize>) {
    let (i, j, alias) = match plan.policy {
        OutlierPolicy::Random | OutlierPolicy::Grouped => (
            rng.random_range(0..=vertices - len),
            rng.random_range(0..=vertices - len),
            None,
        ),
        OutlierPolicy::Local => {
            let d = rng.random_range(2..=plan.local_window.min(vertices - 1));
            let i = rng.random_range(0..vertices - d);
            (i, i + d, None)
        }
        OutlierPolicy::Aliased => {
            let s = plan.alias_offsets.sample(rng);
            let (i, j) = if revisits.is_empty() || plan.alias_place == AliasPlace::Anywhere {
                (
                    rng.random_range(0..=vertices - len),
                    rng.random_range(0..=vertices - len),
                )
            } else {
                revisits[rng.random_range(0..revisits.len())]
            };
            (i, j, Some(s))
        }
    };
    (i.min(j), i.max(j), alias)
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
