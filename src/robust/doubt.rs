//! Accepted clusters the map cannot vouch for: what a place mistaken for
//! another looks like once the decisions have accepted it.
//!
//! A stretch of the map said to be another place (perceptual aliasing: two
//! identical corridors, a car park's rows) gives a cluster of loops that
//! all err by about one offset — the distance between the two places, in
//! each member's frame. When nothing else ties those places, the map bends
//! to fit the cluster, its members' innovations stay moderate, the loop
//! model holds them true and the χ² test passes: the evidence the
//! decisions weigh cannot tell it from a true cluster (docs/method.md §7).
//! Two things still set it apart:
//!
//! * its errors share one offset beyond what its members' independent
//!   noise gives: at the map, with `S` the covariance of the members'
//!   errors `e_A`, the share of `e_Aᵀ·S⁻¹·e_A` one common offset explains
//!   (`D` degrees of freedom) against the rest (`D·(a − 1)`) is an F
//!   statistic, whatever the scale of the file's information;
//! * the map leans on that offset: without it in the members' errors the
//!   map would move by `δ = H⁻¹·J_Aᵀ·S⁻¹·U·b̂` (`b̂` the offset, `U` the
//!   stacked identities; the part of the move without the cluster,
//!   `H⁻¹·J_Aᵀ·S⁻¹·e_A` of [`super::innovation`], that the offset makes),
//!   and some pose by more than [`DOUBT_MOVE`] of the map's size.
//!
//! True clusters of real maps also share offsets (a scan matcher's bias in
//! one place: on the public files behind docs/benchmarks.md, F tests at
//! `p` 10⁻¹⁶ among them), but what such an offset does to the map is
//! small; an alias group's offset is what bends the map. A cluster that
//! does both is *doubtful*: the map is kept — the decisions and the χ²
//! test hold it — and the report names the cluster, with the move its
//! offset makes, for a person or the front end to check.
//!
//! The other way round, true loops can be *held back*: rejected although
//! their innovations speak for a true loop (the likelihood ratio of the
//! innovation alone above 1), because their inlier counts look like a
//! wrong loop's. The gate's count model is fitted to what may be a few
//! dozen counts, and a narrow true-loop component can put a true loop's
//! modest count at a posterior of 10⁻⁷; where the map's odometry is loose
//! the innovation cannot outweigh that. Such candidates of one cluster are
//! named when adding them would move the map, to first order (a Kalman
//! update, [`Evaluation::adding`]), by more than [`DOUBT_MOVE`] of its
//! size: the map then rests on the counts alone.
//!
//! And an accepted loop can be *outlying*: its innovation beyond what the
//! map's true loops reach, though the likelihood ratio favours a true loop
//! there because the wrong loops' population lies further out still. If
//! the `K` accepted loops are all true, their log innovations are `K`
//! draws from the true loops' fitted density, and the largest has an
//! upper tail below `α / K` with a chance of at most `α` (the χ² test's;
//! [`LoopModel::beyond_reach`]). The decisions reject such a loop
//! themselves where its `ν²` exceeds its information's mean
//! ([`super::schedule::verdict`]); below that — the map's true loops far
//! tighter than their information — this check names it. Aliases the map
//! bent to fit widen that density around themselves, so an accepted loop
//! is outlying too where the information — its `χ²_D` shape, on the
//! scale the true loops show — calls it an outlier at the same level and
//! the fitted density expects fewer than one true loop as far out
//! ([`LoopModel::beyond_stated`]); either test alone names true loops of
//! real maps. Those of one cluster are named when removing them would
//! move the map, to first order (the deleted residuals' move,
//! [`Evaluation::removing`]), by more than [`DOUBT_MOVE`] of its size.
//!
//! Last, the map's *keystone*: the accepted cluster whose removal would
//! move it most, to first order, where that is more than
//! [`KEYSTONE_MOVE`] of its size. On a map with few loops every true
//! cluster holds a stretch of it, and so does a group of aliases that
//! bent it: a settled, passing end can rest on an alias that keeps the
//! true loops of the place it hides out (their innovations at the bent
//! map beyond EM's kernel). [`super::starts::recheck`] tries the end
//! without it.
//!
//! Only a passing map whose decisions settled is examined (docs/method.md
//! §7).

