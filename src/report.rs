//! The report of a run: what was read, how it was initialised and
//! optimised, serialised to JSON with `--json` and summarised for humans.
//! The types its fields hold are re-exported here.

use crate::gate::GateDecision;
use crate::geometry::Pose;
use crate::graph::VertexId;
use crate::io::g2o::ReadSummary;
use crate::linear::BlockSystem;
use crate::solve::{Method, Summary};
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::Path;

pub use crate::gate::{
    Degeneracy, DegeneratePolicy, EmStart, GateMode, LogNormalMixture, Separation, TwoNormals,
};
pub use crate::robust::{
    DOUBT_MOVE, Doubt, HeldBack, Layers, LoopModel, Outlying, Reason, RobustMethod, Search, Start,
    StartEnd, Suspect,
};
pub use crate::solve::init::Initialization;
pub use crate::solve::{StopReason, Timing};
pub use crate::stats::{Chi2Test, DofConvention};

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
    /// The geometric-verification gate.
    pub gate: GateReport,
    /// The χ² goodness-of-fit test of the result (absent when it cannot be
    /// computed, with a warning saying why).
    pub chi2_test: Option<Chi2Test>,
    /// The robust back end.
    pub robust: RobustReport,
    /// One entry per loop candidate, in file order.
    pub loops: Vec<LoopReport>,
    /// SVG pictures written (`--plot`).
    pub plots: Vec<String>,
    /// Trajectory files written (`pgo optimize --tum`, then `--kitti`;
    /// [`crate::Solution::write_tum`], [`crate::Solution::write_kitti`]),
    /// as given (`-`: stdout).
    pub trajectories: Vec<String>,
    /// Warnings, one line each.
    pub warnings: Vec<String>,
    /// Where the job's time went.
    pub time: JobTime,
    /// What an incremental update did ([`crate::PoseGraph::update`]);
    /// absent from a batch job's report.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub incremental: Option<IncrementalReport>,
    /// The certificate of global optimality of the map (`pgo optimize
    /// --certify`; [`crate::Solution::certificate`]); absent unless asked
    /// for.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub certificate: Option<crate::Certificate>,
}

/// Where a job's time went, in seconds: the phases in the order they ran,
/// and parts of the solve. A phase that did not run is 0.
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct JobTime {
    /// Reading and parsing the input.
    pub read_s: f64,
    /// The gate: the mixture fit on the inlier counts.
    pub gate_s: f64,
    /// The initial guess ([`InitializationReport::time_s`]).
    pub initialize_s: f64,
    /// The (robust) solve and the χ² test: the optimiser's runs
    /// ([`OptimizerReport::time_s`]), the next two, and EM's own steps.
    pub solve_s: f64,
    /// Of the solve: EM's chordal relaxations (outside the optimiser).
    pub relaxation_s: f64,
    /// Of the solve: EM's evaluations of maps (innovations and their
    /// covariances, the loop model, the decisions).
    pub evaluation_s: f64,
    /// Of the evaluations: the loop model's fits (EM on the innovations
    /// and counts); the rest is the innovations and their covariances.
    pub loop_model_s: f64,
    /// Writing the output.
    pub write_s: f64,
    /// The whole job.
    pub total_s: f64,
}

/// How an incremental update ([`crate::PoseGraph::update`]) reached its
/// map.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum UpdateSolve {
    /// The whole job from scratch: the first update, or the first after
    /// the kept state was invalidated (`reason` says which).
    Batch,
    /// Nothing was added since the last update: its solution stands.
    None,
    /// Only new poses, each hung on the map by one trusted edge: they are
    /// composed from it and the rest of the map is unchanged, which is
    /// exactly the optimum; no factorisation.
    Extended,
    /// From the last solution (new poses composed along trusted edges) and
    /// the last decisions: EM's decisions by innovation and its χ² search
    /// until the accepted set repeats — no annealing.
    Warm,
    /// From the last solution, every candidate weighed again by the robust
    /// kernel (a kernel method, or fewer candidates than EM's model needs).
    /// No longer made: from the last map a kernel can end in another
    /// minimum than the batch job's, so such an update runs the whole job
    /// ([`UpdateSolve::Batch`], docs/method.md §7b). Kept so that reports
    /// and bindings keep their names.
    Full,
}

