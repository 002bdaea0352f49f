//! The steps around the robust solve: the initial guess, the χ² test, the
//! report and the pictures.

use super::{OptimizeConfig, PipelineError};
use crate::graph::Graph;
use crate::io::g2o::G2oPose;
use crate::report::{InitializationReport, LoopReport, OptimizerReport, Report, RobustReport};
use crate::robust::{self, Candidate, Outcome, RobustMethod, Test};
use crate::solve::init::{ChordalInit, Initialization, initialize as init_poses};
use crate::solve::{
    Budget, Observer, Optimizer, PhaseTimes, Session, SolveError, SolverOptions, Summary,
};
use crate::stats::{Chi2Test, StatsError};
use std::path::Path;
use std::time::Instant;

/// Reports the file's own guess, then makes the configured initial guess
/// from the edges of non-zero `weights`, and checks that every edge of
/// weight 1 has a finite cost there. Returns the file's own guess (the
/// vertices without a line composed along a spanning tree).
pub fn initialize<P: G2oPose<D> + ChordalInit<D>, const D: usize>(
    graph: &mut Graph<P, D>,
    missing: &[usize],
    config: &OptimizeConfig,
    weights: &[f64],
    report: &mut Report,
    start: Instant,
) -> Result<Vec<P>, PipelineError> {
    let solve_error = |source| PipelineError::Solve {
        path: config.input.clone(),
        source,
    };
    // The file's own guess first (vertices without a line by spanning
    // tree), so that its χ² can be reported whatever the initialisation.
    init_poses(graph, missing, Initialization::File, Some(weights)).map_err(solve_error)?;
    report.input_chi2 = graph.chi2();
    if !report.input_chi2.is_finite() {
        report.warnings.push(format!(
            "the file's own guess has a non-finite χ² ({}; null in JSON)",
            report.input_chi2
        ));
    }
    let given = graph.poses.clone();
    if config.initialization != Initialization::File {
        init_poses(graph, missing, config.initialization, Some(weights)).map_err(solve_error)?;
    }
    // An edge whose cost overflows at the start makes the objective
    // meaningless: name it rather than report a bare non-finite objective.
    if let Some(k) = (0..graph.edges.len())
        .find(|&k| weights[k] != 0.0 && !graph.edge_chi2(&graph.edges[k]).is_finite())
    {
        let e = &graph.edges[k];
        return Err(PipelineError::NonFiniteEdge {
            path: config.input.clone(),
            edge: k + 1,
            from: graph.id(e.from),
            to: graph.id(e.to),
            initialization: config.initialization,
        });
    }
    report.initialization = InitializationReport {
        method: config.initialization,
        chi2: graph.chi2(),
        time_s: start.elapsed().as_secs_f64(),
        vertices_without_line: missing.len(),
    };
    Ok(given)
}

