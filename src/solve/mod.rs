//! Nonlinear least squares on the pose graph: Gauss–Newton and
//! Levenberg–Marquardt over the sparse normal equations of
//! [`crate::linear`], plus initial guesses ([`init`]).
//!
//! The objective is `Σ wₖ·eₖᵀΩₖeₖ` with the g2o edge error of
//! [`crate::geometry`] and per-edge weights `wₖ` (1 unless a robust method
//! sets them). The gauge vertices are held fixed.

pub mod init;

use crate::geometry::{NormalBlocks, Pose};
use crate::graph::{PoseGraph, VertexId};
use crate::linear::{BlockSystem, LinearError, SelectedInverse};
use nalgebra::SMatrix;
use rayon::prelude::*;
use serde::Serialize;
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

/// Options of the optimiser.
#[derive(Clone, Debug)]
pub struct SolverOptions {
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
    /// Stop when this much time has passed; the best estimate so far is kept.
    pub time_limit: Option<Duration>,
    /// LM damping `λ` (relative to the diagonal of `H`) after the first
    /// rejected step; until then λ = 0.
    pub initial_lambda: f64,
    /// Threads: 0 (automatic) and 1 run everything in the calling thread;
    /// N ≥ 2 linearises, assembles and factorises (independent subtrees and
    /// the large dense blocks) in rayon's current pool, whose size the
    /// caller sets (pgo's `--threads N`). Automatic is sequential because on
    /// the 2-core machine these figures come from, shared with other work, a
    /// second thread cost more than it gave at every size measured (see the
    /// README's Speed section).
    pub threads: usize,
}

impl Default for SolverOptions {
    fn default() -> Self {
        Self {
            method: Method::LevenbergMarquardt,
            max_iterations: 100,
            relative_tolerance: 1e-9,
            step_tolerance: 1e-12,
            time_limit: None,
            initial_lambda: 1e-6,
            threads: 0,
        }
    }
}

/// Why the optimiser stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum StopReason {
    /// The objective's relative decrease fell below the tolerance.
    RelativeDecrease,
    /// The step became negligible.
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
    /// LM damping used for the accepted step (0 for GN).
    pub lambda: f64,
    /// Rejected LM trials before the accepted step.
    pub rejected: usize,
    /// Largest absolute component of the step.
    pub step_max: f64,
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

/// Adds the time since `start` to `slot` and returns now.
fn lap(slot: &mut f64, start: Instant) -> Instant {
    let now = Instant::now();
    *slot += (now - start).as_secs_f64();
    now
}

impl Summary {
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

/// Receives progress from the optimiser.
pub trait Observer {
    /// Called after every outer iteration.
    fn iteration(&mut self, record: &IterationRecord);
}

impl<F: FnMut(&IterationRecord)> Observer for F {
    fn iteration(&mut self, record: &IterationRecord) {
        self(record)
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
    /// Time to build the pattern (ordering, symbolic factorisation) and of
    /// the last numeric factorisation.
    build_time: Duration,
    factor_time: Duration,
    /// Values of the largest factor among the patterns built so far.
    max_nnz_factor: usize,
    options: SolverOptions,
    trial: Vec<P>,
    best: Vec<P>,
    step: Vec<f64>,
    terms: Vec<EdgeTerms<D>>,
    /// Each edge's measurement, prepared once ([`Pose::prepare`]).
    measurements: Vec<P::Prepared>,
    /// The poses being evaluated, prepared.
    prepared: Vec<P::Prepared>,
}

impl<P: Pose<D>, const D: usize> Optimizer<P, D> {
    /// Prepares to optimise `graph` (its structure, not its values).
    /// Fails if some vertex is not connected to the gauge by edges of
    /// non-zero weight (`weights`: one per edge, default 1).
    pub fn new(
        graph: &PoseGraph<P, D>,
        weights: Option<&[f64]>,
        options: SolverOptions,
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
        let start = Instant::now();
        let system = Self::pattern(graph, &variable, &in_pattern, vertex_of.len(), &options)?;
        Ok(Self {
            max_nnz_factor: system.nnz_factor(),
            system,
            in_pattern,
            build_time: start.elapsed(),
            factor_time: Duration::ZERO,
            step: vec![0.0; vertex_of.len() * D],
            vertex_of,
            trial: graph.poses.clone(),
            best: graph.poses.clone(),
            options,
            terms: Vec::new(),
            measurements: graph
                .edges
                .iter()
                .map(|e| e.measurement.prepare())
                .collect(),
            prepared: graph.poses.iter().map(|p| p.prepare()).collect(),
        })
    }

    /// The block system of the edges in the pattern.
    fn pattern(
        graph: &PoseGraph<P, D>,
        variable: &[Option<usize>],
        in_pattern: &[bool],
        n_blocks: usize,
        options: &SolverOptions,
    ) -> Result<BlockSystem<D>, SolveError> {
        let pairs: Vec<(Option<usize>, Option<usize>)> = graph
            .edges
            .iter()
            .zip(in_pattern)
            .map(|(e, &inside)| {
                if inside {
                    (variable[e.from], variable[e.to])
                } else {
                    (None, None)
                }
            })
            .collect();
        let threads = if options.threads >= 2 { 0 } else { 1 };
        Ok(BlockSystem::new(n_blocks, &pairs, threads)?)
    }

