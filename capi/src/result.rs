//! The optimisation, batch (`pgo_graph_optimize`) or incremental
//! (`pgo_graph_update`), and what it returns: `PgoResult`, with one
//! `PgoLoopDecision` per loop candidate and, for an update, a `PgoUpdate`
//! and one `PgoDecisionChange` per earlier decision it changed.

use crate::cancel::{PgoCancel, Watch};
use crate::graph::PgoGraph;
use crate::options::PgoOptions;
use crate::status::{Failure, PgoStatus, borrow, borrow_mut, out_ptr, status, text, value};
use pgo::{AnySolution, DecisionChange, LoopDecision, MapStatus, Options, Reason, UpdateSolve};
use std::ffi::{CStr, CString, c_char};
use std::ptr;
use std::sync::{Mutex, OnceLock};

/// What `pgo_graph_optimize` or `pgo_graph_update` returns (opaque): the
/// optimised poses by id, one decision per loop candidate, χ², the χ²
/// test's verdict, the report `pgo optimize --json` prints and, for an
/// update, what it did (`pgo_result_update`).
///
/// Owned by the caller, freed by `pgo_result_free`; the strings it hands
/// out live as long as it. It may be read by several threads at once.
pub struct PgoResult {
    pub(crate) solution: AnySolution,
    /// The map's covariances, computed at the first request
    /// (`pgo_result_covariance`).
    pub(crate) covariances: OnceLock<pgo::AnyCovariances>,
    report_json: OnceLock<CString>,
    /// An update's reason, as `pgo_result_update_reason` hands it out.
    update_reason: Option<CString>,
}

impl PgoResult {
    /// The library's solution.
    pub(crate) fn solution(&self) -> &AnySolution {
        &self.solution
    }

    /// A result holding `solution`.
    fn new(solution: AnySolution) -> Box<Self> {
        // The library's words: no NUL (one would be written out).
        let update_reason = solution
            .incremental()
            .map(|i| CString::new(i.reason.replace('\0', "\\0")).unwrap_or_default());
        Box::new(Self {
            solution,
            covariances: OnceLock::new(),
            report_json: OnceLock::new(),
            update_reason,
        })
    }
}

/// How the optimisation decided one loop candidate (a plain struct the
/// caller owns, filled by `pgo_result_loop`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PgoLoopDecision {
    /// Its index, as `pgo_graph_add_loop_candidate` stored it (edges and
    /// candidates numbered together).
    pub index: usize,
    /// Its first vertex id.
    pub from: u64,
    /// Its second vertex id.
    pub to: u64,
    /// Its inlier count; -1 if it has none.
    pub inliers: i64,
    /// Whether the gate kept it.
    pub kept: bool,
    /// Its final weight in the optimisation, in [0, 1].
    pub weight: f64,
    /// Whether it is in the map (weight ≥ ½).
    pub accepted: bool,
    /// EM's posterior probability that it is a true loop; NaN where the
    /// method gives none.
    pub posterior: f64,
    /// Its squared innovation ν² against the map without it and its
    /// cluster; NaN where there is none.
    pub innovation: f64,
}

impl From<&LoopDecision> for PgoLoopDecision {
    fn from(d: &LoopDecision) -> Self {
        Self {
            index: d.index,
            from: d.from,
            to: d.to,
            inliers: d
                .inliers
                .map_or(-1, |n| i64::try_from(n).unwrap_or(i64::MAX)),
            kept: d.kept,
            weight: d.weight,
            accepted: d.accepted,
            posterior: d.posterior.unwrap_or(f64::NAN),
            innovation: d.innovation.unwrap_or(f64::NAN),
        }
    }
}

