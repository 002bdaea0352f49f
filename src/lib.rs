//! pgo: pose-graph SLAM back end with unsupervised loop-closure gating.
pub mod geometry;
pub mod graph;
pub mod simulate;
