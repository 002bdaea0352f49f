//! What a call returns ([`PgoStatus`]), the thread's last error message,
//! and the guard every entry point runs its body in: arguments checked,
//! panics caught, the library's [`pgo::Error`] turned into a status and a
//! message.

use pgo::{ErrorKind, Setting};
use std::any::Any;
use std::cell::RefCell;
use std::ffi::{CStr, CString, c_char};
use std::panic::{AssertUnwindSafe, catch_unwind};

/// What a call of the C API returned: `PGO_OK`, or why it failed (then
/// `pgo_last_error()` says more, naming the vertex, option, file or line).
/// Codes may be added in later versions; treat an unknown one as an error.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PgoStatus {
    /// Success.
    PgoOk = 0,
    /// A NULL pointer, a string that is not UTF-8, an index out of range,
    /// or another argument no call can take.
    PgoErrInvalidArgument,
    /// An edge, `pgo_graph_fix` or `pgo_result_pose` names a vertex id
    /// that the graph does not have.
    PgoErrUnknownVertex,
    /// A pose was added twice under the same id.
    PgoErrDuplicateVertex,
    /// An edge from a vertex to itself.
    PgoErrSelfLoop,
    /// A pose or measurement that is not one: a NaN or infinite number, an
    /// SE(3) quaternion of zero norm.
    PgoErrInvalidPose,
    /// An information matrix that is not finite, symmetric and positive
    /// definite.
    PgoErrInvalidInformation,
    /// An array of numbers of the wrong length for the graph's dimension.
    PgoErrLength,
    /// A dimension other than 2 or 3, or a file of the other dimension.
    PgoErrDimension,
    /// `pgo_options_set` was given a name that is no option.
    PgoErrUnknownOption,
    /// An option's value does not parse or is out of range.
    PgoErrInvalidOption,
    /// A file could not be opened, read or written.
    PgoErrIo,
    /// A g2o file is malformed (the message names the file and line).
    PgoErrParse,
    /// A graph without poses cannot be optimised.
    PgoErrEmptyGraph,
    /// Some poses are tied to the fixed ones by no chain of edges (for a
    /// covariance: of the edges in the map).
    PgoErrUnconstrained,
    /// The optimisation is numerically impossible: a pose its edges do
    /// not determine, or numbers too large for floating point.
    PgoErrNumerical,
    /// A failure of pgo's own (memory, threads), not the input's.
    PgoErrInternal,
    /// A failure of a kind this version of the C API does not classify.
    PgoErrOther,
    /// pgo panicked, a bug (please report it); the message is the
    /// panic's. Handles stay valid to free, but one the call was changing
    /// may hold part of the change.
    PgoErrPanic,
    /// A request pgo does not serve for this graph: a certificate of a map
    /// with several fixed poses.
    PgoErrUnsupported,
}

/// A failed call: its status and message.
#[derive(Debug)]
pub(crate) struct Failure {
    status: PgoStatus,
    message: String,
}

impl Failure {
    /// A failure with this status and message.
    pub(crate) fn new(status: PgoStatus, message: impl Into<String>) -> Self {
        Self {
            status,
            message: message.into(),
        }
    }

    /// An argument no call can take.
    pub(crate) fn invalid(message: impl Into<String>) -> Self {
        Self::new(PgoStatus::PgoErrInvalidArgument, message)
    }

    /// A panic, with its message if it has one.
    fn panic(payload: Box<dyn Any + Send>) -> Self {
        let what = payload
            .downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| payload.downcast_ref::<String>().cloned())
            .unwrap_or_else(|| "a panic without a message".to_owned());
        Self::new(PgoStatus::PgoErrPanic, format!("pgo panicked: {what}"))
    }

    /// Stores the message as the thread's last error; returns the status.
    fn record(self) -> PgoStatus {
        set_last_error(&self.message);
        self.status
    }
}

impl From<pgo::Error> for Failure {
    fn from(error: pgo::Error) -> Self {
        Self::new(status_of(&error), error.message_with(&c_name))
    }
}

/// The status of a library error: that of its kind (the library
/// classifies its errors once, for the C and the Python API alike).
pub(crate) fn status_of(error: &pgo::Error) -> PgoStatus {
    error.kind().into()
}