/// Runs the whole job of `pgo optimize` on the graph (which is left as it
/// is) with `options` (NULL: the defaults): the gate learned from the loop
/// candidates' inlier counts, the initial guess, the robust optimisation
/// and the χ² test. Stores the result at `*out` (NULL on failure); free it
/// with `pgo_result_free`.
///
/// Errors: `PGO_ERR_EMPTY_GRAPH`, `PGO_ERR_UNCONSTRAINED`,
/// `PGO_ERR_NUMERICAL`, `PGO_ERR_INVALID_OPTION`, `PGO_ERR_INTERNAL`,
/// `PGO_ERR_INVALID_ARGUMENT`.
///
/// # Safety
/// `graph` is NULL or a live graph nothing changes during the call;
/// `options` is NULL or live options; `out` is NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pgo_graph_optimize(
    graph: *const PgoGraph,
    options: *const PgoOptions,
    out: *mut *mut PgoResult,
) -> PgoStatus {
    // SAFETY: the caller's contract, for `graph`, `options` and `out`.
    unsafe { pgo_graph_optimize_with(graph, options, ptr::null(), out) }
}

/// `pgo_graph_optimize`, stopped at its next iteration once `cancel`
/// (NULL: none) is cancelled by `pgo_cancel_request` from another thread:
/// the result then holds the best map so far and `pgo_result_cancelled`
/// says so. The token's progress callback (`pgo_cancel_set_progress`), if
/// any, sees every solver iteration.
///
/// Errors: those of `pgo_graph_optimize`.
///
/// # Safety
/// As `pgo_graph_optimize`'s; `cancel` is NULL or a live token.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pgo_graph_optimize_with(
    graph: *const PgoGraph,
    options: *const PgoOptions,
    cancel: *const PgoCancel,
    out: *mut *mut PgoResult,
) -> PgoStatus {
    // SAFETY: the caller's contract, for `graph`, `options`, `cancel` and
    // `out`.
    unsafe {
        run_job(options, out, |o| {
            let graph = &borrow(graph, "graph")?.graph;
            Ok(graph.optimize_with(o, &mut Watch::of(cancel))?)
        })
    }
}

/// Runs `job` with `options` (NULL: the defaults) and stores its result at
/// `*out` (NULL on failure).
///
/// # Safety
/// `options` is NULL or live options; `out` is NULL or writable.
unsafe fn run_job(
    options: *const PgoOptions,
    out: *mut *mut PgoResult,
    job: impl FnOnce(&Options) -> Result<AnySolution, Failure>,
) -> PgoStatus {
    status(|| {
        let slot = out_ptr(out, "out")?;
        // SAFETY: writable, by the caller's contract.
        unsafe { *slot = ptr::null_mut() };
        let defaults = Options::default();
        // SAFETY: NULL or live, by the caller's contract.
        let options = unsafe { options.as_ref() }.map_or(&defaults, |o| &o.options);
        let solution = job(options)?;
        // SAFETY: as above.
        unsafe { *slot = Box::into_raw(PgoResult::new(solution)) };
        Ok(())
    })
}

/// The job again after poses, edges or loop candidates were added, for a
/// mapping front end that asks for the map every keyframe: the map and
/// decisions `pgo_graph_optimize` would give the graph as it now is, with
/// `options` (NULL: the defaults), reached from the last update's. The
/// graph keeps that update's poses, decisions and report; only as much is
/// solved as the additions need — nothing when nothing was added, a
/// composition when only odometry was (`PgoUpdate.solve` says which).
/// The first update, one with other options than the last, and one after
/// `pgo_graph_fix` or `pgo_graph_forget` run the whole job
/// (`PGO_UPDATE_BATCH`). Stores the result at `*out` (NULL on failure;
/// the graph then keeps its earlier state); free it with
/// `pgo_result_free`.
///
/// Errors: those of `pgo_graph_optimize`.
///
/// # Safety
/// `graph` is NULL or a live graph nothing else uses during the call;
/// `options` is NULL or live options; `out` is NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pgo_graph_update(
    graph: *mut PgoGraph,
    options: *const PgoOptions,
    out: *mut *mut PgoResult,
) -> PgoStatus {
    // SAFETY: the caller's contract, for `graph`, `options` and `out`.
    unsafe { pgo_graph_update_with(graph, options, ptr::null(), out) }
}

