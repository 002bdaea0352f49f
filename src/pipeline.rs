//! The whole job of `pgo optimize`, as a library call: read → initialise →
//! optimise → report → write. The CLI is a thin layer over [`run`].

use crate::gate::{self, DegeneratePolicy, GateMode, MixtureOptions};
use crate::graph::{AnyPoseGraph, PoseGraph};
use crate::io::g2o::{self, G2oFile, G2oPose, ReadError, ReadOptions};
use crate::io::inliers::{self, InlierCsvError};
use crate::report::{GateReport, InitializationReport, LoopReport, OptimizerReport, Report};
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
}

impl OptimizeConfig {
    /// Defaults for everything but the input.
    pub fn new(input: impl Into<PathBuf>) -> Self {
        Self {
            input: input.into(),
            output: None,
            inliers: None,
            fix_information: false,
            initialization: Initialization::default(),
            solver: SolverOptions::default(),
            gate: GateMode::default(),
            degenerate: DegeneratePolicy::default(),
            mixture: MixtureOptions::default(),
            alpha: 0.05,
            dof: DofConvention::default(),
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
    /// The optimiser produced non-finite poses (nothing was written).
    #[error("{path}: the optimiser produced non-finite poses; nothing was written")]
    NonFiniteResult {
        /// The input file.
        path: PathBuf,
    },
}

impl PipelineError {
    /// The process exit status: 2 for bad input, 1 for other failures.
    pub fn exit_code(&self) -> i32 {
        match self {
            Self::Read(ReadError::Io { .. }) | Self::Inliers(InlierCsvError::Io { .. }) => 2,
            Self::Read(_) | Self::Inliers(_) => 2,
            Self::Solve {
                source: SolveError::Unconstrained { .. } | SolveError::NotPositiveDefinite { .. },
                ..
            } => 2,
            Self::Solve {
                source: SolveError::NonFiniteStart,
                ..
            } => 2,
            Self::Solve { .. } | Self::Write { .. } | Self::NonFiniteResult { .. } => 1,
        }
    }
}

/// Runs `pgo optimize`: returns the report (and writes the output file if
/// asked). `observer` sees every iteration.
pub fn run(
    config: &OptimizeConfig,
    observer: &mut dyn FnMut(&IterationRecord),
) -> Result<Report, PipelineError> {
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
    report.loop_candidates = file.graph.num_candidates();
    if let Some(out) = &config.output {
        write_output(&file, out)?;
        report.output = Some(out.display().to_string());
    }
    Ok(report)
}

fn optimize_graph<P: G2oPose<D> + ChordalInit<D>, const D: usize>(
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

    // Gate: learn T_GV from the candidates' counts and drop those below it.
    let candidates: Vec<usize> = (0..graph.edges.len())
        .filter(|&k| graph.edges[k].is_candidate())
        .collect();
    let counts: Vec<Option<u64>> = candidates
        .iter()
        .map(|&k| graph.edges[k].candidate.and_then(|c| c.inliers))
        .collect();
    let decision = gate::gate(&counts, config.gate, config.degenerate, &config.mixture);
    let mut weights = vec![1.0; graph.edges.len()];
    for (&k, &kept) in candidates.iter().zip(&decision.kept) {
        weights[k] = if kept { 1.0 } else { 0.0 };
    }
    report.gate = GateReport::new(&decision, &counts);
    if decision.degenerate && report.gate.counted > 0 {
        if let Some(reason) = &decision.reason {
            report.warnings.push(format!(
                "the inlier counts are degenerate: {reason}; policy {:?}",
                config.degenerate
            ));
        }
    }

    // An unconstrained vertex makes every later step meaningless: say so first.
    let mut optimizer =
        Optimizer::new(graph, Some(&weights), config.solver.clone()).map_err(solve_error)?;

    let start = Instant::now();
    // The file's own guess first (vertices without a line by spanning tree),
    // so that its χ² can be reported whatever the initialisation.
    initialize(graph, missing, Initialization::File, Some(&weights)).map_err(solve_error)?;
    report.input_chi2 = graph.chi2();
    if config.initialization != Initialization::File {
        initialize(graph, missing, config.initialization, Some(&weights)).map_err(solve_error)?;
    }
    report.initialization = InitializationReport {
        method: config.initialization,
        chi2: graph.chi2(),
        time_s: start.elapsed().as_secs_f64(),
        vertices_without_line: missing.len(),
    };

    let summary = optimizer
        .run(graph, Some(&weights), &mut |r: &IterationRecord| {
            observer(r)
        })
        .map_err(solve_error)?;
    if graph.poses.iter().any(|p| !p.is_finite()) {
        return Err(PipelineError::NonFiniteResult {
            path: config.input.clone(),
        });
    }
    report.optimizer = OptimizerReport::new(&summary, graph.chi2(), optimizer.system());

    // The χ² test over the edges that were optimised (weight ≥ ½), each at
    // its plain cost.
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
    report.loops = candidates
        .iter()
        .zip(&decision.kept)
        .map(|(&k, &kept)| {
            let e = &graph.edges[k];
            LoopReport {
                from: graph.id(e.from),
                to: graph.id(e.to),
                inliers: e.candidate.and_then(|c| c.inliers),
                kept,
                weight: weights[k],
            }
        })
        .collect();
    Ok(())
}

fn write_output(file: &G2oFile, out: &Path) -> Result<(), PipelineError> {
    crate::io::write_atomically(out, |w| file.write(w)).map_err(|source| PipelineError::Write {
        path: out.to_owned(),
        source,
    })
}
