//! The marginal covariances of a result's map (`pgo_result_covariance`
//! and the others), each matrix written row by row into the caller's
//! buffer. The first call factorises the map's normal matrix; the result
//! keeps it for the others.

use crate::result::PgoResult;
use crate::status::{Failure, PgoStatus, borrow, out_ptr, status};
use pgo::AnyCovariances;
use std::ptr;

/// The result's covariances, computed at the first request.
fn covariances(result: &PgoResult) -> Result<&AnyCovariances, Failure> {
    if let Some(c) = result.covariances.get() {
        return Ok(c);
    }
    let computed = result.solution.covariances()?;
    // Another thread may have been first: either value is the same.
    let _ = result.covariances.set(computed);
    result
        .covariances
        .get()
        .ok_or_else(|| Failure::new(PgoStatus::PgoErrInternal, "no covariances"))
}

/// Writes `numbers` to the `len` doubles at `out`, if `len` is their count.
///
/// # Safety
/// `out` is NULL or points to `len` writable doubles.
unsafe fn write(numbers: &[f64], out: *mut f64, len: usize, what: &str) -> Result<(), Failure> {
    let slot = out_ptr(out, "out")?;
    if numbers.len() != len {
        return Err(Failure::new(
            PgoStatus::PgoErrLength,
            format!(
                "{what}: expected a buffer of {} numbers, got {len}",
                numbers.len()
            ),
        ));
    }
    // SAFETY: `len` writable doubles at `slot`, by the caller's contract.
    unsafe { ptr::copy_nonoverlapping(numbers.as_ptr(), slot, len) };
    Ok(())
}

/// Copies the marginal covariance of pose `id` into the `len` numbers at
/// `out`, row by row: D×D, `len` = 9 in 2D (x, y, θ), 36 in 3D (x, y, z,
/// rx, ry, rz). Perturbations are on the right (in the pose's own frame),
/// translation first, in the graph's units and radians; the normal matrix
/// is that of the map's edges (trusted edges and accepted loops) at the
/// optimised poses, and the fixed poses are the gauge (their covariance is
/// zero). The first covariance asked of a result factorises that matrix
/// (about three factorisations' time); the result keeps it, so later calls
/// are fast. Thread-safe.
///
/// Errors: `PGO_ERR_UNKNOWN_VERTEX`, `PGO_ERR_UNCONSTRAINED` (no trusted
/// edge or accepted loop ties the pose to the fixed ones: its covariance
/// is unbounded), `PGO_ERR_LENGTH`, `PGO_ERR_NUMERICAL`,
/// `PGO_ERR_INVALID_ARGUMENT`.
///
/// # Safety
/// `result` is NULL or a live result; `out` is NULL or points to `len`
/// writable numbers.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pgo_result_covariance(
    result: *const PgoResult,
    id: u64,
    out: *mut f64,
    len: usize,
) -> PgoStatus {
    status(|| {
        // SAFETY: the caller's contract.
        let c = covariances(unsafe { borrow(result, "result")? })?;
        // SAFETY: as above.
        unsafe { write(&c.pose(id)?, out, len, "covariance") }
    })
}

/// Copies the covariances of the `n` poses `ids` into the `len` numbers at
/// `out`, one D×D matrix after the other (`len` = `n`·9 in 2D, `n`·36 in
/// 3D), each as `pgo_result_covariance` writes it.
///
/// Errors: those of `pgo_result_covariance`, for the first id that has
/// none (nothing is written then).
///
/// # Safety
/// `result` is NULL or a live result; `ids` is NULL or points to `n` ids;
/// `out` is NULL or points to `len` writable numbers.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pgo_result_covariances(
    result: *const PgoResult,
    ids: *const u64,
    n: usize,
    out: *mut f64,
    len: usize,
) -> PgoStatus {
    status(|| {
        // SAFETY: the caller's contract.
        let c = covariances(unsafe { borrow(result, "result")? })?;
        let ids = match (ids.is_null(), n) {
            (_, 0) => &[][..],
            (true, _) => return Err(Failure::invalid(format!("ids is NULL, with n {n}"))),
            // SAFETY: `n` readable ids, by the caller's contract.
            (false, _) => unsafe { std::slice::from_raw_parts(ids, n) },
        };
        // SAFETY: as above.
        unsafe { write(&c.poses(ids)?, out, len, "covariances") }
    })
}

/// Copies the joint covariance of poses `a` and `b` into the `len` numbers
/// at `out`, row by row: 2D×2D (`len` = 36 in 2D, 144 in 3D), the blocks
/// `[[Σ_aa, Σ_ab], [Σ_ba, Σ_bb]]` in the convention of
/// `pgo_result_covariance`.
///
/// Errors: those of `pgo_result_covariance`.
///
/// # Safety
/// `result` is NULL or a live result; `out` is NULL or points to `len`
/// writable numbers.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pgo_result_joint_covariance(
    result: *const PgoResult,
    a: u64,
    b: u64,
    out: *mut f64,
    len: usize,
) -> PgoStatus {
    status(|| {
        // SAFETY: the caller's contract.
        let c = covariances(unsafe { borrow(result, "result")? })?;
        // SAFETY: as above.
        unsafe { write(&c.joint(a, b)?, out, len, "joint covariance") }
    })
}

/// Copies the covariance of pose `b` relative to pose `a` — of `Xa⁻¹·Xb`,
/// perturbed on the right as every pose here: `b`'s uncertainty as seen
/// from `a`, whichever poses are fixed — into the `len` numbers at `out`,
/// row by row (D×D as `pgo_result_covariance`).
///
/// Errors: those of `pgo_result_covariance`.
///
/// # Safety
/// `result` is NULL or a live result; `out` is NULL or points to `len`
/// writable numbers.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pgo_result_relative_covariance(
    result: *const PgoResult,
    a: u64,
    b: u64,
    out: *mut f64,
    len: usize,
) -> PgoStatus {
    status(|| {
        // SAFETY: the caller's contract.
        let c = covariances(unsafe { borrow(result, "result")? })?;
        // SAFETY: as above.
        unsafe { write(&c.relative(a, b)?, out, len, "relative covariance") }
    })
}
