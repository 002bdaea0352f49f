//! Shared helpers: the binary, temporary files, the public datasets.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// The repository's root (the command line's crate is `cli/` in it).
pub fn repository() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

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

/// A fresh temporary directory for one test.
pub fn temp_dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("pgo-it-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).expect("create temp dir");
    d
}

/// Writes `text` to `dir/name` and returns the path.
pub fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).expect("write test file");
    p
}

/// The public benchmark datasets: `$PGO_DATASETS`, else
/// `../shared/datasets` beside the repository. When they are absent,
/// `None` with the reason printed, so that the tests that need them skip —
/// unless `CI` is `true`, where a missing dataset directory fails the test.
pub fn datasets() -> Option<PathBuf> {
    let dir = std::env::var_os("PGO_DATASETS")
        .map(PathBuf::from)
        .unwrap_or_else(|| repository().join("../shared/datasets"));
    if dir.join("intel.g2o").is_file() {
        return Some(dir);
    }
    let reason = format!(
        "public datasets not found at {} (set PGO_DATASETS)",
        dir.display()
    );
    if std::env::var("CI").is_ok_and(|ci| ci == "true") {
        panic!("{reason}; CI=true, where the datasets must be present");
    }
    eprintln!("skipped: {reason}");
    None
}

/// A bundled sample file.
pub fn sample(name: &str) -> String {
    repository()
        .join("g2o_samples")
        .join(name)
        .to_string_lossy()
        .into_owned()
}

/// The exit status `pgo optimize` gives for its JSON report: 3 when the χ²
/// test failed, 0 otherwise.
pub fn verdict_status(report: &serde_json::Value) -> i32 {
    if report["chi2_test"]["passed"] == serde_json::Value::Bool(false) {
        3
    } else {
        0
    }
}
