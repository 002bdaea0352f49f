//! The steps around the robust solve: the initial guess, the χ² test, the
//! report and the pictures.

use super::{Error, Settings};
use crate::geometry::Pose;
use crate::graph::Graph;
use crate::io::g2o::G2oPose;
use crate::report::{InitializationReport, LoopReport, OptimizerReport, Report, RobustReport};
use crate::robust::{
    self, Candidate, Doubt, HeldBack, Outcome, Outlying, Reason, RobustMethod, Test,
};
use crate::solve::init::{ChordalInit, Initialization, initialize as init_poses};
use crate::solve::{
    Budget, Observer, Optimizer, PhaseTimes, Session, SolveError, SolveSettings, Summary,
};
use crate::stats::{Chi2Test, StatsError};
use std::time::Instant;

/// The largest move of a position, as a share of the map's size (the
/// diagonal of its positions' bounding box), of a chord step that ends an
/// update's solve, and how far a batch job's last solve may leave the
/// poses from the optimum before it is carried on
/// ([`SolveSettings::end_step`], [`end_step`]; with [`END_STEP_TURN`] for
/// the rotations). An update promises positions within 10⁻⁶ of that size
/// and rotations within 10⁻⁶ rad of the batch job's. Replaying
/// manhattanOlson3500 every pose (`examples/replay FILE 1 --gap-every 1`,
/// every update compared with a batch job) with any chord step allowed
/// to end a solve, 150 of 3,500 updates left positions more than 10⁻⁶ of
/// the size from the batch job's (up to 2.6·10⁻⁵) and 244 rotations more
/// than 10⁻⁶ rad (up to 1.3·10⁻⁴); every 10 poses, 50 and 80 of 350. Over
/// the 1,362 updates that ended on a chord step the positions were left
/// up to 2.7 times the step's largest move from the batch job's (median
/// 1.1): a fifth of the promise keeps them within it.
pub const END_STEP_SHARE: f64 = 2e-7;

/// The largest turn of a rotation, in radians, of a chord step that ends
/// an update's solve (see [`END_STEP_SHARE`]). The turn bound is the
/// promise itself: at 5·10⁻⁶ rad, city10000's updates every 10 poses
/// ended up to 1.9·10⁻⁶ rad from the batch job's (21 of the 200 compared
/// over 10⁻⁶); at 10⁻⁶ rad, within 6·10⁻⁷, and manhattanOlson3500's every
/// pose within 4.4·10⁻⁷.
pub const END_STEP_TURN: f64 = 1e-6;

/// The bound on the last step of a map returned, `(translation,
/// rotation)`: [`END_STEP_SHARE`] of `graph`'s size (at least 1) and
/// [`END_STEP_TURN`].
pub(crate) fn end_step<P: Pose<D>, const D: usize>(graph: &Graph<P, D>) -> (f64, f64) {
    (END_STEP_SHARE * graph.extent().max(1.0), END_STEP_TURN)
}

/// Reports the file's own guess, then makes the configured initial guess
/// from the edges of non-zero `weights`, and checks that every edge of
/// weight 1 has a finite cost there. Returns the file's own guess (the
/// vertices without a line composed along a spanning tree).
pub fn initialize<P: G2oPose<D> + ChordalInit<D>, const D: usize>(
    graph: &mut Graph<P, D>,
    missing: &[usize],
    config: &Settings<'_>,
    weights: &[f64],
    report: &mut Report,
    start: Instant,
) -> Result<Vec<P>, Error> {
    let solve_error = Error::from;
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
    if config.options.solver.init != Initialization::File {
        init_poses(graph, missing, config.options.solver.init, Some(weights))
            .map_err(solve_error)?;
    }
    // An edge whose cost overflows at the start makes the objective
    // meaningless: name it rather than report a bare non-finite objective.
    if let Some(k) = (0..graph.edges.len())
        .find(|&k| weights[k] != 0.0 && !graph.edge_chi2(&graph.edges[k]).is_finite())
    {
        let e = &graph.edges[k];
        return Err(Error::NonFiniteEdge {
            edge: k,
            from: graph.id(e.from),
            to: graph.id(e.to),
            initialization: config.options.solver.init,
        });
    }
    report.initialization = InitializationReport {
        method: config.options.solver.init,
        chi2: graph.chi2(),
        time_s: start.elapsed().as_secs_f64(),
        vertices_without_line: missing.len(),
    };
    Ok(given)
}