    /// Rebuilds the pattern for the edges of non-zero weight when an edge
    /// left out of it now has a weight, or when edges in it have weight 0
    /// (loops a robust method removed) and a factorisation costs more than
    /// building the pattern did — wrong loops that join distant places are
    /// the ones that cost the most fill. Vertices that the edges of non-zero
    /// weight no longer connect to the gauge (a part of the map joined only
    /// by rejected loops) are held at their poses until an edge joins them
    /// again.
    fn update_pattern(
        &mut self,
        graph: &PoseGraph<P, D>,
        weights: Option<&[f64]>,
    ) -> Result<(), SolveError> {
        let needed = |k: usize| weights.is_none_or(|w| w[k] != 0.0);
        let missing = (0..self.in_pattern.len()).any(|k| !self.in_pattern[k] && needed(k));
        let unused = (0..self.in_pattern.len()).any(|k| self.in_pattern[k] && !needed(k));
        // Edges gone from the objective may also cut vertices off the gauge,
        // which then have to leave the variables (`vertex_of` is sorted).
        let mut cut_off = None;
        let mut newly_cut_off = || {
            let cut = graph.unconstrained_vertices(weights);
            let any = cut.iter().any(|v| self.vertex_of.binary_search(v).is_ok());
            cut_off = Some(cut);
            any
        };
        if !(missing || unused && (self.factor_time > self.build_time || newly_cut_off())) {
            return Ok(());
        }
        let cut_off = cut_off.unwrap_or_else(|| graph.unconstrained_vertices(weights));
        for k in 0..self.in_pattern.len() {
            self.in_pattern[k] = needed(k);
        }
        let start = Instant::now();
        let variable = Self::variables(graph, &cut_off, &mut self.vertex_of);
        self.step.resize(self.vertex_of.len() * D, 0.0);
        // The old factor goes before the new pattern is built, so that the
        // two never take memory at the same time.
        self.system.release_factor();
        self.system = Self::pattern(
            graph,
            &variable,
            &self.in_pattern,
            self.vertex_of.len(),
            &self.options,
        )?;
        self.build_time = start.elapsed();
        self.max_nnz_factor = self.max_nnz_factor.max(self.system.nnz_factor());
        Ok(())
    }

    /// The variable block of each vertex: every vertex but the gauge and
    /// `cut_off` (those the edges of non-zero weight do not connect to it,
    /// [`PoseGraph::unconstrained_vertices`]). Fills `vertex_of` with the
    /// vertex of each block.
    fn variables(
        graph: &PoseGraph<P, D>,
        cut_off: &[usize],
        vertex_of: &mut Vec<usize>,
    ) -> Vec<Option<usize>> {
        let n = graph.num_vertices();
        let mut fixed = vec![false; n];
        for k in graph.gauge().into_iter().chain(cut_off.iter().copied()) {
            fixed[k] = true;
        }
        vertex_of.clear();
        (0..n)
            .map(|k| {
                (!fixed[k]).then(|| {
                    vertex_of.push(k);
                    vertex_of.len() - 1
                })
            })
            .collect()
    }

    /// The smallest piece of a parallel loop: everything in one piece
    /// (the calling thread) unless [`SolverOptions::threads`] asks for more.
    fn min_len(&self) -> usize {
        if self.options.threads >= 2 {
            256
        } else {
            usize::MAX
        }
    }

    /// The options, e.g. to change the iteration limit between runs.
    pub fn options_mut(&mut self) -> &mut SolverOptions {
        &mut self.options
    }