impl From<ErrorKind> for PgoStatus {
    fn from(kind: ErrorKind) -> Self {
        use PgoStatus::*;
        match kind {
            ErrorKind::DuplicateVertex => PgoErrDuplicateVertex,
            ErrorKind::UnknownVertex => PgoErrUnknownVertex,
            ErrorKind::SelfLoop => PgoErrSelfLoop,
            ErrorKind::InvalidPose => PgoErrInvalidPose,
            ErrorKind::InvalidInformation => PgoErrInvalidInformation,
            ErrorKind::Length => PgoErrLength,
            ErrorKind::Dimension => PgoErrDimension,
            ErrorKind::UnknownOption => PgoErrUnknownOption,
            ErrorKind::InvalidOption => PgoErrInvalidOption,
            ErrorKind::Io => PgoErrIo,
            ErrorKind::Parse => PgoErrParse,
            ErrorKind::EmptyGraph => PgoErrEmptyGraph,
            ErrorKind::Unconstrained => PgoErrUnconstrained,
            ErrorKind::Numerical => PgoErrNumerical,
            ErrorKind::Internal => PgoErrInternal,
            ErrorKind::Unsupported => PgoErrUnsupported,
            _ => PgoErrOther,
        }
    }
}

/// A setting a message suggests, as a C caller sets it: an option by the
/// name `pgo_options_set` takes, a repair by its function.
fn c_name(setting: Setting) -> String {
    match setting {
        Setting::Option(name) => format!("option \"{name}\""),
        Setting::RepairAdded => "pgo_graph_set_repair_information(graph, true)".to_owned(),
        Setting::RepairRead => "pgo_graph_read_g2o_repairing".to_owned(),
        other => other.rust_name(),
    }
}

thread_local! {
    /// The message of the last failed call on this thread.
    static LAST_ERROR: RefCell<CString> = RefCell::new(CString::default());
}

/// Stores `message` as this thread's last error (a NUL inside it, from a
/// caller's string, is written `\0`).
fn set_last_error(message: &str) {
    let text = CString::new(message.replace('\0', "\\0")).unwrap_or_default();
    LAST_ERROR.with(|e| *e.borrow_mut() = text);
}

/// This thread's last error message, as the pointer `pgo_last_error`
/// returns: it stays valid until the next failed call on this thread.
pub(crate) fn last_error_ptr() -> *const c_char {
    LAST_ERROR.with(|e| e.borrow().as_ptr())
}

/// Runs an entry point's body: panics caught, a failure recorded as the
/// last error and returned as its status.
pub(crate) fn status(body: impl FnOnce() -> Result<(), Failure>) -> PgoStatus {
    match catch_unwind(AssertUnwindSafe(body)) {
        Ok(Ok(())) => PgoStatus::PgoOk,
        Ok(Err(failure)) => failure.record(),
        Err(payload) => Failure::panic(payload).record(),
    }
}

/// Runs the body of an entry point that returns a value: on a failure or
/// a panic, recorded as the last error, `fallback` is returned.
pub(crate) fn value<T>(fallback: T, body: impl FnOnce() -> Result<T, Failure>) -> T {
    match catch_unwind(AssertUnwindSafe(body)) {
        Ok(Ok(v)) => v,
        Ok(Err(failure)) => {
            failure.record();
            fallback
        }
        Err(payload) => {
            Failure::panic(payload).record();
            fallback
        }
    }
}

/// The object behind a caller's pointer, or a failure naming `what` for
/// NULL.
///
/// # Safety
/// `p` is NULL or points to a live `T` that nothing mutates for `'a`.
pub(crate) unsafe fn borrow<'a, T>(p: *const T, what: &str) -> Result<&'a T, Failure> {
    // SAFETY: non-NULL pointers are valid, by the caller's contract.
    unsafe { p.as_ref() }.ok_or_else(|| Failure::invalid(format!("{what} is NULL")))
}

/// [`borrow`], mutably.
///
/// # Safety
/// `p` is NULL or points to a live `T` that nothing else uses for `'a`.
pub(crate) unsafe fn borrow_mut<'a, T>(p: *mut T, what: &str) -> Result<&'a mut T, Failure> {
    // SAFETY: non-NULL pointers are valid and unaliased, by the contract.
    unsafe { p.as_mut() }.ok_or_else(|| Failure::invalid(format!("{what} is NULL")))
}

/// The `len` numbers at `p` (NULL is allowed when `len` is 0).
///
/// # Safety
/// `p` is NULL or points to `len` readable `double`s.
pub(crate) unsafe fn numbers<'a>(
    p: *const f64,
    len: usize,
    what: &str,
) -> Result<&'a [f64], Failure> {
    if p.is_null() {
        return match len {
            0 => Ok(&[]),
            _ => Err(Failure::invalid(format!(
                "{what} is NULL, with length {len}"
            ))),
        };
    }
    // SAFETY: `len` readable numbers at `p`, by the caller's contract.
    Ok(unsafe { std::slice::from_raw_parts(p, len) })
}

