//! Nonlinear least squares on the pose graph: Gauss–Newton and
//! Levenberg–Marquardt over the sparse normal equations of
//! [`crate::linear`], plus initial guesses ([`init`]) and the innovations
//! of single edges against a solution ([`Optimizer::innovation_chi2`]).
//!
//! The private modules follow the method: `normal` assembles the normal
//! equations and evaluates the objective, `pattern` keeps their sparsity
//! pattern, `gn` and `lm` find one step, `innovation` judges single edges.
//!
//! The objective is `Σ wₖ·eₖᵀΩₖeₖ` with the g2o edge error of
//! [`crate::geometry`] and per-edge weights `wₖ` (1 unless a robust method
//! sets them). The gauge vertices are held fixed.

mod chord;
mod gn;
pub mod init;
mod innovation;
mod keep;
mod lm;
mod normal;
mod pattern;
mod progress;
mod remaining;
mod session;
#[cfg(test)]
mod tests;

use crate::geometry::Pose;
use crate::graph::{Graph, VertexId};
use crate::linear::{BlockSystem, LinearError, Parallelism};
use chord::Chord;
use innovation::FactoredAt;
use lm::Damping;
use normal::EdgeTerms;
use remaining::Remaining;
// The batches of a linearisation, also for the covariances' (`crate::covariance`).
pub(crate) use normal::{EDGES_PER_TASK, LINEARIZE_CHUNK};
pub use pattern::Ordering;
pub use progress::{Cancel, Cancellable, Observer};
use serde::Serialize;
pub(crate) use session::{Budget, PhaseTimes, Session};
use std::time::{Duration, Instant};

/// The nonlinear least-squares method.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum Method {
    /// Levenberg–Marquardt with Marquardt's diagonal scaling and Nielsen's
    /// damping update, starting undamped: λ = 0 (a Gauss–Newton step) until
    /// a step is rejected, then `initial_lambda` and Nielsen's rule.
    #[default]
    LevenbergMarquardt,
    /// Gauss–Newton: the undamped step, always taken.
    GaussNewton,
}

impl Method {
    /// `"lm"` or `"gn"`.
    pub fn short_name(self) -> &'static str {
        match self {
            Self::LevenbergMarquardt => "lm",
            Self::GaussNewton => "gn",
        }
    }
}

/// The optimiser's settings for one solve: method, bounds, tolerances and
/// threads. The job derives them from the caller's
/// [`crate::SolverOptions`]; an incremental update tightens or loosens
/// the tolerances for its own solves.
#[derive(Clone, Debug)]
pub struct SolveSettings {
    /// GN or LM.
    pub method: Method,
    /// Most outer iterations (accepted or final steps).
    pub max_iterations: usize,
    /// Stop when the relative decrease of the objective in one iteration is
    /// below this.
    pub relative_tolerance: f64,
    /// Stop when the step's largest component is below this (radians /
    /// metres-ish: the units of the tangent space).
    pub step_tolerance: f64,
    /// Also stop after a lightly damped step whose decrease the
    /// Gauss–Newton model foresaw to within this share of the objective:
    /// what the model missed is the nonlinearity the next step would take
    /// out, and near an optimum that next decrease is smaller still (off by
    /// default; incremental updates, which start next to the optimum, use
    /// it to save the iteration that would only confirm convergence).
    pub model_tolerance: Option<f64>,
    /// Also stop after a step that only crawls ([`Crawl`]). Not
    /// convergence ([`StopReason::Crawling`]); off by default (EM's
    /// decisions use it for accepted sets that have not settled yet).
    pub crawl_tolerance: Option<Crawl>,
    /// Take chord steps: after an undamped step, the next one is solved
    /// with the same factor against the new gradient, and the matrix is
    /// factorised again only where that step falls short
    /// ([`chord`](self::chord)). Off by default; an incremental update's
    /// solves, which start next to the optimum, use it.
    pub reuse_factor: bool,
    /// A chord step ends a run (by the relative or the model's tolerance)
    /// only if it moved no pose by more than this — `(translation,
    /// rotation)`, in the map's units and radians; else a Gauss–Newton
    /// step follows. A chord step contracts the error least along the
    /// map's weakest directions, where the objective is flattest: one that
    /// lowers it by 10⁻¹⁰ of itself can leave the poses about as far from
    /// the optimum again as it moved them ([`remaining`](self::remaining)).
    /// `None`: any chord step may end it.
    pub end_step: Option<(f64, f64)>,
    /// Stop when this much time has passed; the best estimate so far is kept.
    pub time_limit: Option<Duration>,
    /// LM damping `λ` (relative to the diagonal of `H`) after the first
    /// rejected step; until then λ = 0.
    pub initial_lambda: f64,
    /// Keep the last factorisation's panels that no change of `H` reaches
    /// (a capped update's, [`keep`](self::keep)): a block counts as changed
    /// where it is new, a new edge reaches it, or an edge joins it to a
    /// pose that moved by more than this (the largest component of its
    /// tangent-space move) since its block was last formed. `None`: every
    /// factorisation is whole.
    pub keep_factor: Option<f64>,
    /// Threads of the parallel work (linearisation, the objective at trial
    /// points, assembly and numeric factorisation): 0 and 1 run all of it in
    /// the calling thread and start no thread; N ≥ 2 runs it on a private
    /// pool of exactly N threads that the optimiser starts and owns (rayon's
    /// global pool is neither used nor configured). The same input, options
    /// and number of threads give the same bits.
    pub threads: usize,
}