    /// The linear system, e.g. to factorise and solve it in a benchmark.
    pub fn system_mut(&mut self) -> &mut BlockSystem<D> {
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
        graph: &mut PoseGraph<P, D>,
        weights: Option<&[f64]>,
        observer: &mut dyn Observer,
    ) -> Result<Summary, SolveError> {
        if let Some(w) = weights {
            if w.len() != graph.edges.len() {
                return Err(SolveError::WeightCount {
                    weights: w.len(),
                    edges: graph.edges.len(),
                });
            }
        }
        if self.in_pattern.len() != graph.edges.len() {
            return Err(SolveError::WeightCount {
                weights: self.in_pattern.len(),
                edges: graph.edges.len(),
            });
        }
        self.update_pattern(graph, weights)?;
        let start = Instant::now();
        let opts = self.options.clone();
        let mut summary = Summary {
            method: opts.method,
            iterations: 0,
            initial_objective: 0.0,
            final_objective: 0.0,
            stop_reason: StopReason::MaxIterations,
            factorizations: 0,
            time: Duration::ZERO,
            history: Vec::new(),
            timing: Timing::default(),
        };
        let mut clock = Instant::now();
        let mut objective = self.linearize(graph, weights);
        clock = lap(&mut summary.timing.linearize_s, clock);
        summary.initial_objective = objective;
        summary.final_objective = objective;
        if !objective.is_finite() {
            return Err(SolveError::NonFiniteStart);
        }
        if self.vertex_of.is_empty() {
            summary.stop_reason = StopReason::NothingToOptimize;
            summary.time = start.elapsed();
            return Ok(summary);
        }
        // λ = 0 until a step fails: near a minimum, where the Gauss–Newton
        // model is good, any damping only slows the convergence down (on
        // long trajectories the smallest eigenvalues of H are ~1e-6 of its
        // diagonal, so even λ = 1e-6 halves their steps). Every run starts
        // undamped: a robust round changed the weights, and carrying the
        // previous run's damping over was measured to make EM's short
        // M-steps crawl (10⁵-pose grid: 787 iterations instead of 319, and
        // 2 % fewer true loops accepted).
        let mut lambda = 0.0;
        let mut nu = 2.0;
        let raise = |lambda: &mut f64, nu: &mut f64| {
            if *lambda == 0.0 {
                *lambda = opts.initial_lambda;
            } else {
                *lambda *= *nu;
                *nu *= 2.0;
            }
        };
        self.best.clone_from(&graph.poses);
        let mut best_objective = objective;
        let stop = loop {
            if objective == 0.0 && summary.iterations > 0 {
                break StopReason::ZeroError;
            }
            if summary.iterations >= opts.max_iterations {
                break StopReason::MaxIterations;
            }
            if opts.time_limit.is_some_and(|t| start.elapsed() >= t) {
                break StopReason::TimeLimit;
            }
            // Find a step: GN takes the first; LM raises λ until the step
            // decreases the objective. The very first trial of a run is
            // undamped in both, so that a singular system (an undetermined
            // vertex) is reported rather than hidden by the damping.
            let mut rejected = 0;
            let outcome = loop {
                let structural_check = summary.factorizations == 0;
                let damping = if opts.method == Method::GaussNewton {
                    0.0
                } else {
                    lambda
                };
                summary.factorizations += 1;
                let factorized = self.system.factorize(damping);
                self.factor_time = clock.elapsed();
                clock = lap(&mut summary.timing.factorize_s, clock);
                match factorized {
                    Ok(()) => {}
                    Err(LinearError::NotPositiveDefinite { block }) => {
                        if opts.method == Method::GaussNewton || structural_check || lambda > 1e16 {
                            return Err(SolveError::NotPositiveDefinite {
                                vertex: graph.id(self.vertex_of[block]),
                            });
                        }
                        raise(&mut lambda, &mut nu);
                        rejected += 1;
                        continue;
                    }
                    Err(e) => return Err(e.into()),
                }
                self.system.solve(&mut self.step);
                clock = lap(&mut summary.timing.solve_s, clock);
                let step_max = self.step.iter().fold(0.0f64, |m, s| m.max(s.abs()));
                if !step_max.is_finite() {
                    if opts.method == Method::GaussNewton || lambda > 1e16 {
                        break None;
                    }
                    raise(&mut lambda, &mut nu);
                    rejected += 1;
                    continue;
                }
                if step_max < opts.step_tolerance {
                    break Some((step_max, objective, true));
                }
                self.apply_step(graph);
                let trial = std::mem::take(&mut self.trial);
                let new_objective = self.objective(&trial, graph, weights);
                self.trial = trial;
                clock = lap(&mut summary.timing.evaluate_s, clock);
                if opts.method == Method::GaussNewton {
                    if new_objective.is_finite() {
                        break Some((step_max, new_objective, false));
                    }
                    break None;
                }
                let predicted = self.system.predicted_decrease(&self.step);
                let rho = (objective - new_objective) / predicted;
                if new_objective.is_finite() && new_objective <= objective && rho > 0.0 {
                    if lambda > 0.0 {
                        lambda *= (1.0 - (2.0 * rho - 1.0).powi(3)).max(1.0 / 3.0);
                        lambda = lambda.max(1e-12);
                    }
                    nu = 2.0;
                    break Some((step_max, new_objective, false));
                }
                raise(&mut lambda, &mut nu);
                rejected += 1;
                if lambda > 1e16 {
                    break None;
                }
            };
            let Some((step_max, new_objective, negligible)) = outcome else {
                break StopReason::NoDecrease;
            };
            if negligible {
                break StopReason::SmallStep;
            }
            summary.iterations += 1;
            std::mem::swap(&mut graph.poses, &mut self.trial);
            let decrease = (objective - new_objective) / objective;
            objective = new_objective;
            if objective < best_objective {
                best_objective = objective;
                self.best.clone_from(&graph.poses);
            }
            let record = IterationRecord {
                iteration: summary.iterations,
                objective,
                lambda: if opts.method == Method::GaussNewton {
                    0.0
                } else {
                    lambda
                },
                rejected,
                step_max,
            };
            summary.history.push(record);
            observer.iteration(&record);
            if decrease.abs() < opts.relative_tolerance {
                break StopReason::RelativeDecrease;
            }
            self.linearize(graph, weights);
            clock = lap(&mut summary.timing.linearize_s, clock);
        };
        if objective > best_objective {
            graph.poses.clone_from(&self.best);
            objective = best_objective;
        }
        summary.final_objective = objective;
        summary.stop_reason = stop;
        summary.time = start.elapsed();
        Ok(summary)
    }

    /// `trial = poses ⊞ step`.
    fn apply_step(&mut self, graph: &PoseGraph<P, D>) {
        self.trial.clone_from(&graph.poses);
        for (block, &v) in self.vertex_of.iter().enumerate() {
            let delta = nalgebra::SVector::<f64, D>::from_column_slice(
                &self.step[block * D..block * D + D],
            );
            self.trial[v] = graph.poses[v].retract(&delta);
        }
    }

    /// The weighted objective at `poses`.
    fn objective(&mut self, poses: &[P], graph: &PoseGraph<P, D>, weights: Option<&[f64]>) -> f64 {
        let min_len = self.min_len();
        prepare(poses, &mut self.prepared, min_len);
        let (prepared, measurements) = (&self.prepared, &self.measurements);
        graph
            .edges
            .par_iter()
            .enumerate()
            .with_min_len(min_len)
            .map(|(k, e)| {
                let w = weights.map_or(1.0, |w| w[k]);
                if w == 0.0 {
                    return 0.0;
                }
                let r = P::error_prepared(&prepared[e.from], &prepared[e.to], &measurements[k]);
                w * r.dot(&(e.information * r))
            })
            .sum()
    }

