//! Levenberg–Marquardt: Marquardt's diagonal scaling of the damping, the
//! gain ratio to accept a step, and Nielsen's update of the damping.

use super::normal::Solved;
use super::{Observer, Optimizer, Progress, SolveError, Step, StepOutcome};
use crate::geometry::Pose;
use crate::graph::Graph;

/// Damping beyond which LM gives up: `λ·diag H` then exceeds `diag H` by
/// more than the inverse of the machine epsilon (2.2·10⁻¹⁶), so the damped
/// matrix is `λ·diag H` to rounding and more damping only shrinks the
/// same scaled-gradient step.
const MAX_LAMBDA: f64 = 1e16;

/// The smallest damping once damping has started (Nielsen's update shrinks
/// it by at most 3 per step): along the weakest directions of long
/// trajectories, whose eigenvalues are ~10⁻⁶ of the diagonal, it changes
/// the step by 10⁻⁶ relative, and it stays a number that the update can
/// raise again.
const MIN_LAMBDA: f64 = 1e-12;

/// LM's damping `λ` (relative to the diagonal of `H`) and Nielsen's growth
/// factor `ν`.
///
/// λ = 0 until a step fails: near a minimum, where the Gauss–Newton model
/// is good, any damping only slows the convergence down (on long
/// trajectories the smallest eigenvalues of H are ~1e-6 of its diagonal,
/// so even λ = 1e-6 halves their steps). Every run starts undamped: a
/// robust round changed the weights, and carrying the previous run's
/// damping over was measured to make EM's short M-steps crawl (10⁵-pose
/// grid: 787 iterations instead of 319, and 2 % fewer true loops accepted).
pub(super) struct Damping {
    lambda: f64,
    nu: f64,
}

impl Damping {
    /// No damping yet.
    pub(super) fn undamped() -> Self {
        Self {
            lambda: 0.0,
            nu: 2.0,
        }
    }

    /// After a rejected trial: `initial` the first time, then `λ·ν` with `ν`
    /// doubling.
    fn raise(&mut self, initial: f64) {
        if self.lambda == 0.0 {
            self.lambda = initial;
        } else {
            self.lambda *= self.nu;
            self.nu *= 2.0;
        }
    }

    /// After an accepted step of gain ratio `rho`: Nielsen's
    /// `λ·max(1 − (2ρ − 1)³, ⅓)` (no damping stays none).
    fn accept(&mut self, rho: f64) {
        if self.lambda > 0.0 {
            self.lambda *= (1.0 - (2.0 * rho - 1.0).powi(3)).max(1.0 / 3.0);
            self.lambda = self.lambda.max(MIN_LAMBDA);
        }
        self.nu = 2.0;
    }
}

impl<P: Pose<D>, const D: usize> Optimizer<P, D> {
    /// Levenberg–Marquardt's step from the current linearisation at
    /// `objective`: trials of growing damping until one lowers the
    /// objective with a positive gain ratio. The very first trial of a run
    /// is undamped, so that a singular system (an undetermined vertex) is
    /// reported rather than hidden by the damping. The observer is asked
    /// before each trial after a rejected one whether to stop.
    pub(super) fn levenberg_marquardt_step(
        &mut self,
        graph: &Graph<P, D>,
        weights: Option<&[f64]>,
        objective: f64,
        damping: &mut Damping,
        progress: &mut Progress,
        observer: &mut dyn Observer,
    ) -> Result<StepOutcome, SolveError> {
        let initial = self.options.initial_lambda;
        let mut rejected = 0;
        loop {
            if rejected > 0 && observer.should_stop() {
                return Ok(StepOutcome::Cancelled);
            }
            let structural_check = progress.summary.factorizations == 0;
            let lambda = damping.lambda;
            let step_max = match self.solve_damped(lambda, progress)? {
                Solved::NotPositiveDefinite(block) => {
                    if structural_check || lambda > MAX_LAMBDA {
                        return Err(self.not_positive_definite(graph, block));
                    }
                    damping.raise(initial);
                    rejected += 1;
                    continue;
                }
                Solved::Step(step_max) => step_max,
            };
            if !step_max.is_finite() {
                if lambda > MAX_LAMBDA {
                    return Ok(StepOutcome::Failed);
                }
                damping.raise(initial);
                rejected += 1;
                continue;
            }
            if step_max < self.options.step_tolerance {
                return Ok(StepOutcome::Negligible);
            }
            let new_objective = self.evaluate_step(graph, weights, progress);
            let predicted = self.system.predicted_decrease(&self.step);
            let rho = (objective - new_objective) / predicted;
            if new_objective.is_finite() && new_objective <= objective && rho > 0.0 {
                damping.accept(rho);
                return Ok(StepOutcome::Taken(Step {
                    step_max,
                    objective: new_objective,
                    lambda: damping.lambda,
                    rejected,
                    reused_factor: false,
                }));
            }
            if self.lightly_damped() && predicted <= self.options.relative_tolerance * objective {
                return Ok(StepOutcome::AtMinimum);
            }
            damping.raise(initial);
            rejected += 1;
            if damping.lambda > MAX_LAMBDA {
                return Ok(StepOutcome::Failed);
            }
        }
    }
}