/// The least share of the last Gauss–Newton step's gain that the next
/// step's gain keeps where Gauss–Newton converges linearly ([`Crawl`]):
/// near a small-residual optimum, where it converges quadratically, each
/// gain is a small share of the last; ½ lies between.
const LINEAR_CONVERGENCE: f64 = 0.5;

/// When a step only crawls ([`SolveSettings::crawl_tolerance`]): each a
/// share of the objective.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Crawl {
    /// A damped LM step (λ > 0) that lowered the objective by less than
    /// this: LM crawling along a curved valley, each step cut short by the
    /// damping.
    pub damped: f64,
    /// A Gauss–Newton step (undamped, not a chord step) that lowered it by
    /// less than this and by at least [`LINEAR_CONVERGENCE`] of what the
    /// Gauss–Newton step before it did: converging linearly, as
    /// Gauss–Newton does where the residuals stay large, each step a nearly
    /// constant share of the last.
    pub linear: f64,
}

impl Default for SolveSettings {
    fn default() -> Self {
        Self {
            method: Method::LevenbergMarquardt,
            max_iterations: 100,
            relative_tolerance: 1e-9,
            step_tolerance: 1e-12,
            model_tolerance: None,
            crawl_tolerance: None,
            reuse_factor: false,
            end_step: None,
            time_limit: None,
            initial_lambda: 1e-6,
            keep_factor: None,
            threads: 0,
        }
    }
}

/// Why the optimiser stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum StopReason {
    /// The objective's relative decrease fell below the tolerance after a
    /// step the Gauss–Newton model is trusted at (at most lightly damped,
    /// its decrease foreseen by the model).
    RelativeDecrease,
    /// The step became negligible, at most lightly damped.
    SmallStep,
    /// The objective is zero.
    ZeroError,
    /// LM could not find a decreasing step however much it damped.
    NoDecrease,
    /// The iteration limit was reached.
    MaxIterations,
    /// The time limit was reached.
    TimeLimit,
    /// There was nothing to optimise (no free vertex).
    NothingToOptimize,
    /// The observer asked to stop ([`Observer::should_stop`]).
    Cancelled,
    /// Damped steps lowered the objective by less than
    /// [`SolveSettings::crawl_tolerance`]: LM was crawling. Not a minimum.
    Crawling,
    /// The objective stopped decreasing (the relative decrease or the step
    /// fell below its tolerance) where the Gauss–Newton model is not
    /// trusted: under heavy damping, or after a step that gave far less
    /// than the model foresaw. Not a minimum; the best poses are kept.
    Stalled,
}

impl StopReason {
    /// Whether this reason means convergence.
    pub fn converged(self) -> bool {
        matches!(
            self,
            Self::RelativeDecrease | Self::SmallStep | Self::ZeroError | Self::NothingToOptimize
        )
    }
}

