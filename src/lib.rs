//! pgo: pose-graph SLAM back end with unsupervised loop-closure gating.

// The robust and I/O modules document how they work inside; their links to
// private items are for readers of the source.
#![allow(rustdoc::private_intra_doc_links)]
// Index loops over small fixed-size blocks read like the maths they implement.
#![allow(clippy::needless_range_loop)]
// No panics on bad input: errors are values. Tests may unwrap.
#![cfg_attr(not(test), deny(clippy::unwrap_used, clippy::expect_used))]
pub mod gate;
pub mod geometry;
pub mod graph;
pub mod io;
pub mod linear;
pub mod pipeline;
pub mod plot;
pub mod report;
pub mod robust;
pub mod simulate;
pub mod solve;
pub mod stats;
