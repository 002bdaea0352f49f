//! The whole job of `pgo optimize`, as a library call, in the order the data
//! flows: read → gate → initialise → optimise (robustly) → test → report →
//! write. The CLI is a thin layer over [`run`].

use crate::gate::{self, DegeneratePolicy, GateMode, MixtureOptions};
use crate::graph::{AnyPoseGraph, PoseGraph};
use crate::io::g2o::{self, G2oFile, G2oPose, ReadError, ReadOptions};
use crate::io::inliers::{self, InlierCsvError};
use crate::options::Options;
use crate::report::{
    GateReport, InitializationReport, LoopReport, OptimizerReport, Report, RobustReport,
};
use crate::robust::{CandidateState, MapFit, Reweighter, RobustMethod, RobustOptions};
use crate::solve::init::{ChordalInit, Initialization, initialize};
use crate::solve::{IterationRecord, Optimizer, SolveError, SolverOptions};
use crate::stats::{Chi2Test, DofConvention};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Everything `pgo optimize` can be told.
#[derive(Clone, Debug)]
pub struct OptimizeConfig {
    /// The g2o file to read.
    pub input: PathBuf,
    /// Where to write the optimised graph, if anywhere.
    pub output: Option<PathBuf>,
    /// Inlier counts kept apart from the g2o file.
    pub inliers: Option<PathBuf>,
    /// Project non-positive-definite information matrices instead of failing.
    pub fix_information: bool,
    /// The initial guess.
    pub initialization: Initialization,
    /// Solver options.
    pub solver: SolverOptions,
    /// How loop candidates are gated by their inlier counts.
    pub gate: GateMode,
    /// What the learned gate does when the counts are degenerate.
    pub degenerate: DegeneratePolicy,
    /// Options of the mixture fit.
    pub mixture: MixtureOptions,
    /// Significance level of the χ² test.
    pub alpha: f64,
    /// Degrees of freedom of the χ² test.
    pub dof: DofConvention,
    /// Which edges are loop candidates.
    pub candidates: CandidateRule,
    /// The robust method for loop candidates and its kernel width (`None`:
    /// the default width for the edge dimension).
    pub robust: RobustMethod,
    /// Kernel width override.
    pub robust_c: Option<f64>,
    /// Most solver iterations in all, robust rounds included (`None`: each
    /// solve bounded by `solver.max_iterations`, the rounds by their own
    /// limits).
    pub iteration_budget: Option<usize>,
    /// EM: rescue the candidates the gate dropped whose residual at the map
    /// of the kept ones is that of an inlier (default on).
    pub rescue: bool,
    /// EM: judge the candidates the decided map was solved without (dropped
    /// by the gate, rejected by EM) by their innovation at that map
    /// ([`crate::robust::Reweighter::accept_by_innovation`]; default on).
    pub innovation: bool,
    /// EM: report every weighed candidate's innovation against the final
    /// map without it (`loops[].innovation`,
    /// [`crate::solve::Optimizer::leave_one_out_chi2`]; default off: it
    /// takes a selected inversion of the normal matrix).
    pub loop_innovations: bool,
    /// EM: learn the decision width from the residuals
    /// ([`crate::robust::Reweighter::decision_c`]; default on).
    pub learn_width: bool,
    /// EM: search the noise scale when a decided map does not fit the
    /// file's information ([`crate::robust::Reweighter::update_fit`];
    /// default on).
    pub scale_search: bool,
    /// Write SVG pictures (inlier-count histogram with the fitted mixture;
    /// trajectory before and after) into this directory.
    pub plot: Option<PathBuf>,
}

/// Which edges are loop-closure candidates.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum CandidateRule {
    /// Edges with an inlier count (in the file or the `--inliers` CSV).
    #[default]
    Counted,
    /// Also every edge between non-consecutive ids (|i − j| ≠ 1), with or
    /// without a count: robust weighting applies to them, gating only to
    /// those with a count.
    NonSequential,
}

impl OptimizeConfig {
    /// Defaults for everything but the input: those of [`Options`].
    pub fn new(input: impl Into<PathBuf>) -> Self {
        Self::from_options(input, &Options::default())
    }