/// One outer iteration, for observers and the report.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct IterationRecord {
    /// 1-based iteration number.
    pub iteration: usize,
    /// Objective after the iteration.
    pub objective: f64,
    /// LM's damping after the iteration: the damping of the accepted step
    /// as Nielsen's rule updated it for the next one (0 for GN, and while
    /// LM has not damped).
    pub lambda: f64,
    /// Rejected LM trials before the accepted step.
    pub rejected: usize,
    /// Largest absolute component of the step.
    pub step_max: f64,
    /// Wall time from the start of the run to the end of the iteration.
    #[serde(rename = "elapsed_s", serialize_with = "serialize_seconds")]
    pub elapsed: Duration,
}

/// What an optimisation did.
#[derive(Clone, Debug, Serialize)]
pub struct Summary {
    /// The method.
    pub method: Method,
    /// Outer iterations.
    pub iterations: usize,
    /// Objective at the start.
    pub initial_objective: f64,
    /// Objective at the end (the best seen).
    pub final_objective: f64,
    /// Why it stopped.
    pub stop_reason: StopReason,
    /// Numeric factorisations (LM retries included).
    pub factorizations: usize,
    /// Wall time.
    #[serde(serialize_with = "serialize_seconds")]
    pub time: Duration,
    /// Per-iteration history.
    pub history: Vec<IterationRecord>,
    /// Where the time went.
    pub timing: Timing,
}

/// Wall time spent in each part of the optimiser, in seconds.
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct Timing {
    /// Errors, Jacobians and assembly of `H` and `b`.
    pub linearize_s: f64,
    /// Numeric Cholesky factorisations (with damping).
    pub factorize_s: f64,
    /// Triangular solves.
    pub solve_s: f64,
    /// Objective at trial points (and the step update).
    pub evaluate_s: f64,
}

impl Timing {
    /// Adds another run's times.
    pub fn add(&mut self, other: &Timing) {
        self.linearize_s += other.linearize_s;
        self.factorize_s += other.factorize_s;
        self.solve_s += other.solve_s;
        self.evaluate_s += other.evaluate_s;
    }
}

/// Wall time since a run started, and since the last lap.
struct Stopwatch {
    start: Instant,
    last: Instant,
}

impl Stopwatch {
    fn start() -> Self {
        let now = Instant::now();
        Self {
            start: now,
            last: now,
        }
    }

    /// Adds the time since the last lap to `slot`; a new lap starts.
    fn lap(&mut self, slot: &mut f64) {
        let now = Instant::now();
        *slot += (now - self.last).as_secs_f64();
        self.last = now;
    }

    /// Time since the start.
    fn elapsed(&self) -> Duration {
        self.start.elapsed()
    }
}

/// What a run has done so far: the summary it will return, and its clock.
struct Progress {
    summary: Summary,
    watch: Stopwatch,
}

impl Progress {
    /// Counts the taken `step` as one iteration more, in the history and
    /// for the `observer`.
    fn record(&mut self, step: &Step, observer: &mut dyn Observer) {
        let summary = &mut self.summary;
        summary.iterations += 1;
        let record = step.record(summary.iterations, self.watch.elapsed());
        summary.history.push(record);
        observer.iteration(&record);
    }

    /// The summary of a run that stopped for `reason` at `objective`.
    fn finish(mut self, reason: StopReason, objective: f64) -> Summary {
        self.summary.final_objective = objective;
        self.summary.stop_reason = reason;
        self.summary.time = self.watch.elapsed();
        self.summary
    }

    /// Adds the time since the last lap to the slot `part` picks.
    fn lap(&mut self, part: impl FnOnce(&mut Timing) -> &mut f64) {
        self.watch.lap(part(&mut self.summary.timing));
    }
}

impl Summary {
    /// A run of `method` that has not started.
    fn new(method: Method) -> Self {
        Self {
            method,
            iterations: 0,
            initial_objective: 0.0,
            final_objective: 0.0,
            stop_reason: StopReason::MaxIterations,
            factorizations: 0,
            time: Duration::ZERO,
            history: Vec::new(),
            timing: Timing::default(),
        }
    }