impl UpdateSolve {
    /// Its name as the JSON report spells it: `batch`, `none`,
    /// `extended`, `warm` or `full` (for bindings).
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Batch => "batch",
            Self::None => "none",
            Self::Extended => "extended",
            Self::Warm => "warm",
            Self::Full => "full",
        }
    }
}

/// What an incremental update added and changed.
#[derive(Clone, Debug, Serialize)]
pub struct IncrementalReport {
    /// How the map was reached.
    pub solve: UpdateSolve,
    /// Why that way, in a few words.
    pub reason: String,
    /// Poses added since the last update.
    pub new_poses: usize,
    /// Edges (loop candidates included) added since the last update.
    pub new_edges: usize,
    /// Loop candidates among them.
    pub new_candidates: usize,
    /// The earlier candidates whose decision this update changed.
    pub changed: Vec<DecisionChange>,
}

/// An earlier loop candidate's decision that an update changed.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct DecisionChange {
    /// Its index, as [`crate::PoseGraph::add_loop_candidate`] returned it.
    pub index: usize,
    /// Its first vertex id.
    pub from: VertexId,
    /// Its second vertex id.
    pub to: VertexId,
    /// Whether it is in the map now (it was not before, or the reverse).
    pub accepted: bool,
    /// Why it ends where it does now.
    pub reason: Reason,
}

/// What the gate did.
#[derive(Clone, Debug, Serialize, Default)]
pub struct GateReport {
    /// Whether a gate was applied (mode other than `off`).
    pub enabled: bool,
    /// `auto`, `off` or `{"fixed": N}`.
    pub mode: GateMode,
    /// The degenerate policy.
    pub policy: DegeneratePolicy,
    /// `T_GV` in inlier counts (`count < T_GV` is dropped), when one was applied.
    pub threshold: Option<f64>,
    /// `T_GV / max_inliers`.
    pub normalized_threshold: Option<f64>,
    /// The largest inlier count.
    pub max_inliers: u64,
    /// Candidates with a count of zero (never fitted; "not a loop").
    pub zero_counts: usize,
    /// Candidates with a count.
    pub counted: usize,
    /// The fitted log-normal mixture (`mode = auto` or `soft`).
    pub mixture: Option<LogNormalMixture>,
    /// The whole fit, for pictures (not serialised: `mixture` and
    /// `separation` carry its numbers).
    #[serde(skip)]
    pub fit: Option<crate::gate::ThresholdFit>,
    /// BIC, Ashman's D and the loop component's size.
    pub separation: Option<Separation>,
    /// Candidates kept.
    pub kept: usize,
    /// Candidates dropped.
    pub dropped: usize,
    /// Whether the counts were found degenerate.
    pub degenerate: bool,
    /// Why, in plain words.
    pub reason: Option<String>,
}

impl GateReport {
    /// From the gate's decision and the candidates' counts.
    pub(crate) fn new(decision: &GateDecision, counts: &[Option<u64>]) -> Self {
        let max_inliers = counts.iter().flatten().copied().max().unwrap_or(0);
        let fit = decision.fit.as_ref();
        Self {
            enabled: decision.mode != GateMode::Off,
            mode: decision.mode,
            policy: decision.policy,
            threshold: decision.threshold,
            normalized_threshold: decision
                .threshold
                .filter(|_| max_inliers > 0)
                .map(|t| t / max_inliers as f64),
            max_inliers,
            zero_counts: counts.iter().filter(|c| **c == Some(0)).count(),
            counted: counts.iter().flatten().count(),
            mixture: fit.and_then(|f| f.mixture.clone()),
            fit: fit.cloned(),
            separation: fit.and_then(|f| f.separation.clone()),
            kept: decision.kept_count(),
            dropped: decision.dropped_count(),
            degenerate: decision.degenerate,
            reason: decision.reason.as_ref().map(|r| r.to_string()),
        }
    }