/// The robust solve (`method`: how the job weighs `candidates`, from
/// `weights`, with kernel width `c` and the χ² test EM's search acts on) within
/// the job's iteration and time budget, then the χ² test of the map it
/// returns and the report (`initial_chi2`: the objective it started from).
#[allow(clippy::too_many_arguments)]
pub fn solve_and_test<P: G2oPose<D>, const D: usize, M>(
    graph: &mut Graph<P, D>,
    optimizer: &mut Optimizer<P, D>,
    solver: SolverOptions,
    weights: &mut [f64],
    candidates: &[Candidate],
    kind: RobustMethod,
    method: M,
    config: &OptimizeConfig,
    report: &mut Report,
    observer: &mut dyn Observer,
) -> Result<(), PipelineError>
where
    M: FnOnce(
        &mut Session<'_, P, D>,
        &mut [f64],
        f64,
        &Test<'_, P, D>,
    ) -> Result<Outcome, SolveError>,
{
    // The caller's initialisation left the map whose χ² it reported.
    let initial_chi2 = report.initialization.chi2;
    let budget = Budget {
        iterations: config.iteration_budget.unwrap_or(usize::MAX),
        deadline: config.solver.time_limit.map(|t| Instant::now() + t),
    };
    let c = (config.robust_c).unwrap_or_else(|| robust::default_c(kind, D));
    let test = |g: &Graph<P, D>, w: &[f64]| chi2_test(g, w, config).ok();
    let mut session = Session::new(optimizer, graph, solver, budget, observer);
    let outcome =
        method(&mut session, weights, c, &test).map_err(|source| PipelineError::Solve {
            path: config.input.clone(),
            source,
        })?;
    let phases = session.phases();
    let summary = session.finish(outcome.cut_short);
    if graph.poses.iter().any(|p| !p.is_finite()) {
        return Err(PipelineError::NonFiniteResult {
            path: config.input.clone(),
        });
    }
    // One pass over the edges at the final map serves the test and the
    // report; the optimiser's last evaluation was usually that pass.
    let edge_chi2: std::borrow::Cow<'_, [f64]> = match optimizer.edge_chi2s_at(graph) {
        Some(chi2) => chi2.into(),
        None => graph.edge_chi2s().into(),
    };
    match test_of(&edge_chi2, graph, weights, config) {
        Ok(t) => report.chi2_test = Some(t),
        Err(e) => report.warnings.push(format!("no χ² test: {e}")),
    }
    if !outcome.accepted.is_empty() && !outcome.accepted.contains(&true) {
        report.warnings.push(format!(
            "none of the {} loop candidates was accepted: the map is that of the trusted edges \
             alone",
            outcome.accepted.len()
        ));
    }
    self::report(
        graph,
        optimizer,
        summary,
        (initial_chi2, sum(edge_chi2.iter().copied())),
        candidates,
        &outcome,
        kind,
        c,
        phases,
        report,
    );
    Ok(())
}

/// The χ² test over the edges the map was solved with (weight ≥ ½), each at
/// its plain cost (paper §II-C).
pub fn chi2_test<P: G2oPose<D>, const D: usize>(
    graph: &Graph<P, D>,
    weights: &[f64],
    config: &OptimizeConfig,
) -> Result<Chi2Test, StatsError> {
    test_of(&graph.edge_chi2s(), graph, weights, config)
}

/// [`chi2_test`] from each edge's χ² at the map (`edge_chi2`).
fn test_of<P: G2oPose<D>, const D: usize>(
    edge_chi2: &[f64],
    graph: &Graph<P, D>,
    weights: &[f64],
    config: &OptimizeConfig,
) -> Result<Chi2Test, StatsError> {
    let in_map = |k: usize| weights[k] >= 0.5;
    let used = (0..weights.len()).filter(|&k| in_map(k)).count();
    let d2 = sum((0..weights.len())
        .filter(|&k| in_map(k))
        .map(|k| edge_chi2[k]));
    let free = graph.num_vertices() - graph.gauge().len();
    let dof_residual = (used * D) as i64 - (free * D) as i64;
    Chi2Test::new(d2, used as u64, dof_residual, config.dof, config.alpha)
}

/// Fills the optimiser's, the robust back end's and every loop's part of
/// the report (`(initial_chi2, final_chi2)`: the χ² of every edge at the
/// start and at the map).
#[allow(clippy::too_many_arguments)]
pub fn report<P: G2oPose<D>, const D: usize>(
    graph: &Graph<P, D>,
    optimizer: &Optimizer<P, D>,
    summary: Option<Summary>,
    (initial_chi2, final_chi2): (f64, f64),
    candidates: &[Candidate],
    outcome: &Outcome,
    method: RobustMethod,
    c: f64,
    phases: PhaseTimes,
    report: &mut Report,
) {
    if let Some(summary) = &summary {
        report.optimizer = OptimizerReport::new(
            summary,
            initial_chi2,
            final_chi2,
            optimizer.system(),
            optimizer.max_nnz_factor(),
        );
    } else {
        // No solver run (a budget spent before the first): the map is the
        // one it started from.
        report.optimizer.initial_chi2 = initial_chi2;
        report.optimizer.final_chi2 = final_chi2;
    }
    let accepted = outcome.accepted.iter().filter(|&&a| a).count();
    report.robust = RobustReport {
        method,
        c,
        rounds: outcome.rounds,
        relaxations: outcome.relaxations,
        decisions: outcome.decisions,
        relaxed_starts: outcome.relaxed_starts,
        clusters: outcome.clusters,
        accepted_loops: accepted,
        rejected_loops: candidates.len() - accepted,
        rescued_loops: candidates
            .iter()
            .zip(&outcome.accepted)
            .filter(|(c, a)| **a && !c.kept)
            .count(),
        model: outcome.model.clone(),
        search: outcome.search.clone(),
        starts: outcome.starts.clone(),
    };
    report.time.relaxation_s = phases.relaxation.as_secs_f64();
    report.time.evaluation_s = phases.evaluation.as_secs_f64();
    report.loops = candidates
        .iter()
        .enumerate()
        .map(|(k, cand)| {
            let e = &graph.edges[cand.edge];
            LoopReport {
                from: graph.id(e.from),
                to: graph.id(e.to),
                inliers: e.candidate.and_then(|c| c.inliers),
                kept: cand.kept,
                accepted: outcome.accepted[k],
                weight: outcome.weights[k],
                prior: outcome
                    .model
                    .as_ref()
                    .map(|m| m.prior(cand.count_posterior)),
                posterior: outcome.posteriors[k],
                innovation: outcome.innovations[k],
                reason: outcome.reasons[k],
            }
        })
        .collect();
}