    /// Whether the optimiser converged.
    pub fn converged(&self) -> bool {
        self.stop_reason.converged()
    }
}

fn serialize_seconds<S: serde::Serializer>(d: &Duration, s: S) -> Result<S::Ok, S::Error> {
    s.serialize_f64(d.as_secs_f64())
}

/// Errors of the optimiser.
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
pub enum SolveError {
    /// Some vertices are not connected to the gauge by any chain of edges,
    /// so their poses are undetermined.
    #[error(
        "{} vertices are not connected to the gauge vertex {gauge} by any edge chain, e.g. {}",
        .vertices.len(),
        list_ids(.vertices)
    )]
    Unconstrained {
        /// The gauge vertex (first fixed vertex).
        gauge: VertexId,
        /// The unconstrained vertex ids.
        vertices: Vec<VertexId>,
    },
    /// The normal equations are singular or indefinite at a vertex.
    #[error(
        "the normal equations are not positive definite at vertex {vertex}: its edges do not determine its pose"
    )]
    NotPositiveDefinite {
        /// The vertex id.
        vertex: VertexId,
    },
    /// The initial estimate gives a non-finite objective.
    #[error("the initial objective is not finite (NaN or infinite poses or information)")]
    NonFiniteStart,
    /// The linear solver failed otherwise.
    #[error(transparent)]
    Linear(#[from] LinearError),
    /// The edge weights do not match the edges.
    #[error("{weights} edge weights for {edges} edges")]
    WeightCount {
        /// Weights given.
        weights: usize,
        /// Edges in the graph.
        edges: usize,
    },
}

fn list_ids(ids: &[VertexId]) -> String {
    let shown: Vec<String> = ids.iter().take(10).map(|i| i.to_string()).collect();
    if ids.len() > 10 {
        format!("{} …", shown.join(", "))
    } else {
        shown.join(", ")
    }
}

/// An optimiser bound to one graph structure: the sparsity pattern, its
/// ordering and symbolic factorisation are built once here and reused by
/// every [`Optimizer::run`] (e.g. across robust reweighting rounds).
pub struct Optimizer<P: Pose<D>, const D: usize> {
    system: BlockSystem<D>,
    /// Vertex of each variable block.
    vertex_of: Vec<usize>,
    /// Whether each edge is in the sparsity pattern (edges of weight 0 at
    /// construction are not; see [`Self::update_pattern`]).
    in_pattern: Vec<bool>,
    /// Whether the optimiser has factorised since it was made (see
    /// [`Self::update_pattern`]).
    factorized: bool,
    /// The poses, weights and gauge of the undamped factorisation
    /// ([`Self::factor_at`]) the system holds, with its selected inverse
    /// once taken, while nothing has changed the system since: the checks
    /// after the decisions factorise the map the decisions' last
    /// evaluation factorised.
    factored_at: Option<FactoredAt<P>>,
    /// Values of the largest factor among the patterns built so far.
    max_nnz_factor: usize,
    options: SolveSettings,
    trial: Vec<P>,
    best: Vec<P>,
    step: Vec<f64>,
    /// How far the last run's last step left the poses from the optimum.
    remaining: Remaining,
    terms: Vec<EdgeTerms<D>>,
    /// Each edge's plain χ² at the last poses evaluated.
    edge_chi2: Vec<f64>,
    /// Whether those are still the poses in `prepared` (a linearisation
    /// elsewhere since replaces them).
    chi2_at_prepared: bool,
    /// Each edge's measurement, prepared once ([`Pose::prepare`]).
    measurements: Vec<P::Prepared>,
    /// The poses last evaluated, each with its preparation.
    prepared: Vec<(P, P::Prepared)>,
    /// Where the parallel work runs ([`SolveSettings::threads`]); shared
    /// with `system`.
    parallelism: Parallelism,
    /// The order kept across a growing graph's solves, if any.
    ordering: Option<Ordering>,
    /// The last factorisation, for a later capped update to keep
    /// ([`SolveSettings::keep_factor`]), and what the last assembly found.
    kept: Option<keep::Kept<P>>,
    plan: Option<keep::Plan<P>>,
}

