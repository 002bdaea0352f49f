//! Why a call of the library failed: [`Error`], one enum for the whole
//! public API, each variant naming what was wrong (the vertex id, the edge,
//! the option as the command line spells it, the file and line).
//!
//! For bindings, the surface they need without parsing messages:
//! [`Error::kind`] classifies an error ([`ErrorKind`], from which the C
//! API's status codes and the Python module's exception classes are both
//! made), and [`Error::message_with`] words the message with the binding's
//! own names for the settings it suggests ([`Setting`]).

use crate::graph::VertexId;
use crate::io::g2o::{LineProblem, ReadError};
use std::path::PathBuf;

/// Why a call of the library failed.
///
/// Its `Debug` form is its message, so that a `main` returning
/// `Result<(), pgo::Error>` prints a readable line (`{:#?}` adds the
/// [`ErrorKind`]):
///
/// ```
/// let err = pgo::AnyPoseGraph::new(4).unwrap_err();
/// assert_eq!(format!("{err:?}"), "a pose graph is 2D or 3D, not 4D");
/// assert_eq!(err.kind(), pgo::ErrorKind::Dimension);
/// ```
#[derive(thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// A pose was added twice under the same id.
    #[error("vertex {id} already exists")]
    DuplicateVertex {
        /// The id.
        id: VertexId,
    },
    /// An edge or `fix` names a vertex that was never added.
    #[error("unknown vertex id {id}")]
    UnknownVertex {
        /// The id.
        id: VertexId,
    },
    /// An entry of [`crate::PoseGraph::set_inlier_counts`] names a vertex
    /// pair with no (further) edge between them.
    #[error("no (further) edge between vertices {from} and {to}")]
    NoEdge {
        /// Its first vertex id.
        from: VertexId,
        /// Its second vertex id.
        to: VertexId,
        /// Its position in the list, from 0.
        entry: usize,
    },
    /// An edge from a vertex to itself.
    #[error("edge from vertex {id} to itself")]
    SelfLoop {
        /// The id.
        id: VertexId,
    },
    /// A pose that cannot be one.
    #[error("vertex {id}: {problem}")]
    InvalidPose {
        /// The vertex id.
        id: VertexId,
        /// What is wrong.
        problem: PoseProblem,
    },
    /// An edge's measurement that cannot be a pose.
    #[error("edge {from} → {to}: measurement {problem}")]
    InvalidMeasurement {
        /// The first vertex id.
        from: VertexId,
        /// The second vertex id.
        to: VertexId,
        /// What is wrong.
        problem: PoseProblem,
    },
    /// An edge's information matrix that is not symmetric positive
    /// definite (and was not repaired), or out of range.
    #[error("{}", information_message(*.from, *.to, .problem, &Setting::rust_name))]
    InvalidInformation {
        /// The first vertex id.
        from: VertexId,
        /// The second vertex id.
        to: VertexId,
        /// What is wrong.
        problem: InformationProblem,
    },
    /// A slice of numbers of the wrong length ([`crate::AnyPoseGraph`]).
    #[error("{what}: expected {expected} numbers for a {dimension}D graph, got {found}")]
    Length {
        /// What the numbers are (`pose`, `measurement`, `information`).
        what: &'static str,
        /// 2 or 3.
        dimension: usize,
        /// How many numbers it takes.
        expected: usize,
        /// How many were given.
        found: usize,
    },
    /// A pose graph is 2D or 3D.
    #[error("a pose graph is 2D or 3D, not {dimension}D")]
    UnsupportedDimension {
        /// The dimension asked for.
        dimension: usize,
    },
    /// A file of the other dimension than the graph's.
    #[error("expected a {expected}D pose graph, got {found}D")]
    Dimension {
        /// The graph's dimension.
        expected: usize,
        /// The dimension found.
        found: usize,
    },
    /// A graph without poses cannot be optimised.
    #[error("the pose graph has no poses")]
    EmptyGraph,
    /// [`crate::Options::set`] was given a name that is no option.
    #[error("unknown option '{name}' (options: {})", crate::Options::names().collect::<Vec<_>>().join(", "))]
    UnknownOption {
        /// The name given.
        name: String,
    },
    /// An option's value does not parse or is out of range.
    #[error("{} {message}", Setting::rust_name(Setting::Option(.option)))]
    InvalidOption {
        /// The option as the command line spells it, without `--`.
        option: &'static str,
        /// What is wrong, with the value given.
        message: String,
    },
    /// A g2o file is unreadable or malformed (the file and line are named).
    #[error("{}", read_message(.0, &Setting::rust_name))]
    Read(ReadError),
    /// A file could not be written.
    #[error("{}: cannot write: {source}", path.display())]
    Write {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// Some poses are not connected to the fixed ones by any chain of
    /// edges (loop candidates the gate dropped do not count), so they are
    /// undetermined.
    #[error(
        "{} vertices are not connected to the fixed vertex {gauge} by any chain of edges, e.g. {}",
        .vertices.len(),
        list_ids(.vertices)
    )]
    Unconstrained {
        /// The first fixed vertex.
        gauge: VertexId,
        /// The vertices not connected to it.
        vertices: Vec<VertexId>,
    },
    /// The edges at a vertex do not determine its pose (the normal
    /// equations are singular there).
    #[error("the edges at vertex {vertex} do not determine its pose")]
    Undetermined {
        /// The vertex id.
        vertex: VertexId,
    },
    /// A covariance was asked of a pose that no chain of edges in the map
    /// (trusted edges and accepted loops) ties to the fixed poses: the map
    /// held it where it was, and its covariance is unbounded
    /// ([`crate::Covariances`]).
    #[error(
        "vertex {id}: no chain of trusted edges and accepted loops ties it to the fixed poses, \
         so its covariance is unbounded"
    )]
    Unbounded {
        /// The vertex id.
        id: VertexId,
    },
    /// An edge's cost is not finite at the initial guess: its measurement,
    /// information or poses are too large for floating point.
    #[error(
        "edge {edge} (vertex {from} → {to}) has a non-finite χ² at the {} initial guess: \
         its measurement, information or poses are too large",
        initialization_name(*.initialization)
    )]
    NonFiniteEdge {
        /// The edge's index, as returned when it was added (a file's edges
        /// counted from 0 in file order).
        edge: usize,
        /// Its first vertex id.
        from: VertexId,
        /// Its second vertex id.
        to: VertexId,
        /// The initial guess ([`crate::SolverOptions::init`]).
        initialization: crate::Initialization,
    },
    /// The initial guess or the optimiser's result is not finite.
    #[error("the optimisation produced non-finite poses")]
    NonFinite,
    /// The solver's threads could not be started.
    #[error("cannot start {threads} solver threads: {message}")]
    Threads {
        /// Threads asked for.
        threads: usize,
        /// The cause.
        message: String,
    },
    /// A failure of pgo's own, not the input's: the factorisation could
    /// not allocate its memory, or the like.
    #[error("internal failure: {0}")]
    Internal(String),
    /// A certificate of global optimality could not be computed
    /// ([`crate::Solution::certificate`]).
    #[error(transparent)]
    Certify(#[from] crate::certify::CertifyError),
}

