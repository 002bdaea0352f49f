//! Shared helpers: the binary, temporary files, the public datasets.

use std::process::{Command, Output};

// The library's test fixtures: temporary directories, files, datasets.
#[path = "../../../tests/common/mod.rs"]
mod fixtures;
pub use fixtures::{TempDir, datasets, temp_dir, write};

/// Runs the `pgo` binary with `args`.
pub fn pgo(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_pgo"))
        .args(args)
        .output()
        .expect("run pgo")
}

/// stderr as text.
pub fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// A bundled sample file, as an argument of the binary.
pub fn sample(name: &str) -> String {
    fixtures::sample(name).to_string_lossy().into_owned()
}

/// The exit status `pgo optimize` gives for its JSON report: 3 when the χ²
/// test failed, 4 when its budget stopped it, 0 otherwise.
pub fn verdict_status(report: &serde_json::Value) -> i32 {
    let stop = report["optimizer"]["stop_reason"].as_str();
    if report["chi2_test"]["passed"] == serde_json::Value::Bool(false) {
        3
    } else if matches!(stop, Some("time_limit" | "max_iterations")) {
        4
    } else {
        0
    }
}