/// `pgo_graph_update`, stopped at its next iteration once `cancel` (NULL:
/// none) is cancelled by `pgo_cancel_request` from another thread: the
/// result then holds the best map so far, `pgo_result_cancelled` says so,
/// and the graph keeps its state from before the call (the next update
/// starts from there).
///
/// Errors: those of `pgo_graph_optimize`.
///
/// # Safety
/// As `pgo_graph_update`'s; `cancel` is NULL or a live token.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pgo_graph_update_with(
    graph: *mut PgoGraph,
    options: *const PgoOptions,
    cancel: *const PgoCancel,
    out: *mut *mut PgoResult,
) -> PgoStatus {
    // SAFETY: the caller's contract, for `graph`, `options`, `cancel` and
    // `out`.
    unsafe {
        run_job(options, out, |o| {
            let graph = &mut borrow_mut(graph, "graph")?.graph;
            Ok(graph.update_with(o, &mut Watch::of(cancel))?)
        })
    }
}

/// How a result was reached (`PgoUpdate.solve`).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PgoUpdateSolve {
    /// Not an update: the result of `pgo_graph_optimize`.
    PgoNotAnUpdate = 0,
    /// The whole job from scratch: the first update, the first with
    /// other options, or the first after `pgo_graph_fix` or
    /// `pgo_graph_forget` (`pgo_result_update_reason` says which).
    PgoUpdateBatch,
    /// Nothing was added since the last update: its map stands.
    PgoUpdateNone,
    /// Only new poses, each hung on the map by one trusted edge: composed
    /// from the map, which is otherwise unchanged; nothing solved.
    PgoUpdateExtended,
    /// From the last map and decisions: EM's decisions by innovation and
    /// its χ² search, without annealing.
    PgoUpdateWarm,
    /// From the last map, every candidate weighed again by the robust
    /// kernel (a kernel method, or fewer candidates than EM's model needs).
    PgoUpdateFull,
}

impl From<UpdateSolve> for PgoUpdateSolve {
    fn from(solve: UpdateSolve) -> Self {
        match solve {
            UpdateSolve::Batch => Self::PgoUpdateBatch,
            UpdateSolve::None => Self::PgoUpdateNone,
            UpdateSolve::Extended => Self::PgoUpdateExtended,
            UpdateSolve::Warm => Self::PgoUpdateWarm,
            UpdateSolve::Full => Self::PgoUpdateFull,
        }
    }
}

/// What an update did (a plain struct the caller owns, filled by
/// `pgo_result_update`); all zero (`PGO_NOT_AN_UPDATE`) for the result of
/// `pgo_graph_optimize`.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PgoUpdate {
    /// How the map was reached.
    pub solve: PgoUpdateSolve,
    /// Poses added since the last update (a batch update: all of them).
    pub new_poses: usize,
    /// Edges, loop candidates included, added since the last update.
    pub new_edges: usize,
    /// Loop candidates among them.
    pub new_candidates: usize,
    /// Earlier loop candidates whose decision this update changed: read
    /// them with `pgo_result_change`.
    pub num_changed: usize,
}

/// An earlier loop candidate's decision that an update changed (a plain
/// struct the caller owns, filled by `pgo_result_change`); why it ends
/// where it does now is `pgo_result_change_reason`.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PgoDecisionChange {
    /// Its index, as `pgo_graph_add_loop_candidate` stored it (that of its
    /// `PgoLoopDecision`).
    pub index: usize,
    /// Its first vertex id.
    pub from: u64,
    /// Its second vertex id.
    pub to: u64,
    /// Whether it is in the map now (it was not before, or the reverse).
    pub accepted: bool,
}

impl From<&DecisionChange> for PgoDecisionChange {
    fn from(c: &DecisionChange) -> Self {
        Self {
            index: c.index,
            from: c.from,
            to: c.to,
            accepted: c.accepted,
        }
    }
}