/// What an optimiser hands to the next one of the same graph grown by
/// vertices and edges appended (an incremental update's): its
/// factorisation's allocation, which the next fills instead of faulting
/// fresh pages in; each edge's measurement, prepared; and the poses it
/// last evaluated, prepared, which the next does not prepare again while
/// they are unchanged. Its copy holds nothing, so that a copy of a graph's
/// state starts without one.
pub struct Spare<P: Pose<D>, const D: usize> {
    factor: Vec<f64>,
    kept: Option<keep::Kept<P>>,
    measurements: Vec<P::Prepared>,
    prepared: Vec<(P, P::Prepared)>,
}

impl<P: Pose<D>, const D: usize> Default for Spare<P, D> {
    fn default() -> Self {
        Self {
            factor: Vec::new(),
            kept: None,
            measurements: Vec::new(),
            prepared: Vec::new(),
        }
    }
}

impl<P: Pose<D>, const D: usize> Clone for Spare<P, D> {
    fn clone(&self) -> Self {
        Self::default()
    }
}

impl<P: Pose<D>, const D: usize> std::fmt::Debug for Spare<P, D> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Spare")
            .field("factor", &self.factor.capacity())
            .field("measurements", &self.measurements.len())
            .field("prepared", &self.prepared.len())
            .finish()
    }
}

impl<P: Pose<D>, const D: usize> Optimizer<P, D> {
    /// Prepares to optimise `graph` (its structure, not its values).
    /// Fails if some vertex is not connected to the gauge by edges of
    /// non-zero weight (`weights`: one per edge, default 1).
    pub fn new(
        graph: &Graph<P, D>,
        weights: Option<&[f64]>,
        options: SolveSettings,
    ) -> Result<Self, SolveError> {
        Self::with_ordering(graph, weights, options, None)
    }

    /// [`Optimizer::new`] that orders the pattern as `ordering` does while
    /// that costs little more fill than a fresh order ([`Ordering`]), and
    /// keeps the order it uses there ([`Optimizer::ordering`]): the same
    /// graph grown by a few poses is then not ordered afresh.
    pub fn with_ordering(
        graph: &Graph<P, D>,
        weights: Option<&[f64]>,
        options: SolveSettings,
        ordering: Option<Ordering>,
    ) -> Result<Self, SolveError> {
        if let Some(w) = weights {
            if w.len() != graph.edges.len() {
                return Err(SolveError::WeightCount {
                    weights: w.len(),
                    edges: graph.edges.len(),
                });
            }
        }
        let unconstrained = graph.unconstrained_vertices(weights);
        let gauge = graph.gauge();
        if !unconstrained.is_empty() {
            return Err(SolveError::Unconstrained {
                gauge: gauge.first().map(|&g| graph.id(g)).unwrap_or(0),
                vertices: unconstrained.iter().map(|&k| graph.id(k)).collect(),
            });
        }
        let mut vertex_of = Vec::new();
        let variable = Self::variables(graph, &unconstrained, &mut vertex_of);
        let in_pattern: Vec<bool> = (0..graph.edges.len())
            .map(|k| weights.is_none_or(|w| w[k] != 0.0))
            .collect();
        let parallelism = Parallelism::new(options.threads)?;
        let mut optimizer = Self {
            max_nnz_factor: 0,
            factorized: false,
            factored_at: None,
            system: BlockSystem::new(0, &[], parallelism.clone())?,
            ordering,
            in_pattern,
            step: vec![0.0; vertex_of.len() * D],
            vertex_of,
            trial: graph.poses.clone(),
            remaining: Remaining::default(),
            best: graph.poses.clone(),
            options,
            terms: Vec::new(),
            edge_chi2: Vec::new(),
            chi2_at_prepared: false,
            // Filled by the first linearisation or evaluation.
            measurements: Vec::new(),
            prepared: Vec::new(),
            parallelism,
            kept: None,
            plan: None,
        };
        optimizer.system = optimizer.pattern(graph, &variable)?;
        optimizer.max_nnz_factor = optimizer.system.nnz_factor();
        Ok(optimizer)
    }