/// What is wrong with a pose or a measurement.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum PoseProblem {
    /// A number is NaN or infinite.
    #[error("is not finite")]
    NotFinite,
    /// An SE(3) rotation whose quaternion has zero norm.
    #[error("has a quaternion of zero norm")]
    ZeroQuaternion,
}

/// What is wrong with an information matrix.
#[derive(Clone, Copy, Debug, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum InformationProblem {
    /// An entry is NaN or infinite.
    #[error("has a non-finite entry at ({row}, {col})")]
    NotFinite {
        /// Its row.
        row: usize,
        /// Its column.
        col: usize,
    },
    /// Entries `(row, col)` and `(col, row)` differ by more than 10⁻⁹ of the
    /// largest entry.
    #[error("is not symmetric: ({row}, {col}) = {upper:e} but ({col}, {row}) = {lower:e}")]
    NotSymmetric {
        /// The row of the upper entry.
        row: usize,
        /// Its column.
        col: usize,
        /// The upper entry.
        upper: f64,
        /// The lower entry.
        lower: f64,
    },
    /// The matrix is not positive definite. ([`Error`]'s message adds
    /// the setting that repairs such matrices: [`Setting::RepairAdded`].)
    #[error("is not positive definite (smallest eigenvalue {min_eigenvalue:e})")]
    NotPositiveDefinite {
        /// Its smallest eigenvalue (NaN if it could not be computed).
        min_eigenvalue: f64,
    },
    /// A diagonal entry outside [`crate::INFORMATION_RANGE`], beyond
    /// what the solver computes with in floating point (repair does not
    /// change it).
    #[error(
        "has diagonal entry ({index}, {index}) = {value:e}, outside the range pgo computes \
         with ({:e} to {:e}; rescale the information or the units)",
        crate::INFORMATION_RANGE.start(),
        crate::INFORMATION_RANGE.end()
    )]
    OutOfRange {
        /// Its row and column.
        index: usize,
        /// The entry.
        value: f64,
    },
    /// Repair was asked for, but the matrix is zero or too large to
    /// decompose.
    #[error("cannot be made positive definite (it is zero, or too large to decompose)")]
    NotRepairable,
}