/// Stores what the update that made `result` did at `*out`: how it
/// reached the map, what was added since the last update, and how many
/// earlier decisions it changed. For a result of `pgo_graph_optimize`,
/// `solve` is `PGO_NOT_AN_UPDATE` and the counts are 0.
///
/// Errors: `PGO_ERR_INVALID_ARGUMENT`.
///
/// # Safety
/// `result` is NULL or a live result; `out` is NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pgo_result_update(
    result: *const PgoResult,
    out: *mut PgoUpdate,
) -> PgoStatus {
    // SAFETY: the caller's contract.
    unsafe {
        get(result, out, |s| match s.incremental() {
            Some(i) => PgoUpdate {
                solve: i.solve.into(),
                new_poses: i.new_poses,
                new_edges: i.new_edges,
                new_candidates: i.new_candidates,
                num_changed: i.changed.len(),
            },
            None => PgoUpdate {
                solve: PgoUpdateSolve::PgoNotAnUpdate,
                new_poses: 0,
                new_edges: 0,
                new_candidates: 0,
                num_changed: 0,
            },
        })
    }
}

/// Why the update reached its map the way it did, in a few words (e.g.
/// "no earlier solution", "options changed"), as a NUL-terminated string
/// owned by the result: valid until `pgo_result_free`, never free it.
/// NULL on failure (`PGO_ERR_INVALID_ARGUMENT` in `pgo_last_error`: NULL
/// `result`, or a result of `pgo_graph_optimize`).
///
/// # Safety
/// `result` is NULL or a live result.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pgo_result_update_reason(result: *const PgoResult) -> *const c_char {
    value(ptr::null(), || {
        // SAFETY: the caller's contract.
        let result = unsafe { borrow(result, "result")? };
        result
            .update_reason
            .as_ref()
            .map(|r| r.as_ptr())
            .ok_or_else(not_an_update)
    })
}

/// Copies the `k`-th earlier decision the update changed (0 ≤ `k` <
/// `PgoUpdate.num_changed`, in the order of their indices) into `*out`.
///
/// Errors: `PGO_ERR_INVALID_ARGUMENT` (also for `k` out of range, and for
/// a result of `pgo_graph_optimize`, which changed none).
///
/// # Safety
/// `result` is NULL or a live result; `out` is NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pgo_result_change(
    result: *const PgoResult,
    k: usize,
    out: *mut PgoDecisionChange,
) -> PgoStatus {
    status(|| {
        // SAFETY: the caller's contract.
        let change = unsafe { change(result, k)? };
        let slot = out_ptr(out, "out")?;
        // SAFETY: writable, by the caller's contract.
        unsafe { slot.write(change.into()) };
        Ok(())
    })
}

/// Why the `k`-th changed decision ends where it does now, named as
/// `pgo_result_loop_reason` names it. The string is static: never free
/// it. NULL on failure (`PGO_ERR_INVALID_ARGUMENT` in `pgo_last_error`:
/// NULL `result`, `k` out of range, a result of `pgo_graph_optimize`).
///
/// # Safety
/// `result` is NULL or a live result.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pgo_result_change_reason(
    result: *const PgoResult,
    k: usize,
) -> *const c_char {
    value(ptr::null(), || {
        // SAFETY: the caller's contract.
        let change = unsafe { change(result, k)? };
        Ok(reason_name(&change.reason).as_ptr())
    })
}

/// The failure of asking a result of `pgo_graph_optimize` what an update
/// did.
fn not_an_update() -> Failure {
    Failure::invalid("the result is not an update's (pgo_graph_optimize made it)")
}

/// The `k`-th changed decision of an update's result.
///
/// # Safety
/// `result` is NULL or a live result.
unsafe fn change<'a>(result: *const PgoResult, k: usize) -> Result<&'a DecisionChange, Failure> {
    // SAFETY: the caller's contract.
    let result = unsafe { borrow(result, "result")? };
    let changed = &result
        .solution
        .incremental()
        .ok_or_else(not_an_update)?
        .changed;
    changed.get(k).ok_or_else(|| {
        Failure::invalid(format!(
            "change {k} out of range: the update changed {} decisions",
            changed.len()
        ))
    })
}