    /// One line for humans.
    pub fn summary(&self) -> String {
        let total = self.kept + self.dropped;
        if total == 0 {
            return "gate: no loop candidates".into();
        }
        let rule = match (self.mode, self.threshold) {
            (GateMode::Off, _) => "off".to_string(),
            (GateMode::Fixed(n), _) => format!("fixed threshold {n} inliers"),
            // Nothing to learn from (a public benchmark, `--candidates
            // non-sequential`): not a degenerate fit, there was none.
            _ if self.counted == 0 => "no inlier counts".to_string(),
            (GateMode::Soft, _) if !self.degenerate => {
                "soft (each candidate's P(true loop | count) is its robust prior)".to_string()
            }
            (_, Some(t)) if !self.degenerate => format!("T_GV = {t:.1} inliers"),
            (_, Some(t)) => format!("T_GV = {t:.1} inliers despite degenerate counts"),
            (_, None) if self.degenerate => {
                format!("degenerate counts (policy {})", self.policy.name())
            }
            (_, None) => "no threshold".to_string(),
        };
        format!(
            "gate: {rule}; kept {} of {total} loop candidates",
            self.kept
        )
    }
}

/// What the robust back end did.
#[derive(Clone, Debug, Serialize, Default)]
pub struct RobustReport {
    /// The method (`none` when there were no candidates to weigh).
    pub method: RobustMethod,
    /// Kernel width on the whitened-residual-norm scale (EM: the end of its
    /// annealing).
    pub c: f64,
    /// EM: E-steps of the annealing; the kernels: reweighting rounds.
    pub rounds: usize,
    /// EM with the chordal initial guess: chordal relaxations solved (two
    /// linear solves each): one per E-step of the annealing and one per
    /// accepted set solved.
    pub relaxations: usize,
    /// EM: accepted sets solved while deciding by innovation.
    pub decisions: usize,
    /// EM with the chordal initial guess: accepted sets solved from their
    /// chordal relaxation, which fitted them better than the map before.
    pub relaxed_starts: usize,
    /// EM: clusters of candidates judged together.
    pub clusters: usize,
    /// Candidates accepted at the end (the final map was solved with them).
    pub accepted_loops: usize,
    /// Candidates not accepted.
    pub rejected_loops: usize,
    /// Candidates the gate dropped that were accepted.
    pub rescued_loops: usize,
    /// EM: the loop model at the last evaluation (the spreads of the log
    /// innovations of true and wrong loops, the aliasing rate, the share of
    /// true loops among candidates without a count).
    pub model: Option<LoopModel>,
    /// EM: what the search on a failed χ² test did (removed clusters, and
    /// the suspects when it still fails).
    pub search: Option<Search>,
    /// EM: where each of its starts ended and which was kept (empty with
    /// one start).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub starts: Vec<StartEnd>,
    /// EM: whether its decisions did not settle at the last map they
    /// judged, which EM's second start and an update's whole job follow.
    /// A set kept from a cycle is reported as judged at its own map, where
    /// its loops can be `unsettled` though this is false — unless that map
    /// disputes as many candidates as it confirms of the set.
    #[serde(skip)]
    pub unsettled: bool,
    /// EM: the accepted clusters of a passing map whose errors share one
    /// offset and without which the map would move by more than
    /// [`DOUBT_MOVE`] of its size — what a place mistaken
    /// for another looks like (docs/method.md §7).
    pub doubtful: Vec<Doubt>,
    /// EM: the rejected loops of a passing map, by cluster, whose
    /// innovations speak for a true loop and whose inlier counts alone kept
    /// them out, and whose addition would move the map by more than
    /// [`DOUBT_MOVE`] of its size (docs/method.md §7).
    pub held_back: Vec<HeldBack>,
    /// EM: the accepted loops of a passing map, by cluster, whose
    /// innovations lie beyond what its true loops reach (at the χ² test's
    /// α over the loops tested) and whose removal would move the map by
    /// more than [`DOUBT_MOVE`] of its size (docs/method.md §7).
    pub outlying: Vec<Outlying>,
}

impl RobustReport {
    /// One clause for humans: what was accepted and how.
    pub fn summary(&self) -> String {
        let mut notes = Vec::new();
        if self.rescued_loops > 0 {
            notes.push(format!(
                "{} rescued from those the gate dropped",
                self.rescued_loops
            ));
        }
        if let Some(search) = &self.search {
            let removed: usize = search.removed.iter().map(|r| r.loops.len()).sum();
            if removed > 0 {
                notes.push(format!(
                    "{removed} taken out by the χ² search in {} clusters",
                    search.removed.len()
                ));
            }
        }
        let notes = if notes.is_empty() {
            String::new()
        } else {
            format!(" ({})", notes.join("; "))
        };
        format!(
            "robust {}: accepted {}{notes}, rejected {}",
            self.method.name(),
            self.accepted_loops,
            self.rejected_loops
        )
    }
}