    /// Hands over what a later optimiser of this graph grown can reuse
    /// ([`Optimizer::reuse_spare`]).
    pub fn take_spare(&mut self) -> Spare<P, D> {
        self.forget_factored();
        Spare {
            factor: self.system.take_factor_allocation(),
            kept: self.kept.take(),
            measurements: std::mem::take(&mut self.measurements),
            prepared: std::mem::take(&mut self.prepared),
        }
    }

    /// Takes over `spare`, from an earlier optimiser of this graph when it
    /// had the same first edges ([`Optimizer::take_spare`]), before the
    /// first linearisation or evaluation.
    pub fn reuse_spare(&mut self, spare: Spare<P, D>) {
        self.forget_factored();
        self.system.reuse_factor_allocation(spare.factor);
        self.kept = spare.kept;
        self.measurements = spare.measurements;
        self.prepared = spare.prepared;
    }

    /// The elimination order kept for a later [`Optimizer::with_ordering`]
    /// (`None` for an optimiser made by [`Optimizer::new`]).
    pub fn ordering(&self) -> Option<&Ordering> {
        self.ordering.as_ref()
    }

    /// Starts or stops the private pool if [`SolveSettings::threads`] was
    /// changed ([`Self::options_mut`]) since it was set up.
    fn match_threads(&mut self) -> Result<(), SolveError> {
        if self.options.threads.max(1) != self.parallelism.threads() {
            self.parallelism = Parallelism::new(self.options.threads)?;
            self.system.set_parallelism(self.parallelism.clone());
        }
        Ok(())
    }

    /// The threads the optimiser's linear algebra runs on, for other
    /// linear solves of the same job.
    pub fn parallelism(&self) -> &Parallelism {
        &self.parallelism
    }

    /// The options, e.g. to change the iteration limit between runs.
    pub fn options_mut(&mut self) -> &mut SolveSettings {
        &mut self.options
    }

    /// The linear system, e.g. to factorise and solve it in a benchmark.
    #[cfg(any(test, feature = "internals"))]
    pub fn system_mut(&mut self) -> &mut BlockSystem<D> {
        self.forget_factored();
        &mut self.system
    }

    /// The linear system (for statistics such as the factor's size).
    pub fn system(&self) -> &BlockSystem<D> {
        &self.system
    }

    /// Values of the largest Cholesky factor among the patterns this
    /// optimiser has built (a pattern rebuilt without the loops a robust
    /// method removed has a smaller factor than the first one).
    pub fn max_nnz_factor(&self) -> usize {
        self.max_nnz_factor
    }

