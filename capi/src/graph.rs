//! The pose graph: `PgoGraph`, built call by call or read from a g2o file.

use crate::status::{
    Failure, PgoStatus, borrow, borrow_mut, numbers, out_ptr, status, text, value,
};
use pgo::AnyPoseGraph;
use std::ffi::c_char;
use std::ptr;

/// A pose graph (opaque): SE(2) or SE(3) poses with ids, trusted edges,
/// loop-closure candidates with their inlier counts, and the poses held
/// fixed. Poses and measurements are their g2o numbers — `x y θ` in 2D,
/// `x y z qx qy qz qw` in 3D (the quaternion normalised) — and information
/// matrices are D × D, row by row (D = 3 in 2D, 6 in 3D).
///
/// Made by `pgo_graph_new` or `pgo_graph_read_g2o`, owned by the caller,
/// freed by `pgo_graph_free`. A graph may be read (optimised, written) by
/// several threads at once, but not changed (added to, updated, forgotten)
/// while anything else uses it. It keeps the last `pgo_graph_update`'s
/// poses and decisions, which the next update starts from.
pub struct PgoGraph {
    pub(crate) graph: AnyPoseGraph,
}

/// Stores a new graph at `out` (NULL on failure, when `out` is not NULL).
///
/// # Safety
/// `out` is NULL or writable.
unsafe fn make(
    out: *mut *mut PgoGraph,
    build: impl FnOnce() -> Result<AnyPoseGraph, Failure>,
) -> PgoStatus {
    status(|| {
        let slot = out_ptr(out, "out")?;
        // SAFETY: `slot` is writable, by the caller's contract.
        unsafe { *slot = ptr::null_mut() };
        let graph = Box::new(PgoGraph { graph: build()? });
        // SAFETY: as above.
        unsafe { *slot = Box::into_raw(graph) };
        Ok(())
    })
}

/// Makes an empty graph of poses in `dim` dimensions (2 or 3) and stores
/// it at `*out`; free it with `pgo_graph_free`. On failure `*out` is NULL.
///
/// Errors: `PGO_ERR_DIMENSION` for another `dim`, `PGO_ERR_INVALID_ARGUMENT`
/// for a NULL `out`.
///
/// # Safety
/// `out` is NULL or points to writable storage for a pointer.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pgo_graph_new(dim: i32, out: *mut *mut PgoGraph) -> PgoStatus {
    let build = || match usize::try_from(dim) {
        Ok(dimension) => Ok(AnyPoseGraph::new(dimension)?),
        Err(_) => Err(Failure::new(
            PgoStatus::PgoErrDimension,
            format!("a pose graph is 2D or 3D, not {dim}D"),
        )),
    };
    // SAFETY: the caller's contract.
    unsafe { make(out, build) }
}

/// Reads a g2o file (2D or 3D; loop candidates carry a trailing inlier
/// count) into a new graph stored at `*out`; free it with `pgo_graph_free`.
/// On failure `*out` is NULL.
///
/// Errors: `PGO_ERR_IO` (the file cannot be read), `PGO_ERR_PARSE` (the
/// message names the file and line; an information matrix that is not
/// positive definite: `pgo_graph_read_g2o_repairing` repairs it),
/// `PGO_ERR_INVALID_INFORMATION` (an information matrix beyond the range
/// pgo computes with, 1e-100 to 1e100 on the diagonal),
/// `PGO_ERR_INVALID_ARGUMENT` (NULL or non-UTF-8 `path`, NULL `out`).
///
/// # Safety
/// `path` is NULL or a NUL-terminated string; `out` is NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pgo_graph_read_g2o(
    path: *const c_char,
    out: *mut *mut PgoGraph,
) -> PgoStatus {
    // SAFETY: the caller's contract.
    unsafe {
        make(out, || {
            let path = text(path, "path")?;
            Ok(AnyPoseGraph::read_g2o(path)?)
        })
    }
}

/// `pgo_graph_read_g2o`, with information matrices that are not positive
/// definite projected to the nearest positive-definite ones instead of
/// refused (as `pgo optimize --fix-information`; the report's
/// `information_fixed` counts them). Zero or non-finite matrices are
/// refused either way.
///
/// Errors: those of `pgo_graph_read_g2o`.
///
/// # Safety
/// As `pgo_graph_read_g2o`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pgo_graph_read_g2o_repairing(
    path: *const c_char,
    out: *mut *mut PgoGraph,
) -> PgoStatus {
    // SAFETY: the caller's contract.
    unsafe {
        make(out, || {
            let path = text(path, "path")?;
            Ok(AnyPoseGraph::read_g2o_repairing(path)?)
        })
    }
}

/// Writes the graph as a g2o file at `path`, atomically (a temporary file
/// renamed over it).
///
/// Errors: `PGO_ERR_IO`, `PGO_ERR_INVALID_ARGUMENT`.
///
/// # Safety
/// `graph` is NULL or a live graph; `path` is NULL or a NUL-terminated
/// string.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pgo_graph_write_g2o(
    graph: *const PgoGraph,
    path: *const c_char,
) -> PgoStatus {
    status(|| {
        // SAFETY: the caller's contract.
        let (graph, path) = unsafe { (borrow(graph, "graph")?, text(path, "path")?) };
        Ok(graph.graph.write_g2o(path)?)
    })
}

