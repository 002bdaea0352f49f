//! `pgo._pgo`, the extension module of the Python package `pgo`: the
//! library's public API — build or read a pose graph, optimise it with
//! `pgo optimize`'s options, read the poses, the loop decisions and the
//! report — with numbers in and out as Python sequences or numpy arrays.
//! Every error of the library is raised as the `pgo.Error` subclass of
//! its kind (all `ValueError`s; see `errors`), and the library's `log`
//! records reach Python's `logging` under the logger `pgo`.

mod cancel;
mod convert;
mod covariance;
mod errors;
mod graph;
mod solution;

use graph::PoseGraph;
use pyo3::prelude::*;
use solution::Solution;

/// Reads a g2o file (`str` or path-like) of either dimension into a
/// `PoseGraph`; loop candidates are the edges with a trailing inlier
/// count. With `repair_information=True`, information matrices that are
/// not positive definite are projected to the nearest ones (counted in
/// the report's `information_fixed`). A missing file raises
/// `pgo.MissingFileError` (a `FileNotFoundError`), a malformed one
/// `pgo.ParseError` naming the line.
#[pyfunction]
#[pyo3(signature = (path, *, repair_information = false))]
fn read_g2o(path: &Bound<'_, PyAny>, repair_information: bool) -> PyResult<PoseGraph> {
    let path = convert::path(path)?;
    let graph = if repair_information {
        pgo::AnyPoseGraph::read_g2o_repairing(path)
    } else {
        pgo::AnyPoseGraph::read_g2o(path)
    };
    graph.map(PoseGraph::from_graph).map_err(convert::error)
}

/// The names `PoseGraph.optimize` takes, as `pgo optimize` spells its
/// flags (`-` may be written `_`).
#[pyfunction]
fn option_names() -> Vec<&'static str> {
    pgo::Options::names().collect()
}

/// Sends the library's `log` records to Python's `logging`: the target
/// `pgo::pose_graph` to the logger `pgo.pose_graph`, and so on. Records
/// of level debug and above are forwarded (the library's are warnings);
/// the per-iteration traces are not, as each would take the GIL. The
/// logger objects are cached, their levels are not, so `logging`
/// configured at any time applies.
fn forward_logs(py: Python<'_>) -> PyResult<()> {
    let logger =
        pyo3_log::Logger::new(py, pyo3_log::Caching::Loggers)?.filter(log::LevelFilter::Debug);
    // Another logger of this module's copy of `log`: keep it.
    let _ = logger.install();
    Ok(())
}

/// The module: the classes, the functions and the exceptions.
#[pymodule]
fn _pgo(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<cancel::Cancel>()?;
    m.add_class::<PoseGraph>()?;
    m.add_class::<Solution>()?;
    m.add_function(wrap_pyfunction!(read_g2o, m)?)?;
    m.add_function(wrap_pyfunction!(option_names, m)?)?;
    errors::register(m)?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    forward_logs(m.py())
}
