//! A sequence of solver runs on one graph under one budget: the robust back
//! end solves many times (a step per reweighting, a solve per decision),
//! and `--max-iters` / `--time-limit` bound all of them together.

use super::{Crawl, Observer, Optimizer, SolveError, SolveSettings, StopReason, Summary};
use crate::geometry::Pose;
use crate::graph::Graph;
use std::time::{Duration, Instant};

/// Iterations and time left for all the runs of a session.
#[derive(Clone, Copy, Debug)]
pub struct Budget {
    /// Most iterations in all.
    pub iterations: usize,
    /// When to stop.
    pub deadline: Option<Instant>,
}

impl Budget {
    /// No limit.
    #[cfg(test)]
    pub fn unlimited() -> Self {
        Self {
            iterations: usize::MAX,
            deadline: None,
        }
    }
}

/// Most runs of the options' iteration limit that carry a job's last solve
/// on ([`Session::finish_converging`]): ten times the limit more, enough
/// for a solve that lowers its objective by a few percent per iteration
/// to reach a relative decrease of 10⁻⁹ (0.975¹⁰⁰⁰ ≈ 10⁻¹¹), and a bound
/// on one that never converges.
pub const FINAL_RUNS: usize = 10;

/// The optimiser, the graph it works on, what is left of the budget, and
/// the summary of every run so far.
pub struct Session<'a, P: Pose<D>, const D: usize> {
    /// The optimiser (its sparsity pattern follows the weights).
    pub optimizer: &'a mut Optimizer<P, D>,
    /// The graph; its poses are the current map.
    pub graph: &'a mut Graph<P, D>,
    /// Options of a run to convergence.
    pub options: SolveSettings,
    budget: Budget,
    observer: &'a mut dyn Observer,
    summary: Option<Summary>,
    cancelled: bool,
    phases: PhaseTimes,
}

/// Time a robust method spent outside the optimiser's runs, by phase.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PhaseTimes {
    /// Chordal relaxations (the annealing's E-steps, relaxed starts).
    pub relaxation: Duration,
    /// Evaluations of the map: innovations and their covariances, the
    /// model fitted to them, the decisions they give.
    pub evaluation: Duration,
    /// Of the evaluations: the loop model's fits to the innovations.
    pub model: Duration,
}

impl<'a, P: Pose<D>, const D: usize> Session<'a, P, D> {
    /// A session of runs with `options` within `budget`.
    pub fn new(
        optimizer: &'a mut Optimizer<P, D>,
        graph: &'a mut Graph<P, D>,
        options: SolveSettings,
        budget: Budget,
        observer: &'a mut dyn Observer,
    ) -> Self {
        Self {
            optimizer,
            graph,
            options,
            budget,
            observer,
            summary: None,
            cancelled: false,
            phases: PhaseTimes::default(),
        }
    }

    /// Adds the time since `start` to the relaxations' time.
    /// Then asks the observer whether to stop ([`Self::exhausted`]).
    pub fn relaxed_since(&mut self, start: Instant) {
        self.phases.relaxation += start.elapsed();
        self.poll();
    }

    /// Adds the time since `start` to the evaluations' time. Then asks the
    /// observer whether to stop ([`Self::exhausted`]).
    pub fn evaluated_since(&mut self, start: Instant) {
        self.phases.evaluation += start.elapsed();
        self.poll();
    }

    /// Adds `took` to the loop model's time (a part of the evaluations').
    pub fn modelled(&mut self, took: Duration) {
        self.phases.model += took;
    }

    /// Asks the observer whether to stop: between the optimiser's runs too,
    /// so that a job is cancelled within one evaluation or relaxation, not
    /// only at its next iteration.
    fn poll(&mut self) {
        self.cancelled |= self.observer.should_stop();
    }

    /// The time spent so far in each phase outside the optimiser's runs.
    pub fn phases(&self) -> PhaseTimes {
        self.phases
    }

    /// Iterations run so far.
    pub fn iterations(&self) -> usize {
        self.summary.as_ref().map_or(0, |s| s.iterations)
    }

    /// Runs `f` on this session with at most `cap` more iterations (within
    /// the budget); returns its result and whether it used all of them.
    pub fn capped<R>(&mut self, cap: usize, f: impl FnOnce(&mut Self) -> R) -> (R, bool) {
        let full = self.budget.iterations;
        self.budget.iterations = full.min(self.iterations().saturating_add(cap));
        let result = f(self);
        let used = self.iterations() >= self.budget.iterations;
        self.budget.iterations = full;
        (result, used)
    }