    /// The squared *innovation* `ν² = eᵀ(Ω⁻¹ + J·H⁻¹·Jᵀ)⁻¹e` of each of
    /// `edges` at the graph's poses: the Mahalanobis distance of the error of
    /// an edge the solution was made without, with the solution's own
    /// uncertainty (`H` the normal matrix of the edges of non-zero `weights`
    /// at these poses, undamped) added to the edge's. `ν² ≤ eᵀΩe`, and much
    /// less where the solution is loosely tied between the edge's two poses.
    /// An edge at a vertex that is held fixed because no edge of non-zero
    /// weight ties it to the gauge gets its plain `eᵀΩe` (the solution
    /// knows nothing of that vertex to add).
    pub fn innovation_chi2(
        &mut self,
        graph: &PoseGraph<P, D>,
        weights: &[f64],
        edges: &[usize],
    ) -> Result<Vec<f64>, SolveError> {
        let block = self.factor_undamped(graph, weights)?;
        let gauge = graph.gauge();
        Ok(edges
            .iter()
            .map(|&k| self.left_out_chi2(graph, &block, &gauge, k))
            .collect())
    }

    /// The squared innovation of each of `edges` against the solution
    /// without it, whether the solution was made without it (weight 0 in
    /// `weights`: [`Optimizer::innovation_chi2`]) or with it (weight 1):
    /// then Baarda's deleted residual `eᵀ(Ω⁻¹ − J·H⁻¹·Jᵀ)⁻¹e`, `H` as there.
    /// `Ω⁻¹ − J·H⁻¹·Jᵀ` is the covariance of the edge's residual at the
    /// optimum, and the number is, to first order (exactly for a linear
    /// problem), the innovation the edge would have against the optimum of
    /// the others — so the two kinds compare like with like. `None` for an
    /// edge of another weight, or one of the solution that the others do
    /// not determine in some direction (a bridge: the whitened redundancy
    /// `I − Ω^½·J·H⁻¹·Jᵀ·Ω^½` has an eigenvalue below `1e-9`).
    pub fn leave_one_out_chi2(
        &mut self,
        graph: &PoseGraph<P, D>,
        weights: &[f64],
        edges: &[usize],
    ) -> Result<Vec<Option<f64>>, SolveError> {
        let block = self.factor_undamped(graph, weights)?;
        let gauge = graph.gauge();
        // The edges of the solution read H⁻¹ from its selected inverse (one
        // pass over the factor), not from a solve each.
        let inverse = edges
            .iter()
            .any(|&k| weights[k] == 1.0)
            .then(|| self.system.selected_inverse());
        Ok(edges
            .iter()
            .map(|&k| match (weights[k], &inverse) {
                (0.0, _) => Some(self.left_out_chi2(graph, &block, &gauge, k)),
                (1.0, Some(z)) => self.deleted_chi2(graph, &block, z, k),
                _ => None,
            })
            .collect())
    }

    /// [`Optimizer::innovation_chi2`] of edge `k`, at the factor of
    /// [`Optimizer::factor_undamped`] (`block`) with the graph's `gauge`.
    fn left_out_chi2(
        &mut self,
        graph: &PoseGraph<P, D>,
        block: &[Option<usize>],
        gauge: &[usize],
        k: usize,
    ) -> f64 {
        let e = &graph.edges[k];
        let lin = P::error_and_jacobians(&graph.poses[e.from], &graph.poses[e.to], &e.measurement);
        let plain = lin.error.dot(&(e.information * lin.error));
        let known = |v: usize| block[v].is_some() || gauge.contains(&v);
        if !(known(e.from) && known(e.to)) {
            return plain;
        }
        let spread = self
            .system
            .propagate(block[e.from], &lin.jac_i, block[e.to], &lin.jac_j);
        let innovation = e
            .information
            .try_inverse()
            .map(|sigma| sigma + spread)
            .and_then(|s| s.cholesky());
        match innovation {
            Some(s) => lin.error.dot(&s.solve(&lin.error)).min(plain),
            None => plain,
        }
    }

    /// The deleted residual of edge `k`, one of the solution
    /// ([`Optimizer::leave_one_out_chi2`]), with `H⁻¹` from its selected
    /// `inverse`.
    fn deleted_chi2(
        &self,
        graph: &PoseGraph<P, D>,
        block: &[Option<usize>],
        inverse: &SelectedInverse,
        k: usize,
    ) -> Option<f64> {
        let e = &graph.edges[k];
        let lin = P::error_and_jacobians(&graph.poses[e.from], &graph.poses[e.to], &e.measurement);
        let spread = self.system.propagate_selected(
            inverse,
            block[e.from],
            &lin.jac_i,
            block[e.to],
            &lin.jac_j,
        )?;
        // Whitened: Ω = LLᵀ, ẽ = Lᵀe, R = I − Lᵀ·spread·L.
        let l = e.information.cholesky()?.unpack();
        let whitened = l.transpose() * lin.error;
        let redundancy = SMatrix::<f64, D, D>::identity() - l.transpose() * spread * l;
        // (Dynamic: nalgebra's eigen solver is not generic in D.)
        let eig =
            nalgebra::DMatrix::from_column_slice(D, D, redundancy.as_slice()).symmetric_eigen();
        if eig.eigenvalues.min() < 1e-9 {
            return None;
        }
        let projected = eig.eigenvectors.transpose() * whitened;
        Some(
            projected
                .iter()
                .zip(eig.eigenvalues.iter())
                .map(|(p, lambda)| p * p / lambda)
                .sum(),
        )
    }