/// Copies the optimised pose with id `id` into the `len` numbers at `out`
/// (`x y θ` in 2D, `len` = 3; `x y z qx qy qz qw` in 3D, `len` = 7).
///
/// Errors: `PGO_ERR_UNKNOWN_VERTEX`, `PGO_ERR_LENGTH`,
/// `PGO_ERR_INVALID_ARGUMENT`.
///
/// # Safety
/// `result` is NULL or a live result; `out` is NULL or points to `len`
/// writable numbers.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pgo_result_pose(
    result: *const PgoResult,
    id: u64,
    out: *mut f64,
    len: usize,
) -> PgoStatus {
    status(|| {
        // SAFETY: the caller's contract.
        let result = unsafe { borrow(result, "result")? };
        let slot = out_ptr(out, "out")?;
        let pose = result.solution.pose(id).ok_or_else(|| {
            Failure::new(
                PgoStatus::PgoErrUnknownVertex,
                format!("unknown vertex id {id}"),
            )
        })?;
        if pose.len() != len {
            return Err(Failure::new(
                PgoStatus::PgoErrLength,
                format!(
                    "pose: expected {} numbers for a {}D graph, got {len}",
                    result.solution.pose_width(),
                    result.solution.dimension()
                ),
            ));
        }
        // SAFETY: `len` writable numbers at `slot`, by the caller's contract.
        unsafe { ptr::copy_nonoverlapping(pose.as_ptr(), slot, len) };
        Ok(())
    })
}

/// Stores the number of loop decisions (one per loop candidate) at `*out`.
///
/// Errors: `PGO_ERR_INVALID_ARGUMENT`.
///
/// # Safety
/// `result` is NULL or a live result; `out` is NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pgo_result_num_loops(
    result: *const PgoResult,
    out: *mut usize,
) -> PgoStatus {
    // SAFETY: the caller's contract.
    unsafe { get(result, out, |s| s.loops().len()) }
}

/// Copies the `k`-th loop decision (0 ≤ `k` < `pgo_result_num_loops`, in
/// the order the candidates were added) into `*out`.
///
/// Errors: `PGO_ERR_INVALID_ARGUMENT` (also for `k` out of range).
///
/// # Safety
/// `result` is NULL or a live result; `out` is NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pgo_result_loop(
    result: *const PgoResult,
    k: usize,
    out: *mut PgoLoopDecision,
) -> PgoStatus {
    status(|| {
        // SAFETY: the caller's contract.
        let decision = unsafe { decision(result, k)? };
        let slot = out_ptr(out, "out")?;
        // SAFETY: writable, by the caller's contract.
        unsafe { slot.write(decision.into()) };
        Ok(())
    })
}

/// Why the `k`-th loop ended where it did: `"consistent"`,
/// `"inconsistent"`, `"outlying"`, `"unchecked"`, `"explains_chi2"`, `"unsettled"`,
/// `"kernel"`, `"dropped"` or `"trusted"` (the reason's name in snake case; later
/// versions may add reasons). The string is static: never free it. NULL on failure
/// (`PGO_ERR_INVALID_ARGUMENT` in `pgo_last_error`: NULL `result`, `k` out
/// of range).
///
/// # Safety
/// `result` is NULL or a live result.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pgo_result_loop_reason(
    result: *const PgoResult,
    k: usize,
) -> *const c_char {
    value(ptr::null(), || {
        // SAFETY: the caller's contract.
        let decision = unsafe { decision(result, k)? };
        Ok(reason_name(&decision.reason).as_ptr())
    })
}

/// The `k`-th decision of a result.
///
/// # Safety
/// `result` is NULL or a live result.
unsafe fn decision<'a>(result: *const PgoResult, k: usize) -> Result<&'a LoopDecision, Failure> {
    // SAFETY: the caller's contract.
    let loops = unsafe { borrow(result, "result")? }.solution.loops();
    loops.get(k).ok_or_else(|| {
        Failure::invalid(format!(
            "loop {k} out of range: the result has {} loops",
            loops.len()
        ))
    })
}