/// One loop candidate's fate.
#[derive(Clone, Debug, Serialize)]
pub struct LoopReport {
    /// First vertex id.
    pub from: VertexId,
    /// Second vertex id.
    pub to: VertexId,
    /// Its inlier count, if it has one.
    pub inliers: Option<u64>,
    /// Whether it passed the gate.
    pub kept: bool,
    /// Whether the final map was solved with it.
    pub accepted: bool,
    /// Its weight in the final solve, in [0, 1] (≥ ½ exactly when
    /// accepted).
    pub weight: f64,
    /// EM: its prior probability of being a true loop (from its count).
    pub prior: Option<f64>,
    /// EM: its posterior probability of being a true loop.
    pub posterior: Option<f64>,
    /// EM: its squared innovation `ν²` against the map without it and its
    /// cluster (`null` when nothing else checks it).
    pub innovation: Option<f64>,
    /// Why it ended where it did.
    pub reason: Reason,
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
    /// χ² at the start (after initialisation): `Σ eᵀΩe` over all edges,
    /// g2o's error definition.
    pub initial_chi2: f64,
    /// χ² at the end, over all edges (dropped or down-weighted candidates
    /// included).
    pub final_chi2: f64,
    /// The objective minimised, `Σ wₖ eₖᵀΩₖeₖ`, at the start (equals
    /// `initial_chi2` when every weight is 1).
    pub initial_objective: f64,
    /// The objective at the end.
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
    /// Values stored for the Cholesky factor (8 bytes each) of the last
    /// pattern.
    pub nnz_factor: usize,
    /// The same for the largest factor of the run (the first pattern, when
    /// robust weighting later removed loops from it): what the peak memory
    /// held.
    pub max_nnz_factor: usize,
    /// Objective after each iteration.
    pub history: Vec<f64>,
    /// Where the optimiser's time went.
    pub timing: crate::solve::Timing,
}

impl OptimizerReport {
    /// From a solver summary, the unweighted χ² before and after, the
    /// linear system and the largest factor of the run (values).
    pub(crate) fn new<const D: usize>(
        summary: &Summary,
        initial_chi2: f64,
        final_chi2: f64,
        system: &BlockSystem<D>,
        max_nnz_factor: usize,
    ) -> Self {
        Self {
            solver: summary.method.short_name(),
            iterations: summary.iterations,
            initial_chi2,
            final_chi2,
            initial_objective: summary.initial_objective,
            final_objective: summary.final_objective,
            converged: summary.converged(),
            stop_reason: summary.stop_reason,
            time_s: summary.time.as_secs_f64(),
            factorizations: summary.factorizations,
            nnz_hessian: system.nnz_hessian(),
            nnz_factor: system.nnz_factor(),
            max_nnz_factor: max_nnz_factor.max(system.nnz_factor()),
            history: summary.history.iter().map(|r| r.objective).collect(),
            timing: summary.timing,
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
            initial_objective: 0.0,
            final_objective: 0.0,
            converged: false,
            stop_reason: StopReason::MaxIterations,
            time_s: 0.0,
            factorizations: 0,
            nnz_hessian: 0,
            nnz_factor: 0,
            max_nnz_factor: 0,
            history: Vec::new(),
            timing: Default::default(),
        }
    }
}

/// How far a finished job's map can be taken as it is — what `pgo
/// optimize`'s exit status says of it (0, 3, 4, 5, 130), for callers of
/// the library ([`Report::status`]). The first that applies, in this order:
/// cancelled, χ² test failed, unfinished, unsettled, questioned, ok.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum MapStatus {
    /// Nothing questions the map: the job finished, its χ² test passed
    /// (or there is none: the warnings say why), its loop decisions
    /// settled and the evidence questions none of them. Exit status 0.
    Ok,
    /// The χ² test failed: the map does not fit its measurements (the
    /// report's `robust.search` names the suspects). Exit status 3.
    Chi2Failed,
    /// An iteration or time limit stopped the job before it finished — a
    /// budget (`max_iterations`, `time_limit`; an update's `update_iters`
    /// on purpose) or the last solve's own limit: the best map so far, its
    /// decisions and χ² verdict unfinished. Exit status 4.
    Unfinished,
    /// The loop decisions did not settle (candidates
    /// [`Reason::Unsettled`]): the map rests on decisions its loop model
    /// does not confirm. Exit status 4.
    Unsettled,
    /// The map passed its χ² test with settled decisions, but the evidence
    /// questions some: a doubtful cluster ([`RobustReport::doubtful`]),
    /// loops held back by their counts ([`RobustReport::held_back`]) or
    /// accepted loops beyond the true loops' reach
    /// ([`RobustReport::outlying`]), any of which reversed would move the
    /// map by over [`DOUBT_MOVE`] of its size. Exit status 5.
    Questioned,
    /// A cancellation ([`crate::Cancel`]) stopped the job: the best map so
    /// far. Exit status 130 (Ctrl-C).
    Cancelled,
}

