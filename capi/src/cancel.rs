//! Stopping a running optimisation from another thread: `PgoCancel`.

use crate::status::{PgoStatus, borrow, out_ptr, status, value};
use pgo::{IterationRecord, Observer};
use std::ffi::c_void;
use std::sync::Mutex;

/// A cancellation token (opaque): pass it to `pgo_graph_optimize_with` or
/// `pgo_graph_update_with`, and call `pgo_cancel_request` from any thread
/// (a watchdog, a ROS 2 callback, a signal-handling thread) to stop that
/// job at its next iteration. The stopped job returns the best map so
/// far, and `pgo_result_cancelled` says so; a stopped update leaves the
/// graph's kept state as it was. Once requested, a token stays
/// cancelled: make a new one for the next job.
///
/// Made by `pgo_cancel_new`, owned by the caller, freed by
/// `pgo_cancel_free` once no job uses it. Several threads may use it at
/// once.
pub struct PgoCancel {
    pub(crate) token: pgo::Cancel,
    /// The progress callback and its pointer (`pgo_cancel_set_progress`).
    progress: Mutex<(PgoProgress, usize)>,
}

/// A progress callback: called at every solver iteration of a job run with
/// the token that holds it, with the solver iterations of the job so far
/// (every solve of it), the objective the solver just reached, and the
/// `user_data` given to `pgo_cancel_set_progress`. It runs on the thread
/// that runs the job; a nonzero return cancels the token (as
/// `pgo_cancel_request`), stopping the job.
pub type PgoProgress =
    Option<unsafe extern "C" fn(iterations: usize, objective: f64, user_data: *mut c_void) -> i32>;

/// What a job run with a token watches: the token, and its progress
/// callback.
pub(crate) struct Watch {
    token: pgo::Cancel,
    progress: PgoProgress,
    user_data: *mut c_void,
    iterations: usize,
}

impl Watch {
    /// What `cancel` (NULL: nothing cancels, no callback) asks of a job.
    ///
    /// # Safety
    /// `cancel` is NULL or a live token.
    pub(crate) unsafe fn of(cancel: *const PgoCancel) -> Self {
        // SAFETY: the caller's contract.
        let cancel = unsafe { cancel.as_ref() };
        let (progress, user_data) = cancel
            .and_then(|c| c.progress.lock().ok().map(|p| *p))
            .unwrap_or((None, 0));
        Self {
            token: cancel.map_or_else(pgo::Cancel::new, |c| c.token.clone()),
            progress,
            user_data: user_data as *mut c_void,
            iterations: 0,
        }
    }
}

impl Observer for Watch {
    fn iteration(&mut self, record: &IterationRecord) {
        self.iterations += 1;
        if let Some(progress) = self.progress {
            // SAFETY: the callback's contract (`pgo_cancel_set_progress`).
            let stop = unsafe { progress(self.iterations, record.objective, self.user_data) };
            if stop != 0 {
                self.token.cancel();
            }
        }
    }

    fn should_stop(&mut self) -> bool {
        self.token.is_cancelled()
    }
}

/// Makes a token not cancelled yet and stores it at `*out`; free it with
/// `pgo_cancel_free`.
///
/// Errors: `PGO_ERR_INVALID_ARGUMENT` for a NULL `out`.
///
/// # Safety
/// `out` is NULL or points to writable storage for a pointer.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pgo_cancel_new(out: *mut *mut PgoCancel) -> PgoStatus {
    status(|| {
        let slot = out_ptr(out, "out")?;
        let cancel = Box::new(PgoCancel {
            token: pgo::Cancel::new(),
            progress: Mutex::new((None, 0)),
        });
        // SAFETY: writable, by the caller's contract.
        unsafe { *slot = Box::into_raw(cancel) };
        Ok(())
    })
}

/// Cancels the token: every job that holds it stops at its next
/// iteration. Safe to call from any thread, any number of times.
///
/// Errors: `PGO_ERR_INVALID_ARGUMENT` for a NULL `cancel`.
///
/// # Safety
/// `cancel` is NULL or a live token.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pgo_cancel_request(cancel: *const PgoCancel) -> PgoStatus {
    status(|| {
        // SAFETY: the caller's contract.
        unsafe { borrow(cancel, "cancel")? }.token.cancel();
        Ok(())
    })
}

/// Stores at `*out` whether the token was cancelled.
///
/// Errors: `PGO_ERR_INVALID_ARGUMENT`.
///
/// # Safety
/// `cancel` is NULL or a live token; `out` is NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pgo_cancel_requested(
    cancel: *const PgoCancel,
    out: *mut bool,
) -> PgoStatus {
    status(|| {
        let slot = out_ptr(out, "out")?;
        // SAFETY: the caller's contract.
        let cancelled = unsafe { borrow(cancel, "cancel")? }.token.is_cancelled();
        // SAFETY: writable, by the caller's contract.
        unsafe { *slot = cancelled };
        Ok(())
    })
}

/// Sets the progress callback of jobs run with this token from now on
/// (NULL: none): `progress(iterations, objective, user_data)` at every
/// solver iteration, on the job's thread — to show a long job alive, or
/// to stop it by returning nonzero.
///
/// Errors: `PGO_ERR_INVALID_ARGUMENT` for a NULL `cancel`.
///
/// # Safety
/// `cancel` is NULL or a live token; `progress` is NULL or a function
/// that may be called with `user_data` from the thread of any job run
/// with this token, for as long as it is set.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pgo_cancel_set_progress(
    cancel: *const PgoCancel,
    progress: PgoProgress,
    user_data: *mut c_void,
) -> PgoStatus {
    status(|| {
        // SAFETY: the caller's contract.
        let cancel = unsafe { borrow(cancel, "cancel")? };
        if let Ok(mut slot) = cancel.progress.lock() {
            *slot = (progress, user_data as usize);
        }
        Ok(())
    })
}

/// Frees a token made by `pgo_cancel_new`. NULL is allowed and does
/// nothing.
///
/// # Safety
/// `cancel` is NULL or a token from this API not yet freed, which no job
/// or thread uses any more.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pgo_cancel_free(cancel: *mut PgoCancel) {
    if !cancel.is_null() {
        value((), || {
            // SAFETY: made by Box::into_raw and not yet freed, by the contract.
            drop(unsafe { Box::from_raw(cancel) });
            Ok(())
        });
    }
}