    /// Minimises `Σ wₖ eₖᵀΩₖeₖ` from the graph's current poses and leaves the
    /// best poses found in the graph. `weights` (one per edge) default to 1.
    pub fn run(
        &mut self,
        graph: &mut Graph<P, D>,
        weights: Option<&[f64]>,
        observer: &mut dyn Observer,
    ) -> Result<Summary, SolveError> {
        self.check_edge_count(graph, weights)?;
        self.match_threads()?;
        self.update_pattern(graph, weights, false)?;
        let mut progress = Progress {
            summary: Summary::new(self.options.method),
            watch: Stopwatch::start(),
        };
        let mut objective = self.linearize(graph, weights);
        progress.lap(|t| &mut t.linearize_s);
        progress.summary.initial_objective = objective;
        progress.summary.final_objective = objective;
        if !objective.is_finite() {
            return Err(SolveError::NonFiniteStart);
        }
        if self.vertex_of.is_empty() {
            return Ok(progress.finish(StopReason::NothingToOptimize, objective));
        }
        self.best.clone_from(&graph.poses);
        let mut best_objective = objective;
        // Every run starts undamped (see `Damping`).
        let mut damping = Damping::undamped();
        let mut chord = Chord::default();
        self.remaining = Remaining::default();
        // The relative gain of the last step if it was a Gauss–Newton one
        // (undamped, not chord), to tell linear convergence from quadratic.
        let mut newton_gain = None;
        let stop = loop {
            if let Some(reason) = self.stop_before_step(objective, &progress, observer) {
                break reason;
            }
            let outcome = self.next_step(
                (graph, weights),
                (objective, chord.ready),
                &mut damping,
                &mut progress,
                observer,
            )?;
            let step = match outcome {
                StepOutcome::Taken(step) => step,
                StepOutcome::Negligible if self.lightly_damped() => break StopReason::SmallStep,
                StepOutcome::Negligible => break StopReason::Stalled,
                StepOutcome::AtMinimum => break StopReason::RelativeDecrease,
                StepOutcome::Failed => break StopReason::NoDecrease,
                StepOutcome::Cancelled => break StopReason::Cancelled,
            };
            std::mem::swap(&mut graph.poses, &mut self.trial);
            let previous = objective;
            objective = step.objective;
            chord.after(&step, previous, self.options.reuse_factor);
            if objective < best_objective {
                best_objective = objective;
                self.best.clone_from(&graph.poses);
            }
            progress.record(&step, observer);
            self.remaining.after::<D>(&self.step, step.reused_factor);
            let newton = step.lambda == 0.0 && !step.reused_factor;
            let gain = newton.then(|| (previous - objective) / previous);
            let before = std::mem::replace(&mut newton_gain, gain).filter(|_| newton);
            if let Some(reason) = self.stop_after_step((previous, objective), step.lambda, before) {
                if !step.reused_factor || self.remaining.within(self.options.end_step) {
                    break reason;
                }
                // Converged by the objective, not by the poses: chord
                // steps crawl along the weakest directions, and a
                // Gauss–Newton step takes out what they leave.
                chord.ready = false;
            }
            self.linearize(graph, weights);
            progress.lap(|t| &mut t.linearize_s);
        };
        // The best poses back if they beat the last.
        if objective > best_objective {
            graph.poses.clone_from(&self.best);
            objective = best_objective;
        }
        Ok(progress.finish(stop, objective))
    }

    /// The next step from the current linearisation at `objective`: a chord
    /// step with the last factor where one is `ready` and taken, else the
    /// method's ([`Self::method_step`]).
    fn next_step(
        &mut self,
        (graph, weights): (&Graph<P, D>, Option<&[f64]>),
        (objective, ready): (f64, bool),
        damping: &mut Damping,
        progress: &mut Progress,
        observer: &mut dyn Observer,
    ) -> Result<StepOutcome, SolveError> {
        let chord = if ready {
            self.chord_step(graph, weights, objective, progress)
        } else {
            None
        };
        match chord {
            Some(outcome) => Ok(outcome),
            None => self.method_step((graph, weights), objective, damping, progress, observer),
        }
    }

    /// The method's step from the current linearisation at `objective`
    /// (Gauss–Newton's, or Levenberg–Marquardt's with `damping`).
    fn method_step(
        &mut self,
        (graph, weights): (&Graph<P, D>, Option<&[f64]>),
        objective: f64,
        damping: &mut Damping,
        progress: &mut Progress,
        observer: &mut dyn Observer,
    ) -> Result<StepOutcome, SolveError> {
        match self.options.method {
            Method::GaussNewton => self.gauss_newton_step(graph, weights, progress),
            Method::LevenbergMarquardt => self
                .levenberg_marquardt_step(graph, weights, objective, damping, progress, observer),
        }
    }

    /// The reason to stop after a step of damping `lambda` that took the
    /// objective from `previous` to `objective`, if any: a crawl
    /// ([`SolveSettings::crawl_tolerance`]: a damped step, or a
    /// Gauss–Newton step whose decrease is at least [`LINEAR_CONVERGENCE`]
    /// of `before`, the Gauss–Newton step's before it), or a relative
    /// decrease below
    /// the tolerance or foreseen by the model to within
    /// [`SolveSettings::model_tolerance`] — convergence where the model is
    /// trusted, else a stall.
    fn stop_after_step(
        &self,
        (previous, objective): (f64, f64),
        lambda: f64,
        before: Option<f64>,
    ) -> Option<StopReason> {
        let decrease = ((previous - objective) / previous).abs();
        let small = decrease < self.options.relative_tolerance;
        let crawl = self.options.crawl_tolerance.is_some_and(|t| {
            let linear = before.is_some_and(|b| decrease >= LINEAR_CONVERGENCE * b);
            (lambda > 0.0 && decrease < t.damped) || (linear && decrease < t.linear)
        });
        if !small && crawl {
            return Some(StopReason::Crawling);
        }
        (small || self.model_agreed(previous, objective)).then(|| {
            if self.model_trusted(previous, objective) {
                StopReason::RelativeDecrease
            } else {
                StopReason::Stalled
            }
        })
    }

