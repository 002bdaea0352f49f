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

/// Writes a 2D graph as g2o to `path`.
pub fn write_graph(graph: &pgo::graph::Graph<pgo::geometry::Se2, 3>, path: &Path) {
    let mut f = std::io::BufWriter::new(std::fs::File::create(path).expect("create"));
    pgo::io::g2o::write_graph(graph, &[], &mut f).expect("write");
}

/// For every loop candidate (an edge between poses not one apart) of a
/// `pgo corrupt --labels` CSV (`edge,from,to,wrong`), in file order,
/// whether it is wrong.
pub fn candidate_wrong(labels_csv: &str) -> Vec<bool> {
    labels_csv
        .lines()
        .skip(1)
        .filter_map(|line| {
            let f: Vec<&str> = line.split(',').collect();
            let (from, to): (u64, u64) = (f[1].parse().ok()?, f[2].parse().ok()?);
            (from.abs_diff(to) != 1).then(|| f[3] == "1")
        })
        .collect()
}

/// A simulated planar graph as the tests take it apart: the noisy graph in
/// the library's insides (written as g2o by the simulator and read back,
/// the same numbers), and which of its edges are wrong.
pub struct Simulated {
    pub noisy: pgo::graph::Graph<pgo::geometry::Se2, 3>,
    pub wrong: Vec<bool>,
}

/// [`pgo_sim::simulate_planar`], taken apart ([`Simulated`]).
pub fn simulate_planar(
    options: &pgo_sim::SimulationOptions,
) -> Result<Simulated, pgo_sim::SimulationError> {
    let sim = pgo_sim::simulate_planar(options)?;
    let dir = tempfile::tempdir().expect("temporary directory");
    let path = dir.path().join("simulated.g2o");
    sim.noisy.write_g2o(&path).expect("write");
    let noisy = match pgo::io::g2o::read(&path, Default::default())
        .expect("read back")
        .graph
    {
        pgo::graph::AnyGraph::Planar(g) => g,
        pgo::graph::AnyGraph::Spatial(_) => unreachable!("a grid is planar"),
    };
    Ok(Simulated {
        noisy,
        wrong: sim.wrong,
    })
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
