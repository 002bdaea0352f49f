//! `pgo._pgo`, the extension module of the Python package `pgo`: the
//! library's public API — build or read a pose graph, optimise it with
//! `pgo optimize`'s options, read the poses, the loop decisions and the
//! report — with numbers in and out as Python sequences or numpy arrays.
//! Every error of the library is a `pgo.Error` (a `ValueError`) carrying
//! its message.

mod cancel;
mod convert;
mod covariance;
mod graph;
mod solution;

use graph::PoseGraph;
use pyo3::prelude::*;
use solution::Solution;
use std::path::PathBuf;

pyo3::create_exception!(
    pgo,
    Error,
    pyo3::exceptions::PyValueError,
    "Bad input to pgo or a failed optimisation, with the library's message \
     (a subclass of ValueError)."
);

/// Reads a g2o file (`str` or path-like) of either dimension into a
/// `PoseGraph`; loop candidates are the edges with a trailing inlier
/// count. With `repair_information=True`, information matrices that are
/// not positive definite are projected to the nearest ones (as
/// `pgo optimize --fix-information`).
#[pyfunction]
#[pyo3(signature = (path, *, repair_information = false))]
fn read_g2o(path: PathBuf, repair_information: bool) -> PyResult<PoseGraph> {
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

/// The module: the classes, the functions and `Error`.
#[pymodule]
fn _pgo(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<cancel::Cancel>()?;
    m.add_class::<PoseGraph>()?;
    m.add_class::<Solution>()?;
    m.add_function(wrap_pyfunction!(read_g2o, m)?)?;
    m.add_function(wrap_pyfunction!(option_names, m)?)?;
    m.add("Error", m.py().get_type::<Error>())?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