/// One robust solve of a job: its settings, the solver's settings for this
/// solve, the loop candidates the gate left, and how they are weighed.
pub struct Run<'a> {
    /// The job's settings.
    pub config: &'a Settings<'a>,
    /// This solve's method, bounds and tolerances.
    pub solver: SolveSettings,
    /// The loop candidates, with what the gate made of them.
    pub candidates: &'a [Candidate],
    /// How they are weighed.
    pub method: RobustMethod,
}

impl Run<'_> {
    /// The kernel width for poses of `D` degrees of freedom: the options',
    /// else the method's default.
    fn c<const D: usize>(&self) -> f64 {
        (self.config.options.robust.c).unwrap_or_else(|| robust::default_c(self.method, D))
    }

    /// The robust solve (`weigh`: the job's robust back end on a session,
    /// from `weights`, with kernel width `c` and the χ² test EM's search
    /// acts on) within the job's iteration and time budget, then the χ²
    /// test of the map it returns and the report.
    pub fn solve_and_test<P: G2oPose<D>, const D: usize, M>(
        &self,
        graph: &mut Graph<P, D>,
        optimizer: &mut Optimizer<P, D>,
        weights: &mut [f64],
        weigh: M,
        report: &mut Report,
        observer: &mut dyn Observer,
    ) -> Result<(), Error>
    where
        M: FnOnce(
            &mut Session<'_, P, D>,
            &mut [f64],
            f64,
            &Test<'_, P, D>,
        ) -> Result<Outcome, SolveError>,
    {
        let config = self.config;
        let budget = Budget {
            iterations: config.options.solver.max_iterations.unwrap_or(usize::MAX),
            deadline: config.solver.time_limit.map(|t| Instant::now() + t),
        };
        let test = |g: &Graph<P, D>, w: &[f64]| chi2_test(g, w, config).ok();
        // An update's solves already end only where their chord steps
        // moved the poses little; a batch job's last solve is polished.
        let polish = (self.solver.end_step.is_none()).then(|| end_step(graph));
        let solver = self.solver.clone();
        let mut session = Session::new(optimizer, graph, solver, budget, observer);
        let outcome = weigh(&mut session, weights, self.c::<D>(), &test)?;
        // The map returned converges unless the caller bounded the work
        // (a budget, or an update's own iteration cap).
        let own_limit = config.options.solver.max_iterations.is_none()
            && session.options.max_iterations == SolveSettings::default().max_iterations;
        if own_limit && !outcome.cut_short && !outcome.swung {
            session.finish_converging(&*weights, polish)?;
        }
        let phases = session.phases();
        let summary = session.finish(outcome.cut_short);
        if graph.poses.iter().any(|p| !p.is_finite()) {
            return Err(Error::NonFinite);
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
                "none of the {} loop candidates was accepted: the map is that of the trusted \
                 edges alone",
                outcome.accepted.len()
            ));
        }
        let final_chi2 = sum(edge_chi2.iter().copied());
        self.report(
            graph,
            optimizer,
            (summary, phases),
            final_chi2,
            &outcome,
            report,
        );
        Ok(())
    }

    /// Fills the optimiser's, the robust back end's and every loop's part
    /// of the report (`final_chi2`: the χ² of every edge at the map; the
    /// session's summary and phase times).
    fn report<P: G2oPose<D>, const D: usize>(
        &self,
        graph: &Graph<P, D>,
        optimizer: &Optimizer<P, D>,
        (summary, phases): (Option<Summary>, PhaseTimes),
        final_chi2: f64,
        outcome: &Outcome,
        report: &mut Report,
    ) {
        // The initialisation left the map whose χ² it reported.
        let initial_chi2 = report.initialization.chi2;
        let (candidates, method, c) = (self.candidates, self.method, self.c::<D>());
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
        report.robust = robust_report(outcome, candidates, (method, c));
        report.time.relaxation_s = phases.relaxation.as_secs_f64();
        report.time.evaluation_s = phases.evaluation.as_secs_f64();
        report.time.loop_model_s = phases.model.as_secs_f64();
        report.loops = loop_reports(graph, candidates, outcome);
        let warnings = decision_warnings(outcome, &report.loops);
        report.warnings.extend(warnings);
    }
}

