//! The normal equations shared by both methods: linearisation of every edge
//! into `H` and `b` ([`Optimizer::linearize`]), the objective at trial
//! poses, and one (damped) step from the factorisation.

use super::{Optimizer, Progress, SolveError};
use crate::geometry::{NormalBlocks, Pose};
use crate::graph::Graph;
use crate::linear::LinearError;
use nalgebra::SMatrix;
use rayon::prelude::*;
use std::sync::atomic::{AtomicBool, Ordering::Relaxed};

/// Edges linearised per parallel batch (512 × ~1 kB of terms in 3D: the
/// buffer is memory held for the whole run, and larger batches were not
/// faster).
pub(crate) const LINEARIZE_CHUNK: usize = 1 << 9;

/// One edge's contribution to the normal equations (`active`: its weight
/// is not 0).
#[derive(Clone, Copy, Default)]
pub(super) struct EdgeTerms<const D: usize> {
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

/// The largest damping share ([`crate::linear::BlockSystem::damping_share`]) of a step
/// after which the Gauss–Newton model is trusted: the step is then at least
/// half as long as the model's own minimiser along its direction, so that
/// (along that direction) the model's whole decrease is at most 4/3 of the
/// step's (a fraction `α` of the way gives `2α − α²` of it).
const TRUSTED_DAMPING_SHARE: f64 = 0.5;

/// The smallest gain ratio (actual over predicted decrease) at which the
/// model foresaw a step's decrease: the usual trust-region threshold of
/// adequate agreement (Nocedal & Wright, Numerical Optimization, Alg. 4.1).
pub(super) const TRUSTED_GAIN_RATIO: f64 = 0.25;

/// How a factorisation and solve for one trial step went.
pub(super) enum Solved {
    /// The step is in `Optimizer::step`; its largest absolute component.
    Step(f64),
    /// The damped normal matrix is not positive definite at this variable
    /// block.
    NotPositiveDefinite(usize),
}

impl<P: Pose<D>, const D: usize> Optimizer<P, D> {
    /// Builds `H` and `b` at the graph's poses and returns the objective
    /// (public for benchmarks; [`Optimizer::run`] does this itself). Edges
    /// left out of the pattern ([`Optimizer::new`]) count in the objective
    /// but not in `H`.
    pub fn linearize(&mut self, graph: &Graph<P, D>, weights: Option<&[f64]>) -> f64 {
        let parallelism = self.parallelism.clone();
        parallelism.install(|| self.assemble(graph, weights))
    }

    /// [`Self::linearize`] where the parallel work belongs.
    fn assemble(&mut self, graph: &Graph<P, D>, weights: Option<&[f64]>) -> f64 {
        self.forget_factored();
        self.plan_keeping(graph, weights);
        self.system.clear();
        let parallel = self.parallelism.is_parallel();
        if prepare(&graph.poses, &mut self.prepared, parallel) {
            self.chi2_at_prepared = false;
        }
        self.prepare_measurements(graph);
        let mut objective = 0.0;
        // Edges are linearised in parallel, a chunk at a time, into a buffer
        // reused across iterations, then added into H in parallel by
        // destination ([`BlockSystem::add_edges`]).
        let terms = &mut self.terms;
        let (prepared, measurements) = (&self.prepared, &self.measurements);
        for (c, chunk) in graph.edges.chunks(LINEARIZE_CHUNK).enumerate() {
            let base = c * LINEARIZE_CHUNK;
            terms.resize(chunk.len(), EdgeTerms::default());
            zip_each(parallel, EDGES_PER_TASK, terms, chunk, |i, t, e| {
                let k = base + i;
                let w = weights.map_or(1.0, |w| w[k]);
                *t = if w == 0.0 {
                    EdgeTerms::default()
                } else {
                    let (xi, xj) = (&prepared[e.from].1, &prepared[e.to].1);
                    EdgeTerms::new::<P>(xi, xj, &measurements[k], &e.information, w)
                };
            });
            objective += terms.iter().map(|t| t.blocks.chi2).sum::<f64>();
            self.system
                .add_edges(base, terms, |t| t.active.then_some(&t.blocks));
        }
        objective
    }

