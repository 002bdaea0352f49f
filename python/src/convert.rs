//! Python values to what the library takes: vertex ids, inlier counts,
//! the dimension, vectors and matrices of numbers, paths, option values
//! as command-line text. Whatever does not convert is a `pgo.Error`
//! naming what was expected: `pgo.ArgumentTypeError` (also a `TypeError`)
//! for a value of the wrong type — a bool for an integer, text, bytes,
//! complex numbers or a masked array for numbers — and
//! `pgo.InvalidArgumentError` for one of the right type out of range.

use crate::errors::{invalid, wrong_type};
use numpy::{AllowTypeChange, PyArrayLikeDyn, PyUntypedArrayMethods};
use pyo3::exceptions::PyOverflowError;
use pyo3::prelude::*;
use pyo3::sync::PyOnceLock;
use pyo3::types::{
    PyBool, PyByteArray, PyBytes, PyFloat, PyList, PyMemoryView, PyString, PyTuple, PyType,
};
use std::path::PathBuf;

/// A library error as the `pgo.Error` subclass of its kind.
pub fn error(e: pgo::Error) -> PyErr {
    crate::errors::library(e)
}

/// Whether `value` is a bool, Python's or numpy's (both convert to
/// integers, and neither is an id or a count).
fn is_bool(value: &Bound<'_, PyAny>) -> bool {
    static NUMPY_BOOL: PyOnceLock<Py<PyType>> = PyOnceLock::new();
    value.is_instance_of::<PyBool>()
        || NUMPY_BOOL
            .import(value.py(), "numpy", "bool_")
            .is_ok_and(|t| value.is_instance(t).unwrap_or(false))
}

/// An integer argument: `Some` if it fits an `i128`, `None` for a larger
/// one; a `pgo.ArgumentTypeError` for a bool or a non-integer (a float
/// included: `5.0` is no id).
fn integer(what: &str, value: &Bound<'_, PyAny>) -> PyResult<Option<i128>> {
    if is_bool(value) {
        return Err(wrong_type(format!(
            "{what} must be an integer, not a bool, got {}",
            describe(value)
        )));
    }
    match value.extract::<i128>() {
        Ok(n) => Ok(Some(n)),
        Err(e) if e.is_instance_of::<PyOverflowError>(value.py()) => Ok(None),
        Err(_) => Err(wrong_type(format!(
            "{what} must be an integer, got {}",
            describe(value)
        ))),
    }
}

/// A vertex id: a Python integer in `0 ..= 2⁶⁴ − 1`.
pub fn vertex_id(value: &Bound<'_, PyAny>) -> PyResult<u64> {
    let n = integer("a vertex id", value)?;
    n.and_then(|n| u64::try_from(n).ok()).ok_or_else(|| {
        invalid(format!(
            "a vertex id must be an integer in 0..=18446744073709551615, got {}",
            describe(value)
        ))
    })
}

/// A vertex id to look for: `None` for anything that cannot be one.
pub fn maybe_vertex_id(value: &Bound<'_, PyAny>) -> Option<u64> {
    if is_bool(value) {
        return None;
    }
    value.extract::<u64>().ok()
}

/// An inlier count: `None` or a Python integer in `0 ..= 2⁶⁴ − 1`.
pub fn inlier_count(value: Option<&Bound<'_, PyAny>>) -> PyResult<Option<u64>> {
    let Some(v) = value.filter(|v| !v.is_none()) else {
        return Ok(None);
    };
    let n = integer("inliers", v)?;
    n.and_then(|n| u64::try_from(n).ok())
        .map(Some)
        .ok_or_else(|| {
            invalid(format!(
                "inliers must be None or a non-negative integer, got {}",
                describe(v)
            ))
        })
}

/// A graph's dimension, an integer; the library checks that it is 2 or
/// 3 (a `pgo.DimensionError` for any other integer).
pub fn dimension(value: &Bound<'_, PyAny>) -> PyResult<usize> {
    let n = integer("dim", value)?;
    n.and_then(|n| usize::try_from(n).ok()).ok_or_else(|| {
        crate::errors::dimension(format!(
            "a pose graph is 2D or 3D, not {}D",
            value
                .repr()
                .map_or_else(|_| "?".to_owned(), |r| r.to_string())
        ))
    })
}

/// A path: a `str` or `os.PathLike`.
pub fn path(value: &Bound<'_, PyAny>) -> PyResult<PathBuf> {
    value.extract::<PathBuf>().map_err(|_| {
        wrong_type(format!(
            "path: expected a str or os.PathLike, got {}",
            describe(value)
        ))
    })
}

