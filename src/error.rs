//! Why a call of the library failed: [`Error`], one enum for the whole
//! public API, each variant naming what was wrong (the vertex id, the edge,
//! the option as the command line spells it, the file and line).

use crate::graph::VertexId;
use crate::io::g2o::ReadError;
use std::path::PathBuf;

/// Why a call of the library failed.
#[derive(Debug, thiserror::Error)]
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
    /// definite (and was not repaired).
    #[error("edge {from} → {to}: information matrix {problem}")]
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
    #[error("--{option} {message}")]
    InvalidOption {
        /// The option as the command line spells it, without `--`.
        option: &'static str,
        /// What is wrong, with the value given.
        message: String,
    },
    /// A g2o file is unreadable or malformed (the file and line are named).
    #[error(transparent)]
    Read(#[from] ReadError),
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
        "edge {edge} (vertex {from} → {to}) has a non-finite χ² at the initial guess: \
         its measurement, information or poses are too large"
    )]
    NonFiniteEdge {
        /// The edge's index, as returned when it was added.
        edge: usize,
        /// Its first vertex id.
        from: VertexId,
        /// Its second vertex id.
        to: VertexId,
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
    /// The matrix is not positive definite.
    #[error(
        "is not positive definite (smallest eigenvalue {min_eigenvalue:e}); \
         PoseGraph::set_repair_information(true) projects such matrices to the nearest \
         positive-definite one"
    )]
    NotPositiveDefinite {
        /// Its smallest eigenvalue (NaN if it could not be computed).
        min_eigenvalue: f64,
    },
    /// Repair was asked for, but the matrix is zero or too large to
    /// decompose.
    #[error("cannot be made positive definite (it is zero, or too large to decompose)")]
    NotRepairable,
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
