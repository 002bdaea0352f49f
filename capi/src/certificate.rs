//! The certificate of global optimality of a result's map
//! (`pgo_result_certificate`), filled into a plain struct the caller owns.

use crate::result::PgoResult;
use crate::status::{PgoStatus, borrow, out_ptr, status};

/// Most poses of the eigenvector `PgoCertificate` lists.
pub const PGO_CERTIFICATE_POSES: usize = 10;

/// A certificate of global optimality of a map (filled by
/// `pgo_result_certificate`): the map refined on the isotropic problem
/// over its edges and whether it is that problem's global optimum, proven
/// by a sparse Cholesky factorisation of `S + η·D`; where it is not, the
/// smallest eigenvalue of `S` and the poses where its vector is largest.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PgoCertificate {
    /// Whether the refined map is certified globally optimal.
    pub certified: bool,
    /// The shift η: every eigenvalue of `Q − Λ` is above −η when certified.
    pub eta: f64,
    /// The isotropic cost of the refined (certified) map.
    pub cost: f64,
    /// The isotropic cost of pgo's map.
    pub map_cost: f64,
    /// When certified, a bound on the cost above the global optimum; NaN
    /// otherwise.
    pub gap_bound: f64,
    /// The largest distance between a pose of the refined map and pgo's.
    pub max_translation_change: f64,
    /// The largest rotation between them (radians).
    pub max_rotation_change: f64,
    /// When not certified, the smallest eigenvalue of `Q − Λ`; NaN
    /// otherwise.
    pub lambda_min: f64,
    /// How many of `eigenvector_ids` are set (0 when certified).
    pub num_eigenvector_poses: usize,
    /// The poses where the eigenvector of `lambda_min` is largest, largest
    /// first.
    pub eigenvector_ids: [u64; PGO_CERTIFICATE_POSES],
    /// Their shares of the vector's squared norm.
    pub eigenvector_shares: [f64; PGO_CERTIFICATE_POSES],
    /// Seconds the certificate took.
    pub time_s: f64,
}

/// Computes the certificate of `result`'s map and stores it at `*out`
/// (each call computes it anew).
///
/// Errors: `PGO_ERR_INVALID_ARGUMENT` (NULL pointers; a graph with more
/// than one fixed pose), `PGO_ERR_NUMERICAL` (a non-finite map),
/// `PGO_ERR_INTERNAL`.
///
/// # Safety
/// `result` is NULL or a live result; `out` is NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pgo_result_certificate(
    result: *const PgoResult,
    out: *mut PgoCertificate,
) -> PgoStatus {
    status(|| {
        // SAFETY: the caller's contract.
        let result = unsafe { borrow(result, "result")? };
        let slot = out_ptr(out, "out")?;
        let c = result.solution().certificate()?;
        let mut filled = PgoCertificate {
            certified: c.certified,
            eta: c.eta,
            cost: c.cost,
            map_cost: c.map_cost,
            gap_bound: c.gap_bound.unwrap_or(f64::NAN),
            max_translation_change: c.max_translation_change,
            max_rotation_change: c.max_rotation_change,
            lambda_min: c.lambda_min.unwrap_or(f64::NAN),
            num_eigenvector_poses: c.eigenvector_poses.len().min(PGO_CERTIFICATE_POSES),
            time_s: c.time.total_s,
            ..Default::default()
        };
        for (k, p) in c
            .eigenvector_poses
            .iter()
            .take(PGO_CERTIFICATE_POSES)
            .enumerate()
        {
            filled.eigenvector_ids[k] = p.id;
            filled.eigenvector_shares[k] = p.share;
        }
        // SAFETY: writable, by the caller's contract.
        unsafe { slot.write(filled) };
        Ok(())
    })
}
