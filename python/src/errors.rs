//! The exceptions the module raises: `pgo.Error` (a `ValueError`) and one
//! subclass per kind of the library's errors (`pgo::ErrorKind`, the same
//! classification the C API's status codes come from), plus the binding's
//! own for arguments Python can pass but the library cannot take. A file
//! that cannot be read or written is also an `OSError`, a missing one a
//! `FileNotFoundError`; an argument of the wrong type also a `TypeError`;
//! an unknown vertex also a `LookupError`. Messages name settings as
//! Python spells them (`option max_iters`, `repair_information=True`).

use pgo::{ErrorKind, Setting};
use pyo3::prelude::*;
use pyo3::sync::PyOnceLock;
use pyo3::types::{PyDict, PyTuple, PyType};

/// A base of a class: one of the module's, or a builtin exception.
#[derive(Clone, Copy)]
enum Base {
    Pgo(&'static str),
    Builtin(&'static str),
}

/// A class: its name, bases and docstring. Bases come first.
struct Class {
    name: &'static str,
    bases: &'static [Base],
    doc: &'static str,
}

use Base::{Builtin, Pgo};

const ERROR: Base = Pgo("Error");

/// Every class, each after its bases.
const CLASSES: &[Class] = &[
    Class {
        name: "Error",
        bases: &[Builtin("ValueError")],
        doc: "Bad input to pgo or a failed optimisation, with the library's message (a \
              ValueError). Each kind of failure is a subclass.",
    },
    Class {
        name: "InvalidArgumentError",
        bases: &[ERROR],
        doc: "An argument no call can take: a vertex id or count out of range, an array of \
              the wrong shape.",
    },
    Class {
        name: "ArgumentTypeError",
        bases: &[Pgo("InvalidArgumentError"), Builtin("TypeError")],
        doc: "An argument of the wrong type (also a TypeError): a bool as an id or count, \
              text, complex or masked arrays as numbers, a path that is no str or \
              os.PathLike.",
    },
    Class {
        name: "DuplicateVertexError",
        bases: &[ERROR],
        doc: "A pose was added twice under the same id.",
    },
    Class {
        name: "UnknownVertexError",
        bases: &[ERROR, Builtin("LookupError")],
        doc: "An edge, fix or look-up names a vertex id the graph does not have (also a \
              LookupError).",
    },
    Class {
        name: "SelfLoopError",
        bases: &[ERROR],
        doc: "An edge from a vertex to itself.",
    },
    Class {
        name: "InvalidPoseError",
        bases: &[ERROR],
        doc: "A pose or measurement that is not one: a NaN or infinite number, a zero \
              quaternion.",
    },
    Class {
        name: "InvalidInformationError",
        bases: &[ERROR],
        doc: "An information matrix that is not finite, symmetric, positive definite and \
              within range.",
    },
    Class {
        name: "LengthError",
        bases: &[ERROR],
        doc: "Numbers of the wrong count for the graph's dimension.",
    },
    Class {
        name: "DimensionError",
        bases: &[ERROR],
        doc: "A dimension other than 2 or 3, or a file of the other dimension.",
    },
    Class {
        name: "UnknownOptionError",
        bases: &[ERROR],
        doc: "A name that is no option (pgo.option_names() lists them).",
    },
    Class {
        name: "InvalidOptionError",
        bases: &[ERROR],
        doc: "An option's value that does not parse or is out of range.",
    },
    Class {
        name: "FileError",
        // OSError first: its `__str__`, `[Errno 2] …: 'path'`.
        bases: &[Builtin("OSError"), ERROR],
        doc: "A file that cannot be opened, read or written (also an OSError, with errno, \
              strerror and filename).",
    },
    Class {
        name: "MissingFileError",
        bases: &[Builtin("FileNotFoundError"), Pgo("FileError")],
        doc: "A file that does not exist (also a FileNotFoundError).",
    },
    Class {
        name: "ParseError",
        bases: &[ERROR],
        doc: "A malformed g2o file; the message names the file and line.",
    },
    Class {
        name: "EmptyGraphError",
        bases: &[ERROR],
        doc: "A graph without poses cannot be optimised.",
    },
    Class {
        name: "UnconstrainedError",
        bases: &[ERROR],
        doc: "Poses tied to the fixed ones by no chain of edges.",
    },
    Class {
        name: "NumericalError",
        bases: &[ERROR],
        doc: "A problem floating point cannot solve: a pose its edges do not determine, \
              numbers too large.",
    },
    Class {
        name: "InternalError",
        bases: &[ERROR],
        doc: "A failure of pgo's own (threads, memory, a bug), not the input's.",
    },
    Class {
        name: "UnsupportedError",
        bases: &[ERROR],
        doc: "A request pgo does not serve for this graph: a certificate of a map with \
              several fixed poses.",
    },
];

/// The class of each kind of the library's errors; `Error` for a kind
/// this version does not know.
fn class_name(kind: ErrorKind) -> &'static str {
    match kind {
        ErrorKind::DuplicateVertex => "DuplicateVertexError",
        ErrorKind::UnknownVertex => "UnknownVertexError",
        ErrorKind::SelfLoop => "SelfLoopError",
        ErrorKind::InvalidPose => "InvalidPoseError",
        ErrorKind::InvalidInformation => "InvalidInformationError",
        ErrorKind::Length => "LengthError",
        ErrorKind::Dimension => "DimensionError",
        ErrorKind::UnknownOption => "UnknownOptionError",
        ErrorKind::InvalidOption => "InvalidOptionError",
        ErrorKind::Io => "FileError",
        ErrorKind::Parse => "ParseError",
        ErrorKind::EmptyGraph => "EmptyGraphError",
        ErrorKind::Unconstrained => "UnconstrainedError",
        ErrorKind::Numerical => "NumericalError",
        ErrorKind::Internal => "InternalError",
        ErrorKind::Unsupported => "UnsupportedError",
        _ => "Error",
    }
}

/// A setting as a Python user sets it.
fn python_name(setting: Setting) -> String {
    match setting {
        Setting::Option(name) => format!("option {}", name.replace('-', "_")),
        Setting::RepairAdded => "PoseGraph(dim, repair_information=True)".to_owned(),
        Setting::RepairRead => "read_g2o(path, repair_information=True)".to_owned(),
        other => other.rust_name(),
    }
}

/// The classes, made on first use (by `type(name, bases, namespace)`),
/// in the order of [`CLASSES`].
fn classes(py: Python<'_>) -> PyResult<&'static [Py<PyType>]> {
    static MADE: PyOnceLock<Vec<Py<PyType>>> = PyOnceLock::new();
    MADE.get_or_try_init(py, || {
        let builtins = py.import("builtins")?;
        let type_ = builtins.getattr("type")?;
        let mut made: Vec<Py<PyType>> = Vec::with_capacity(CLASSES.len());
        for class in CLASSES {
            let bases = class
                .bases
                .iter()
                .map(|base| match base {
                    Builtin(name) => builtins.getattr(*name),
                    Pgo(name) => made
                        .get(position(name)?)
                        .map(|base| base.bind(py).clone().into_any())
                        .ok_or_else(|| {
                            pyo3::exceptions::PyRuntimeError::new_err(format!(
                                "pgo: the base {name} comes after {}",
                                class.name
                            ))
                        }),
                })
                .collect::<PyResult<Vec<_>>>()?;
            let namespace = PyDict::new(py);
            namespace.set_item("__doc__", class.doc)?;
            namespace.set_item("__module__", "pgo")?;
            let made_class = type_.call1((class.name, PyTuple::new(py, bases)?, namespace))?;
            made.push(made_class.cast_into::<PyType>()?.unbind());
        }
        Ok(made)
    })
    .map(Vec::as_slice)
}

/// Where the class named `name` is in [`CLASSES`] (a base: before the
/// classes deriving from it).
fn position(name: &str) -> PyResult<usize> {
    CLASSES.iter().position(|c| c.name == name).ok_or_else(|| {
        pyo3::exceptions::PyRuntimeError::new_err(format!("pgo: no exception class {name}"))
    })
}

/// The class named `name` (one of [`CLASSES`]).
fn class<'py>(py: Python<'py>, name: &str) -> PyResult<Bound<'py, PyType>> {
    Ok(classes(py)?[position(name)?].bind(py).clone())
}

