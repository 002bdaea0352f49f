//! pgo: pose-graph SLAM back end with unsupervised loop-closure gating.
pub mod geometry;
pub mod graph;
pub mod io;
pub mod linear;
pub mod solve;
pub mod pipeline;
pub mod report;
