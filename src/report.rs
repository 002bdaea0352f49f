//! The report of a run: what was read, how it was initialised and
//! optimised, serialised to JSON with `--json` and summarised for humans.

use crate::io::g2o::G2oFile;
use crate::linear::BlockSystem;
use crate::solve::init::Initialization;
use crate::solve::{Method, StopReason, Summary};
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::Path;

/// The JSON report of `pgo optimize`.
#[derive(Clone, Debug, Serialize)]
pub struct Report {
    /// The input file.
    pub input: String,
    /// The output file, if one was written.
    pub output: Option<String>,
    /// 2 or 3.
    pub dimension: usize,
    /// Number of vertices.
    pub poses: usize,
    /// Number of edges.
    pub edges: usize,
    /// Number of loop-closure candidates.
    pub loop_candidates: usize,
    /// Lines skipped for their unsupported tags, by tag.
    pub skipped_tags: BTreeMap<String, usize>,
    /// Information matrices projected to positive definite.
    pub information_fixed: usize,
    /// χ² of the file's own guess (vertices without a line composed along a
    /// spanning tree).
    pub input_chi2: f64,
    /// The initial guess.
    pub initialization: InitializationReport,
    /// The optimisation.
    pub optimizer: OptimizerReport,
    /// Warnings, one line each.
    pub warnings: Vec<String>,
}

/// How the initial guess was made.
#[derive(Clone, Debug, Serialize, Default)]
pub struct InitializationReport {
    /// `file`, `odometry` or `chordal`.
    pub method: Initialization,
    /// χ² of the initial guess.
    pub chi2: f64,
    /// Seconds spent.
    pub time_s: f64,
    /// Vertices that edges named but no vertex line defined.
    pub vertices_without_line: usize,
}

/// What the optimiser did.
#[derive(Clone, Debug, Serialize)]
pub struct OptimizerReport {
    /// `lm` or `gn`.
    pub solver: &'static str,
    /// Outer iterations.
    pub iterations: usize,
    /// χ² at the start (after initialisation).
    pub initial_chi2: f64,
    /// χ² at the end: `Σ eᵀΩe` over all edges, g2o's error definition.
    pub final_chi2: f64,
    /// The objective minimised at the end (equals `final_chi2` without robust
    /// weights).
    pub final_objective: f64,
    /// Whether a convergence test stopped it.
    pub converged: bool,
    /// Why it stopped.
    pub stop_reason: StopReason,
    /// Seconds in the optimiser.
    pub time_s: f64,
    /// Numeric factorisations, LM retries included.
    pub factorizations: usize,
    /// Non-zeros of the lower triangle of `H`.
    pub nnz_hessian: usize,
    /// Non-zeros of the Cholesky factor.
    pub nnz_factor: usize,
    /// Objective after each iteration.
    pub history: Vec<f64>,
}

impl OptimizerReport {
    /// From a solver summary, the final unweighted χ² and the linear system.
    pub fn new<const D: usize>(
        summary: &Summary,
        final_chi2: f64,
        system: &BlockSystem<D>,
    ) -> Self {
        Self {
            solver: summary.method.short_name(),
            iterations: summary.iterations,
            initial_chi2: summary.initial_objective,
            final_chi2,
            final_objective: summary.final_objective,
            converged: summary.converged(),
            stop_reason: summary.stop_reason,
            time_s: summary.time.as_secs_f64(),
            factorizations: summary.factorizations,
            nnz_hessian: system.nnz_hessian(),
            nnz_factor: system.nnz_factor(),
            history: summary.history.iter().map(|r| r.objective).collect(),
        }
    }
}

impl Default for OptimizerReport {
    fn default() -> Self {
        Self {
            solver: Method::default().short_name(),
            iterations: 0,
            initial_chi2: 0.0,
            final_chi2: 0.0,
            final_objective: 0.0,
            converged: false,
            stop_reason: StopReason::MaxIterations,
            time_s: 0.0,
            factorizations: 0,
            nnz_hessian: 0,
            nnz_factor: 0,
            history: Vec::new(),
        }
    }
}

impl Report {
    /// A report of what was read, before anything ran.
    pub fn new(input: &Path, file: &G2oFile) -> Self {
        Self {
            input: input.display().to_string(),
            output: None,
            dimension: file.graph.dimension(),
            poses: file.graph.num_vertices(),
            edges: file.graph.num_edges(),
            loop_candidates: file.graph.num_candidates(),
            skipped_tags: file.summary.skipped_tags.clone(),
            information_fixed: file.summary.information_fixed,
            input_chi2: 0.0,
            initialization: InitializationReport::default(),
            optimizer: OptimizerReport::default(),
            warnings: file.summary.warnings.clone(),
        }
    }

    /// The human summary, a few lines for stderr.
    pub fn human_summary(&self) -> String {
        let o = &self.optimizer;
        let mut s = format!(
            "{}: {}D, {} poses, {} edges, {} loop candidates\n",
            self.input, self.dimension, self.poses, self.edges, self.loop_candidates
        );
        s += &format!(
            "initial guess: {:?}, χ² {:.6e} (file's guess {:.6e})\n",
            self.initialization.method, self.initialization.chi2, self.input_chi2
        );
        s += &format!(
            "{}: {} iterations, χ² {:.10e} → {:.10e}, {} ({:?}), {:.3} s\n",
            o.solver,
            o.iterations,
            o.initial_chi2,
            o.final_chi2,
            if o.converged {
                "converged"
            } else {
                "not converged"
            },
            o.stop_reason,
            o.time_s + self.initialization.time_s
        );
        for w in &self.warnings {
            s += &format!("warning: {w}\n");
        }
        if let Some(out) = &self.output {
            s += &format!("wrote {out}\n");
        }
        s
    }
}
