//! The command line is the library's job on a file: `pgo optimize FILE -o
//! OUT --json` with some options writes the poses and reports the decisions
//! of `PoseGraph::read_g2o(FILE)?.optimize(&options)`.

use crate::common::{sample, temp_dir};
use pgo::{Options, PoseGraph, Se2, Se3, Solution};
use std::path::Path;

fn check<P: pgo::GraphPose<D>, const D: usize>(name: &str, options: &Options) {
    let input = sample(name);
    let solution = PoseGraph::<P, D>::read_g2o(&input)
        .unwrap()
        .optimize(options)
        .unwrap();
    let dir = temp_dir(&format!("library-{name}"));
    same_as_the_cli(Path::new(&input), &dir, options, &solution);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_planar_file_gives_the_library_s_job() {
    check::<Se2, 3>("grid2d.g2o", &Options::default());
}

#[test]
fn the_flags_reach_the_job_as_the_options_do() {
    let mut o = Options::default();
    o.set("robust-c", "4").unwrap();
    o.set("max-iters", "60").unwrap();
    o.set("alpha", "0.01").unwrap();
    check::<Se2, 3>("grid2d.g2o", &o);
}

#[test]
fn a_spatial_file_gives_the_library_s_job() {
    check::<Se3, 6>("sphere3d.g2o", &Options::default());
}

/// `pgo optimize FILE -o OUT --json` with the same options: the poses it
/// writes are the solution's, bit for bit, and its JSON decides as the
/// solution's report does.
fn same_as_the_cli<P: pgo::GraphPose<D>, const D: usize>(
    input: &Path,
    dir: &Path,
    options: &Options,
    solution: &Solution<P>,
) {
    let out = dir.join("out.g2o");
    let mut args: Vec<String> = vec![
        "optimize".into(),
        input.display().to_string(),
        "-o".into(),
        out.display().to_string(),
        "--json".into(),
        "--quiet".into(),
    ];
    if options.robust.method == pgo::RobustMethod::Gnc {
        args.extend(["--robust".into(), "gnc".into()]);
    }
    if let Some(c) = options.robust.c {
        args.extend(["--robust-c".into(), c.to_string()]);
    }
    if let Some(n) = options.solver.max_iterations {
        args.extend(["--max-iters".into(), n.to_string()]);
    }
    args.extend(["--alpha".into(), options.test.alpha.to_string()]);
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_pgo"))
        .args(&args)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let cli: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let api: serde_json::Value =
        serde_json::from_str(&solution.report().to_json().unwrap()).unwrap();
    for field in [
        "loops",
        "chi2_test",
        "gate",
        "robust",
        "input_chi2",
        "edges",
    ] {
        assert_eq!(cli[field], api[field], "{field}");
    }
    for field in ["final_chi2", "iterations", "history"] {
        assert_eq!(cli["optimizer"][field], api["optimizer"][field], "{field}");
    }
    let written = PoseGraph::<P, D>::read_g2o(&out).unwrap();
    for (id, p) in solution.poses() {
        let q = written.pose(id).unwrap();
        let same = p
            .log()
            .iter()
            .zip(q.log().iter())
            .all(|(x, y)| x.to_bits() == y.to_bits());
        assert!(same, "vertex {id}: {p:?} vs {q:?}");
    }
}