/// Writes `counts.svg` (when there are counts), `loops.svg` (when EM's
/// loop model decided) and `trajectory.svg` into `dir`, and lists them in
/// the report.
pub fn plot<P: G2oPose<D>, const D: usize>(
    dir: &Path,
    graph: &Graph<P, D>,
    before: &[[f64; 2]],
    weights: &[f64],
    config: &OptimizeConfig,
    report: &mut Report,
) -> Result<(), PipelineError> {
    use crate::plot::{LoopLine, plot_counts, plot_loops, plot_trajectory, top_view};
    std::fs::create_dir_all(dir).map_err(|source| PipelineError::Write {
        path: dir.to_owned(),
        source,
    })?;
    let counts: Vec<u64> = graph
        .edges
        .iter()
        .filter_map(|e| e.candidate.and_then(|c| c.inliers))
        .collect();
    if let (false, Some(fit)) = (counts.is_empty(), &report.gate.fit) {
        let path = dir.join("counts.svg");
        plot_counts(&path, &counts, fit)?;
        report.plots.push(path.display().to_string());
    }
    if let Some(model) = &report.robust.model {
        let path = dir.join("loops.svg");
        plot_loops(&path, &loop_points(report), model)?;
        report.plots.push(path.display().to_string());
    }
    let ids = graph.ids();
    let odometry: Vec<(usize, usize)> = graph
        .edges
        .iter()
        .filter(|e| e.candidate.is_none() && ids[e.from].abs_diff(ids[e.to]) == 1)
        .map(|e| (e.from, e.to))
        .collect();
    let loops: Vec<LoopLine> = graph
        .edges
        .iter()
        .enumerate()
        .filter(|(_, e)| e.candidate.is_some() || ids[e.from].abs_diff(ids[e.to]) != 1)
        .map(|(k, e)| LoopLine {
            from: e.from,
            to: e.to,
            weight: weights[k],
        })
        .collect();
    let title = config
        .input
        .file_name()
        .map_or_else(|| "pose graph".into(), |n| n.to_string_lossy().into_owned());
    let path = dir.join("trajectory.svg");
    plot_trajectory(
        &path,
        before,
        &top_view(&graph.poses),
        &odometry,
        &loops,
        &title,
    )?;
    report.plots.push(path.display().to_string());
    Ok(())
}

/// The candidates the loop model weighed, for its picture: those with an
/// innovation and a prior.
fn loop_points(report: &Report) -> Vec<crate::plot::LoopPoint> {
    (report.loops.iter())
        .filter_map(|l| {
            Some(crate::plot::LoopPoint {
                innovation: l.innovation?,
                prior: l.prior?,
                accepted: l.accepted,
            })
        })
        .collect()
}

/// A sum in the order given, from +0 ([`Graph::chi2_where`]'s bits).
fn sum(values: impl Iterator<Item = f64>) -> f64 {
    values.fold(0.0, |a, b| a + b)
}
