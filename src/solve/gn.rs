//! Gauss–Newton: the undamped step, taken whatever the objective does there
//! (as long as it is finite); the best poses seen are kept by the run.

use super::normal::Solved;
use super::{Optimizer, Progress, SolveError, Step, StepOutcome};
use crate::geometry::Pose;
use crate::graph::Graph;

impl<P: Pose<D>, const D: usize> Optimizer<P, D> {
    /// Gauss–Newton's step from the current linearisation. A normal matrix
    /// that is not positive definite is an error: nothing regularises it.
    pub(super) fn gauss_newton_step(
        &mut self,
        graph: &Graph<P, D>,
        weights: Option<&[f64]>,
        progress: &mut Progress,
    ) -> Result<StepOutcome, SolveError> {
        let step_max = match self.solve_damped(0.0, progress)? {
            Solved::Step(step_max) => step_max,
            Solved::NotPositiveDefinite(block) => {
                return Err(self.not_positive_definite(graph, block));
            }
        };
        if !step_max.is_finite() {
            return Ok(StepOutcome::Failed);
        }
        if step_max < self.options.step_tolerance {
            return Ok(StepOutcome::Negligible);
        }
        let objective = self.evaluate_step(graph, weights, progress);
        if !objective.is_finite() {
            return Ok(StepOutcome::Failed);
        }
        Ok(StepOutcome::Taken(Step {
            step_max,
            objective,
            lambda: 0.0,
            rejected: 0,
            reused_factor: false,
        }))
    }
}