/// Frees a graph made by `pgo_graph_new` or `pgo_graph_read_g2o`. NULL is
/// allowed and does nothing.
///
/// # Safety
/// `graph` is NULL or a graph from this API not yet freed, which nothing
/// uses any more.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pgo_graph_free(graph: *mut PgoGraph) {
    if !graph.is_null() {
        value((), || {
            // SAFETY: made by Box::into_raw and not yet freed, by the contract.
            drop(unsafe { Box::from_raw(graph) });
            Ok(())
        });
    }
}

/// Adds a pose under a new id: `len` numbers at `pose` (3 in 2D, 7 in 3D).
/// The first pose added is held fixed unless `pgo_graph_fix` fixes others.
///
/// Errors: `PGO_ERR_DUPLICATE_VERTEX`, `PGO_ERR_LENGTH`,
/// `PGO_ERR_INVALID_POSE` (not finite; a zero quaternion),
/// `PGO_ERR_INVALID_ARGUMENT`.
///
/// # Safety
/// `graph` is NULL or a live graph nothing else uses during the call;
/// `pose` is NULL or points to `len` numbers.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pgo_graph_add_pose(
    graph: *mut PgoGraph,
    id: u64,
    pose: *const f64,
    len: usize,
) -> PgoStatus {
    status(|| {
        // SAFETY: the caller's contract.
        let (graph, pose) = unsafe { (borrow_mut(graph, "graph")?, numbers(pose, len, "pose")?) };
        Ok(graph.graph.add_pose(id, pose)?)
    })
}

/// Adds a trusted edge (odometry, a prior, a verified loop): the pose of
/// `to` in the frame of `from` is the `meas_len` numbers at `meas`, with
/// the information matrix (inverse covariance) of `info_len` numbers at
/// `info`, row-major D × D. Edges and loop candidates are numbered
/// together from 0 in the order they are added.
///
/// Errors: `PGO_ERR_UNKNOWN_VERTEX`, `PGO_ERR_SELF_LOOP`, `PGO_ERR_LENGTH`,
/// `PGO_ERR_INVALID_POSE`, `PGO_ERR_INVALID_INFORMATION`,
/// `PGO_ERR_INVALID_ARGUMENT`.
///
/// # Safety
/// `graph` is NULL or a live graph nothing else uses during the call;
/// `meas` and `info` are NULL or point to `meas_len` and `info_len`
/// numbers.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pgo_graph_add_edge(
    graph: *mut PgoGraph,
    from: u64,
    to: u64,
    meas: *const f64,
    meas_len: usize,
    info: *const f64,
    info_len: usize,
) -> PgoStatus {
    status(|| {
        // SAFETY: the caller's contract.
        let (graph, z, omega) = unsafe { edge_arguments(graph, meas, meas_len, info, info_len)? };
        graph.graph.add_edge(from, to, z, omega)?;
        Ok(())
    })
}

/// Adds a loop-closure candidate, whose correctness the optimisation
/// decides: an edge as `pgo_graph_add_edge` adds one, with `inliers` the
/// inlier count of its geometric verification (negative: none). Its index
/// (edges and candidates numbered together) is stored at `*index_out`
/// unless `index_out` is NULL; its `PgoLoopDecision` carries it.
///
/// Errors as `pgo_graph_add_edge`.
///
/// # Safety
/// As `pgo_graph_add_edge`; `index_out` is NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pgo_graph_add_loop_candidate(
    graph: *mut PgoGraph,
    from: u64,
    to: u64,
    meas: *const f64,
    meas_len: usize,
    info: *const f64,
    info_len: usize,
    inliers: i64,
    index_out: *mut usize,
) -> PgoStatus {
    status(|| {
        // SAFETY: the caller's contract.
        let (graph, z, omega) = unsafe { edge_arguments(graph, meas, meas_len, info, info_len)? };
        let inliers = u64::try_from(inliers).ok();
        let index = graph
            .graph
            .add_loop_candidate(from, to, z, omega, inliers)?;
        // SAFETY: NULL or writable, by the caller's contract.
        if let Some(slot) = unsafe { index_out.as_mut() } {
            *slot = index;
        }
        Ok(())
    })
}

/// The graph and an edge's numbers, checked for NULL.
///
/// # Safety
/// As `pgo_graph_add_edge`.
unsafe fn edge_arguments<'a>(
    graph: *mut PgoGraph,
    meas: *const f64,
    meas_len: usize,
    info: *const f64,
    info_len: usize,
) -> Result<(&'a mut PgoGraph, &'a [f64], &'a [f64]), Failure> {
    // SAFETY: the caller's contract.
    unsafe {
        Ok((
            borrow_mut(graph, "graph")?,
            numbers(meas, meas_len, "measurement")?,
            numbers(info, info_len, "information")?,
        ))
    }
}

