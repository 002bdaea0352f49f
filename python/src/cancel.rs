//! `pgo.Cancel`: a token another thread cancels to stop a running
//! `optimize` or `update`, and the observer that also stops one on Ctrl-C.

use pgo::{IterationRecord, Observer};
use pyo3::prelude::*;

/// A cancellation token: pass it as `cancel=` to `PoseGraph.optimize` or
/// `PoseGraph.update`, and call `cancel()` from any thread (a GUI, a
/// watchdog, a ROS callback) to stop that job at its next iteration. The
/// stopped job returns the best map so far with `Result.cancelled` true;
/// a stopped update leaves the graph's kept state as it was. Once
/// cancelled, a token stays cancelled: make a new one for the next job.
#[pyclass(name = "Cancel", module = "pgo", frozen)]
pub struct Cancel(pgo::Cancel);

#[pymethods]
impl Cancel {
    /// A token not cancelled yet.
    #[new]
    fn new() -> Self {
        Self(pgo::Cancel::new())
    }

    /// Stops every job that holds this token, at its next iteration.
    fn cancel(&self) {
        self.0.cancel();
    }

    /// Whether `cancel()` was called.
    #[getter]
    fn cancelled(&self) -> bool {
        self.0.is_cancelled()
    }

    /// `Cancel(cancelled=…)`.
    fn __repr__(&self) -> String {
        let cancelled = if self.0.is_cancelled() {
            "True"
        } else {
            "False"
        };
        format!("Cancel(cancelled={cancelled})")
    }
}

/// What stops a job run from Python: its token, if it has one, or a signal
/// (Ctrl-C's `KeyboardInterrupt`), whose error is kept to be raised when
/// the job has returned.
pub struct Stop {
    token: Option<pgo::Cancel>,
    /// The error a signal handler (or the progress callback) raised, once
    /// one did.
    pub interrupted: Option<PyErr>,
    /// Called with the solver's iterations so far and the last objective.
    progress: Option<Py<PyAny>>,
    iterations: usize,
}

impl Stop {
    /// Stops on `token` (if any) or on a signal.
    pub fn new(token: Option<&Bound<'_, Cancel>>) -> Self {
        Self {
            token: token.map(|t| t.get().0.clone()),
            interrupted: None,
            progress: None,
            iterations: 0,
        }
    }

    /// Also calls `progress(iterations, objective)` at every solver
    /// iteration; an exception it raises stops the job and is raised when
    /// the job has returned.
    pub fn reporting_to(mut self, progress: Option<Py<PyAny>>) -> Self {
        self.progress = progress;
        self
    }
}

impl Observer for Stop {
    fn iteration(&mut self, record: &IterationRecord) {
        self.iterations += 1;
        let Some(progress) = &self.progress else {
            return;
        };
        if self.interrupted.is_some() {
            return;
        }
        let n = self.iterations;
        self.interrupted = Python::attach(|py| progress.call1(py, (n, record.objective)).err());
    }

    fn should_stop(&mut self) -> bool {
        if self.token.as_ref().is_some_and(pgo::Cancel::is_cancelled) {
            return true;
        }
        if self.interrupted.is_none() {
            // Python runs signal handlers in the main thread only; from
            // another this returns Ok.
            self.interrupted = Python::attach(|py| py.check_signals()).err();
        }
        self.interrupted.is_some()
    }
}