/// The name of a reason (the library's, [`Reason::as_str`]) as a C
/// string, interned.
pub(crate) fn reason_name(reason: &Reason) -> &'static CStr {
    static NAMES: Mutex<Vec<&'static CStr>> = Mutex::new(Vec::new());
    let name = reason.as_str();
    let mut names = NAMES
        .lock()
        .unwrap_or_else(|poisoned| poisoned.into_inner());
    if let Some(known) = names.iter().find(|n| n.to_bytes() == name.as_bytes()) {
        return known;
    }
    // Snake case: no NUL. One leak per variant, ever.
    let interned: &'static CStr =
        Box::leak(CString::new(name).unwrap_or_default().into_boxed_c_str());
    names.push(interned);
    interned
}

/// Stores `Σ eᵀΩe` over all edges at the optimised poses (g2o's χ²,
/// dropped candidates included) at `*out`.
///
/// Errors: `PGO_ERR_INVALID_ARGUMENT`.
///
/// # Safety
/// `result` is NULL or a live result; `out` is NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pgo_result_chi2(result: *const PgoResult, out: *mut f64) -> PgoStatus {
    // SAFETY: the caller's contract.
    unsafe { get(result, out, |s| s.chi2()) }
}

/// Stores `D²`, the χ² of the edges in the map that the χ² test tests, at
/// `*out`; NaN when there is no test (see `pgo_result_verdict`).
///
/// Errors: `PGO_ERR_INVALID_ARGUMENT`.
///
/// # Safety
/// `result` is NULL or a live result; `out` is NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pgo_result_d2(result: *const PgoResult, out: *mut f64) -> PgoStatus {
    // SAFETY: the caller's contract.
    unsafe { get(result, out, |s| s.d2().unwrap_or(f64::NAN)) }
}

/// Stores the χ² test's verdict at `*out`: 1 passed (`D²` within the
/// critical value), 0 failed, -1 no test (it could not be computed; the
/// report's warnings say why).
///
/// Errors: `PGO_ERR_INVALID_ARGUMENT`.
///
/// # Safety
/// `result` is NULL or a live result; `out` is NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pgo_result_verdict(result: *const PgoResult, out: *mut i32) -> PgoStatus {
    // SAFETY: the caller's contract.
    unsafe { get(result, out, |s| s.passed().map_or(-1, i32::from)) }
}

/// How far a result's map can be taken as it is, as `pgo optimize`'s exit
/// status says it (`pgo_result_status`): the first that applies, from
/// `PGO_MAP_CANCELLED` back to `PGO_MAP_QUESTIONED`, else `PGO_MAP_OK`.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PgoMapStatus {
    /// Nothing questions the map: the job finished, its χ² test passed
    /// (or there is none), its loop decisions settled and the evidence
    /// questions none (exit status 0).
    PgoMapOk = 0,
    /// The χ² test failed (exit status 3).
    PgoMapChi2Failed,
    /// An iteration or time limit stopped the job before it finished: the
    /// best map so far (exit status 4).
    PgoMapUnfinished,
    /// The loop decisions did not settle (loops `"unsettled"`; exit
    /// status 4).
    PgoMapUnsettled,
    /// Passed with settled decisions, but a doubtful cluster, loops held
    /// back by their counts or outlying accepted loops would each move the
    /// map by over 1 % (the report's `robust.doubtful`, `robust.held_back`,
    /// `robust.outlying`; exit status 5).
    PgoMapQuestioned,
    /// A `PgoCancel` token stopped the job: the best map so far (exit
    /// status 130).
    PgoMapCancelled,
}

impl From<MapStatus> for PgoMapStatus {
    fn from(status: MapStatus) -> Self {
        match status {
            MapStatus::Ok => Self::PgoMapOk,
            MapStatus::Chi2Failed => Self::PgoMapChi2Failed,
            MapStatus::Unfinished => Self::PgoMapUnfinished,
            MapStatus::Unsettled => Self::PgoMapUnsettled,
            MapStatus::Questioned => Self::PgoMapQuestioned,
            MapStatus::Cancelled => Self::PgoMapCancelled,
        }
    }
}

