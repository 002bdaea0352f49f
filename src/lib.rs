//! pgo: pose-graph SLAM back end with unsupervised loop-closure gating.
//!
//! Build a [`PoseGraph`] call by call (or read one with
//! [`PoseGraph::read_g2o`]), then [`PoseGraph::optimize`] it: the whole job of
//! `pgo optimize` — the geometric-verification gate learned from the loop
//! candidates' inlier counts, the robust weighting of the loops that are
//! left, and the χ² test of the result — in memory, returning the optimised
//! poses, a [`LoopDecision`] per loop candidate and the [`report::Report`]
//! the command line prints as JSON. [`Options`] says everything the job can
//! be told, by field or by the command line's flag names
//! ([`Options::set`]). [`AnyPoseGraph`] is the same graph with its
//! dimension chosen at run time, for bindings.
//!
//! ```
//! use pgo::{Options, PoseGraph2, Se2};
//! use pgo::nalgebra::Matrix3;
//!
//! let mut graph = PoseGraph2::new();
//! for k in 0..4 {
//!     graph.add_pose(k, Se2::new(k as f64, 0.0, 0.0))?;
//! }
//! for k in 1..4 {
//!     graph.add_edge(k - 1, k, Se2::new(1.0, 0.0, 0.0), Matrix3::identity())?;
//! }
//! graph.add_loop_candidate(0, 3, Se2::new(3.0, 0.0, 0.0), Matrix3::identity(), Some(120))?;
//! let solution = graph.optimize(&Options::default())?;
//! assert!(solution.loops()[0].accepted);
//! # Ok::<(), pgo::Error>(())
//! ```
//!
//! The library is the solver and its public API. The `pgo` command line
//! (`pgo-cli`), the simulator (`pgo-sim`) and the C and Python bindings are
//! crates of their own built on this API.
//!
//! # Features
//!
//! * `json` (default): [`report::Report::to_json`] and `Certificate::to_json`.
//! * `clap`: [`Options`] and its parts derive `clap::Args`, so a command
//!   line gets every option of the job as a flag (the `pgo` binary's).
//! * `plot`: the `plot` module and `Solution::write_plots`: the SVG
//!   pictures of a job (what `pgo optimize --plot DIR` writes), drawn with
//!   plotters.
//! * `internals`: internals for pgo's own benchmarks, probes and fuzz
//!   targets; no stability promise, not part of the API.

// The robust and I/O modules document how they work inside; their links to
// private items are for readers of the source.
#![allow(rustdoc::private_intra_doc_links)]
// Index loops over small fixed-size blocks read like the maths they implement.
#![allow(clippy::needless_range_loop)]
// No panics on bad input: errors are values. Tests may unwrap.
#![cfg_attr(not(test), deny(clippy::unwrap_used, clippy::expect_used))]

pub use nalgebra;

pub mod geometry;
pub mod output;
#[cfg(feature = "plot")]
pub mod plot;
pub mod report;

mod certify;
mod covariance;
mod error;
mod gate;
mod graph;
mod io;
mod job;
mod linear;
mod options;
mod pose_graph;
mod robust;
mod solution;
mod solve;
mod stats;

pub use certify::{
    Certificate, CertificateTime, CertifyError, ETA_RELATIVE as CERTIFICATE_ETA_RELATIVE,
    EigenvectorPose,
};
pub use covariance::{AnyCovariances, Covariances};
pub use error::{Error, ErrorKind, InformationProblem, PoseProblem, Setting};
pub use gate::{
    Component, Degeneracy, DegeneratePolicy, GateMode, LogNormalMixture, MixtureOptions, Threshold,
    ThresholdFit, learn_threshold,
};
pub use geometry::{Pose, Se2, Se3};
pub use graph::{INFORMATION_RANGE, VertexId};
pub use io::g2o::{LineProblem, ReadError};
pub use options::{
    CandidateRule, ExpertOptions, GateOptions, MAX_THREADS, MAX_TIME_LIMIT_S, Options,
    ROBUST_C_RANGE, RobustOptions, SolverOptions, TestOptions,
};
pub use pose_graph::{AnyPoseGraph, Edge, GraphPose, PoseGraph, PoseGraph2, PoseGraph3};
pub use report::{DecisionChange, IncrementalReport, MapStatus, UpdateSolve};
pub use robust::{LoopModel, RobustMethod};
pub use solution::{AnySolution, LoopDecision, Reason, Solution};
pub use solve::Method as SolverMethod;
pub use solve::init::Initialization;
pub use solve::{Cancel, Cancellable, IterationRecord, Observer, StopReason};
pub use stats::{Chi2Test, DofConvention};

/// Internals for pgo's own stage benchmarks, probes and fuzz targets
/// (benches/, examples/, fuzz/): no stability promise, not part of the API.
#[cfg(feature = "internals")]
#[doc(hidden)]
pub mod internals {
    pub use crate::graph::{AnyGraph, Graph};
    pub use crate::io::g2o::{
        G2oFile, G2oPose, ReadOptions, RewriteError, read, read_from, write_graph,
    };
    pub use crate::solve::init::{ChordalInit, Initialization, initialize};
    pub use crate::solve::{IterationRecord, Optimizer, SolveSettings};
}

/// The README's Rust example, compiled and run with the doctests.
#[cfg(doctest)]
#[doc = include_str!("../README.md")]
pub struct ReadmeDoctests;