use super::clusters;
use super::innovation::{Evaluation, Innovations};
use super::model::LoopModel;
use super::{Candidate, Layers};
use crate::geometry::Pose;
use crate::graph::Graph;
use crate::solve::{Session, SolveError};
use serde::Serialize;
use statrs::distribution::{ContinuousCDF, FisherSnedecor};

/// A doubtful cluster's offset moves some pose by more than this share
/// of the map's size (the diagonal of its positions' bounding box).
/// Measured over every labelled file of docs/benchmarks.md's outlier and
/// aliasing sweeps (483 files, docs/method.md §7): of the accepted
/// clusters whose offset stands out at the test's level, the true ones'
/// offsets move their maps by at most 0.78 % (a run of 26–32 loops
/// between two rings of sphere2500, in every sphere2500 file), the alias
/// groups' by 1.41 % to 9.79 %. At 0.5 %, the benchmarks' goal for a
/// map's error, that true run would warn on every sphere2500 map.
pub const DOUBT_MOVE: f64 = 0.01;

/// An accepted loop the outlying check flags (module doc) whose removal
/// would move the map by more than this share of its size, but not by
/// [`DOUBT_MOVE`], is not named, but EM's decisions are tried without it
/// and the end that ranks first kept ([`super::starts::recheck`]): 0.5 %,
/// the benchmarks' goal for a map's error (docs/benchmarks.md), as a loop
/// that moves the map less leaves it within that goal either way. Over
/// 584 labelled runs (docs/method.md §7, "Flagged, below the warning")
/// the ends without such loops that rank first hold 11 aliases fewer and
/// 37 true loops fewer, those of kitti_00 moving the map by 0.011 %;
/// without the floor, 287 true loops fewer for 10 aliases over 152 runs.
pub const RECHECK_MOVE: f64 = 0.005;

/// A keystone's removal moves some pose by more than this share of the
/// map's size (module doc). Measured over 572 labelled runs
/// (docs/method.md §7, "A keystone"): the largest move a single accepted
/// cluster's removal makes is at most 2.2 % on every map but MIT, and
/// 12.7 % to 57 % on MIT (20 true loops in 808 poses), whose true
/// clusters hold it up one by one; a tenth of the map lies in that gap.
/// Below it, a wrong cluster is answered by EM's decisions and the
/// checks above at [`DOUBT_MOVE`].
pub const KEYSTONE_MOVE: f64 = 0.1;

/// The most clusters whose moves are solved for in the search for a
/// keystone: those whose moves are largest in the map's own metric
/// (`gᵀ·H⁻¹·g`, [`Evaluation::removing`]), solved in one pass over the
/// factor. Every cluster of a map with as few loops as MIT's (13–14
/// accepted clusters) is solved for; on a map with thousands the pass
/// costs about what 32 more solves of the map do.
pub const KEYSTONE_CANDIDATES: usize = 32;

/// An accepted cluster whose errors share one offset and that moves the
/// map (module doc).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Doubt {
    /// Its candidates the map was solved with (indices among the loop
    /// candidates).
    pub loops: Vec<usize>,
    /// The F statistic of one offset common to every member against their
    /// independent errors (`D` and `D·(loops − 1)` degrees of freedom).
    pub common_offset_f: f64,
    /// Its p-value; a cluster is doubtful below the test's α over the
    /// clusters tested.
    pub p_value: f64,
    /// The largest move of a pose's position that the common offset makes
    /// (to first order), as a share of the map's size.
    pub map_moves: f64,
}

/// Candidates of one cluster held back by their counts (module doc).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct HeldBack {
    /// The candidates (indices among the loop candidates), all rejected,
    /// each with an innovation whose likelihood ratio speaks for a true
    /// loop.
    pub loops: Vec<usize>,
    /// The largest move of a pose's position that adding them would make
    /// (to first order), as a share of the map's size.
    pub map_moves: f64,
}