    /// Whether the last run left the poses within `bound` of the optimum,
    /// `(translation, rotation)`, as its last step estimates it
    /// ([`remaining`](self::remaining)).
    pub fn converged_within(&self, bound: (f64, f64)) -> bool {
        self.remaining.within(Some(bound))
    }

    /// Fails unless `weights` (if any) and the pattern have one entry per
    /// edge of `graph`.
    fn check_edge_count(
        &self,
        graph: &Graph<P, D>,
        weights: Option<&[f64]>,
    ) -> Result<(), SolveError> {
        let edges = graph.edges.len();
        for count in weights
            .map(<[f64]>::len)
            .into_iter()
            .chain([self.in_pattern.len()])
        {
            if count != edges {
                return Err(SolveError::WeightCount {
                    weights: count,
                    edges,
                });
            }
        }
        Ok(())
    }

    /// The reason to stop before the next step, if any: the objective is
    /// zero, the iteration limit is reached, the observer asks to stop, or
    /// the time limit is reached.
    fn stop_before_step(
        &self,
        objective: f64,
        progress: &Progress,
        observer: &mut dyn Observer,
    ) -> Option<StopReason> {
        let iterations = progress.summary.iterations;
        if objective == 0.0 && iterations > 0 {
            Some(StopReason::ZeroError)
        } else if iterations >= self.options.max_iterations {
            Some(StopReason::MaxIterations)
        } else if observer.should_stop() {
            Some(StopReason::Cancelled)
        } else if (self.options.time_limit).is_some_and(|t| progress.watch.elapsed() >= t) {
            Some(StopReason::TimeLimit)
        } else {
            None
        }
    }

    /// The error for a normal matrix that is not positive definite at
    /// variable block `block`.
    fn not_positive_definite(&self, graph: &Graph<P, D>, block: usize) -> SolveError {
        SolveError::NotPositiveDefinite {
            vertex: graph.id(self.vertex_of[block]),
        }
    }
}

/// What one method's search for a step found.
enum StepOutcome {
    /// A step to `Optimizer::trial`, to be taken.
    Taken(Step),
    /// The step's largest component is below the step tolerance.
    Negligible,
    /// A lightly damped step was rejected whose model foresaw a decrease
    /// below the relative tolerance: the map is at its minimum to that
    /// tolerance, and the rejection is rounding.
    AtMinimum,
    /// No step with a finite (for LM: lower) objective.
    Failed,
    /// The observer asked to stop between two LM trials.
    Cancelled,
}

/// A step to be taken.
struct Step {
    /// Largest absolute component.
    step_max: f64,
    /// Objective after it.
    objective: f64,
    /// LM's damping after the step (0 for GN).
    lambda: f64,
    /// Rejected LM trials before it.
    rejected: usize,
    /// Whether it was solved with the factor of an earlier linearisation
    /// (a chord step).
    reused_factor: bool,
}

impl Step {
    /// The record of iteration `iteration`, this step, ended `elapsed`
    /// after the run started.
    fn record(&self, iteration: usize, elapsed: Duration) -> IterationRecord {
        IterationRecord {
            iteration,
            objective: self.objective,
            lambda: self.lambda,
            rejected: self.rejected,
            step_max: self.step_max,
            elapsed,
        }
    }
}

/// Optimises `graph` in place with unit weights: a convenience over
/// [`Optimizer`] for the tests.
#[cfg(test)]
pub fn optimize<P: Pose<D>, const D: usize>(
    graph: &mut Graph<P, D>,
    options: &SolveSettings,
) -> Result<Summary, SolveError> {
    let mut optimizer = Optimizer::new(graph, None, options.clone())?;
    optimizer.run(graph, None, &mut |_: &IterationRecord| {})
}
