//! The steps of [`corrupt`](super::corrupt): placing wrong loops in an
//! existing graph, measuring them, and giving every candidate its count.

use super::counts::{sample_wrong_candidate, sample_wrong_group};
use super::noise::{ErrorCoordinates, perturb, sample_with_information};
use super::wrong::{WrongGroup, WrongLoopPlan, random_measurement, wrong_groups};
use super::{CorruptionOptions, SimulationError};
use crate::graph::{Graph, LoopCandidate};
use nalgebra::SMatrix;
use rand::Rng;

/// A wrong loop planned before the graph is touched: vertex indices,
/// measurement and information.
pub(super) type PlannedWrong<P, const D: usize> = (usize, usize, P, SMatrix<f64, D, D>);

/// The plan of the options' wrong loops.
pub(super) fn plan(options: &CorruptionOptions) -> WrongLoopPlan {
    WrongLoopPlan {
        count: options.outliers,
        policy: options.policy,
        group_size: options.group_size,
        local_window: options.local_window,
        alias_offsets: options.alias_offsets,
        alias_place: options.alias_place,
        translation_scale: options.translation_scale,
        rotation_scale: options.rotation_scale,
    }
}

/// Places the wrong loops between vertices that are neither consecutive in
/// index nor in id (aliased groups at one of the `revisits`, the vertex
/// pairs of the graph's true loops). An aliased vertex must be farther from the vertex it
/// stands in for than the median length of the sequential edges (one
/// typical step, on the graph's poses): nearer, it would be the same place.
pub(super) fn place<P: ErrorCoordinates<D>, const D: usize, R: Rng + ?Sized>(
    graph: &Graph<P, D>,
    plan: &WrongLoopPlan,
    sequential: &[bool],
    revisits: &[(usize, usize)],
    rng: &mut R,
) -> Result<Vec<WrongGroup>, SimulationError> {
    let ids = graph.ids();
    let position = |k: usize| graph.poses[k].position();
    let mut steps: Vec<f64> = (graph.edges.iter().zip(sequential))
        .filter(|(_, seq)| **seq)
        .map(|(e, _)| (position(e.from) - position(e.to)).norm())
        .collect();
    steps.sort_by(f64::total_cmp);
    let step = steps.get(steps.len() / 2).copied().unwrap_or(0.0);
    let consecutive = |i: usize, j: usize| ids[i].abs_diff(ids[j]) == 1;
    let distinct = |j: usize, t: usize| (position(j) - position(t)).norm() > step;
    wrong_groups(plan, ids.len(), revisits, consecutive, distinct, rng)
}

/// The measurements and information of the wrong loops: per group, the
/// information of a random edge of `sources`, then one random measurement
/// for the group, or for an aliased group the relative pose of the graph's
/// poses from `i` to the aliased vertex with noise drawn from that
/// information, per candidate.
pub(super) fn measure<P: ErrorCoordinates<D>, const D: usize, R: Rng + ?Sized>(
    graph: &Graph<P, D>,
    plan: &WrongLoopPlan,
    groups: &[WrongGroup],
    sources: &[usize],
    rng: &mut R,
) -> Result<Vec<PlannedWrong<P, D>>, SimulationError> {
    let mut planned = Vec::with_capacity(plan.count);
    for group in groups {
        let source = sources[rng.random_range(0..sources.len())];
        let information = graph.edges[source].information;
        let Some(alias) = &group.alias else {
            let measurement = random_measurement::<P, D, R>(plan, rng)?;
            planned.extend((group.pairs.iter()).map(|&(i, j)| (i, j, measurement, information)));
            continue;
        };
        // Noise needs information that can draw it: where the source's
        // cannot, another source's (files mix edges of all kinds).
        let mut information = information;
        let mut tries = 0;
        for (k, &(i, j)) in group.pairs.iter().enumerate() {
            let e = loop {
                if let Some(e) = sample_with_information::<P, D, R>(&information, rng) {
                    break e;
                }
                tries += 1;
                if tries >= sources.len() {
                    return Err(SimulationError::UnusableInformation { edge: source });
                }
                information = graph.edges[sources[rng.random_range(0..sources.len())]].information;
            };
            let exact = alias.exact(&graph.poses, k, (i, j));
            planned.push((i, j, perturb(&exact, &e), information));
        }
    }
    Ok(planned)
}

/// Makes every non-sequential edge a candidate: with a count from the
/// true-loop model, or for the known-wrong ones one drawn as for wrong
/// candidates, when there is a model; keeping its count (or giving none)
/// otherwise. Returns the number of candidates not known to be wrong.
pub(super) fn mark_candidates<P, const D: usize, R: Rng + ?Sized>(
    graph: &mut Graph<P, D>,
    options: &CorruptionOptions,
    sequential: &[bool],
    wrong: &[bool],
    rng: &mut R,
) -> usize {
    let mut marked = 0;
    for ((edge, &seq), &known_wrong) in graph.edges.iter_mut().zip(sequential).zip(wrong) {
        if seq {
            continue;
        }
        marked += usize::from(!known_wrong);
        edge.candidate = match (&options.inliers, edge.candidate) {
            (Some(model), _) => Some(LoopCandidate {
                inliers: Some(if known_wrong {
                    sample_wrong_candidate(model, options.true_like_share, rng)
                } else {
                    model.sample_true(rng)
                }),
            }),
            (None, Some(existing)) => Some(existing),
            (None, None) => Some(LoopCandidate { inliers: None }),
        };
    }
    marked
}

/// Appends the planned wrong loops (in the order of `groups`) as
/// candidates with counts drawn for wrong candidates (none without a
/// model), group by group.
pub(super) fn append<P: ErrorCoordinates<D>, const D: usize, R: Rng + ?Sized>(
    graph: &mut Graph<P, D>,
    planned: Vec<PlannedWrong<P, D>>,
    groups: &[WrongGroup],
    options: &CorruptionOptions,
    rng: &mut R,
) {
    let shares = (options.true_like_share, options.true_like_by_group);
    let counts: Vec<Option<u64>> = (groups.iter())
        .flat_map(|g| match &options.inliers {
            Some(model) => (sample_wrong_group(model, shares, g.pairs.len(), rng).into_iter())
                .map(Some)
                .collect(),
            None => vec![None; g.pairs.len()],
        })
        .collect();
    for ((from, to, measurement, information), inliers) in planned.into_iter().zip(counts) {
        let (from, to) = (graph.id(from), graph.id(to));
        let candidate = Some(LoopCandidate { inliers });
        graph.add_edge(from, to, measurement, information, candidate);
    }
}
