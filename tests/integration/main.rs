//! Integration tests: one test binary (as nalgebra does), one module per
//! concern.

mod cli;
mod common;
mod datasets;
mod robust;