/// The numbers of a vector (`what` is `pose` or `measurement`): any
/// sequence of numbers or one-dimensional array. Its length is the
/// library's to check.
pub fn vector(what: &str, value: &Bound<'_, PyAny>) -> PyResult<Vec<f64>> {
    let array = numbers(what, value)?;
    if array.ndim() != 1 {
        return Err(invalid(format!(
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
        return Err(invalid(format!(
            "information: expected a {size}×{size} matrix, got an array of shape {}",
            shape(array.shape())
        )));
    }
    // In logical (row-major) order, whatever the memory layout.
    Ok(array.as_array().iter().copied().collect())
}

/// Any array-like of real numbers (integers or floats) as a float64
/// array. Refused: text and bytes, a memoryview of bytes included (numpy
/// would parse `'1'` as 1, or take each byte as a number), bools, complex
/// numbers (numpy would drop the imaginary part), objects, and masked
/// arrays, also as rows of a list (numpy would drop the mask).
fn numbers<'py>(
    what: &str,
    value: &Bound<'py, PyAny>,
) -> PyResult<PyArrayLikeDyn<'py, f64, AllowTypeChange>> {
    static ASARRAY: PyOnceLock<Py<PyAny>> = PyOnceLock::new();
    static MASKED: PyOnceLock<Py<PyType>> = PyOnceLock::new();
    let py = value.py();
    let text = value.is_instance_of::<PyString>()
        || value.is_instance_of::<PyBytes>()
        || value.is_instance_of::<PyByteArray>();
    if text {
        return Err(wrong_type(format!(
            "{what}: expected numbers, got {}",
            describe(value)
        )));
    }
    if let Ok(view) = value.cast::<PyMemoryView>() {
        // A view of bytes is bytes: numpy would take each byte as a number.
        let exporter = view.getattr("obj")?;
        let bytes =
            exporter.is_instance_of::<PyBytes>() || exporter.is_instance_of::<PyByteArray>();
        let format: String = view.getattr("format")?.extract()?;
        if bytes && matches!(format.as_str(), "B" | "b" | "c") {
            return Err(wrong_type(format!(
                "{what}: expected numbers, got a view of bytes {}",
                describe(&exporter)
            )));
        }
    }
    let masked = MASKED.import(py, "numpy.ma", "MaskedArray")?;
    if let Some(found) = find_masked(value, masked, 0)? {
        let inside = if found.is(value) {
            String::new()
        } else {
            format!(" inside {}", describe(value))
        };
        return Err(wrong_type(format!(
            "{what}: a masked array's mask would be ignored; pass an array without one \
             (.filled() or .compressed()), got {}{inside}",
            describe(&found)
        )));
    }
    let asarray = ASARRAY.import(py, "numpy", "asarray")?;
    let array = asarray.call1((value,)).map_err(|e| {
        invalid(format!(
            "{what}: expected numbers, got {} ({e})",
            describe(value)
        ))
    })?;
    let dtype = array.getattr("dtype")?;
    let kind: String = dtype.getattr("kind")?.extract()?;
    let refused = match kind.as_str() {
        "f" | "i" | "u" => None,
        "b" => Some("booleans"),
        "c" => Some("complex numbers (only real ones are taken)"),
        "U" | "S" => Some("text"),
        _ => Some("no numbers"),
    };
    if let Some(found) = refused {
        return Err(wrong_type(format!(
            "{what}: expected real numbers, got {found}: {} (dtype {})",
            describe(value),
            dtype
                .str()
                .map_or_else(|_| "?".to_owned(), |s| s.to_string())
        )));
    }
    array.extract().map_err(|e: PyErr| {
        invalid(format!(
            "{what}: expected numbers, got {} ({e})",
            describe(value)
        ))
    })
}

/// `value` if it is a masked array (`numpy.ma.masked` included), else
/// the first masked array nested in it as lists and tuples, rows of a
/// matrix say: numpy would take their data and drop their masks.
fn find_masked<'py>(
    value: &Bound<'py, PyAny>,
    masked: &Bound<'py, PyType>,
    depth: usize,
) -> PyResult<Option<Bound<'py, PyAny>>> {
    if value.is_instance(masked)? {
        return Ok(Some(value.clone()));
    }
    // Deeper than any vector or matrix: numpy refuses it anyway.
    if depth >= 32 {
        return Ok(None);
    }
    let items = if let Ok(list) = value.cast::<PyList>() {
        list.iter().collect::<Vec<_>>()
    } else if let Ok(tuple) = value.cast::<PyTuple>() {
        tuple.iter().collect()
    } else {
        return Ok(None);
    };
    for item in &items {
        if let Some(found) = find_masked(item, masked, depth + 1)? {
            return Ok(Some(found));
        }
    }
    Ok(None)
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
    Err(wrong_type(format!(
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