/// The UTF-8 text of a caller's NUL-terminated string.
///
/// # Safety
/// `p` is NULL or points to a NUL-terminated string.
pub(crate) unsafe fn text<'a>(p: *const c_char, what: &str) -> Result<&'a str, Failure> {
    if p.is_null() {
        return Err(Failure::invalid(format!("{what} is NULL")));
    }
    // SAFETY: a NUL-terminated string, by the caller's contract.
    let bytes = unsafe { CStr::from_ptr(p) };
    bytes
        .to_str()
        .map_err(|_| Failure::invalid(format!("{what} is not UTF-8")))
}

/// Checks that an out-pointer is not NULL.
pub(crate) fn out_ptr<T>(p: *mut T, what: &str) -> Result<*mut T, Failure> {
    if p.is_null() {
        Err(Failure::invalid(format!("{what} is NULL")))
    } else {
        Ok(p)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn message() -> String {
        // SAFETY: the thread's message, NUL-terminated.
        unsafe { CStr::from_ptr(last_error_ptr()) }
            .to_string_lossy()
            .into_owned()
    }

    #[test]
    fn a_panic_becomes_a_status_and_its_message() {
        assert_eq!(status(|| panic!("boom {}", 7)), PgoStatus::PgoErrPanic);
        assert_eq!(message(), "pgo panicked: boom 7");
        assert_eq!(value(5, || panic!("static")), 5);
        assert_eq!(message(), "pgo panicked: static");
    }

    #[test]
    fn each_kind_has_its_status() {
        let kinds = [
            (ErrorKind::DuplicateVertex, PgoStatus::PgoErrDuplicateVertex),
            (ErrorKind::UnknownVertex, PgoStatus::PgoErrUnknownVertex),
            (ErrorKind::SelfLoop, PgoStatus::PgoErrSelfLoop),
            (ErrorKind::InvalidPose, PgoStatus::PgoErrInvalidPose),
            (
                ErrorKind::InvalidInformation,
                PgoStatus::PgoErrInvalidInformation,
            ),
            (ErrorKind::Length, PgoStatus::PgoErrLength),
            (ErrorKind::Dimension, PgoStatus::PgoErrDimension),
            (ErrorKind::UnknownOption, PgoStatus::PgoErrUnknownOption),
            (ErrorKind::InvalidOption, PgoStatus::PgoErrInvalidOption),
            (ErrorKind::Io, PgoStatus::PgoErrIo),
            (ErrorKind::Parse, PgoStatus::PgoErrParse),
            (ErrorKind::EmptyGraph, PgoStatus::PgoErrEmptyGraph),
            (ErrorKind::Unconstrained, PgoStatus::PgoErrUnconstrained),
            (ErrorKind::Numerical, PgoStatus::PgoErrNumerical),
            (ErrorKind::Internal, PgoStatus::PgoErrInternal),
        ];
        let mut seen = Vec::new();
        for (kind, expected) in kinds {
            let status = PgoStatus::from(kind);
            assert_eq!(status, expected, "{kind:?}");
            assert!(!seen.contains(&status), "{kind:?}: two kinds, one status");
            seen.push(status);
        }
        assert_eq!(
            status_of(&pgo::Error::Undetermined { vertex: 1 }),
            PgoStatus::PgoErrNumerical
        );
    }

    #[test]
    fn messages_name_settings_as_c_sets_them() {
        let e = pgo::Options::default().set("alpha", "2").unwrap_err();
        let failure = Failure::from(e);
        assert_eq!(failure.message, "option \"alpha\" must be in (0, 1), got 2");
        let mut graph = pgo::AnyPoseGraph::new(2).unwrap();
        graph.add_pose(0, &[0.0; 3]).unwrap();
        graph.add_pose(1, &[1.0, 0.0, 0.0]).unwrap();
        let negative = [-1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
        let e = graph
            .add_edge(0, 1, &[1.0, 0.0, 0.0], &negative)
            .unwrap_err();
        let failure = Failure::from(e);
        assert_eq!(failure.status, PgoStatus::PgoErrInvalidInformation);
        assert!(
            failure
                .message
                .contains("; pgo_graph_set_repair_information(graph, true) projects"),
            "{}",
            failure.message
        );
        assert!(!failure.message.contains("PoseGraph::"));
    }

    #[test]
    fn a_nul_in_a_message_is_written_out() {
        let s = status(|| Err(Failure::new(PgoStatus::PgoErrOther, "a\0b")));
        assert_eq!(s, PgoStatus::PgoErrOther);
        assert_eq!(message(), "a\\0b");
    }
}
