//! The C ABI of pgo: build a pose graph, optimise it (as one job, or
//! incrementally as it grows), and read the poses, the loop decisions, the
//! χ² test's verdict and the report, from C (or any language with a C
//! FFI). The header is `include/pgo.h`, generated from this crate by
//! cbindgen; `README.md` says how to build and link.
//!
//! Every function returns a `PgoStatus` (or, for a string, NULL on
//! failure) and records a message for `pgo_last_error`; no panic crosses
//! the boundary. Handles (`PgoGraph`, `PgoOptions`, `PgoResult`,
//! `PgoCancel`) are
//! opaque, made by a `_new` (or `pgo_graph_read_g2o`, `pgo_graph_optimize`,
//! `pgo_graph_update`) and freed by their `_free`; strings handed out are
//! owned by the API.

mod cancel;
mod certificate;
mod covariance;
mod graph;
mod options;
mod result;
mod status;

pub use cancel::*;
pub use certificate::*;
pub use covariance::*;
pub use graph::*;
pub use options::*;
pub use result::*;
pub use status::PgoStatus;

use std::ffi::c_char;

/// The message of the last failed call on this thread (naming the vertex,
/// the option, the file and line, ...), or "" if none failed. The string
/// is owned by the library: valid until the next call of a `pgo_`
/// function on this thread; copy it to keep it. Never NULL.
#[unsafe(no_mangle)]
pub extern "C" fn pgo_last_error() -> *const c_char {
    status::last_error_ptr()
}

/// The version of this library, e.g. "0.1.0" (static; never free it).
#[unsafe(no_mangle)]
pub extern "C" fn pgo_version() -> *const c_char {
    concat!(env!("CARGO_PKG_VERSION"), "\0").as_ptr().cast()
}

/// The handles may be read from several threads at once and moved between
/// threads, as their documentation promises.
const _: () = {
    const fn shareable<T: Send + Sync>() {}
    shareable::<PgoGraph>();
    shareable::<PgoOptions>();
    shareable::<PgoResult>();
};