/// Accepted candidates of one cluster whose innovations lie beyond what
/// the true loops reach, and that move the map (module doc).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Outlying {
    /// The candidates (indices among the loop candidates), all accepted.
    pub loops: Vec<usize>,
    /// The chance that some true loop among the accepted candidates tested
    /// has an innovation as large as the largest of these: their least
    /// upper-tail probability under the true loops' fitted density, or
    /// where that names none of them under the information (`stated`),
    /// times the candidates tested; below the χ² test's α.
    pub p_value: f64,
    /// Whether only the information's tail names them (`χ²_D` on the true
    /// loops' own scale, [`LoopModel::beyond_stated`]), not the true loops'
    /// fitted density.
    pub stated: bool,
    /// The largest move of a pose's position that removing them would make
    /// (to first order), as a share of the map's size.
    pub map_moves: f64,
}

/// A cluster's errors at a map, its members in the map: the joint
/// statistic and the share of it one common offset explains
/// ([`super::innovation::CommonOffset`]), as the decisions' own evaluation
/// found them.
#[derive(Clone, Debug)]
pub struct Offset {
    /// Its candidates the map was solved with.
    pub loops: Vec<usize>,
    /// `e_Aᵀ·S⁻¹·e_A`.
    pub joint: f64,
    /// The common offset's share of it.
    pub common: f64,
}

/// Every cluster's [`Offset`] from an evaluation `innov` of `clusters`, for
/// the clusters with two or more members in the map; `None` unless the
/// evaluation judged the set `accepted` (then the doubts are found afresh).
pub fn offsets(
    innov: &Innovations,
    clusters: &[Vec<usize>],
    accepted: &[bool],
) -> Option<Vec<Offset>> {
    if innov.accepted != accepted || innov.common.len() != clusters.len() {
        return None;
    }
    let tested = (clusters.iter().zip(&innov.joint).zip(&innov.common))
        .filter_map(|((members, &joint), &common)| {
            let loops: Vec<usize> = members.iter().copied().filter(|&k| accepted[k]).collect();
            (loops.len() >= 2).then_some((loops, joint?, common?))
        })
        .map(|(loops, joint, common)| Offset {
            loops,
            joint,
            common,
        });
    Some(tested.collect())
}

/// The doubtful clusters (module doc) of the map in the session's graph,
/// solved with the edges of non-zero `weights`, among the clusters of two
/// or more `accepted` candidates; `alpha` is the χ² test's. `known`: their
/// [`Offset`]s at this map, from the decisions' last evaluation, when it
/// judged this set (only the clusters whose offset stands out are then
/// evaluated again, for the map's move); otherwise every cluster is
/// evaluated. Empty where the clusters layer is off (every candidate its
/// own cluster).
pub fn doubtful<P: Pose<D>, const D: usize>(
    session: &mut Session<'_, P, D>,
    weights: &[f64],
    (candidates, accepted): (&[Candidate], &[bool]),
    (layers, alpha): (&Layers, f64),
    known: Option<&[Offset]>,
) -> Result<Vec<Doubt>, SolveError> {
    let graph = &*session.graph;
    let size = graph.extent();
    if !layers.clusters || size <= 0.0 {
        return Ok(Vec::new());
    }
    let edges: Vec<usize> = candidates.iter().map(|c| c.edge).collect();
    let tested: Vec<Vec<usize>> = match known {
        Some(known) => known.iter().map(|o| o.loops.clone()).collect(),
        None => (clusters::of_edges(graph, &edges).into_iter())
            .map(|c| c.into_iter().filter(|&k| accepted[k]).collect::<Vec<_>>())
            .filter(|c| c.len() >= 2)
            .collect(),
    };
    let level = alpha / tested.len().max(1) as f64;
    // With the offsets known, only those that stand out are evaluated.
    let evaluated: Vec<Vec<usize>> = match known {
        Some(known) => (known.iter())
            .filter(|o| offset_test(o.joint, o.common, (D, o.loops.len())).1 < level)
            .map(|o| o.loops.clone())
            .collect(),
        None => tested,
    };
    if evaluated.is_empty() {
        return Ok(Vec::new());
    }
    let mut eval =
        Evaluation::for_clusters(session.optimizer, graph, weights, (&edges, &evaluated))?;
    let mut doubts = Vec::new();
    for members in evaluated {
        let Some(offset) = eval.common_offset(&edges, &members) else {
            continue;
        };
        let (f, p_value) = offset_test(offset.joint, offset.common, (D, offset.members));
        if p_value >= level {
            continue;
        }
        let map_moves = eval.largest_move(offset.gradient()) / size;
        if map_moves > DOUBT_MOVE {
            doubts.push(Doubt {
                loops: members,
                common_offset_f: f,
                p_value,
                map_moves,
            });
        }
    }
    Ok(doubts)
}