    /// Factorises the undamped normal matrix of the edges of non-zero
    /// `weights` at the graph's poses; returns each vertex's block (`None`
    /// for a vertex held fixed).
    fn factor_undamped(
        &mut self,
        graph: &PoseGraph<P, D>,
        weights: &[f64],
    ) -> Result<Vec<Option<usize>>, SolveError> {
        if weights.len() != graph.edges.len() {
            return Err(SolveError::WeightCount {
                weights: weights.len(),
                edges: graph.edges.len(),
            });
        }
        self.update_pattern(graph, Some(weights))?;
        self.linearize(graph, Some(weights));
        match self.system.factorize(0.0) {
            Ok(()) => {}
            Err(LinearError::NotPositiveDefinite { block }) => {
                return Err(SolveError::NotPositiveDefinite {
                    vertex: graph.id(self.vertex_of[block]),
                });
            }
            Err(e) => return Err(e.into()),
        }
        let mut block = vec![None; graph.num_vertices()];
        for (b, &v) in self.vertex_of.iter().enumerate() {
            block[v] = Some(b);
        }
        Ok(block)
    }

    /// Builds `H` and `b` at the graph's poses and returns the objective
    /// (public for benchmarks; [`Optimizer::run`] does this itself). Edges
    /// left out of the pattern ([`Optimizer::new`]) count in the objective
    /// but not in `H`.
    pub fn linearize(&mut self, graph: &PoseGraph<P, D>, weights: Option<&[f64]>) -> f64 {
        self.system.clear();
        let min_len = self.min_len();
        prepare(&graph.poses, &mut self.prepared, min_len);
        let mut objective = 0.0;
        // Edges are linearised in parallel, a chunk at a time, into a buffer
        // reused across iterations, then added into H in parallel by
        // destination ([`BlockSystem::add_edges`]).
        let terms = &mut self.terms;
        let (prepared, measurements) = (&self.prepared, &self.measurements);
        for (c, chunk) in graph.edges.chunks(LINEARIZE_CHUNK).enumerate() {
            let base = c * LINEARIZE_CHUNK;
            terms.resize(chunk.len(), EdgeTerms::default());
            terms
                .par_iter_mut()
                .zip(chunk.par_iter())
                .enumerate()
                .with_min_len(min_len)
                .for_each(|(i, (t, e))| {
                    let k = base + i;
                    let w = weights.map_or(1.0, |w| w[k]);
                    *t = if w == 0.0 {
                        EdgeTerms::default()
                    } else {
                        let (xi, xj) = (&prepared[e.from], &prepared[e.to]);
                        EdgeTerms::new::<P>(xi, xj, &measurements[k], &e.information, w)
                    };
                });
            objective += terms.iter().map(|t| t.blocks.chi2).sum::<f64>();
            self.system
                .add_edges(base, terms, |t| t.active.then_some(&t.blocks));
        }
        objective
    }
}

/// `out[k] = poses[k].prepare()`, in pieces of at least `min_len`.
fn prepare<P: Pose<D>, const D: usize>(poses: &[P], out: &mut Vec<P::Prepared>, min_len: usize) {
    if out.len() != poses.len() {
        *out = poses.iter().map(|p| p.prepare()).collect();
    } else {
        out.par_iter_mut()
            .zip(poses.par_iter())
            .with_min_len(min_len.max(4096))
            .for_each(|(o, p)| *o = p.prepare());
    }
}

/// Edges linearised per parallel batch (512 × ~1 kB of terms in 3D: the
/// buffer is memory held for the whole run, and larger batches were not
/// faster).
const LINEARIZE_CHUNK: usize = 1 << 9;

/// One edge's contribution to the normal equations (`active`: its weight
/// is not 0).
#[derive(Clone, Copy, Default)]
struct EdgeTerms<const D: usize> {
    active: bool,
    blocks: NormalBlocks<D>,
}

impl<const D: usize> EdgeTerms<D> {
    /// `JᵀwΩJ`, `JᵀwΩe` and `w·eᵀΩe` of one edge at prepared poses.
    fn new<P: Pose<D>>(
        xi: &P::Prepared,
        xj: &P::Prepared,
        z: &P::Prepared,
        information: &SMatrix<f64, D, D>,
        w: f64,
    ) -> Self {
        let blocks = if w == 1.0 {
            P::normal_blocks_prepared(xi, xj, z, information)
        } else {
            P::normal_blocks_prepared(xi, xj, z, &(information * w))
        };
        Self {
            active: true,
            blocks,
        }
    }
}

/// Optimises `graph` in place with unit weights: a convenience over
/// [`Optimizer`].
///
/// ```ignore
/// use nalgebra::Matrix3;
/// use pgo::geometry::{Pose, Se2};
/// use pgo::graph::PoseGraph;
/// use pgo::solve::{optimize, SolverOptions};
/// let mut g = PoseGraph::<Se2, 3>::new();
/// for k in 0..3 {
///     g.add_vertex(k, Se2::new(0.3 * k as f64, 0.0, 0.0)).unwrap();
/// }
/// let step = Se2::new(1.0, 0.0, 0.0);
/// g.add_edge(0, 1, step, Matrix3::identity(), None).unwrap();
/// g.add_edge(1, 2, step, Matrix3::identity(), None).unwrap();
/// let summary = optimize(&mut g, &SolverOptions::default()).unwrap();
/// assert!(summary.final_objective < 1e-20);
/// assert!((g.poses[2].x - 2.0).abs() < 1e-9);
/// ```
pub fn optimize<P: Pose<D>, const D: usize>(
    graph: &mut PoseGraph<P, D>,
    options: &SolverOptions,
) -> Result<Summary, SolveError> {
    let mut optimizer = Optimizer::new(graph, None, options.clone())?;
    optimizer.run(graph, None, &mut |_: &IterationRecord| {})
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{Se2, Se3};
    use nalgebra::{Matrix3, Matrix6, UnitQuaternion, Vector3, Vector6};
    use rand::{Rng, SeedableRng, rngs::StdRng};
    use std::f64::consts::{FRAC_PI_2, PI};

    /// A square loop of 4 poses with one loop closure whose measurements are
    /// consistent: the optimum has zero error.
    fn square(noise: f64, seed: u64) -> PoseGraph<Se2, 3> {
        let mut rng = StdRng::seed_from_u64(seed);
        let truth = [
            Se2::new(0.0, 0.0, 0.0),
            Se2::new(1.0, 0.0, FRAC_PI_2),
            Se2::new(1.0, 1.0, PI),
            Se2::new(0.0, 1.0, -FRAC_PI_2),
        ];
        let mut g = PoseGraph::new();
        for (k, t) in truth.iter().enumerate() {
            let p = if k == 0 {
                *t
            } else {
                Se2::new(
                    t.x + noise * rng.random_range(-1.0..1.0),
                    t.y + noise * rng.random_range(-1.0..1.0),
                    t.theta + noise * rng.random_range(-1.0..1.0),
                )
            };
            g.add_vertex(k as u64, p).unwrap();
        }
        for (i, j) in [(0, 1), (1, 2), (2, 3), (3, 0)] {
            let z = truth[i].inverse().compose(&truth[j]);
            g.add_edge(i as u64, j as u64, z, Matrix3::identity(), None)
                .unwrap();
        }
        g
    }

    #[test]
    fn lm_and_gn_reach_the_exact_optimum_of_a_consistent_loop() {
        for method in [Method::LevenbergMarquardt, Method::GaussNewton] {
            let mut g = square(0.3, 1);
            let s = optimize(
                &mut g,
                &SolverOptions {
                    method,
                    ..Default::default()
                },
            )
            .unwrap();
            assert!(
                s.final_objective < 1e-16,
                "{method:?}: {}",
                s.final_objective
            );
            assert!(s.converged());
            assert!((g.poses[2].x - 1.0).abs() < 1e-8 && (g.poses[2].y - 1.0).abs() < 1e-8);
        }
    }

    /// Four collinear-free translations around a loop that does not close
    /// by 0.4 in x, all rotations zero, and the information of its edges
    /// (rotations pinned by a huge information: the problem is linear).
    fn open_loop() -> (PoseGraph<Se2, 3>, Matrix3<f64>) {
        let mut g = PoseGraph::<Se2, 3>::new();
        for k in 0..4 {
            g.add_vertex(k, Se2::identity()).unwrap();
        }
        let i = Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, 1e8));
        g.add_edge(0, 1, Se2::new(1.0, 0.0, 0.0), i, None).unwrap();
        g.add_edge(1, 2, Se2::new(0.0, 1.0, 0.0), i, None).unwrap();
        g.add_edge(2, 3, Se2::new(-1.0, 0.0, 0.0), i, None).unwrap();
        g.add_edge(3, 0, Se2::new(0.4, -1.0, 0.0), i, None).unwrap();
        (g, i)
    }

