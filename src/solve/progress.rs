//! Progress and cancellation of a run: the [`Observer`] that the optimiser
//! reports every iteration to and asks whether to go on, and the [`Cancel`]
//! token that another thread (a Ctrl-C handler, a caller's thread) sets to
//! stop it.

use super::IterationRecord;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

/// Receives progress from the optimiser and may stop it.
///
/// A closure `FnMut(&IterationRecord)` is an observer that never stops the
/// run; [`Cancel`] is one that reports nothing and stops once cancelled;
/// [`Cancellable`] does both.
pub trait Observer {
    /// Called after every outer iteration.
    fn iteration(&mut self, record: &IterationRecord);

    /// Asked before every outer iteration (the first included) and before
    /// every further LM trial after a rejected one: `true` ends the run
    /// with [`super::StopReason::Cancelled`], keeping the best poses so far
    /// in the graph. The default never stops.
    fn should_stop(&mut self) -> bool {
        false
    }
}

impl<F: FnMut(&IterationRecord)> Observer for F {
    fn iteration(&mut self, record: &IterationRecord) {
        self(record)
    }
}

/// A request to stop, shared by its clones: hand one clone to another
/// thread to [`Cancel::cancel`], and let the run's observer consult another
/// ([`Cancel::is_cancelled`]). Once cancelled it stays cancelled, for every
/// run that consults it.
#[derive(Clone, Debug, Default)]
pub struct Cancel(Arc<AtomicBool>);

impl Cancel {
    /// A token not cancelled yet.
    pub fn new() -> Self {
        Self::default()
    }

    /// Asks every run that consults this token (or a clone) to stop.
    pub fn cancel(&self) {
        self.0.store(true, Ordering::Release);
    }

    /// Whether [`Cancel::cancel`] was called on this token or a clone.
    pub fn is_cancelled(&self) -> bool {
        self.0.load(Ordering::Acquire)
    }
}

/// An observer that reports nothing and stops the run once cancelled.
impl Observer for Cancel {
    fn iteration(&mut self, _: &IterationRecord) {}

    fn should_stop(&mut self) -> bool {
        self.is_cancelled()
    }
}

/// An observer that hands every record to `progress` and stops the run
/// once `cancel` is cancelled.
#[derive(Clone, Debug)]
pub struct Cancellable<F> {
    cancel: Cancel,
    progress: F,
}

impl<F: FnMut(&IterationRecord)> Cancellable<F> {
    /// Reports to `progress`; stops when `cancel` (or a clone) is cancelled.
    pub fn new(cancel: Cancel, progress: F) -> Self {
        Self { cancel, progress }
    }
}

impl<F: FnMut(&IterationRecord)> Observer for Cancellable<F> {
    fn iteration(&mut self, record: &IterationRecord) {
        (self.progress)(record)
    }

    fn should_stop(&mut self) -> bool {
        self.cancel.is_cancelled()
    }
}