    /// The weighted objective at `poses`.
    pub(super) fn objective(
        &mut self,
        poses: &[P],
        graph: &Graph<P, D>,
        weights: Option<&[f64]>,
    ) -> f64 {
        let parallelism = self.parallelism.clone();
        parallelism.install(|| self.sum_chi2(poses, graph, weights))
    }

    /// [`Self::objective`] where the parallel work belongs.
    fn sum_chi2(&mut self, poses: &[P], graph: &Graph<P, D>, weights: Option<&[f64]>) -> f64 {
        let parallel = self.parallelism.is_parallel();
        prepare(poses, &mut self.prepared, parallel);
        self.prepare_measurements(graph);
        let (prepared, measurements) = (&self.prepared, &self.measurements);
        self.edge_chi2.resize(graph.edges.len(), 0.0);
        zip_each(
            parallel,
            EDGES_PER_TASK,
            &mut self.edge_chi2,
            &graph.edges,
            |k, chi2, e| {
                let (xi, xj) = (&prepared[e.from].1, &prepared[e.to].1);
                let r = P::error_prepared(xi, xj, &measurements[k]);
                *chi2 = r.dot(&(e.information * r));
            },
        );
        self.chi2_at_prepared = true;
        // Summed in edge order, not as the parallel loop was split (that
        // split follows the work stealing, and a floating-point sum depends
        // on its order): the same bits in every run and with any number of
        // threads. An edge of weight 0 adds nothing, even where its cost
        // is not finite.
        (self.edge_chi2.iter().enumerate())
            .map(|(k, &chi2)| match weights.map_or(1.0, |w| w[k]) {
                0.0 => 0.0,
                w => w * chi2,
            })
            .sum()
    }

    /// Each edge's plain `eᵀΩe` at the graph's poses if the optimiser's last
    /// evaluation was there (the same bits as [`Graph::edge_chi2s`]),
    /// which it usually was after [`Optimizer::run`].
    pub fn edge_chi2s_at(&self, graph: &Graph<P, D>) -> Option<&[f64]> {
        let at_poses = self.prepared.len() == graph.poses.len()
            && (self.prepared.iter().zip(&graph.poses)).all(|((p, _), q)| p == q);
        (self.chi2_at_prepared && at_poses && self.edge_chi2.len() == graph.edges.len())
            .then_some(&self.edge_chi2[..])
    }

    /// Factorises `H + λ·diag H` and solves for the step into `self.step`;
    /// counts the factorisation and times both into `progress`.
    pub(super) fn solve_damped(
        &mut self,
        lambda: f64,
        progress: &mut Progress,
    ) -> Result<Solved, SolveError> {
        progress.summary.factorizations += 1;
        self.forget_factored();
        let factorized = if lambda == 0.0 && self.factorize_keeping() {
            Ok(())
        } else {
            let whole = self.system.factorize(lambda);
            self.kept_after_factorization(lambda);
            whole
        };
        self.factorized = true;
        progress.lap(|t| &mut t.factorize_s);
        match factorized {
            Ok(()) => {}
            Err(LinearError::NotPositiveDefinite { block }) => {
                return Ok(Solved::NotPositiveDefinite(block));
            }
            Err(e) => return Err(e.into()),
        }
        self.system.solve(&mut self.step);
        progress.lap(|t| &mut t.solve_s);
        Ok(Solved::Step(
            self.step.iter().fold(0.0f64, |m, s| m.max(s.abs())),
        ))
    }

    /// The objective at `poses ⊞ step` (left in `self.trial`).
    pub(super) fn evaluate_step(
        &mut self,
        graph: &Graph<P, D>,
        weights: Option<&[f64]>,
        progress: &mut Progress,
    ) -> f64 {
        self.apply_step(graph);
        let trial = std::mem::take(&mut self.trial);
        let new_objective = self.objective(&trial, graph, weights);
        self.trial = trial;
        progress.lap(|t| &mut t.evaluate_s);
        new_objective
    }

    /// Whether the last step (in `self.step`, from the last factorisation)
    /// was at most lightly damped ([`TRUSTED_DAMPING_SHARE`]).
    pub(super) fn lightly_damped(&self) -> bool {
        self.system.damping_share(&self.step) <= TRUSTED_DAMPING_SHARE
    }

