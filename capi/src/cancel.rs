//! Stopping a running optimisation from another thread: `PgoCancel`.

use crate::status::{PgoStatus, borrow, out_ptr, status, value};

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