/// Stores at `*out` how far the result's map can be taken as it is
/// (`PgoMapStatus`; `PGO_MAP_OK` when nothing questions it).
///
/// Errors: `PGO_ERR_INVALID_ARGUMENT`.
///
/// # Safety
/// `result` is NULL or a live result; `out` is NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pgo_result_status(
    result: *const PgoResult,
    out: *mut PgoMapStatus,
) -> PgoStatus {
    // SAFETY: the caller's contract.
    unsafe { get(result, out, |s| s.status().into()) }
}

/// Stores at `*out` whether a `PgoCancel` token stopped the job (the
/// poses are then the best found until it did).
///
/// Errors: `PGO_ERR_INVALID_ARGUMENT`.
///
/// # Safety
/// `result` is NULL or a live result; `out` is NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pgo_result_cancelled(
    result: *const PgoResult,
    out: *mut bool,
) -> PgoStatus {
    // SAFETY: the caller's contract.
    unsafe { get(result, out, |s| s.cancelled()) }
}

/// Stores at `*out` whether the solve converged: false when it stopped at
/// an iteration or time limit — an update capped by the `update-iters`
/// option then left the map short of the optimum, and the next update
/// goes on from it — or was cancelled.
///
/// Errors: `PGO_ERR_INVALID_ARGUMENT`.
///
/// # Safety
/// `result` is NULL or a live result; `out` is NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pgo_result_converged(
    result: *const PgoResult,
    out: *mut bool,
) -> PgoStatus {
    // SAFETY: the caller's contract.
    unsafe { get(result, out, |s| s.report().optimizer.converged) }
}

/// The report `pgo optimize --json` prints, as a NUL-terminated JSON
/// string owned by the result: valid until `pgo_result_free`, never free
/// it. Its fields are documented with the command line, not by this API.
/// NULL on failure (see `pgo_last_error`).
///
/// # Safety
/// `result` is NULL or a live result.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pgo_result_report_json(result: *const PgoResult) -> *const c_char {
    value(ptr::null(), || {
        // SAFETY: the caller's contract.
        let result = unsafe { borrow(result, "result")? };
        if let Some(json) = result.report_json.get() {
            return Ok(json.as_ptr());
        }
        let json = result.solution.report().to_json()?;
        let json = CString::new(json)
            .map_err(|_| Failure::new(PgoStatus::PgoErrInternal, "the report holds a NUL byte"))?;
        Ok(result.report_json.get_or_init(|| json).as_ptr())
    })
}

/// Writes the optimised map as a g2o file at `path`, atomically (a
/// temporary file renamed over it; `"-"` writes the standard output): a
/// graph read from a file as that file's own text with the new poses
/// (every other line byte for byte), any other graph as
/// `pgo_graph_write_g2o` writes it, with the optimised poses. Nothing is
/// replaced on failure.
///
/// Errors: `PGO_ERR_IO` (the message names the file),
/// `PGO_ERR_INVALID_ARGUMENT` (NULL `result`, NULL or non-UTF-8 `path`).
///
/// # Safety
/// `result` is NULL or a live result; `path` is NULL or a NUL-terminated
/// string.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pgo_result_write_g2o(
    result: *const PgoResult,
    path: *const c_char,
) -> PgoStatus {
    // SAFETY: the caller's contract.
    unsafe { write(result, path, |s, p| s.write_g2o(p)) }
}

/// Writes the optimised trajectory in the TUM format at `path`, as evo
/// reads it, atomically as `pgo_result_write_g2o` writes: one line per
/// pose in the graph's order, `timestamp tx ty tz qx qy qz qw`, the
/// timestamp the vertex id (poses have no time); a 2D pose as z = 0 and a
/// rotation about z. Numbers in their shortest form that reads back to the
/// same bits.
///
/// Errors: those of `pgo_result_write_g2o`.
///
/// # Safety
/// As `pgo_result_write_g2o`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pgo_result_write_tum(
    result: *const PgoResult,
    path: *const c_char,
) -> PgoStatus {
    // SAFETY: the caller's contract.
    unsafe { write(result, path, |s, p| s.write_tum(p)) }
}

