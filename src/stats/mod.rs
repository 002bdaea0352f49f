//! The statistics the method rests on: the χ² goodness-of-fit test of an
//! optimised graph ([`chi2`]).
//!
//! The χ² items are re-exported here, so `crate::stats::chi2_critical` and
//! the like name them directly.

pub mod chi2;

pub use chi2::{Chi2Test, DofConvention, StatsError, chi2_critical, normal_upper_quantile};
