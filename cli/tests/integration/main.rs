//! Integration tests: one test binary (as nalgebra does), one module per
//! concern.

mod certify;
mod cli;
mod common;
mod covariance;
mod datasets;
mod faults;
mod gating;
mod hostile;
mod library;
mod replays;
mod trajectory;
// SIGKILL, and /proc to tell which leftover temporaries are stale.
#[cfg(target_os = "linux")]
mod killed;