/// What the robust back end did, from its `outcome` on `candidates`
/// (`method` at kernel width `c`).
fn robust_report(
    outcome: &Outcome,
    candidates: &[Candidate],
    (method, c): (RobustMethod, f64),
) -> RobustReport {
    let accepted = outcome.accepted.iter().filter(|&&a| a).count();
    RobustReport {
        method,
        c,
        rounds: outcome.rounds,
        relaxations: outcome.relaxations,
        decisions: outcome.decisions,
        relaxed_starts: outcome.relaxed_starts,
        clusters: outcome.clusters,
        accepted_loops: accepted,
        rejected_loops: candidates.len() - accepted,
        rescued_loops: (candidates.iter().zip(&outcome.accepted))
            .filter(|(c, a)| **a && !c.kept)
            .count(),
        model: outcome.model.clone(),
        search: outcome.search.clone(),
        starts: outcome.starts.clone(),
        unsettled: outcome.unsettled,
        doubtful: outcome.doubtful.clone(),
        held_back: outcome.held_back.clone(),
        outlying: outcome.outlying.clone(),
    }
}

/// One entry per loop candidate, in file order: its ends, count, gate and
/// decision, as the `outcome` left them.
fn loop_reports<P: G2oPose<D>, const D: usize>(
    graph: &Graph<P, D>,
    candidates: &[Candidate],
    outcome: &Outcome,
) -> Vec<LoopReport> {
    (candidates.iter().enumerate())
        .map(|(k, cand)| {
            let e = &graph.edges[cand.edge];
            LoopReport {
                from: graph.id(e.from),
                to: graph.id(e.to),
                inliers: e.candidate.and_then(|c| c.inliers),
                kept: cand.kept,
                accepted: outcome.accepted[k],
                weight: outcome.weights[k],
                prior: (outcome.model.as_ref()).map(|m| m.prior(cand.count_posterior)),
                posterior: outcome.posteriors[k],
                innovation: outcome.innovations[k],
                reason: outcome.reasons[k],
            }
        })
        .collect()
}

/// The warnings about the loop decisions of `outcome`: that they did not
/// settle, each doubtful cluster, each cluster held back (`loops` name
/// them by their ends).
fn decision_warnings(outcome: &Outcome, loops: &[LoopReport]) -> Vec<String> {
    let mut warnings = Vec::new();
    let unsettled = (outcome.reasons.iter())
        .filter(|&&r| r == Reason::Unsettled)
        .count();
    if unsettled > 0 {
        warnings.push(format!(
            "the loop decisions did not settle: {unsettled} of {} candidates were accepted \
             on some of the maps the decisions visited and rejected on others (reason \
             `unsettled`); the map is that of the best-fitting of those sets, and may hold \
             wrong loops or lack true ones",
            loops.len()
        ));
    }
    warnings.extend(outcome.doubtful.iter().map(|d| doubt_warning(d, loops)));
    warnings.extend(
        outcome
            .held_back
            .iter()
            .map(|h| held_back_warning(h, loops)),
    );
    warnings.extend(outcome.outlying.iter().map(|o| outlying_warning(o, loops)));
    warnings
}

/// The warning of a doubtful cluster ([`crate::robust::Doubt`]): its loops
/// by their ends, and what it does to the map.
fn doubt_warning(doubt: &Doubt, loops: &[LoopReport]) -> String {
    let ends = |k: usize| format!("{}–{}", loops[k].from, loops[k].to);
    let (first, last) = (doubt.loops[0], doubt.loops[doubt.loops.len() - 1]);
    format!(
        "{} accepted loops ({} … {}) err by one common offset beyond their own noise \
         (F = {:.1}, p = {:.1e}), and that offset moves a pose by {:.1} % of the map's size. \
         One place mistaken for another looks like this; check them (`robust.doubtful` in \
         the JSON report)",
        doubt.loops.len(),
        ends(first),
        ends(last),
        doubt.common_offset_f,
        doubt.p_value,
        100.0 * doubt.map_moves
    )
}