/// The candidates held back by their counts (module doc) of the map in the
/// session's graph, solved with the edges of non-zero `weights`: of the
/// candidates `held` marks (rejected, their innovations speaking for a
/// true loop), those of each cluster together whose addition would move
/// the map by more than [`DOUBT_MOVE`] of its size. With the clusters
/// layer off, each candidate alone.
pub fn held_back<P: Pose<D>, const D: usize>(
    session: &mut Session<'_, P, D>,
    weights: &[f64],
    (candidates, held): (&[Candidate], &[bool]),
    layers: &Layers,
) -> Result<Vec<HeldBack>, SolveError> {
    let graph = &*session.graph;
    let size = graph.extent();
    if size <= 0.0 || !held.contains(&true) {
        return Ok(Vec::new());
    }
    let edges: Vec<usize> = candidates.iter().map(|c| c.edge).collect();
    let groups = of_clusters(graph, &edges, held, layers.clusters);
    let mut eval = Evaluation::for_clusters(session.optimizer, graph, weights, (&edges, &groups))?;
    let mut held_back = Vec::new();
    for loops in groups {
        let Some(g) = eval.adding(&edges, &loops) else {
            continue;
        };
        let map_moves = eval.largest_move(&g) / size;
        if map_moves > DOUBT_MOVE {
            held_back.push(HeldBack { loops, map_moves });
        }
    }
    Ok(held_back)
}

/// The outlying candidates (module doc) of the map in the session's graph,
/// solved with the edges of non-zero `weights`: of the `accepted`
/// candidates with an innovation (`nu2`), `K` of them, those whose upper
/// tail under the true loops' density of `model` is below `alpha / K`
/// (the χ² test's α over the candidates tested), or under the information
/// on the true loops' own scale where that density expects fewer than one
/// as far out ([`LoopModel::beyond_stated`]), outside the clusters
/// already named `doubtful`; of each cluster together (each alone with the
/// clusters layer off), those whose removal would move the map by more
/// than [`DOUBT_MOVE`] of its size. Second, the flagged clusters whose
/// removal would move it by more than [`RECHECK_MOVE`] but not
/// [`DOUBT_MOVE`]: too little to warn, enough for the end without them to
/// be tried ([`super::starts::recheck`]).
pub fn outlying<P: Pose<D>, const D: usize>(
    session: &mut Session<'_, P, D>,
    weights: &[f64],
    (candidates, accepted): (&[Candidate], &[bool]),
    (nu2, model): (&[Option<f64>], &LoopModel),
    (layers, alpha, doubtful): (&Layers, f64, &[Doubt]),
) -> Result<(Vec<Outlying>, Vec<Vec<usize>>), SolveError> {
    let graph = &*session.graph;
    let size = graph.extent();
    let tested: Vec<(usize, f64)> = (0..candidates.len())
        .filter(|&k| accepted[k])
        .filter_map(|k| nu2[k].filter(|&v| v > 0.0).map(|v| (k, v)))
        .collect();
    let named: Vec<usize> = doubtful.iter().flat_map(|d| d.loops.clone()).collect();
    // Each candidate's tail: the fitted one where that names it, else the
    // information's, and whether it is the information's.
    let mut p_value = vec![(1.0, false); candidates.len()];
    for (k, p) in model.beyond_reach(&tested, alpha) {
        p_value[k] = (p, false);
    }
    for (k, p) in model.beyond_stated(&tested, alpha) {
        if p_value[k].0 >= alpha {
            p_value[k] = (p, true);
        }
    }
    for &k in &named {
        p_value[k] = (1.0, false);
    }
    let flagged: Vec<bool> = p_value.iter().map(|&(p, _)| p < alpha).collect();
    if size <= 0.0 || !flagged.contains(&true) {
        return Ok((Vec::new(), Vec::new()));
    }
    let edges: Vec<usize> = candidates.iter().map(|c| c.edge).collect();
    let groups = of_clusters(graph, &edges, &flagged, layers.clusters);
    let mut eval = Evaluation::for_clusters(session.optimizer, graph, weights, (&edges, &groups))?;
    let (mut outlying, mut below_warning) = (Vec::new(), Vec::new());
    for loops in groups {
        let Some((g, _)) = eval.removing(&edges, &loops) else {
            continue;
        };
        let map_moves = eval.largest_move(&g) / size;
        let (p_value, stated) = (loops.iter().map(|&k| p_value[k]))
            .fold((1.0, false), |a, b| if b.0 < a.0 { b } else { a });
        log::debug!(
            "outlying loops {loops:?}: p = {p_value:.2e}, removing them moves the map by {:.2} %",
            100.0 * map_moves
        );
        if map_moves > DOUBT_MOVE {
            outlying.push(Outlying {
                loops,
                p_value,
                stated,
                map_moves,
            });
        } else if map_moves > RECHECK_MOVE {
            below_warning.push(loops);
        }
    }
    Ok((outlying, below_warning))
}