impl MapStatus {
    /// Its name in snake case (`"ok"`, `"chi2_failed"`, `"unfinished"`,
    /// `"unsettled"`, `"questioned"`, `"cancelled"`).
    pub fn name(self) -> &'static str {
        match self {
            Self::Ok => "ok",
            Self::Chi2Failed => "chi2_failed",
            Self::Unfinished => "unfinished",
            Self::Unsettled => "unsettled",
            Self::Questioned => "questioned",
            Self::Cancelled => "cancelled",
        }
    }
}

impl Report {
    /// A report of a graph (read from `input`, with what the reader
    /// noticed, or built in memory), before anything ran.
    pub(crate) fn for_graph<P: Pose<D>, const D: usize>(
        input: &Path,
        graph: &crate::graph::Graph<P, D>,
        read: &ReadSummary,
    ) -> Self {
        Self {
            input: input.display().to_string(),
            output: None,
            dimension: crate::geometry::dimension::<D>(),
            poses: graph.num_vertices(),
            edges: graph.edges.len(),
            loop_candidates: graph.num_candidates(),
            skipped_tags: read.skipped_tags.clone(),
            information_fixed: read.information_fixed,
            input_chi2: 0.0,
            initialization: InitializationReport::default(),
            optimizer: OptimizerReport::default(),
            gate: GateReport::default(),
            chi2_test: None,
            robust: RobustReport::default(),
            loops: Vec::new(),
            plots: Vec::new(),
            trajectories: Vec::new(),
            warnings: read.warnings.clone(),
            time: JobTime::default(),
            incremental: None,
            certificate: None,
        }
    }

    /// How far the map can be taken as it is ([`MapStatus`]).
    pub fn status(&self) -> MapStatus {
        let stop = self.optimizer.stop_reason;
        let robust = &self.robust;
        if stop == StopReason::Cancelled {
            MapStatus::Cancelled
        } else if self.chi2_test.as_ref().is_some_and(|t| !t.passed) {
            MapStatus::Chi2Failed
        } else if matches!(stop, StopReason::MaxIterations | StopReason::TimeLimit) {
            MapStatus::Unfinished
        } else if self.loops.iter().any(|l| l.reason == Reason::Unsettled) {
            MapStatus::Unsettled
        } else if !(robust.doubtful.is_empty()
            && robust.held_back.is_empty()
            && robust.outlying.is_empty())
        {
            MapStatus::Questioned
        } else {
            MapStatus::Ok
        }
    }

    /// The report as `pgo optimize --json` prints it (pretty-printed; NaN
    /// and infinities as `null`). Errors: [`crate::Error::Internal`],
    /// which plain fields like these do not give.
    #[cfg(feature = "json")]
    pub fn to_json(&self) -> Result<String, crate::Error> {
        serde_json::to_string_pretty(self)
            .map_err(|e| crate::Error::Internal(format!("cannot serialise the report: {e}")))
    }

    /// The human summary, a few lines for stderr: [`Self::header`], then
    /// [`Self::human_body`].
    pub fn human_summary(&self) -> String {
        let mut s = Self::header(
            &self.input,
            self.dimension,
            [self.poses, self.edges, self.loop_candidates],
        );
        s.push('\n');
        s + &self.human_body()
    }

    /// The summary's first line: the input, its dimension and its poses,
    /// edges and loop candidates (what `pgo optimize` prints before it
    /// starts).
    pub fn header(input: &str, dimension: usize, [poses, edges, candidates]: [usize; 3]) -> String {
        format!("{input}: {dimension}D, {poses} poses, {edges} edges, {candidates} loop candidates")
    }

