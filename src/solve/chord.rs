//! Chord steps (Shamanskii's variant of Newton's method): the Gauss–Newton
//! step at a new linearisation solved with the factor of an earlier one.
//!
//! Near an optimum `H` changes little from one iteration to the next. A
//! step solved with the last factor `H₀` against the new gradient `b`,
//! `δ = −H₀⁻¹b`, leaves the error `(I − H₀⁻¹H)` times the last one: it
//! converges, with a contraction as small as `H` moved. Its fixed point is
//! Gauss–Newton's (`b = 0`), so a run of chord steps stops where a run of
//! Gauss–Newton steps stops, by the same tolerances; it saves the
//! factorisations and keeps the linearisations and triangular solves.
//!
//! A chord step is taken where it lowers the objective by at least
//! [`TRUSTED_GAIN_RATIO`] of what the model at the new linearisation
//! foresees for it; otherwise the iteration factorises as usual, from the
//! same poses. The first chord step follows a Gauss–Newton step that
//! moved the map little ([`CHORD_DECREASE`]); chord steps go on while each
//! lowers the objective by at most [`CHORD_CONTRACTION`] of what the step
//! before did.

use super::normal::TRUSTED_GAIN_RATIO;
use super::{Optimizer, Progress, Step, StepOutcome};
use crate::geometry::Pose;
use crate::graph::Graph;

/// The largest relative decrease of a Gauss–Newton step after which the
/// next step is a chord step. A chord step contracts the error by about
/// how far `H` moved, which is about how long the last step was; a step
/// that lowered the objective by `τ·χ²` was about `√τ` of the objective's
/// scale long. Replaying manhattanOlson3500 with an update every pose
/// (`examples/replay`, 4211 iterations): after steps of decrease up to
/// 10⁻⁴ every chord step did as well as the Gauss–Newton step it replaced
/// (the same iterations, 2779 factorisations instead of 4211); at 10⁻³ and
/// above some fell short and cost iterations (4233 at 10⁻³, 4550 with no
/// bound).
pub(super) const CHORD_DECREASE: f64 = 1e-4;

/// The largest ratio of a chord step's relative decrease to the previous
/// step's after which the next step is a chord step too: a chord step
/// that takes the decrease down by a decade or more is worth its cost
/// (a linearisation, two triangular solves and an evaluation); at a
/// slower contraction a factorisation (about as much again on the
/// replayed maps) and Gauss–Newton's quadratic convergence pay for
/// themselves.
pub(super) const CHORD_CONTRACTION: f64 = 0.1;

/// Whether the next iteration tries a chord step, and the relative
/// decrease of the last step.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct Chord {
    /// Try a chord step next.
    pub(super) ready: bool,
    last_decrease: f64,
}

impl Chord {
    /// After `step` took the objective from `previous`: a chord step comes
    /// next (if `enabled`) after an undamped step solved with a fresh
    /// factor that lowered the objective by at most [`CHORD_DECREASE`] of
    /// it, or after a chord step that contracted by [`CHORD_CONTRACTION`]
    /// or more.
    pub(super) fn after(&mut self, step: &Step, previous: f64, enabled: bool) {
        let decrease = (previous - step.objective) / previous;
        let undamped = step.lambda == 0.0 && step.rejected == 0;
        let contracting = match step.reused_factor {
            true => decrease <= CHORD_CONTRACTION * self.last_decrease,
            false => decrease <= CHORD_DECREASE,
        };
        self.ready = enabled && undamped && contracting;
        self.last_decrease = decrease;
    }
}

impl<P: Pose<D>, const D: usize> Optimizer<P, D> {
    /// A chord step from the current linearisation at `objective`, solved
    /// with the last factor: `Some` if it is negligible or lowers the
    /// objective as the model foresees (see the module's doc), `None` to
    /// factorise instead.
    pub(super) fn chord_step(
        &mut self,
        graph: &Graph<P, D>,
        weights: Option<&[f64]>,
        objective: f64,
        progress: &mut Progress,
    ) -> Option<StepOutcome> {
        self.system.solve(&mut self.step);
        progress.lap(|t| &mut t.solve_s);
        let step_max = self.step.iter().fold(0.0f64, |m, s| m.max(s.abs()));
        let predicted = self.system.predicted_decrease(&self.step);
        if !(step_max.is_finite() && predicted > 0.0) {
            return None;
        }
        if step_max < self.options.step_tolerance {
            return Some(StepOutcome::Negligible);
        }
        let new_objective = self.evaluate_step(graph, weights, progress);
        let gain = (objective - new_objective) / predicted;
        (new_objective.is_finite() && gain >= TRUSTED_GAIN_RATIO).then_some(StepOutcome::Taken(
            Step {
                step_max,
                objective: new_objective,
                lambda: 0.0,
                rejected: 0,
                reused_factor: true,
            },
        ))
    }
}