    #[test]
    fn inconsistent_loop_matches_the_closed_form_optimum() {
        // The optimum spreads the error equally: objective = 0.4² / 4.
        let (mut g, _) = open_loop();
        let s = optimize(&mut g, &SolverOptions::default()).unwrap();
        assert!(
            (s.final_objective - 0.04).abs() < 1e-8,
            "{}",
            s.final_objective
        );
    }

    #[test]
    fn innovation_is_the_chi2_a_left_out_edge_adds_to_the_optimum() {
        // The open loop solved without its closing edge: the chain fits
        // exactly, the closing edge's plain error there is 0.4² = 0.16, and
        // adding it raises the optimum's χ² to 0.04 (the mismatch spread
        // over four edges). That rise is its innovation:
        // ν² = eᵀ(Ω⁻¹ + J·H⁻¹·Jᵀ)⁻¹e with H of the chain (exact here: the
        // problem is linear).
        let (mut g, i) = open_loop();
        let without = [1.0, 1.0, 1.0, 0.0];
        let mut opt = Optimizer::new(&g, Some(&without), SolverOptions::default()).unwrap();
        opt.run(&mut g, Some(&without), &mut |_: &IterationRecord| {})
            .unwrap();
        let plain = g.edge_chi2(&g.edges[3]);
        assert!((plain - 0.16).abs() < 1e-9, "{plain}");
        let nu2 = opt.innovation_chi2(&g, &without, &[3]).unwrap();
        assert!((nu2[0] - 0.04).abs() < 1e-8, "{nu2:?}");
        // An edge of the solution itself: J·H⁻¹·Jᵀ only adds, so ν² ≤ e²
        // (0 here: the chain fits exactly).
        let nu2 = opt.innovation_chi2(&g, &without, &[0, 1]).unwrap();
        assert!(nu2.iter().all(|&v| v.abs() < 1e-12), "{nu2:?}");
        // With the edge in the solution, the optimum's χ² is that rise.
        let s = optimize(&mut g, &SolverOptions::default()).unwrap();
        assert!((s.final_objective - 0.04).abs() < 1e-8);
        // A vertex no edge of non-zero weight ties to the gauge is held
        // fixed: the solution adds nothing to an edge at it.
        let mut g2 = g.clone();
        g2.add_vertex(9, Se2::new(5.0, 0.0, 0.0)).unwrap();
        g2.add_edge(3, 9, Se2::new(1.0, 0.0, 0.0), i, None).unwrap();
        let w = [1.0, 1.0, 1.0, 1.0, 0.0];
        let mut opt = Optimizer::new(&g2, Some(&[1.0; 5]), SolverOptions::default()).unwrap();
        let nu2 = opt.innovation_chi2(&g2, &w, &[4]).unwrap();
        assert_eq!(nu2[0], g2.edge_chi2(&g2.edges[4]));
        // Weights must match the edges.
        assert!(opt.innovation_chi2(&g2, &w[..2], &[4]).is_err());
    }