impl From<ReadError> for Error {
    fn from(e: ReadError) -> Self {
        Self::Read(e)
    }
}

/// The kind of an [`Error`], for callers that act on it rather than
/// print it: the C API returns one status code per kind, the Python
/// module raises one exception class per kind.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum ErrorKind {
    /// A pose was added twice under the same id
    /// ([`Error::DuplicateVertex`]).
    DuplicateVertex,
    /// An edge, a fix or a look-up names an id the graph does not have
    /// ([`Error::UnknownVertex`]), or a pair of ids no (further) edge joins
    /// ([`Error::NoEdge`]).
    UnknownVertex,
    /// An edge from a vertex to itself ([`Error::SelfLoop`]).
    SelfLoop,
    /// A pose or measurement that is not one: a NaN or infinite number, a
    /// zero quaternion ([`Error::InvalidPose`],
    /// [`Error::InvalidMeasurement`]).
    InvalidPose,
    /// An information matrix that is not finite, symmetric, positive
    /// definite and within range ([`Error::InvalidInformation`]).
    InvalidInformation,
    /// Numbers of the wrong count for the graph's dimension
    /// ([`Error::Length`]).
    Length,
    /// A dimension other than 2 or 3, or a file of the other dimension
    /// ([`Error::UnsupportedDimension`], [`Error::Dimension`]).
    Dimension,
    /// A name that is no option ([`Error::UnknownOption`]).
    UnknownOption,
    /// An option's value that does not parse or is out of range
    /// ([`Error::InvalidOption`]).
    InvalidOption,
    /// A file that cannot be opened, read or written
    /// ([`ReadError::Io`], [`Error::Write`]).
    Io,
    /// A malformed g2o file; the message names the file and line
    /// ([`Error::Read`] but for [`ReadError::Io`]).
    Parse,
    /// A graph without poses ([`Error::EmptyGraph`]).
    EmptyGraph,
    /// Poses tied to the fixed ones by no chain of edges
    /// ([`Error::Unconstrained`]).
    Unconstrained,
    /// A problem floating point cannot solve: a pose its edges do not
    /// determine, numbers too large ([`Error::Undetermined`],
    /// [`Error::NonFiniteEdge`], [`Error::NonFinite`]).
    Numerical,
    /// A failure of pgo's own (threads, memory), not the input's
    /// ([`Error::Threads`], [`Error::Internal`]).
    Internal,
    /// A request the library does not serve for this graph: a certificate
    /// of a map with several fixed poses ([`Error::Certify`]).
    Unsupported,
}

/// A setting that an error message suggests changing. Each surface of the
/// library names it in its own words ([`Error::message_with`]): the Rust
/// API as [`Setting::rust_name`] does (what `Display` shows), the command
/// line by its flag, a binding by its own function or keyword.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum Setting {
    /// An option, by its name in [`crate::Options::set`] (`max-iters`).
    Option(&'static str),
    /// Repairing the information matrices of edges added from now on:
    /// [`crate::PoseGraph::set_repair_information`].
    RepairAdded,
    /// Repairing the information matrices of a g2o file being read:
    /// [`crate::PoseGraph::read_g2o_repairing`].
    RepairRead,
}

impl Setting {
    /// The setting as the Rust API's messages name it: an option by its
    /// command-line flag (`--max-iters`, the names [`crate::Options::set`]
    /// takes), a repair by its method.
    pub fn rust_name(self) -> String {
        match self {
            Self::Option(name) => format!("--{name}"),
            Self::RepairAdded => "PoseGraph::set_repair_information(true)".into(),
            Self::RepairRead => "PoseGraph::read_g2o_repairing".into(),
        }
    }
}

impl Error {
    /// The kind of the error, one per status code of the C API and
    /// exception class of the Python module.
    pub fn kind(&self) -> ErrorKind {
        use ErrorKind as K;
        match self {
            Self::DuplicateVertex { .. } => K::DuplicateVertex,
            Self::UnknownVertex { .. } | Self::NoEdge { .. } => K::UnknownVertex,
            Self::SelfLoop { .. } => K::SelfLoop,
            Self::InvalidPose { .. } | Self::InvalidMeasurement { .. } => K::InvalidPose,
            Self::InvalidInformation { .. } => K::InvalidInformation,
            Self::Length { .. } => K::Length,
            Self::UnsupportedDimension { .. } | Self::Dimension { .. } => K::Dimension,
            Self::UnknownOption { .. } => K::UnknownOption,
            Self::InvalidOption { .. } => K::InvalidOption,
            Self::Read(ReadError::Io { .. }) | Self::Write { .. } => K::Io,
            Self::Read(_) => K::Parse,
            Self::EmptyGraph => K::EmptyGraph,
            Self::Unconstrained { .. } | Self::Unbounded { .. } => K::Unconstrained,
            Self::Undetermined { .. } | Self::NonFiniteEdge { .. } | Self::NonFinite => {
                K::Numerical
            }
            Self::Threads { .. } | Self::Internal(_) => K::Internal,
            Self::Certify(crate::CertifyError::SeveralFixed { .. }) => K::Unsupported,
            Self::Certify(crate::CertifyError::NonFinite) => K::Numerical,
            Self::Certify(_) => K::Internal,
        }
    }

