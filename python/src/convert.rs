//! Python values to what the library takes: vertex ids, inlier counts,
//! vectors and matrices of numbers, option values as command-line text.
//! Whatever does not convert is a `pgo.Error` naming what was expected.

use crate::Error;
use numpy::{AllowTypeChange, PyArrayLikeDyn, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::{PyBool, PyFloat, PyString};

/// A library error as a `pgo.Error` with the library's message.
pub fn error(e: pgo::Error) -> PyErr {
    Error::new_err(e.to_string())
}

/// A vertex id: a Python integer in `0 ..= 2⁶⁴ − 1`.
pub fn vertex_id(value: &Bound<'_, PyAny>) -> PyResult<u64> {
    value.extract::<u64>().map_err(|_| {
        Error::new_err(format!(
            "a vertex id must be an integer in 0..=18446744073709551615, got {}",
            describe(value)
        ))
    })
}

/// An inlier count: `None` or a Python integer in `0 ..= 2⁶⁴ − 1`.
pub fn inlier_count(value: Option<&Bound<'_, PyAny>>) -> PyResult<Option<u64>> {
    match value {
        None => Ok(None),
        Some(v) if v.is_none() => Ok(None),
        Some(v) => v.extract::<u64>().map(Some).map_err(|_| {
            Error::new_err(format!(
                "inliers must be None or a non-negative integer, got {}",
                describe(v)
            ))
        }),
    }
}

/// The numbers of a vector (`what` is `pose` or `measurement`): any
/// sequence of numbers or one-dimensional array. Its length is the
/// library's to check.
pub fn vector(what: &str, value: &Bound<'_, PyAny>) -> PyResult<Vec<f64>> {
    let array = numbers(what, value)?;
    if array.ndim() != 1 {
        return Err(Error::new_err(format!(
            "{what}: expected a sequence of numbers, got an array of shape {}",
            shape(array.shape())
        )));
    }
    Ok(array.as_array().iter().copied().collect())
}

/// The numbers of a `size × size` information matrix, row by row: a
/// nested sequence or two-dimensional array (or its `size²` numbers
/// flat, row by row, whose count the library checks).
pub fn matrix(value: &Bound<'_, PyAny>, size: usize) -> PyResult<Vec<f64>> {
    let array = numbers("information", value)?;
    let square = array.ndim() == 2 && array.shape() == [size, size];
    if !(square || array.ndim() == 1) {
        return Err(Error::new_err(format!(
            "information: expected a {size}×{size} matrix, got an array of shape {}",
            shape(array.shape())
        )));
    }
    // In logical (row-major) order, whatever the memory layout.
    Ok(array.as_array().iter().copied().collect())
}

/// Any array-like of numbers as a float64 array, or a `pgo.Error`.
fn numbers<'py>(
    what: &str,
    value: &Bound<'py, PyAny>,
) -> PyResult<PyArrayLikeDyn<'py, f64, AllowTypeChange>> {
    value.extract().map_err(|e: PyErr| {
        Error::new_err(format!(
            "{what}: expected numbers, got {} ({e})",
            describe(value)
        ))
    })
}

/// An option's value as the text `pgo optimize` takes after its flag:
/// `True`/`False` as `true`/`false`, integers and floats as numbers, a
/// string as it is. `None` is not a value (the caller leaves the option
/// at its default).
pub fn option_text(name: &str, value: &Bound<'_, PyAny>) -> PyResult<String> {
    if value.is_instance_of::<PyBool>() {
        return Ok(value.is_truthy()?.to_string());
    }
    if let Ok(text) = value.cast::<PyString>() {
        return Ok(text.to_cow()?.into_owned());
    }
    if !value.is_instance_of::<PyFloat>() {
        if let Ok(n) = value.extract::<i128>() {
            return Ok(n.to_string());
        }
    }
    if let Ok(x) = value.extract::<f64>() {
        // Debug: the shortest text that reads back to the same number.
        return Ok(format!("{x:?}"));
    }
    Err(Error::new_err(format!(
        "option {name}: expected a bool, int, float or str, got {}",
        describe(value)
    )))
}

/// An array's shape as Python prints it: `(3,)`, `(6, 6)`.
fn shape(dims: &[usize]) -> String {
    match dims {
        [n] => format!("({n},)"),
        _ => {
            let dims: Vec<String> = dims.iter().map(|d| d.to_string()).collect();
            format!("({})", dims.join(", "))
        }
    }
}

/// `repr(value)` (shortened) and its type, for messages.
fn describe(value: &Bound<'_, PyAny>) -> String {
    let type_name = value
        .get_type()
        .name()
        .map_or_else(|_| "?".to_owned(), |n| n.to_string());
    let mut text = value
        .repr()
        .map_or_else(|_| "?".to_owned(), |r| r.to_string());
    if text.chars().count() > 60 {
        text = text.chars().take(57).collect::<String>() + "...";
    }
    format!("{text} ({type_name})")
}