    /// The summary after its header: the initial guess, the optimiser, the
    /// gate's and the robust method's decisions and the χ² verdict, the
    /// certificate, the warnings and the files written.
    pub fn human_body(&self) -> String {
        let o = &self.optimizer;
        let mut s = String::new();
        s += &format!(
            "initial guess: {:?}, χ² {:.6e} (file's guess {:.6e})\n",
            self.initialization.method, self.initialization.chi2, self.input_chi2
        );
        s += &format!(
            "{}: {} iterations, objective {:.10e} → {:.10e}, {} ({:?}), {:.3} s\n",
            o.solver,
            o.iterations,
            o.initial_objective,
            o.final_objective,
            if o.converged {
                "converged"
            } else {
                "not converged"
            },
            o.stop_reason,
            o.time_s + self.initialization.time_s
        );
        // One line: the threshold, what was kept, and the χ² verdict.
        let mut verdict = Vec::new();
        if self.loop_candidates > 0 {
            verdict.push(self.gate.summary());
            if self.robust.method != RobustMethod::None {
                verdict.push(self.robust.summary());
            }
        }
        if let Some(t) = &self.chi2_test {
            verdict.push(format!(
                "χ² test {}: D² = {:.4e} {} χ²({}, {}) = {:.4e}",
                if t.passed { "passed" } else { "FAILED" },
                t.d2,
                if t.passed { "≤" } else { ">" },
                t.dof,
                1.0 - t.alpha,
                t.critical,
            ));
        }
        if !verdict.is_empty() {
            s += &verdict.join("; ");
            s.push('\n');
        }
        if let Some(c) = &self.certificate {
            s += &c.summary();
            s.push('\n');
        }
        for w in &self.warnings {
            s += &format!("warning: {w}\n");
        }
        if let Some(out) = &self.output {
            s += &format!("wrote {out}\n");
        }
        for path in &self.trajectories {
            s += &format!("wrote {path}\n");
        }
        s
    }

    /// One line for humans: where the job's time went ([`JobTime`]).
    pub fn time_summary(&self) -> String {
        let t = &self.time;
        format!(
            "time: read {:.2} s, gate {:.2} s, initial guess {:.2} s, solve {:.2} s (optimiser \
             {:.2} s, relaxations {:.2} s, evaluations {:.2} s of which the loop model {:.2} s), \
             write {:.2} s; {:.2} s in all",
            t.read_s,
            t.gate_s,
            t.initialize_s,
            t.solve_s,
            self.optimizer.time_s,
            t.relaxation_s,
            t.evaluation_s,
            t.loop_model_s,
            t.write_s,
            t.total_s
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gate::{MixtureOptions, gate};

    fn summary(counts: &[Option<u64>], mode: GateMode) -> String {
        let policy = DegeneratePolicy::default();
        let decision = gate(counts, mode, policy, &MixtureOptions::default());
        GateReport::new(&decision, counts).summary()
    }

    #[test]
    fn the_gate_summary_says_what_the_gate_had_to_go_on() {
        assert_eq!(summary(&[], GateMode::Auto), "gate: no loop candidates");
        assert_eq!(
            summary(&[None; 5], GateMode::Auto),
            "gate: no inlier counts; kept 5 of 5 loop candidates"
        );
        assert_eq!(
            summary(&[None; 5], GateMode::Off),
            "gate: off; kept 5 of 5 loop candidates"
        );
        // One count value only: a degenerate fit, which is said.
        let same = vec![Some(40); 30];
        assert_eq!(
            summary(&same, GateMode::Auto),
            "gate: degenerate counts (policy keep-all); kept 30 of 30 loop candidates"
        );
        // Two well-separated populations: a learned threshold.
        let two: Vec<Option<u64>> = (0..60)
            .map(|i| {
                Some(if i % 2 == 0 {
                    8 + i % 7
                } else {
                    200 + 3 * (i % 11)
                })
            })
            .collect();
        let line = summary(&two, GateMode::Auto);
        assert!(line.starts_with("gate: T_GV = "), "{line}");
        assert!(line.ends_with("kept 30 of 60 loop candidates"), "{line}");
    }
}