    /// The file and the operating system's error, for an error of kind
    /// [`ErrorKind::Io`] (a binding raises its own "file not found" for
    /// [`std::io::ErrorKind::NotFound`], with the OS's error number).
    pub fn io_error(&self) -> Option<(&std::path::Path, &std::io::Error)> {
        match self {
            Self::Read(ReadError::Io { path, source }) | Self::Write { path, source } => {
                Some((path, source))
            }
            _ => None,
        }
    }

    /// The message, with the settings it suggests named by `name` — a
    /// binding's own words for them — instead of the Rust API's
    /// ([`Setting::rust_name`], which `Display` uses).
    ///
    /// ```
    /// use pgo::{Options, Setting};
    /// let err = Options::default().set("max_iters", "-1").unwrap_err();
    /// let python = err.message_with(&|s| match s {
    ///     Setting::Option(name) => format!("option {}", name.replace('-', "_")),
    ///     other => other.rust_name(),
    /// });
    /// assert!(python.starts_with("option max_iters must be"), "{python}");
    /// assert!(err.to_string().starts_with("--max-iters must be"));
    /// ```
    pub fn message_with(&self, name: &dyn Fn(Setting) -> String) -> String {
        match self {
            Self::InvalidOption { option, message } => {
                format!("{} {message}", name(Setting::Option(option)))
            }
            Self::InvalidInformation { from, to, problem } => {
                information_message(*from, *to, problem, name)
            }
            Self::Read(e) => read_message(e, name),
            other => other.to_string(),
        }
    }
}

impl std::fmt::Debug for Error {
    /// The message (`Display`); `{:#?}` prefixes the kind.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if f.alternate() {
            write!(f, "{:?}: {self}", self.kind())
        } else {
            write!(f, "{self}")
        }
    }
}

/// What a repair hint says after the setting's name.
const REPAIR_HINT: &str = "projects such matrices to the nearest positive-definite one";

/// [`Error::InvalidInformation`]'s message, the repair named by `name`.
fn information_message(
    from: VertexId,
    to: VertexId,
    problem: &InformationProblem,
    name: &dyn Fn(Setting) -> String,
) -> String {
    let message = format!("edge {from} → {to}: information matrix {problem}");
    match problem {
        InformationProblem::NotPositiveDefinite { .. } => {
            format!("{message}; {} {REPAIR_HINT}", name(Setting::RepairAdded))
        }
        _ => message,
    }
}

/// [`Error::Read`]'s message: the reader's, whose repair hint names the
/// command line's flag, with the repair named by `name`.
fn read_message(e: &ReadError, name: &dyn Fn(Setting) -> String) -> String {
    match e {
        ReadError::Line {
            path,
            line,
            problem: LineProblem::InformationNotPositiveDefinite { min_eigenvalue },
        } => format!(
            "{}:{line}: information matrix is not positive definite (smallest eigenvalue \
             {min_eigenvalue:e}); {} {REPAIR_HINT}",
            path.display(),
            name(Setting::RepairRead)
        ),
        other => other.to_string(),
    }
}

/// An initial guess as the options name it.
fn initialization_name(i: crate::Initialization) -> &'static str {
    use crate::Initialization as I;
    match i {
        I::File => "file",
        I::Odometry => "odometry",
        I::Chordal => "chordal",
        I::Previous => "previous",
    }
}

fn list_ids(ids: &[VertexId]) -> String {
    let shown: Vec<String> = ids.iter().take(10).map(|i| i.to_string()).collect();
    if ids.len() > 10 {
        format!("{} …", shown.join(", "))
    } else {
        shown.join(", ")
    }
}

impl From<crate::solve::SolveError> for Error {
    fn from(e: crate::solve::SolveError) -> Self {
        use crate::solve::SolveError;
        match e {
            SolveError::Unconstrained { gauge, vertices } => {
                Self::Unconstrained { gauge, vertices }
            }
            SolveError::NotPositiveDefinite { vertex } => Self::Undetermined { vertex },
            SolveError::NonFiniteStart => Self::NonFinite,
            other => Self::Internal(other.to_string()),
        }
    }
}