/// The accepted members of each cluster with the squared size of the move
/// the map would make without them, in its own metric (`gᵀ·H⁻¹·g`,
/// [`Evaluation::removing`]), and the largest trace of a pose's block of
/// `H⁻¹` ([`Evaluation::largest_marginal`]): what bounds each move
/// ([`keystone`]).
#[derive(Clone, Debug)]
pub struct Moves {
    clusters: Vec<(Vec<usize>, f64)>,
    spread: f64,
}

/// The [`Moves`] of the clusters with members in the map, from an
/// evaluation `innov` of `clusters` that held the selected inverse; `None`
/// unless it judged the set `accepted`.
pub fn moves(innov: &Innovations, clusters: &[Vec<usize>], accepted: &[bool]) -> Option<Moves> {
    if innov.accepted != accepted || innov.moves.len() != clusters.len() {
        return None;
    }
    let spread = innov.spread?;
    let sized = (clusters.iter().zip(&innov.moves))
        .filter_map(|(members, &q)| {
            let loops: Vec<usize> = members.iter().copied().filter(|&k| accepted[k]).collect();
            Some((loops, q?))
        })
        .collect();
    Some(Moves {
        clusters: sized,
        spread,
    })
}

/// The keystone (module doc) of the map in the session's graph, solved
/// with the edges of non-zero `weights`: of the clusters of `accepted`
/// candidates (each alone with the clusters layer off), the one whose
/// removal would move the map most, to first order (the deleted
/// residuals' move, [`Evaluation::removing`]), where that is more than
/// [`KEYSTONE_MOVE`] of the map's size. Only the clusters whose move's
/// bound reaches that are solved for ([`Evaluation::largest_marginal`]),
/// the [`KEYSTONE_CANDIDATES`] of the largest moves in the map's metric:
/// from `known`, the decisions' evaluation of this map, where given —
/// then a map no cluster can move that far is not factorised again.
pub fn keystone<P: Pose<D>, const D: usize>(
    session: &mut Session<'_, P, D>,
    weights: &[f64],
    (candidates, accepted): (&[Candidate], &[bool]),
    layers: &Layers,
    known: Option<&Moves>,
) -> Result<Option<Vec<usize>>, SolveError> {
    let graph = &*session.graph;
    let size = graph.extent();
    if size <= 0.0 || !accepted.contains(&true) {
        return Ok(None);
    }
    let reach = KEYSTONE_MOVE * size;
    let edges: Vec<usize> = candidates.iter().map(|c| c.edge).collect();
    // The clusters to solve for, and the evaluation that solves them.
    let (tried, mut eval) = match known {
        Some(known) => {
            let tried = largest_first(known.clusters.clone(), known.spread, reach);
            if tried.is_empty() {
                return Ok(None);
            }
            let eval =
                Evaluation::for_clusters(session.optimizer, graph, weights, (&edges, &tried))?;
            (tried, eval)
        }
        None => {
            let groups = of_clusters(graph, &edges, accepted, layers.clusters);
            let eval =
                Evaluation::for_clusters(session.optimizer, graph, weights, (&edges, &groups))?;
            let sized = (groups.into_iter())
                .filter_map(|loops| Some((eval.removing(&edges, &loops)?.1, loops)))
                .map(|(q, loops)| (loops, q))
                .collect();
            let spread = eval.largest_marginal().unwrap_or(f64::INFINITY);
            (largest_first(sized, spread, reach), eval)
        }
    };
    let (tried, gradients): (Vec<Vec<usize>>, Vec<Vec<f64>>) = (tried.into_iter())
        .filter_map(|loops| Some((loops.clone(), eval.removing(&edges, &loops)?.0)))
        .unzip();
    let moves = eval.largest_moves(&gradients);
    let best = (tried.into_iter().zip(moves))
        .filter(|(_, m)| *m > reach)
        .max_by(|a, b| a.1.total_cmp(&b.1));
    if let Some((loops, m)) = &best {
        log::debug!(
            "keystone {loops:?}: removing it moves the map by {:.1} %",
            100.0 * m / size
        );
    }
    Ok(best.map(|(loops, _)| loops))
}

