//! The whole job of `pgo optimize`, as a library call, in the order the data
//! flows: read → gate → initialise → optimise (robustly) → test → report →
//! write. The CLI is a thin layer over [`run`].

mod candidates;
mod finish;
#[cfg(test)]
pub(crate) use finish::chi2_test;
mod incremental;

pub(crate) use incremental::{Warm, after_swing, update_graph};

use crate::gate::{DegeneratePolicy, GateMode, MixtureOptions};
use crate::graph::{AnyGraph, Graph};
use crate::io::g2o::{self, G2oFile, G2oPose, ReadError, ReadOptions};
use crate::io::inliers::InlierCsvError;
use crate::options::Options;
use crate::report::Report;
use crate::robust::{self, RobustMethod, Test};
use crate::solve::init::{ChordalInit, Initialization};
use crate::solve::{Observer, Optimizer, Session, SolveError, SolverOptions};
use crate::stats::DofConvention;
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
    /// EM's layers (all on but for an ablation).
    pub layers: robust::Layers,
    /// Most solver iterations in all, robust rounds included (`None`: each
    /// solve bounded by `solver.max_iterations`, the rounds by their own
    /// limits).
    pub iteration_budget: Option<usize>,
    /// Most iterations of each solve in an incremental update (`None`:
    /// updates converge).
    pub update_iterations: Option<usize>,
    /// Write SVG pictures (inlier-count histogram with the fitted mixture;
    /// trajectory before and after) into this directory.
    pub plot: Option<PathBuf>,
    /// Add the map's certificate of global optimality to the report
    /// (`--certify`).
    pub certify: bool,
    /// Write every pose's marginal covariance here (CSV, after the output;
    /// [`crate::Covariances`]).
    pub covariances: Option<PathBuf>,
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
            layers: options.expert.layers,
            iteration_budget: options.solver.max_iterations,
            update_iterations: options.solver.update_iterations,
            plot: None,
            certify: false,
            covariances: None,
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
    /// An information matrix outside the range the job computes with
    /// ([`crate::graph::INFORMATION_RANGE`]).
    #[error("{path}: edge {from} → {to}: information matrix {problem}")]
    Information {
        /// The input file.
        path: PathBuf,
        /// Its first vertex id.
        from: crate::graph::VertexId,
        /// Its second vertex id.
        to: crate::graph::VertexId,
        /// What is wrong.
        problem: crate::InformationProblem,
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
        Initialization::Previous => "previous",
    }
}