    #[test]
    fn leave_one_out_innovation_is_the_innovation_without_the_edge() {
        // The open loop closed: any one edge left out leaves a chain that
        // fits exactly, and adding it back raises χ² by 0.04 (above). So
        // each edge's deleted residual at the optimum of all four is 0.04,
        // the innovation of the closing edge left out.
        let (mut g, i) = open_loop();
        optimize(&mut g, &SolverOptions::default()).unwrap();
        let all = [1.0; 4];
        let mut opt = Optimizer::new(&g, Some(&all), SolverOptions::default()).unwrap();
        let nu2 = opt.leave_one_out_chi2(&g, &all, &[0, 1, 2, 3]).unwrap();
        for v in &nu2 {
            let v = v.expect("every edge of a loop is checked by the others");
            assert!((v - 0.04).abs() < 1e-8, "{nu2:?}");
        }
        // Its plain residual at that optimum is far smaller: (0.4/4)².
        assert!((g.edge_chi2(&g.edges[3]) - 0.01).abs() < 1e-8);
        // A bridge (the only edge to vertex 9, or edge 0 with the closing
        // edge left out) is checked by nothing.
        let mut g2 = g.clone();
        g2.add_vertex(9, Se2::new(5.0, 0.0, 0.0)).unwrap();
        g2.add_edge(3, 9, Se2::new(1.0, 0.0, 0.0), i, None).unwrap();
        let w = [1.0, 1.0, 1.0, 0.0, 1.0];
        let mut opt = Optimizer::new(&g2, Some(&w), SolverOptions::default()).unwrap();
        let nu2 = opt.leave_one_out_chi2(&g2, &w, &[0, 4]).unwrap();
        assert_eq!(nu2, [None, None]);
        // An edge left out gets the innovation `innovation_chi2` gives it;
        // one of another weight nothing.
        let left_out = opt.leave_one_out_chi2(&g2, &w, &[3]).unwrap()[0];
        assert_eq!(
            left_out,
            Some(opt.innovation_chi2(&g2, &w, &[3]).unwrap()[0])
        );
        let half = [1.0, 1.0, 1.0, 0.5, 1.0];
        assert_eq!(opt.leave_one_out_chi2(&g2, &half, &[3]).unwrap(), [None]);
        assert!(opt.leave_one_out_chi2(&g2, &w[..2], &[4]).is_err());
    }

    #[test]
    fn spatial_chain_with_loop_converges() {
        let mut rng = StdRng::seed_from_u64(3);
        let mut truth = vec![Se3::identity()];
        for k in 1..20 {
            let step = Se3::exp(&Vector6::new(1.0, 0.0, 0.1, 0.0, 0.05, 0.3));
            let prev: Se3 = truth[k - 1];
            truth.push(prev.compose(&step));
        }
        let mut g = PoseGraph::<Se3, 6>::new();
        for (k, t) in truth.iter().enumerate() {
            let noise = Se3::new(
                UnitQuaternion::from_scaled_axis(Vector3::new(
                    rng.random_range(-0.1..0.1),
                    rng.random_range(-0.1..0.1),
                    rng.random_range(-0.1..0.1),
                )),
                Vector3::new(
                    rng.random_range(-0.3..0.3),
                    rng.random_range(-0.3..0.3),
                    rng.random_range(-0.3..0.3),
                ),
            );
            g.add_vertex(k as u64, if k == 0 { *t } else { t.compose(&noise) })
                .unwrap();
        }
        for k in 1..20 {
            g.add_edge(
                k as u64 - 1,
                k as u64,
                truth[k - 1].inverse().compose(&truth[k]),
                Matrix6::identity(),
                None,
            )
            .unwrap();
        }
        g.add_edge(
            0,
            19,
            truth[0].inverse().compose(&truth[19]),
            Matrix6::identity() * 10.0,
            None,
        )
        .unwrap();
        let s = optimize(&mut g, &SolverOptions::default()).unwrap();
        assert!(s.final_objective < 1e-14, "{}", s.final_objective);
        assert!((g.poses[19].translation - truth[19].translation).norm() < 1e-6);
    }

    #[test]
    fn weights_switch_edges_off() {
        let mut g = square(0.0, 2);
        // A wrong edge 0→2 that would pull pose 2.
        g.add_edge(
            0,
            2,
            Se2::new(5.0, 5.0, 0.0),
            Matrix3::identity() * 100.0,
            None,
        )
        .unwrap();
        let mut opt = Optimizer::new(&g, None, SolverOptions::default()).unwrap();
        let w = [1.0, 1.0, 1.0, 1.0, 0.0];
        let s = opt
            .run(&mut g, Some(&w), &mut |_: &IterationRecord| {})
            .unwrap();
        assert!(s.final_objective < 1e-16);
        assert!(
            opt.run(&mut g, Some(&w[..3]), &mut |_: &IterationRecord| {})
                .is_err()
        );
    }