/// Of clusters with the squared sizes `q` of their moves in the map's
/// metric, those whose bound `√(q·spread)` exceeds `reach`, the
/// [`KEYSTONE_CANDIDATES`] of the largest `q` first.
fn largest_first(mut sized: Vec<(Vec<usize>, f64)>, spread: f64, reach: f64) -> Vec<Vec<usize>> {
    sized.retain(|(_, q)| (q * spread).sqrt() > reach);
    sized.sort_by(|a, b| b.1.total_cmp(&a.1));
    sized.truncate(KEYSTONE_CANDIDATES);
    sized.into_iter().map(|(loops, _)| loops).collect()
}

/// The candidates `marked` grouped by their clusters among the candidates
/// `edges` of `graph`, or each alone without the clusters layer.
fn of_clusters<P: Pose<D>, const D: usize>(
    graph: &Graph<P, D>,
    edges: &[usize],
    marked: &[bool],
    clusters: bool,
) -> Vec<Vec<usize>> {
    if clusters {
        (clusters::of_edges(graph, edges).into_iter())
            .map(|c| c.into_iter().filter(|&k| marked[k]).collect::<Vec<_>>())
            .filter(|c| !c.is_empty())
            .collect()
    } else {
        (0..marked.len())
            .filter(|&k| marked[k])
            .map(|k| vec![k])
            .collect()
    }
}

/// The F statistic of one offset shared by `members` errors of dimension
/// `dim` (`common` of their `joint` statistic, the rest independent) and
/// its p-value; `(∞, 0)` when the offset explains all of it.
fn offset_test(joint: f64, common: f64, (dim, members): (usize, usize)) -> (f64, f64) {
    let (d1, d2) = (dim as f64, (dim * (members - 1)) as f64);
    let rest = joint - common;
    if rest <= 0.0 {
        return if common > 0.0 {
            (f64::INFINITY, 0.0)
        } else {
            (0.0, 1.0)
        };
    }
    let f = (common / d1) / (rest / d2);
    let p = FisherSnedecor::new(d1, d2).map_or(1.0, |dist| dist.sf(f));
    (f, p)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_offset_that_explains_little_is_no_doubt() {
        // Ten 3-D members, joint 30 of which the offset explains its 3 dof's
        // worth: F = 1.
        let (f, p) = offset_test(30.0, 3.0, (3, 10));
        assert!((f - 1.0).abs() < 1e-12, "{f}");
        assert!(p > 0.3 && p < 0.5, "{p}");
    }

    #[test]
    fn an_offset_that_explains_most_is_significant() {
        // MIT's alias group of docs/method.md §7: 35.9 of 46.5 on 30 dof.
        let (f, p) = offset_test(46.5, 35.9, (3, 10));
        assert!((f - 30.49).abs() < 0.01, "{f}");
        assert!(p < 1e-7, "{p}");
        assert_eq!(offset_test(5.0, 5.0, (3, 2)), (f64::INFINITY, 0.0));
        assert_eq!(offset_test(0.0, 0.0, (3, 2)), (0.0, 1.0));
    }
}