/// The warning of loops held back by their counts
/// ([`crate::robust::HeldBack`]): the loops by their ends, and what adding
/// them would do to the map.
fn held_back_warning(held: &HeldBack, loops: &[LoopReport]) -> String {
    let ends = |k: usize| format!("{}–{}", loops[k].from, loops[k].to);
    let (first, last) = (held.loops[0], held.loops[held.loops.len() - 1]);
    let (listed, verbs) = match held.loops.len() {
        1 => (
            format!("1 rejected loop ({})", ends(first)),
            ["fits", "was", "its inlier count", "it"],
        ),
        n => (
            format!("{n} rejected loops ({} … {})", ends(first), ends(last)),
            ["fit", "were", "their inlier counts", "they"],
        ),
    };
    let [fit, were, counts, they] = verbs;
    format!(
        "{listed} {fit} the map as a true loop does but {were} kept out by {counts} alone; \
         added, {they} would move a pose by {:.1} % of the map's size. A true loop that \
         verification scored low looks like this; check them (`robust.held_back` in the JSON \
         report)",
        100.0 * held.map_moves
    )
}

/// The warning of accepted loops beyond the true loops' reach
/// ([`crate::robust::Outlying`]): the loops by their ends, and what
/// removing them would do to the map.
fn outlying_warning(outlying: &Outlying, loops: &[LoopReport]) -> String {
    let ends = |k: usize| format!("{}–{}", loops[k].from, loops[k].to);
    let (first, last) = (outlying.loops[0], outlying.loops[outlying.loops.len() - 1]);
    let (listed, them) = match outlying.loops.len() {
        1 => (format!("1 accepted loop ({}) errs", ends(first)), "it"),
        n => (
            format!("{n} accepted loops ({} … {}) err", ends(first), ends(last)),
            "them",
        ),
    };
    let should = if outlying.stated {
        "the file's information allows on the scale of the map's true loops"
    } else {
        "any true loop of this map should"
    };
    format!(
        "{listed} by more than {should} (p = {:.1e} over the \
         accepted loops), and removing {them} would move a pose by {:.1} % of the map's size. \
         A wrong loop the map has bent to fit looks like this; check them \
         (`robust.outlying` in the JSON report)",
        outlying.p_value,
        100.0 * outlying.map_moves
    )
}

/// The χ² test over the edges the map was solved with (weight ≥ ½), each at
/// its plain cost (paper §II-C).
pub fn chi2_test<P: G2oPose<D>, const D: usize>(
    graph: &Graph<P, D>,
    weights: &[f64],
    config: &Settings<'_>,
) -> Result<Chi2Test, StatsError> {
    test_of(&graph.edge_chi2s(), graph, weights, config)
}

/// [`chi2_test`] from each edge's χ² at the map (`edge_chi2`).
fn test_of<P: G2oPose<D>, const D: usize>(
    edge_chi2: &[f64],
    graph: &Graph<P, D>,
    weights: &[f64],
    config: &Settings<'_>,
) -> Result<Chi2Test, StatsError> {
    let in_map = |k: usize| weights[k] >= 0.5;
    let used = (0..weights.len()).filter(|&k| in_map(k)).count();
    let d2 = sum((0..weights.len())
        .filter(|&k| in_map(k))
        .map(|k| edge_chi2[k]));
    let free = graph.num_vertices() - graph.gauge().len();
    let dof_residual = (used * D) as i64 - (free * D) as i64;
    Chi2Test::new(
        d2,
        used as u64,
        dof_residual,
        config.options.test.dof,
        config.options.test.alpha,
    )
}

/// A sum in the order given, from +0 ([`Graph::chi2_where`]'s bits).
fn sum(values: impl Iterator<Item = f64>) -> f64 {
    values.fold(0.0, |a, b| a + b)
}