    #[test]
    fn vertices_cut_off_by_weight_zero_are_held_and_come_back() {
        // A second part (40, 41) joined to the square by one edge 2→40.
        let mut g = square(0.0, 4);
        let held = Se2::new(7.0, -3.0, 0.4);
        g.add_vertex(40, held).unwrap();
        g.add_vertex(41, Se2::new(9.0, -3.0, 0.4)).unwrap();
        let z = Se2::new(1.0, 0.0, 0.0);
        g.add_edge(2, 40, z, Matrix3::identity(), None).unwrap();
        g.add_edge(40, 41, z, Matrix3::identity(), None).unwrap();
        let mut opt = Optimizer::new(&g, None, SolverOptions::default()).unwrap();
        let mut w = vec![1.0; g.edges.len()];
        w[4] = 0.0;
        let s = opt
            .run(&mut g, Some(&w), &mut |_: &IterationRecord| {})
            .unwrap();
        assert!(s.stop_reason.converged(), "{s:?}");
        // The part cut off the gauge stays where it was.
        assert_eq!(g.poses[4], held);
        assert_eq!(g.poses[5], Se2::new(9.0, -3.0, 0.4));
        // The joining edge back: the part moves next to pose 2.
        w[4] = 1.0;
        let s = opt
            .run(&mut g, Some(&w), &mut |_: &IterationRecord| {})
            .unwrap();
        assert!(s.final_objective < 1e-16, "{s:?}");
        let rel = g.poses[2].inverse().compose(&g.poses[4]);
        assert!((rel.x - 1.0).abs() < 1e-9 && rel.y.abs() < 1e-9);
    }

    #[test]
    fn disconnected_vertices_are_named() {
        let mut g = square(0.0, 3);
        g.add_vertex(40, Se2::identity()).unwrap();
        g.add_vertex(41, Se2::identity()).unwrap();
        g.add_edge(40, 41, Se2::identity(), Matrix3::identity(), None)
            .unwrap();
        let err = optimize(&mut g, &SolverOptions::default()).unwrap_err();
        assert_eq!(
            err,
            SolveError::Unconstrained {
                gauge: 0,
                vertices: vec![40, 41]
            }
        );
        assert!(err.to_string().contains("40, 41"));
    }

    #[test]
    fn rank_deficient_edges_are_a_named_error() {
        // Vertex 1 is tied to the gauge only through an edge whose
        // information ignores rotation: its heading is undetermined.
        let mut g = PoseGraph::<Se2, 3>::new();
        g.add_vertex(0, Se2::identity()).unwrap();
        g.add_vertex(1, Se2::new(1.0, 0.0, 0.0)).unwrap();
        let info = Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, 0.0));
        g.add_edge(0, 1, Se2::new(1.5, 0.0, 0.0), info, None)
            .unwrap();
        for method in [Method::GaussNewton, Method::LevenbergMarquardt] {
            let err = optimize(
                &mut g.clone(),
                &SolverOptions {
                    method,
                    ..Default::default()
                },
            )
            .unwrap_err();
            assert_eq!(err, SolveError::NotPositiveDefinite { vertex: 1 });
        }
    }

    #[test]
    fn iteration_and_time_limits_are_honoured_and_keep_the_best() {
        let mut g = square(0.5, 4);
        let start = g.chi2();
        let s = optimize(
            &mut g,
            &SolverOptions {
                max_iterations: 1,
                ..Default::default()
            },
        )
        .unwrap();
        assert_eq!(
            (s.iterations, s.stop_reason),
            (1, StopReason::MaxIterations)
        );
        assert!(s.final_objective <= start && (g.chi2() - s.final_objective).abs() < 1e-12);
        let s = optimize(
            &mut g,
            &SolverOptions {
                time_limit: Some(Duration::ZERO),
                ..Default::default()
            },
        )
        .unwrap();
        assert_eq!((s.iterations, s.stop_reason), (0, StopReason::TimeLimit));
    }

    #[test]
    fn every_run_starts_undamped() {
        // A start where LM's first step is the undamped one, but later
        // steps are damped and the run ends with λ > 0.
        let mut found = None;
        for seed in 0..500 {
            let mut g = square(2.5, seed);
            let start = g.poses.clone();
            let mut opt = Optimizer::new(&g, None, SolverOptions::default()).unwrap();
            let mut records = Vec::new();
            opt.run(&mut g, None, &mut |r: &IterationRecord| records.push(*r))
                .unwrap();
            let (Some(first), Some(last)) = (records.first(), records.last()) else {
                continue;
            };
            if first.lambda == 0.0 && first.rejected == 0 && last.lambda > 0.0 {
                found = Some((g, start, opt, *first));
                break;
            }
        }
        let (mut g, start, mut opt, first) = found.expect("no start needed damping");
        // The same optimiser from the same start takes the same undamped
        // first step: it does not carry the last run's λ over.
        g.poses = start;
        let mut again = None;
        opt.run(&mut g, None, &mut |r: &IterationRecord| {
            again.get_or_insert(*r);
        })
        .unwrap();
        let again = again.unwrap();
        assert_eq!((again.lambda, again.objective), (0.0, first.objective));
    }

    #[test]
    fn non_finite_start_is_an_error_not_a_nan_result() {
        let mut g = square(0.0, 5);
        g.poses[1].x = f64::NAN;
        assert_eq!(
            optimize(&mut g, &SolverOptions::default()).unwrap_err(),
            SolveError::NonFiniteStart
        );
    }
}
