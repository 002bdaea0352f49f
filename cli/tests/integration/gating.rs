//! Gating through `pgo optimize` on graphs from `pgo simulate`: degenerate
//! counts are reported before optimisation, and the χ² test fails when
//! wrong loops are let in on purpose. (The learned `T_GV` alone is the
//! library's tests/gating.rs.)

use crate::common::{pgo, stderr, temp_dir, verdict_status};

/// Runs `pgo simulate` with `args` into `dir/name` and returns the path.
fn simulated(dir: &std::path::Path, name: &str, args: &[&str]) -> String {
    let path = dir.join(name).to_string_lossy().into_owned();
    let mut all = vec!["simulate", "-o", &path];
    all.extend_from_slice(args);
    let out = pgo(&all);
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    path
}

fn report(args: &[&str]) -> serde_json::Value {
    let mut all = vec!["optimize", "--json", "-q"];
    all.extend_from_slice(args);
    let out = pgo(&all);
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(
        out.status.code(),
        Some(verdict_status(&report)),
        "{}",
        stderr(&out)
    );
    report
}

#[test]
fn degenerate_counts_are_reported_before_optimisation() {
    let dir = temp_dir("degenerate");
    // 3 true loops among 300 wrong candidates.
    let few = simulated(
        &dir,
        "few.g2o",
        &[
            "--poses",
            "600",
            "--loops",
            "3",
            "--outliers",
            "300",
            "--inliers",
            "--seed",
            "5",
        ],
    );
    let r = report(&[&few]);
    assert_eq!(r["gate"]["degenerate"], true, "{}", r["gate"]);
    assert!(r["gate"]["reason"].as_str().is_some_and(|s| !s.is_empty()));
    assert!(r["warnings"].to_string().contains("degenerate"));
    // The default policy (keep-all) leaves them to EM.
    assert_eq!(r["gate"]["policy"], "keep_all");
    assert!(r["gate"]["kept"].as_u64().unwrap() > 0);
    // drop-all drops every candidate: only odometry is optimised.
    let r = report(&[&few, "--degenerate", "drop-all"]);
    assert_eq!(r["gate"]["degenerate"], true, "{}", r["gate"]);
    assert_eq!(r["gate"]["kept"], 0);
    assert!(
        r["loops"]
            .as_array()
            .unwrap()
            .iter()
            .all(|l| l["weight"] == 0.0)
    );
    assert!(r["warnings"].to_string().contains("degenerate"));

    // All counts equal, and a single candidate: the same verdict, said plainly.
    let clean = simulated(
        &dir,
        "clean.g2o",
        &["--poses", "300", "--loops", "40", "--seed", "6"],
    );
    let text = std::fs::read_to_string(&clean).unwrap();
    let mut equal = String::new();
    let mut single = String::new();
    let mut first_loop = true;
    for line in text.lines() {
        let f: Vec<&str> = line.split_whitespace().collect();
        let is_loop = f[0] == "EDGE_SE2"
            && f[1]
                .parse::<i64>()
                .unwrap()
                .abs_diff(f[2].parse::<i64>().unwrap())
                != 1;
        equal.push_str(line);
        single.push_str(line);
        if is_loop {
            equal.push_str(" 42");
            if first_loop {
                single.push_str(" 42");
                first_loop = false;
            }
        }
        equal.push('\n');
        single.push('\n');
    }
    for (name, text, reason) in [
        ("equal.g2o", equal, "all 40 non-zero inlier counts equal 42"),
        ("single.g2o", single, "only 1 non-zero inlier counts"),
    ] {
        let path = crate::common::write(&dir, name, &text);
        let out = pgo(&["optimize", path.to_str().unwrap()]);
        assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
        let err = stderr(&out);
        assert!(err.contains(reason), "{name}: {err}");
        assert!(err.contains("degenerate"), "{name}: {err}");
    }
}