    /// The job of [`Options`] on the g2o file `input`: no output, no inlier
    /// CSV, no pictures, information matrices as read.
    pub fn from_options(input: impl Into<PathBuf>, options: &Options) -> Self {
        let defaults = SolverOptions::default();
        Self {
            input: input.into(),
            output: None,
            inliers: None,
            fix_information: false,
            initialization: options.solver.init,
            solver: SolverOptions {
                method: options.solver.method,
                max_iterations: options
                    .solver
                    .max_iterations
                    .unwrap_or(defaults.max_iterations),
                time_limit: options.solver.time_limit,
                threads: options.solver.threads,
                ..defaults
            },
            gate: options.gate.mode,
            degenerate: options.gate.degenerate,
            mixture: MixtureOptions::default(),
            alpha: options.test.alpha,
            dof: options.test.dof,
            candidates: options.gate.candidates,
            robust: options.robust.method,
            robust_c: options.robust.c,
            iteration_budget: options.solver.max_iterations,
            rescue: options.expert.rescue,
            innovation: options.expert.innovation,
            loop_innovations: options.robust.innovations,
            learn_width: options.expert.learn_width,
            scale_search: options.expert.scale_search,
            plot: None,
        }
    }
}

/// Why `pgo optimize` failed.
#[derive(Debug, thiserror::Error)]
pub enum PipelineError {
    /// The g2o file is unreadable or malformed.
    #[error(transparent)]
    Read(#[from] ReadError),
    /// The inlier CSV is unreadable or malformed.
    #[error(transparent)]
    Inliers(#[from] InlierCsvError),
    /// The problem cannot be solved as posed.
    #[error("{path}: {source}")]
    Solve {
        /// The input file.
        path: PathBuf,
        /// The cause.
        source: SolveError,
    },
    /// The output could not be written.
    #[error("{path}: cannot write: {source}")]
    Write {
        /// The output file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// A picture could not be drawn or written.
    #[error(transparent)]
    Plot(#[from] crate::plot::PlotError),
    /// An edge's cost is not finite at the initial guess (its measurement,
    /// information or poses are too large for floating point).
    #[error(
        "{path}: edge {edge} (vertex {from} → {to}) has a non-finite χ² at the {} initial \
         guess (--init): its measurement, information or poses are too large",
        initialization_name(*.initialization)
    )]
    NonFiniteEdge {
        /// The input file.
        path: PathBuf,
        /// 1-based index of the edge among the file's edges.
        edge: usize,
        /// Its first vertex id.
        from: crate::graph::VertexId,
        /// Its second vertex id.
        to: crate::graph::VertexId,
        /// The initial guess.
        initialization: Initialization,
    },
    /// The optimiser produced non-finite poses (nothing was written).
    #[error("{path}: the optimiser produced non-finite poses; nothing was written")]
    NonFiniteResult {
        /// The input file.
        path: PathBuf,
    },
}

/// `file`, `odometry` or `chordal`, as on the command line.
fn initialization_name(i: Initialization) -> &'static str {
    match i {
        Initialization::File => "file",
        Initialization::Odometry => "odometry",
        Initialization::Chordal => "chordal",
    }
}

impl PipelineError {
    /// The process exit status: 2 for bad input, 1 for other failures.
    pub fn exit_code(&self) -> i32 {
        match self {
            Self::Read(ReadError::Io { .. }) | Self::Inliers(InlierCsvError::Io { .. }) => 2,
            Self::Read(_) | Self::Inliers(_) | Self::NonFiniteEdge { .. } => 2,
            Self::Solve {
                source: SolveError::Unconstrained { .. } | SolveError::NotPositiveDefinite { .. },
                ..
            } => 2,
            Self::Solve {
                source: SolveError::NonFiniteStart,
                ..
            } => 2,
            Self::Solve { .. }
            | Self::Write { .. }
            | Self::NonFiniteResult { .. }
            | Self::Plot(_) => 1,
        }
    }
}

/// Runs `pgo optimize`: returns the report (and writes the output file if
/// asked). `observer` sees every iteration.
pub fn run(
    config: &OptimizeConfig,
    observer: &mut dyn FnMut(&IterationRecord),
) -> Result<Report, PipelineError> {
    #[cfg(not(feature = "plot"))]
    if let Some(dir) = &config.plot {
        return Err(crate::plot::PlotError::Disabled { path: dir.clone() }.into());
    }
    let mut file = g2o::read(
        &config.input,
        ReadOptions {
            fix_information: config.fix_information,
        },
    )?;
    let mut report = Report::new(&config.input, &file);
    match &mut file.graph {
        AnyPoseGraph::Planar(g) => optimize_graph(g, &file.missing, config, &mut report, observer)?,
        AnyPoseGraph::Spatial(g) => {
            optimize_graph(g, &file.missing, config, &mut report, observer)?
        }
    }
    for w in &report.warnings {
        log::warn!("{w}");
    }
    if let Some(out) = &config.output {
        write_output(&file, out)?;
        report.output = Some(out.display().to_string());
    }
    Ok(report)
}

/// The loop candidates of a graph and how the gate treated them.
struct Candidates {
    /// Edge index of each candidate, in file order.
    edges: Vec<usize>,
    /// Its inlier count, if any.
    counts: Vec<Option<u64>>,
    /// Whether the gate kept it.
    kept: Vec<bool>,
    /// Its prior inlier probability for the robust back end.
    priors: Vec<f64>,
    /// Whether EM may rescue the dropped ones: a threshold was learned or
    /// given (not off, not soft, not a degenerate fit).
    rescuable: bool,
}

/// The job on a graph, shared by [`run`] and [`crate::PoseGraph::optimize`]:
/// fills `report` and leaves the optimised poses in `graph`.
pub(crate) fn optimize_graph<P: G2oPose<D> + ChordalInit<D>, const D: usize>(
    graph: &mut PoseGraph<P, D>,
    missing: &[usize],
    config: &OptimizeConfig,
    report: &mut Report,
    observer: &mut dyn FnMut(&IterationRecord),
) -> Result<(), PipelineError> {
    let solve_error = |source| PipelineError::Solve {
        path: config.input.clone(),
        source,
    };
    if let Some(csv) = &config.inliers {
        let rows = inliers::read_csv(csv)?;
        let replaced = inliers::apply(graph, &rows, csv)?;
        if replaced > 0 {
            report.warnings.push(format!(
                "{}: replaced the inlier counts of {replaced} edges",
                csv.display()
            ));
        }
    }
    if config.candidates == CandidateRule::NonSequential {
        let ids: Vec<u64> = graph.ids().to_vec();
        for e in graph.edges.iter_mut() {
            if e.candidate.is_none() && ids[e.from].abs_diff(ids[e.to]) != 1 {
                e.candidate = Some(crate::graph::LoopCandidate { inliers: None });
            }
        }
    }
    report.loop_candidates = graph.num_candidates();

    let candidates = gate_candidates(graph, config, report);
    let mut weights = vec![1.0; graph.edges.len()];
    for (i, &k) in candidates.edges.iter().enumerate() {
        weights[k] = if candidates.kept[i] { 1.0 } else { 0.0 };
    }

    // An unconstrained vertex makes every later step meaningless: say so first.
    let mut optimizer =
        Optimizer::new(graph, Some(&weights), config.solver.clone()).map_err(solve_error)?;

    // The robust method decides how much the initial guess may trust the
    // candidates: not at all when they are to be reweighted, since a wrong
    // loop in the chordal problem bends the whole map.
    let method = if candidates.kept.iter().any(|&k| k) {
        config.robust
    } else {
        RobustMethod::None
    };
    // The candidates the robust method weighs: those the gate kept, and for
    // EM with --rescue the ones it dropped too, held out of the weighting and
    // decided at the maps of the others (see `Reweighter::hold_out`).
    let rescue = method == RobustMethod::Em && config.rescue && candidates.rescuable;
    let kept: Vec<usize> = (0..candidates.edges.len())
        .filter(|&i| candidates.kept[i] || rescue)
        .collect();
    // The edge of each weighed candidate, and how their weights go in.
    let pool: Vec<usize> = kept.iter().map(|&i| candidates.edges[i]).collect();
    let set_weights = |weights: &mut [f64], from: &[f64]| {
        for (&k, &w) in pool.iter().zip(from) {
            weights[k] = w;
        }
    };
    let mut init_weights = weights.clone();
    if method != RobustMethod::None {
        for &k in &candidates.edges {
            init_weights[k] = 0.0;
        }
    }

    let start = Instant::now();
    // The file's own guess first (vertices without a line by spanning tree),
    // so that its χ² can be reported whatever the initialisation.
    initialize(graph, missing, Initialization::File, Some(&init_weights)).map_err(solve_error)?;
    report.input_chi2 = graph.chi2();
    if !report.input_chi2.is_finite() {
        report.warnings.push(format!(
            "the file's own guess has a non-finite χ² ({}; null in JSON)",
            report.input_chi2
        ));
    }
    if config.initialization != Initialization::File {
        initialize(graph, missing, config.initialization, Some(&init_weights))
            .map_err(solve_error)?;
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

    // Optimise; with a robust method, reweight the kept candidates from
    // their residuals and solve again until the weights settle.
    let initial_chi2 = graph.chi2();
    let before = config
        .plot
        .as_ref()
        .map(|_| crate::plot::top_view(&graph.poses));
    let mut robust_options = RobustOptions::new(method, D);
    robust_options.learn_width = config.learn_width;
    robust_options.scale_search = config.scale_search;
    if let Some(c) = config.robust_c {
        robust_options.c = c;
    }
    let mut reweighter = Reweighter::new(
        robust_options,
        kept.iter().map(|&i| candidates.priors[i]).collect(),
    );
    let held_out: Vec<bool> = kept.iter().map(|&i| !candidates.kept[i]).collect();
    reweighter.hold_out(&held_out);
    set_weights(&mut weights, reweighter.weights());
    // Between reweighting rounds a few iterations are enough (generalised
    // EM: each M-step only has to improve); EM's hard decisions and the
    // last solve of the other methods run to full convergence.
    let full = config.solver.clone();
    let partial = SolverOptions {
        max_iterations: full.max_iterations.min(3),
        relative_tolerance: 1e-6,
        ..full.clone()
    };
    let candidate_r2 = |graph: &PoseGraph<P, D>| -> Vec<f64> {
        pool.iter()
            .map(|&k| graph.edge_chi2(&graph.edges[k]))
            .collect()
    };
    if method == RobustMethod::Em {
        // EM's first E-step is at the initial guess.
        reweighter.update(&candidate_r2(graph));
        set_weights(&mut weights, reweighter.weights());
    }
    // EM's decisions solve to a moderate tolerance; the decided map is then
    // polished to the caller's.
    let deciding = SolverOptions {
        relative_tolerance: full.relative_tolerance.max(1e-6),
        ..full.clone()
    };
    // --max-iters and --time-limit bound the whole optimisation, robust
    // rounds included: each run gets what is left of both.
    let deadline = full.time_limit.map(|t| Instant::now() + t);
    let budget = config.iteration_budget.unwrap_or(usize::MAX);
    let within_budget = |options: &SolverOptions, used: usize| SolverOptions {
        max_iterations: options.max_iterations.min(budget.saturating_sub(used)),
        time_limit: deadline.map(|d| d.saturating_duration_since(Instant::now())),
        ..options.clone()
    };
    let exhausted = |used: usize| used >= budget || deadline.is_some_and(|d| Instant::now() >= d);
    let out_of_budget = |summary: &mut crate::solve::Summary| {
        summary.stop_reason = if summary.iterations >= budget {
            crate::solve::StopReason::MaxIterations
        } else {
            crate::solve::StopReason::TimeLimit
        };
    };
    let mut noise_scale = None;
    let mut total = None::<crate::solve::Summary>;
    loop {
        let robust = reweighter.is_active();
        let options = if !robust {
            &full
        } else if reweighter.full_solve() {
            &deciding
        } else {
            &partial
        };
        let used = total.as_ref().map_or(0, |t| t.iterations);
        let summary = solve(
            &mut optimizer,
            graph,
            &weights,
            within_budget(options, used),
            observer,
        )
        .map_err(solve_error)?;
        let mut merged = merge_summaries(total, summary);
        let stop = !robust || exhausted(merged.iterations);
        if robust && stop {
            // Out of budget before the weights settled.
            out_of_budget(&mut merged);
        }
        total = Some(merged);
        if stop {
            break;
        }
        // EM decides on r²/s², s² from the fit of the latest map
        // (`Reweighter::update_fit`).
        let r2 = candidate_r2(graph);
        let (mut again, s2) = if method == RobustMethod::Em {
            let fit = map_fit(graph, &weights);
            let s2 = reweighter.decision_scale(fit);
            (reweighter.update_fit(&r2, fit), s2)
        } else {
            (reweighter.update(&r2), 1.0)
        };
        if let Some(which) = reweighter
            .innovation_request()
            .filter(|_| config.innovation)
        {
            // The candidates the decided map was solved without (dropped by
            // the gate, rejected by EM) are judged by their innovation at
            // that map, with the set it was solved with
            // (`Reweighter::accept_by_innovation`). If its undamped normal
            // matrix cannot be factorised, the decisions stand.
            let edges: Vec<usize> = which.iter().map(|&c| pool[c]).collect();
            if let Ok(nu2) = optimizer.innovation_chi2(graph, &weights, &edges) {
                again |= reweighter.accept_by_innovation(&which, &nu2, s2);
            }
        }
        if reweighter.full_solve() || !again {
            noise_scale = Some(s2).filter(|_| method == RobustMethod::Em);
        }
        let changed = pool
            .iter()
            .zip(reweighter.weights())
            .any(|(&k, &w)| weights[k] != w);
        set_weights(&mut weights, reweighter.weights());
        if again && reweighter.take_restart() {
            // EM solves each decided set from the initial guess made with the
            // accepted loops (for the chordal guess, the relaxation of the
            // trusted edges and the accepted loops), not from a map that
            // wrong loops may have pulled into another basin. The
            // optimiser's factor is rebuilt by the next run anyway: it goes
            // first, so that it never takes memory beside the guess's.
            optimizer.system_mut().release_factor();
            initialize(graph, missing, config.initialization, Some(&weights))
                .map_err(solve_error)?;
        }
        if !again {
            let polish = if method == RobustMethod::Em {
                // The decided map, polished to the caller's tolerance.
                deciding.relative_tolerance > full.relative_tolerance
            } else {
                // The weights settled: one last solve to full convergence.
                changed
            };
            let used = total.as_ref().map_or(0, |t| t.iterations);
            if polish && !exhausted(used) {
                let summary = solve(
                    &mut optimizer,
                    graph,
                    &weights,
                    within_budget(&full, used),
                    observer,
                )
                .map_err(solve_error)?;
                total = Some(merge_summaries(total, summary));
                if method == RobustMethod::Em {
                    let s2 = reweighter.decision_scale(map_fit(graph, &weights));
                    noise_scale = Some(s2);
                    reweighter.refresh(&candidate_r2(graph), s2);
                }
            }
            break;
        }
    }
    // EM, on request: each candidate's innovation against the final map
    // without it, on the scale of the decisions (a diagnostic: the
    // decisions are made).
    let mut innovations = vec![None; pool.len()];
    if method == RobustMethod::Em && config.loop_innovations {
        let s2 = noise_scale.unwrap_or(1.0);
        match optimizer.leave_one_out_chi2(graph, &weights, &pool) {
            Ok(nu2) => innovations = nu2.into_iter().map(|v| v.map(|v| v / s2)).collect(),
            Err(e) => report
                .warnings
                .push(format!("--innovations: none reported: {e}")),
        }
    }
    // EM reports its posteriors at the final map (≥ ½ exactly for the loops
    // the map was solved with); the others the weights of the last solve.
    set_weights(&mut weights, &reweighter.final_weights());
    if graph.poses.iter().any(|p| !p.is_finite()) {
        return Err(PipelineError::NonFiniteResult {
            path: config.input.clone(),
        });
    }
    if let Some(summary) = &total {
        report.optimizer = OptimizerReport::new(
            summary,
            initial_chi2,
            graph.chi2(),
            optimizer.system(),
            optimizer.max_nnz_factor(),
        );
    }
    let accepted = pool.iter().filter(|&&k| weights[k] >= 0.5).count();
    let (scale_search, scale_trials) = reweighter.scale_search();
    report.robust = RobustReport {
        method,
        c: robust_options.c,
        rounds: reweighter.rounds(),
        active_loops: accepted,
        rejected_loops: candidates.edges.len() - accepted,
        removed_loops: reweighter.removed(),
        switched_off_loops: reweighter
            .states()
            .iter()
            .filter(|s| **s == CandidateState::Off)
            .count(),
        variance_factor: noise_scale,
        rescued_loops: reweighter.rescued(),
        innovation_accepted_loops: reweighter.innovation_accepted(),
        scale_search: (method == RobustMethod::Em).then_some(scale_search),
        scale_trials,
        decision_c: (method == RobustMethod::Em).then(|| reweighter.decision_c()),
        residual_mixture: reweighter.residual_fit().cloned(),
    };

    chi2_test(graph, &weights, config, report);
    if let (Some(dir), Some(before)) = (&config.plot, before) {
        plot(dir, graph, &before, &weights, &candidates, config, report)?;
    }
    // Where each candidate EM weighed is in its list.
    let mut weighed = vec![None; candidates.edges.len()];
    for (c, &i) in kept.iter().enumerate() {
        weighed[i] = Some(c);
    }
    report.loops = (0..candidates.edges.len())
        .map(|i| {
            let k = candidates.edges[i];
            let e = &graph.edges[k];
            let innovation = weighed[i].and_then(|c| innovations[c]);
            let judgement = weighed[i].and_then(|c| reweighter.judgements()[c]);
            LoopReport {
                from: graph.id(e.from),
                to: graph.id(e.to),
                inliers: candidates.counts[i],
                kept: candidates.kept[i],
                weight: weights[k],
                prior: candidates.priors[i],
                innovation,
                judgement,
                weighed: weighed[i].is_some(),
            }
        })
        .collect();
    Ok(())
}

/// Writes `counts.svg` (when there are counts) and `trajectory.svg` into
/// `dir`, and lists them in the report.
fn plot<P: G2oPose<D>, const D: usize>(
    dir: &Path,
    graph: &PoseGraph<P, D>,
    before: &[[f64; 2]],
    weights: &[f64],
    candidates: &Candidates,
    config: &OptimizeConfig,
    report: &mut Report,
) -> Result<(), PipelineError> {
    use crate::plot::{LoopLine, plot_counts, plot_trajectory, top_view};
    std::fs::create_dir_all(dir).map_err(|source| PipelineError::Write {
        path: dir.to_owned(),
        source,
    })?;
    let counts: Vec<u64> = candidates.counts.iter().flatten().copied().collect();
    if let (false, Some(fit)) = (counts.is_empty(), &report.gate.fit) {
        let path = dir.join("counts.svg");
        plot_counts(&path, &counts, fit)?;
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

/// Minimises the weighted objective from the graph's poses with `options`,
/// leaving the result in the graph. Edges of weight 0 (switched-off
/// candidates) leave the optimiser's sparsity pattern when that pays
/// ([`Optimizer::run`]): wrong loops between distant poses fill the factor.
fn solve<P: G2oPose<D>, const D: usize>(
    optimizer: &mut Optimizer<P, D>,
    graph: &mut PoseGraph<P, D>,
    weights: &[f64],
    options: SolverOptions,
    observer: &mut dyn FnMut(&IterationRecord),
) -> Result<crate::solve::Summary, SolveError> {
    *optimizer.options_mut() = options;
    let mut observe = |r: &IterationRecord| observer(r);
    optimizer.run(graph, Some(weights), &mut observe)
}

/// How the map fits the file's noise model ([`MapFit`]): `Σ eₖᵀΩₖeₖ`
/// over the edges of non-zero weight at the graph's poses, and their
/// redundancy `D·edges − D·free poses` (0 when there is not one edge's
/// worth).
fn map_fit<P: G2oPose<D>, const D: usize>(graph: &PoseGraph<P, D>, weights: &[f64]) -> MapFit {
    let (chi2, n) = graph
        .edges
        .iter()
        .zip(weights)
        .filter(|(_, w)| **w > 0.0)
        .fold((0.0, 0usize), |(d2, n), (e, _)| {
            (d2 + graph.edge_chi2(e), n + 1)
        });
    let free = graph.num_vertices() - graph.gauge().len();
    MapFit {
        chi2,
        dof: D * n.saturating_sub(free),
    }
}

/// The summary of several optimiser runs (robust rounds) as one.
fn merge_summaries(
    total: Option<crate::solve::Summary>,
    next: crate::solve::Summary,
) -> crate::solve::Summary {
    match total {
        None => next,
        Some(mut t) => {
            t.iterations += next.iterations;
            t.factorizations += next.factorizations;
            t.time += next.time;
            t.history.extend(next.history);
            t.timing.add(&next.timing);
            t.final_objective = next.final_objective;
            t.stop_reason = next.stop_reason;
            t
        }
    }
}

/// Gate: learn `T_GV` from the candidates' counts and decide which go on.
fn gate_candidates<P: G2oPose<D>, const D: usize>(
    graph: &PoseGraph<P, D>,
    config: &OptimizeConfig,
    report: &mut Report,
) -> Candidates {
    let edges: Vec<usize> = (0..graph.edges.len())
        .filter(|&k| graph.edges[k].is_candidate())
        .collect();
    let counts: Vec<Option<u64>> = edges
        .iter()
        .map(|&k| graph.edges[k].candidate.and_then(|c| c.inliers))
        .collect();
    let decision = gate::gate(&counts, config.gate, config.degenerate, &config.mixture);
    report.gate = GateReport::new(&decision, &counts);
    if decision.degenerate && report.gate.counted > 0 {
        if let Some(reason) = &decision.reason {
            report.warnings.push(format!(
                "the inlier counts are degenerate: {reason}; policy {}: {}",
                config.degenerate.name(),
                match config.degenerate {
                    DegeneratePolicy::DropAll =>
                        "every counted candidate dropped, the trusted edges optimised alone",
                    DegeneratePolicy::KeepAll =>
                        "every candidate with a non-zero count kept, left to the robust back end",
                    DegeneratePolicy::Threshold => "the crossing used anyway where there is one",
                }
            ));
        }
    }
    // The soft gate hands the mixture's posterior on as a prior, and so does
    // the hard gate for the candidates it dropped (EM may rescue them, with
    // the count's evidence against them beyond the calibrated width: see
    // `Reweighter::decision_c`); a kept candidate is known no better than ½
    // (nor is a dropped one under a fixed threshold without a fit). A zero
    // count is no loop by definition: prior 0.
    let max = report.gate.max_inliers;
    let rescuable =
        matches!(config.gate, GateMode::Auto | GateMode::Fixed(_)) && !decision.degenerate;
    let posterior = |n: u64| match &decision.fit {
        _ if n == 0 => 0.0,
        Some(fit) => fit
            .mixture
            .as_ref()
            .map_or(0.5, |m| m.posterior_true_loop(n, max).clamp(1e-6, 0.5)),
        None => 0.5,
    };
    let priors = counts
        .iter()
        .zip(&decision.kept)
        .map(|(c, &kept)| match (config.gate, c) {
            (GateMode::Soft, Some(n)) if !decision.degenerate => posterior(*n),
            (_, Some(n)) if rescuable && !kept => posterior(*n),
            _ => 0.5,
        })
        .collect();
    Candidates {
        edges,
        counts,
        kept: decision.kept,
        priors,
        rescuable,
    }
}

/// The χ² test over the edges that were optimised (weight ≥ ½), each at its
/// plain cost (paper §II-C).
fn chi2_test<P: G2oPose<D>, const D: usize>(
    graph: &PoseGraph<P, D>,
    weights: &[f64],
    config: &OptimizeConfig,
    report: &mut Report,
) {
    let used: Vec<usize> = (0..graph.edges.len())
        .filter(|&k| weights[k] >= 0.5)
        .collect();
    let d2: f64 = used.iter().map(|&k| graph.edge_chi2(&graph.edges[k])).sum();
    let free = graph.num_vertices() - graph.gauge().len();
    let dof_residual = (used.len() * D) as i64 - (free * D) as i64;
    match Chi2Test::new(
        d2,
        used.len() as u64,
        dof_residual,
        config.dof,
        config.alpha,
    ) {
        Ok(test) => report.chi2_test = Some(test),
        Err(e) => report.warnings.push(format!("no χ² test: {e}")),
    }
}

fn write_output(file: &G2oFile, out: &Path) -> Result<(), PipelineError> {
    crate::io::write_atomically(out, |w| file.write(w)).map_err(|source| PipelineError::Write {
        path: out.to_owned(),
        source,
    })
}
