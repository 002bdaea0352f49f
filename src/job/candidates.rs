//! Which edges are loop candidates, what the gate makes of them, and which
//! edges the initial guess trusts.

use super::Settings;
use crate::gate::{self, DegeneratePolicy, GateMode};
use crate::geometry::Pose;
use crate::graph::{Graph, LoopCandidate, UnionFind};
use crate::options::CandidateRule;
use crate::report::{GateReport, Report};
use crate::robust::Candidate;

/// Under [`CandidateRule::NonSequential`], makes every edge between
/// non-consecutive ids a candidate (without a count unless it has one).
pub fn mark<P: Pose<D>, const D: usize>(graph: &mut Graph<P, D>, rule: CandidateRule) {
    if rule == CandidateRule::NonSequential {
        let ids: Vec<u64> = graph.ids().to_vec();
        for e in graph.edges.iter_mut() {
            if e.candidate.is_none() && ids[e.from].abs_diff(ids[e.to]) != 1 {
                e.candidate = Some(LoopCandidate { inliers: None });
            }
        }
    }
}

/// The gate: learns `T_GV` from the candidates' counts, reports it, and
/// returns every candidate with whether it passed and the posterior of the
/// true-loop count component (when the counts were fitted and the mode
/// uses them).
pub fn gate<P: Pose<D>, const D: usize>(
    graph: &Graph<P, D>,
    config: &Settings<'_>,
    report: &mut Report,
) -> Vec<Candidate> {
    let edges: Vec<usize> = (0..graph.edges.len())
        .filter(|&k| graph.edges[k].is_candidate())
        .collect();
    let counts: Vec<Option<u64>> = edges
        .iter()
        .map(|&k| graph.edges[k].candidate.and_then(|c| c.inliers))
        .collect();
    report.loop_candidates = edges.len();
    let decision = gate::gate(
        &counts,
        config.options.gate.mode,
        config.options.gate.degenerate,
        &config.mixture,
    );
    report.gate = GateReport::new(&decision, &counts);
    if decision.degenerate && report.gate.counted > 0 {
        if let Some(reason) = &decision.reason {
            report
                .warnings
                .push(degenerate_warning(reason, config.options.gate.degenerate));
        }
    }
    // The counts speak only through a fit that separates two populations,
    // and not when the gate is off; a zero count is no loop by definition.
    let max = report.gate.max_inliers;
    let mixture = decision.count_model();
    let drop_all =
        decision.degenerate && config.options.gate.degenerate == DegeneratePolicy::DropAll;
    edges
        .iter()
        .zip(&counts)
        .zip(&decision.kept)
        .filter(|((_, count), _)| !(drop_all && count.is_some()))
        .map(|((&edge, count), &kept)| Candidate {
            edge,
            count_posterior: match (count, mixture) {
                (Some(0), _) => Some(0.0),
                (Some(n), Some(m)) => Some(m.posterior_true_loop(*n, max)),
                _ => None,
            },
            kept: kept || config.options.gate.mode == GateMode::Soft,
        })
        .collect()
}

fn degenerate_warning(reason: &impl std::fmt::Display, policy: DegeneratePolicy) -> String {
    format!(
        "the inlier counts are degenerate: {reason}; policy {}: {}",
        policy.name(),
        match policy {
            DegeneratePolicy::DropAll =>
                "every counted candidate dropped, the trusted edges optimised alone",
            DegeneratePolicy::KeepAll =>
                "every candidate with a non-zero count kept, left to the robust back end",
            DegeneratePolicy::Threshold => "the crossing used anyway where there is one",
        }
    )
}

/// The weights of the initial guess: 1 for the trusted edges and, when
/// they are to be `trusted` as they are (no robust method), the candidates
/// that passed the gate; 0 for the others (a wrong loop in the chordal
/// problem bends the whole map) — except that where
/// those do not join a part of the map to the gauge (the sessions of a
/// multi-session map joined by dropped candidates), the most credible
/// candidate joining each part (the highest count posterior, then file
/// order) has weight 1, so that every part starts where its loops put it.
pub fn initial_weights<P: Pose<D>, const D: usize>(
    graph: &Graph<P, D>,
    candidates: &[Candidate],
    trusted: bool,
) -> Vec<f64> {
    let mut weights = vec![1.0; graph.edges.len()];
    for c in candidates {
        weights[c.edge] = if c.kept && trusted { 1.0 } else { 0.0 };
    }
    let mut order: Vec<&Candidate> = candidates.iter().collect();
    order.sort_by(|a, b| {
        let credit = |c: &Candidate| (c.kept, c.count_posterior.unwrap_or(0.5));
        let (ka, pa) = credit(a);
        let (kb, pb) = credit(b);
        kb.cmp(&ka).then(pb.total_cmp(&pa))
    });
    // Union-find over the trusted edges, then the candidates in that order
    // join what is still apart.
    let mut parts = UnionFind::new(graph.num_vertices());
    for (k, e) in graph.edges.iter().enumerate() {
        if weights[k] > 0.0 {
            parts.union(e.from, e.to);
        }
    }
    for c in order {
        let e = &graph.edges[c.edge];
        if c.count_posterior != Some(0.0) && parts.union(e.from, e.to) {
            weights[c.edge] = 1.0;
        }
    }
    weights
}