    /// Whether the budget is spent (or the observer stopped a run).
    pub fn exhausted(&self) -> bool {
        self.cancelled
            || self.iterations() >= self.budget.iterations
            || self.budget.deadline.is_some_and(|d| Instant::now() >= d)
    }

    /// Minimises `Σ wₖ eₖᵀΩₖeₖ` from the current map for at most
    /// `max_iterations` (and what is left of the budget).
    pub fn run(&mut self, weights: &[f64], max_iterations: usize) -> Result<(), SolveError> {
        let left = self.budget.iterations.saturating_sub(self.iterations());
        *self.optimizer.options_mut() = SolveSettings {
            max_iterations: max_iterations.min(left),
            time_limit: self
                .budget
                .deadline
                .map(|d| d.saturating_duration_since(Instant::now())),
            ..self.options.clone()
        };
        let run = self
            .optimizer
            .run(self.graph, Some(weights), &mut *self.observer)?;
        self.cancelled |= run.stop_reason == StopReason::Cancelled;
        self.summary = Some(match self.summary.take() {
            None => run,
            Some(mut total) => {
                total.iterations += run.iterations;
                total.factorizations += run.factorizations;
                total.time += run.time;
                total.history.extend(run.history);
                total.timing.add(&run.timing);
                total.final_objective = run.final_objective;
                total.stop_reason = run.stop_reason;
                total
            }
        });
        Ok(())
    }

    /// Runs to convergence (at most the options' iteration limit).
    pub fn converge(&mut self, weights: &[f64]) -> Result<(), SolveError> {
        self.run(weights, self.options.max_iterations)
    }

    /// Carries the last run on while it stopped at the options' iteration
    /// limit, at most [`FINAL_RUNS`] more runs of it and within the budget:
    /// the map a job returns is converged, not cut at the limit each
    /// intermediate solve of the robust methods has. The last solve of an
    /// aliased CSAIL (300 aliases in groups of 10 placed anywhere, seed 10,
    /// information as published) still lowered its objective by 2.5 % per
    /// iteration at its 100th, and the job ended unconverged with exit
    /// status 4 naming a `--max-iters` it was not given.
    ///
    /// With `polish`, a last run that converged by the objective where its
    /// last step leaves the poses further than that (`(translation,
    /// rotation)`) from the optimum ([`Optimizer::converged_within`]) is
    /// carried on once more, its chord steps bound by it too
    /// ([`SolveSettings::end_step`]): the map returned is converged in its
    /// poses, not only in its objective.
    pub fn finish_converging(
        &mut self,
        weights: &[f64],
        polish: Option<(f64, f64)>,
    ) -> Result<(), SolveError> {
        for _ in 0..FINAL_RUNS {
            let at_limit =
                (self.summary.as_ref()).is_some_and(|s| s.stop_reason == StopReason::MaxIterations);
            if !at_limit || self.exhausted() {
                break;
            }
            self.converge(weights)?;
        }
        let Some(end_step) = polish else {
            return Ok(());
        };
        let converged = (self.summary.as_ref()).is_some_and(|s| s.stop_reason.converged());
        if converged && !self.exhausted() && !self.optimizer.converged_within(end_step) {
            let own = self.options.end_step.replace(end_step);
            let ran = self.converge(weights);
            self.options.end_step = own;
            ran?;
        }
        Ok(())
    }

    /// [`Self::converge`], stopping also once a step crawls by `tolerance`
    /// ([`SolveSettings::crawl_tolerance`]). Returns whether the run
    /// converged (then not crawling).
    pub fn converge_unless_crawling(
        &mut self,
        weights: &[f64],
        tolerance: Crawl,
    ) -> Result<bool, SolveError> {
        let own = self.options.crawl_tolerance;
        self.options.crawl_tolerance = Some(tolerance);
        let ran = self.converge(weights);
        self.options.crawl_tolerance = own;
        ran?;
        Ok(self
            .summary
            .as_ref()
            .is_some_and(|s| s.stop_reason.converged()))
    }

    /// The summary of every run, `None` before the first. `cut_short`: the
    /// caller stopped before it was done because the budget ran out, which
    /// the stop reason then says even if the last run converged.
    pub fn finish(self, cut_short: bool) -> Option<Summary> {
        let limit = self.budget.iterations;
        let cancelled = self.cancelled;
        self.summary.map(|mut s| {
            if cancelled {
                s.stop_reason = StopReason::Cancelled;
            } else if cut_short {
                s.stop_reason = if s.iterations >= limit {
                    StopReason::MaxIterations
                } else {
                    StopReason::TimeLimit
                };
            }
            s
        })
    }
}
