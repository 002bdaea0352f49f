//! The statistics the method rests on: the χ² goodness-of-fit test of an
//! optimised graph ([`chi2`]), mixtures of normal distributions fitted by EM
//! ([`mixture`]) and accelerated by SQUAREM ([`squarem`]) and Newton steps
//! near the optimum, and how far apart two weighted normals are and where
//! their densities cross ([`separation`]).
//!
//! The χ² items are re-exported here, so `crate::stats::chi2_critical` and
//! the like name them directly.

pub mod chi2;
pub mod log_chi2;
pub mod mixture;
pub mod separation;
pub mod squarem;

pub use chi2::{Chi2Test, DofConvention, StatsError, chi2_critical};