impl PipelineError {
    /// The process exit status: 2 for bad input, 1 for other failures.
    pub fn exit_code(&self) -> i32 {
        match self {
            Self::Read(ReadError::Io { .. }) | Self::Inliers(InlierCsvError::Io { .. }) => 2,
            Self::Read(_) | Self::Inliers(_) | Self::NonFiniteEdge { .. } => 2,
            Self::Information { .. } => 2,
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
pub fn run(config: &OptimizeConfig, observer: &mut dyn Observer) -> Result<Report, PipelineError> {
    #[cfg(not(feature = "plot"))]
    if let Some(dir) = &config.plot {
        return Err(crate::plot::PlotError::Disabled { path: dir.clone() }.into());
    }
    let start = Instant::now();
    let mut file = g2o::read(
        &config.input,
        ReadOptions {
            fix_information: config.fix_information,
        },
    )?;
    check_information_range(&file.graph, &config.input)?;
    let mut report = Report::new(&config.input, &file);
    report.time.read_s = start.elapsed().as_secs_f64();
    match &mut file.graph {
        AnyGraph::Planar(g) => optimize_graph(g, &file.missing, config, &mut report, observer)?,
        AnyGraph::Spatial(g) => optimize_graph(g, &file.missing, config, &mut report, observer)?,
    }
    if config.certify {
        certify_into(&file.graph, &mut report);
    }
    for w in &report.warnings {
        log::warn!("{w}");
    }
    if let Some(out) = &config.output {
        let writing = Instant::now();
        write_output(&file, out)?;
        report.output = Some(out.display().to_string());
        report.time.write_s = writing.elapsed().as_secs_f64();
    }
    if let Some(path) = &config.covariances {
        write_covariances(file.graph, config, path, &mut report)?;
    }
    report.time.total_s = start.elapsed().as_secs_f64();
    Ok(report)
}

/// Adds the certificate of the optimised `graph`'s map to `report` (or a
/// warning saying why there is none).
fn certify_into(graph: &AnyGraph, report: &mut Report) {
    let certificate = match graph {
        AnyGraph::Planar(g) => crate::certify::of_graph::<_, 2, 3, 3, 3>(g, report),
        AnyGraph::Spatial(g) => crate::certify::of_graph::<_, 3, 4, 6, 6>(g, report),
    };
    match certificate {
        Ok(c) => report.certificate = Some(c),
        Err(e) => report.warnings.push(format!("no certificate: {e}")),
    }
}

/// Refuses a graph whose information matrices leave
/// [`crate::graph::INFORMATION_RANGE`], naming the first such edge.
fn check_information_range(graph: &AnyGraph, path: &Path) -> Result<(), PipelineError> {
    let found = match graph {
        AnyGraph::Planar(g) => g.information_out_of_range(),
        AnyGraph::Spatial(g) => g.information_out_of_range(),
    };
    match found {
        Some((from, to, index, value)) => Err(PipelineError::Information {
            path: path.to_owned(),
            from,
            to,
            problem: crate::InformationProblem::OutOfRange { index, value },
        }),
        None => Ok(()),
    }
}

/// The job on a graph in memory: gate → initial guess → robust solve → χ²
/// test → report. `missing` lists the vertices the file did not define.
pub(crate) fn optimize_graph<P: G2oPose<D> + ChordalInit<D>, const D: usize>(
    graph: &mut Graph<P, D>,
    missing: &[usize],
    config: &OptimizeConfig,
    report: &mut Report,
    observer: &mut dyn Observer,
) -> Result<(), PipelineError> {
    let solve_error = |source| PipelineError::Solve {
        path: config.input.clone(),
        source,
    };
    // Which edges are loop candidates, and what the gate makes of them.
    candidates::apply_inlier_csv(graph, config, report)?;
    candidates::mark(graph, config.candidates);
    let gating = Instant::now();
    let candidates = candidates::gate(graph, config, report, None);
    report.time.gate_s = gating.elapsed().as_secs_f64();
    let method = if candidates.iter().any(|c| c.kept) {
        config.robust
    } else {
        RobustMethod::None
    };

    // The initial guess, from the trusted edges (and the candidates that
    // alone join parts of the map), before any candidate is weighed.
    let mut weights = candidates::initial_weights(graph, &candidates, method == RobustMethod::None);
    let mut optimizer =
        Optimizer::new(graph, Some(&weights), config.solver.clone()).map_err(solve_error)?;
    let start = Instant::now();
    let given = finish::initialize(graph, missing, config, &weights, report, start)?;
    report.time.initialize_s = report.initialization.time_s;
    let before = config
        .plot
        .as_ref()
        .map(|_| crate::plot::top_view(&graph.poses));

    // The robust solve within the budget, the χ² test of its map, the report.
    let solving = Instant::now();
    let chordal = config.initialization == Initialization::Chordal;
    let weigh =
        |session: &mut Session<'_, P, D>, weights: &mut [f64], c: f64, test: &Test<'_, P, D>| {
            let job = robust::Job {
                candidates: &candidates,
                method,
                c,
                layers: &config.layers,
                test,
                chordal,
                given: Some(&given),
            };
            robust::solve(session, weights, &job)
        };
    finish::solve_and_test(
        graph,
        &mut optimizer,
        config.solver.clone(),
        &mut weights,
        &candidates,
        method,
        weigh,
        config,
        report,
        observer,
    )?;
    report.time.solve_s = solving.elapsed().as_secs_f64();
    if let (Some(dir), Some(before)) = (&config.plot, before) {
        finish::plot(dir, graph, &before, &weights, config, report)?;
    }
    Ok(())
}

/// Writes the covariances of the map `graph` (`--covariances`): a warning
/// names the poses left out.
fn write_covariances(
    graph: AnyGraph,
    config: &OptimizeConfig,
    path: &Path,
    report: &mut Report,
) -> Result<(), PipelineError> {
    use crate::covariance::{CsvError, write_csv};
    let accepted = report.loops.iter().map(|l| l.accepted);
    let threads = config.solver.threads;
    let written = match graph {
        AnyGraph::Planar(g) => write_csv(g, accepted, threads, path),
        AnyGraph::Spatial(g) => write_csv(g, accepted, threads, path),
    };
    let unbounded = written.map_err(|e| match e {
        CsvError::Solve(source) => PipelineError::Solve {
            path: config.input.clone(),
            source,
        },
        CsvError::Write(source) => PipelineError::Write {
            path: path.to_owned(),
            source,
        },
    })?;
    if let Some(first) = unbounded.first() {
        let warning = format!(
            "--covariances: {} poses left out (no trusted edge or accepted loop ties them to the \
             fixed poses: their covariance is unbounded), e.g. {first}",
            unbounded.len()
        );
        log::warn!("{warning}");
        report.warnings.push(warning);
    }
    Ok(())
}

fn write_output(file: &G2oFile, out: &Path) -> Result<(), PipelineError> {
    crate::io::write_atomically(out, |w| Ok(file.rewrite(w)?)).map_err(|source| {
        PipelineError::Write {
            path: out.to_owned(),
            source,
        }
    })
}