/// Adds every class to the module.
pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    for (spec, class) in CLASSES.iter().zip(classes(m.py())?) {
        m.add(spec.name, class.bind(m.py()))?;
    }
    Ok(())
}

/// An exception of the class `name` with `args`.
fn raise<A>(name: &'static str, args: A) -> PyErr
where
    A: for<'py> IntoPyObject<'py> + Send + Sync + 'static,
{
    Python::attach(|py| match class(py, name) {
        Ok(class) => PyErr::from_type(class, args),
        Err(e) => e,
    })
}

/// A library error as the exception of its kind, worded for Python. A
/// file error is an `OSError`, a `FileNotFoundError` for a missing file
/// or directory; with the OS's error number it is raised as `open()`
/// raises one: `[Errno 2] No such file or directory: 'path'`.
pub fn library(e: pgo::Error) -> PyErr {
    let Some((path, io)) = e.io_error() else {
        return raise(class_name(e.kind()), e.message_with(&python_name));
    };
    let class = match io.kind() {
        std::io::ErrorKind::NotFound => "MissingFileError",
        _ => "FileError",
    };
    let Some(errno) = io.raw_os_error() else {
        return raise(class, e.message_with(&python_name));
    };
    let strerror = Python::attach(|py| -> PyResult<String> {
        py.import("os")?
            .call_method1("strerror", (errno,))?
            .extract()
    })
    .unwrap_or_else(|_| io.to_string());
    let strerror = match e {
        pgo::Error::Read(_) => strerror,
        _ => format!("cannot write: {strerror}"),
    };
    raise(
        class,
        (errno, strerror, path.to_string_lossy().into_owned()),
    )
}

/// An argument no call can take (`pgo.InvalidArgumentError`).
pub fn invalid(message: String) -> PyErr {
    raise("InvalidArgumentError", message)
}

/// An argument of the wrong type (`pgo.ArgumentTypeError`, a `TypeError`).
pub fn wrong_type(message: String) -> PyErr {
    raise("ArgumentTypeError", message)
}

/// `pgo.DimensionError`, for a dimension the library's `usize` cannot
/// hold.
pub fn dimension(message: String) -> PyErr {
    raise("DimensionError", message)
}

/// `pgo.InternalError`, for a panic (a bug) or another failure of the
/// binding's own.
pub fn internal(message: String) -> PyErr {
    raise("InternalError", message)
}
