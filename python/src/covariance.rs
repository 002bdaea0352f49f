//! The marginal covariances of a `pgo.Result` as numpy arrays: the
//! library's [`AnyCovariances`], computed (with the GIL released) at the
//! first request and kept by the result.

use crate::convert::{error, vertex_id};
use crate::errors::{internal, wrong_type};
use numpy::{PyArray1, PyArrayMethods};
use pgo::{AnyCovariances, AnySolution};
use pyo3::prelude::*;
use std::panic::{self, AssertUnwindSafe};
use std::sync::OnceLock;

/// `(ids, covariances)`: a uint64 array of N and a float64 array N×D×D.
type Stacked<'py> = (Bound<'py, PyArray1<u64>>, Bound<'py, PyAny>);

/// A result's covariances, once computed.
#[derive(Default)]
pub struct Cache(OnceLock<AnyCovariances>);

impl Cache {
    /// The covariances of `solution`, computed now if they were not.
    fn get(&self, py: Python<'_>, solution: &AnySolution) -> PyResult<&AnyCovariances> {
        if let Some(c) = self.0.get() {
            return Ok(c);
        }
        let computed = py
            .detach(|| panic::catch_unwind(AssertUnwindSafe(|| solution.covariances())))
            .map_err(|_| internal("internal failure: the covariances panicked".into()))?
            .map_err(error)?;
        // Another thread may have been first: either value is the same.
        let _ = self.0.set(computed);
        self.0
            .get()
            .ok_or_else(|| internal("internal failure: no covariances".into()))
    }
}

/// `numbers` (row by row) as a float64 array of `shape`.
fn array<'py>(py: Python<'py>, numbers: Vec<f64>, shape: &[usize]) -> PyResult<Bound<'py, PyAny>> {
    let flat = PyArray1::from_vec(py, numbers);
    Ok(flat.reshape(shape)?.into_any())
}

/// Pose `id`'s covariance, D×D.
pub fn pose<'py>(
    py: Python<'py>,
    cache: &Cache,
    solution: &AnySolution,
    id: &Bound<'py, PyAny>,
) -> PyResult<Bound<'py, PyAny>> {
    let id = vertex_id(id)?;
    let c = cache.get(py, solution)?;
    let d = c.size();
    array(py, c.pose(id).map_err(error)?, &[d, d])
}

/// The covariances of `ids` (every pose, in the graph's order, for
/// `None`): `(ids, N×D×D)`.
pub fn poses<'py>(
    py: Python<'py>,
    cache: &Cache,
    solution: &AnySolution,
    ids: Option<&Bound<'py, PyAny>>,
) -> PyResult<Stacked<'py>> {
    let c = cache.get(py, solution)?;
    let ids: Vec<u64> = match ids {
        Some(ids) if !ids.is_none() => ids
            .try_iter()
            .map_err(|_| wrong_type("ids must be an iterable of vertex ids or None".into()))?
            .map(|id| vertex_id(&id?))
            .collect::<PyResult<_>>()?,
        _ => c.ids().to_vec(),
    };
    let numbers = py.detach(|| c.poses(&ids)).map_err(error)?;
    let d = c.size();
    let stacked = array(py, numbers, &[ids.len(), d, d])?;
    Ok((PyArray1::from_vec(py, ids), stacked))
}

/// The joint covariance of `a` and `b`, 2D×2D.
pub fn joint<'py>(
    py: Python<'py>,
    cache: &Cache,
    solution: &AnySolution,
    (a, b): (&Bound<'py, PyAny>, &Bound<'py, PyAny>),
) -> PyResult<Bound<'py, PyAny>> {
    let (a, b) = (vertex_id(a)?, vertex_id(b)?);
    let c = cache.get(py, solution)?;
    let d = 2 * c.size();
    array(py, py.detach(|| c.joint(a, b)).map_err(error)?, &[d, d])
}

/// The covariance of `b` relative to `a`, D×D.
pub fn relative<'py>(
    py: Python<'py>,
    cache: &Cache,
    solution: &AnySolution,
    (a, b): (&Bound<'py, PyAny>, &Bound<'py, PyAny>),
) -> PyResult<Bound<'py, PyAny>> {
    let (a, b) = (vertex_id(a)?, vertex_id(b)?);
    let c = cache.get(py, solution)?;
    let d = c.size();
    array(py, py.detach(|| c.relative(a, b)).map_err(error)?, &[d, d])
}