    /// Whether the Gauss–Newton model is trusted after the last step took
    /// the objective from `objective` to `new_objective`: the step was at
    /// most lightly damped, and the model foresaw its decrease (gain ratio
    /// at least [`TRUSTED_GAIN_RATIO`]) or foresaw no decrease worth having
    /// (a predicted relative decrease below the relative tolerance).
    pub(super) fn model_trusted(&self, objective: f64, new_objective: f64) -> bool {
        let predicted = self.system.predicted_decrease(&self.step);
        self.lightly_damped()
            && (objective - new_objective >= TRUSTED_GAIN_RATIO * predicted
                || predicted <= self.options.relative_tolerance * objective)
    }

    /// Whether the last step, lightly damped, lowered the objective from
    /// `objective` to `new_objective` by what the model foresaw, to within
    /// [`SolveSettings::model_tolerance`] of the objective.
    pub(super) fn model_agreed(&self, objective: f64, new_objective: f64) -> bool {
        self.options.model_tolerance.is_some_and(|tol| {
            let predicted = self.system.predicted_decrease(&self.step);
            self.lightly_damped()
                && ((objective - new_objective) - predicted).abs() <= tol * objective
        })
    }

    /// Prepares the measurements of the edges not prepared yet (those
    /// appended since, when `measurements` came from an optimiser of the
    /// graph before it grew: [`Optimizer::reuse_spare`]).
    fn prepare_measurements(&mut self, graph: &Graph<P, D>) {
        let done = self.measurements.len().min(graph.edges.len());
        self.measurements.truncate(done);
        (self.measurements).extend(graph.edges[done..].iter().map(|e| e.measurement.prepare()));
    }

    /// `trial = poses ⊞ step`.
    fn apply_step(&mut self, graph: &Graph<P, D>) {
        self.trial.clone_from(&graph.poses);
        for (block, &v) in self.vertex_of.iter().enumerate() {
            let delta = nalgebra::SVector::<f64, D>::from_column_slice(
                &self.step[block * D..block * D + D],
            );
            self.trial[v] = graph.poses[v].retract(&delta);
        }
    }
}

/// `out[k] = (poses[k], poses[k].prepare())`, in parallel if `parallel`;
/// a pose already prepared in `out` is not prepared again. Most poses are:
/// an iteration linearises at the poses its last step evaluated, and an
/// update's solve starts from the last one's map. Returns whether any pose
/// was prepared (or dropped).
fn prepare<P: Pose<D>, const D: usize>(
    poses: &[P],
    out: &mut Vec<(P, P::Prepared)>,
    parallel: bool,
) -> bool {
    let changed = AtomicBool::new(out.len() != poses.len());
    out.truncate(poses.len());
    let old = out.len();
    out.extend(poses[old..].iter().map(|p| (*p, p.prepare())));
    zip_each(
        parallel,
        POSES_PER_TASK,
        &mut out[..old],
        poses,
        |_, o, p| {
            if o.0 != *p {
                *o = (*p, p.prepare());
                changed.store(true, Relaxed);
            }
        },
    );
    changed.into_inner()
}

/// The least edges (linearisations or χ² terms) a parallel task gets: a
/// few tens of microseconds of work, well above the cost of handing it to
/// another thread.
pub(crate) const EDGES_PER_TASK: usize = 256;

/// The least poses a parallel task prepares (a sine and cosine, or a
/// rotation matrix, each: a sixteenth of an edge's linearisation).
const POSES_PER_TASK: usize = 16 * EDGES_PER_TASK;

/// `f(k, &mut out[k], &input[k])` for every `k`: in parallel tasks of at
/// least `per_task` items if `parallel` (in the current pool), else a plain
/// loop in the calling thread that does not touch rayon (which would start
/// its global pool).
fn zip_each<A: Send, B: Sync>(
    parallel: bool,
    per_task: usize,
    out: &mut [A],
    input: &[B],
    f: impl Fn(usize, &mut A, &B) + Sync + Send,
) {
    if parallel {
        out.par_iter_mut()
            .zip(input.par_iter())
            .enumerate()
            .with_min_len(per_task)
            .for_each(|(k, (a, b))| f(k, a, b));
    } else {
        for (k, (a, b)) in out.iter_mut().zip(input).enumerate() {
            f(k, a, b);
        }
    }
}