/// Holds the pose with this id fixed (part of the gauge). Without any
/// call, the first pose added is.
///
/// Errors: `PGO_ERR_UNKNOWN_VERTEX`, `PGO_ERR_INVALID_ARGUMENT`.
///
/// # Safety
/// `graph` is NULL or a live graph nothing else uses during the call.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pgo_graph_fix(graph: *mut PgoGraph, id: u64) -> PgoStatus {
    status(|| {
        // SAFETY: the caller's contract.
        let graph = unsafe { borrow_mut(graph, "graph")? };
        Ok(graph.graph.fix(id)?)
    })
}

/// Drops what `pgo_graph_update` keeps (the last update's poses,
/// decisions and report): the next update runs the whole job. The graph's
/// poses, edges and candidates stay.
///
/// Errors: `PGO_ERR_INVALID_ARGUMENT`.
///
/// # Safety
/// `graph` is NULL or a live graph nothing else uses during the call.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pgo_graph_forget(graph: *mut PgoGraph) -> PgoStatus {
    status(|| {
        // SAFETY: the caller's contract.
        let graph = unsafe { borrow_mut(graph, "graph")? };
        graph.graph.forget();
        Ok(())
    })
}

/// Whether edges added from now on with an information matrix that is not
/// positive definite have it projected to the nearest positive-definite
/// one instead of being refused (off by default; the report counts the
/// repairs). Non-finite, asymmetric or out-of-range matrices are refused
/// either way.
///
/// Errors: `PGO_ERR_INVALID_ARGUMENT`.
///
/// # Safety
/// `graph` is NULL or a live graph nothing else uses during the call.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pgo_graph_set_repair_information(
    graph: *mut PgoGraph,
    repair: bool,
) -> PgoStatus {
    status(|| {
        // SAFETY: the caller's contract.
        let graph = unsafe { borrow_mut(graph, "graph")? };
        graph.graph.set_repair_information(repair);
        Ok(())
    })
}

/// Stores the number of poses at `*out`.
///
/// Errors: `PGO_ERR_INVALID_ARGUMENT`.
///
/// # Safety
/// `graph` is NULL or a live graph; `out` is NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pgo_graph_len(graph: *const PgoGraph, out: *mut usize) -> PgoStatus {
    // SAFETY: the caller's contract.
    unsafe { get(graph, out, |g| g.len()) }
}

/// Stores the number of edges, loop candidates included, at `*out`.
///
/// Errors: `PGO_ERR_INVALID_ARGUMENT`.
///
/// # Safety
/// `graph` is NULL or a live graph; `out` is NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pgo_graph_num_edges(graph: *const PgoGraph, out: *mut usize) -> PgoStatus {
    // SAFETY: the caller's contract.
    unsafe { get(graph, out, |g| g.num_edges()) }
}

/// Copies the ids of the graph's poses, in the order they were added (or
/// read from the file), into the `len` slots at `out`; `len` is the
/// number of poses (`pgo_graph_len`). Poses are looked up by id
/// (`pgo_result_pose`), so this is how a caller who read a file learns
/// them.
///
/// Errors: `PGO_ERR_LENGTH` (`len` is not the number of poses),
/// `PGO_ERR_INVALID_ARGUMENT`.
///
/// # Safety
/// `graph` is NULL or a live graph; `out` is NULL or points to `len`
/// writable `uint64_t`s.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pgo_graph_ids(
    graph: *const PgoGraph,
    out: *mut u64,
    len: usize,
) -> PgoStatus {
    status(|| {
        // SAFETY: the caller's contract.
        let graph = unsafe { borrow(graph, "graph")? };
        let ids = graph.graph.ids();
        if ids.len() != len {
            return Err(Failure::new(
                PgoStatus::PgoErrLength,
                format!("ids: the graph has {} poses, got room for {len}", ids.len()),
            ));
        }
        if len > 0 {
            let slot = out_ptr(out, "out")?;
            // SAFETY: `len` writable ids at `slot`, by the caller's contract.
            unsafe { ptr::copy_nonoverlapping(ids.as_ptr(), slot, len) };
        }
        Ok(())
    })
}

/// Stores the graph's dimension, 2 or 3, at `*out`.
///
/// Errors: `PGO_ERR_INVALID_ARGUMENT`.
///
/// # Safety
/// `graph` is NULL or a live graph; `out` is NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pgo_graph_dim(graph: *const PgoGraph, out: *mut i32) -> PgoStatus {
    // SAFETY: the caller's contract.
    unsafe { get(graph, out, |g| i32::try_from(g.dimension()).unwrap_or(0)) }
}

/// Stores `read(graph)` at `*out`.
///
/// # Safety
/// `graph` is NULL or a live graph; `out` is NULL or writable.
unsafe fn get<T>(
    graph: *const PgoGraph,
    out: *mut T,
    read: impl FnOnce(&AnyPoseGraph) -> T,
) -> PgoStatus {
    status(|| {
        // SAFETY: the caller's contract.
        let graph = unsafe { borrow(graph, "graph")? };
        let slot = out_ptr(out, "out")?;
        // SAFETY: writable, by the caller's contract.
        unsafe { slot.write(read(&graph.graph)) };
        Ok(())
    })
}