#[test]
fn chi2_test_fails_when_wrong_loops_are_let_in_on_purpose() {
    let dir = temp_dir("chi2-gate");
    let g = simulated(
        &dir,
        "g.g2o",
        &[
            "--poses",
            "800",
            "--loops",
            "200",
            "--outliers",
            "40",
            "--inliers",
            "--seed",
            "7",
        ],
    );
    // The default pipeline (learned gate, then EM weights for the few wrong
    // candidates above T_GV): the χ² test passes.
    let gated = report(&[&g]);
    assert_eq!(gated["chi2_test"]["passed"], true, "{}", gated["chi2_test"]);
    // `--gate 0` keeps every candidate, the wrong ones included: it fails.
    let open = report(&[&g, "--gate", "0", "--robust", "none"]);
    assert_eq!(open["gate"]["dropped"], 0);
    assert_eq!(open["chi2_test"]["passed"], false, "{}", open["chi2_test"]);
    assert!(open["chi2_test"]["d2"].as_f64() > open["chi2_test"]["critical"].as_f64());
}

#[test]
fn simulate_plants_wrong_candidates_with_the_count_models_asked_for() {
    let dir = temp_dir("simulate-wrong");
    let labels = dir.join("labels.csv").to_string_lossy().into_owned();
    let g = simulated(
        &dir,
        "g.g2o",
        &[
            "--poses",
            "500",
            "--loops",
            "100",
            "--wrong",
            "50",
            "--wrong-mode",
            "grouped",
            "--true-inliers",
            "300,0.2",
            "--wrong-inliers",
            "12,0.3",
            "--labels",
            &labels,
        ],
    );
    let text = std::fs::read_to_string(&labels).unwrap();
    let wrong: Vec<bool> = text.lines().skip(1).map(|l| l.ends_with(",1")).collect();
    assert_eq!(wrong.iter().filter(|&&w| w).count(), 50);
    // Every loop candidate carries a count from its model: the wrong ones
    // far below the true ones (medians 12 and 300, σ 0.3 and 0.2).
    let edges: Vec<Vec<String>> = std::fs::read_to_string(&g)
        .unwrap()
        .lines()
        .filter(|l| l.starts_with("EDGE_SE2"))
        .map(|l| l.split_whitespace().map(str::to_owned).collect())
        .collect();
    assert_eq!(edges.len(), wrong.len());
    for (f, &w) in edges.iter().zip(&wrong) {
        if f.len() == 13 {
            let n: u64 = f[12].parse().unwrap();
            assert!(if w { n < 60 } else { n > 80 }, "{f:?} wrong={w}");
        } else {
            assert!(!w && f.len() == 12, "{f:?}");
        }
    }
    for bad in ["0", "-3,0.5", "150,-1", "x", "150,nan"] {
        let flag = format!("--true-inliers={bad}");
        let out = pgo(&["simulate", "-o", "/dev/null", &flag]);
        assert_eq!(out.status.code(), Some(2), "{bad}: {}", stderr(&out));
        assert!(
            stderr(&out).contains("MEDIAN") || stderr(&out).contains("median"),
            "{bad}: {}",
            stderr(&out)
        );
    }
}

#[test]
fn a_map_without_any_loop_says_so() {
    // A gate above every count leaves no candidate: the map is the
    // odometry's, which has no χ² test; the report says both.
    let dir = temp_dir("no-loop");
    let g = simulated(
        &dir,
        "g.g2o",
        &["--poses", "200", "--loops", "20", "--inliers"],
    );
    let out = dir.join("out.g2o").to_string_lossy().into_owned();
    let r = report(&[&g, "-o", &out, "--gate", "100000"]);
    let warnings: Vec<&str> = (r["warnings"].as_array().unwrap().iter())
        .map(|w| w.as_str().unwrap())
        .collect();
    assert!(
        warnings
            .iter()
            .any(|w| w.starts_with("none of the 20 loop candidates was accepted")),
        "{warnings:?}"
    );
    assert!(r["chi2_test"].is_null(), "{}", r["chi2_test"]);
}