/// Writes the optimised trajectory in the KITTI format at `path`, as evo
/// reads it, atomically as `pgo_result_write_g2o` writes: one line per
/// pose in the graph's order (the format has no ids: the order of
/// `pgo_graph_ids`), the 3×4 matrix `[R t]` row by row; a 2D pose as
/// z = 0 and a rotation about z.
///
/// Errors: those of `pgo_result_write_g2o`.
///
/// # Safety
/// As `pgo_result_write_g2o`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pgo_result_write_kitti(
    result: *const PgoResult,
    path: *const c_char,
) -> PgoStatus {
    // SAFETY: the caller's contract.
    unsafe { write(result, path, |s, p| s.write_kitti(p)) }
}

/// Writes the job's pictures as SVG files into the directory `dir` (made
/// if missing), what `pgo optimize --plot DIR` writes, each atomically as
/// `pgo_result_write_g2o` writes: `counts.svg` (when the candidates have
/// inlier counts and the gate fitted them), `loops.svg` (when EM's loop
/// model decided the loops) and `trajectory.svg` (the initial guess and
/// the map side by side, the loops coloured by their final weight; a 3D
/// map seen from above).
///
/// Errors: `PGO_ERR_IO` (the directory or a picture cannot be written; the
/// message names it), `PGO_ERR_INTERNAL` (a picture could not be drawn),
/// `PGO_ERR_INVALID_ARGUMENT` (NULL `result`, NULL or non-UTF-8 `dir`).
///
/// # Safety
/// `result` is NULL or a live result; `dir` is NULL or a NUL-terminated
/// string.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pgo_result_write_plots(
    result: *const PgoResult,
    dir: *const c_char,
) -> PgoStatus {
    status(|| {
        // SAFETY: the caller's contract.
        let (result, dir) = unsafe { (borrow(result, "result")?, text(dir, "dir")?) };
        result.solution.write_plots(dir).map_err(pgo::Error::from)?;
        Ok(())
    })
}

/// Runs `write` on the solution and the path.
///
/// # Safety
/// `result` is NULL or a live result; `path` is NULL or a NUL-terminated
/// string.
unsafe fn write(
    result: *const PgoResult,
    path: *const c_char,
    write: impl FnOnce(&AnySolution, &str) -> Result<(), pgo::Error>,
) -> PgoStatus {
    status(|| {
        // SAFETY: the caller's contract.
        let (result, path) = unsafe { (borrow(result, "result")?, text(path, "path")?) };
        Ok(write(&result.solution, path)?)
    })
}

/// Frees a result made by `pgo_graph_optimize` or `pgo_graph_update`, and
/// the strings it handed out. NULL is allowed and does nothing.
///
/// # Safety
/// `result` is NULL or a result from this API not yet freed, which nothing
/// uses any more.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pgo_result_free(result: *mut PgoResult) {
    if !result.is_null() {
        value((), || {
            // SAFETY: made by Box::into_raw and not yet freed, by the contract.
            drop(unsafe { Box::from_raw(result) });
            Ok(())
        });
    }
}

/// Stores `read(solution)` at `*out`.
///
/// # Safety
/// `result` is NULL or a live result; `out` is NULL or writable.
unsafe fn get<T>(
    result: *const PgoResult,
    out: *mut T,
    read: impl FnOnce(&AnySolution) -> T,
) -> PgoStatus {
    status(|| {
        // SAFETY: the caller's contract.
        let result = unsafe { borrow(result, "result")? };
        let slot = out_ptr(out, "out")?;
        // SAFETY: writable, by the caller's contract.
        unsafe { slot.write(read(&result.solution)) };
        Ok(())
    })
}
