//! An update whose EM decisions swing from the last update's — the new
//! evidence overturned them — runs the whole job instead, says so, and
//! lists the decisions it changed (sphere2500 with aliased candidates;
//! skipped without the datasets).

use crate::common::{datasets, pgo, stderr, temp_dir};
use pgo::{AnyPoseGraph, Options, UpdateSolve};

/// g2o's upper triangle (row by row) as the full `n × n` matrix.
fn full(upper: &[f64], n: usize) -> Vec<f64> {
    let mut m = vec![0.0; n * n];
    let mut k = 0;
    for r in 0..n {
        for c in r..n {
            (m[r * n + c], m[c * n + r]) = (upper[k], upper[k]);
            k += 1;
        }
    }
    m
}

#[test]
fn an_update_whose_decisions_swing_runs_the_whole_job() {
    let Some(dir) = datasets() else { return };
    let file = temp_dir("swing").join("sphere2500-aliased.g2o");
    let src = dir.join("sphere2500.g2o");
    let out = pgo(&[
        "corrupt",
        src.to_str().unwrap(),
        "-o",
        file.to_str().unwrap(),
        "--wrong",
        "100",
        "--wrong-mode",
        "aliased",
        "--group-size",
        "5",
        "--true-like-counts",
        "0.5",
        "--seed",
        "1000005",
    ]);
    assert!(out.status.success(), "{}", stderr(&out));
    // The first 300 poses in file order, each edge once both its ends
    // exist, an update every 100 poses.
    let text = std::fs::read_to_string(&file).unwrap();
    let numbers = |t: &[&str]| {
        t.iter()
            .map(|s| s.parse::<f64>().unwrap())
            .collect::<Vec<_>>()
    };
    let mut graph = AnyPoseGraph::new(3).unwrap();
    let (mut poses, mut edges) = (Vec::new(), Vec::new());
    for line in text.lines() {
        let t: Vec<&str> = line.split_whitespace().collect();
        match t.first().copied() {
            Some("VERTEX_SE3:QUAT") => {
                poses.push((t[1].parse::<u64>().unwrap(), numbers(&t[2..9])))
            }
            Some("EDGE_SE3:QUAT") => edges.push(t),
            _ => {}
        }
    }
    let options = Options::default();
    let mut swung = Vec::new();
    let mut last = None;
    for end in [100u64, 200, 300] {
        for (id, pose) in poses.iter().filter(|(id, _)| (end - 100..end).contains(id)) {
            graph.add_pose(*id, pose).unwrap();
        }
        for t in &edges {
            let (i, j): (u64, u64) = (t[1].parse().unwrap(), t[2].parse().unwrap());
            if i.max(j) >= end || i.max(j) < end - 100 {
                continue;
            }
            let (z, info) = (numbers(&t[3..10]), full(&numbers(&t[10..31]), 6));
            match t.get(31) {
                Some(n) => graph.add_loop_candidate(i, j, &z, &info, Some(n.parse().unwrap())),
                None => graph.add_edge(i, j, &z, &info),
            }
            .unwrap();
        }
        let s = graph.update(&options).unwrap();
        let inc = s.incremental().unwrap().clone();
        if inc.reason.contains("swung") {
            assert_eq!(inc.solve, UpdateSolve::Batch);
            // Counted since the last update, with the changes against it.
            assert_eq!(inc.new_poses, 100);
            assert!(inc.new_candidates > 0 && !inc.changed.is_empty(), "{inc:?}");
            swung.push(end);
        }
        last = Some(s);
    }
    assert!(!swung.is_empty(), "no update swung");
    // The last map is the batch job's.
    let batch = graph.optimize(&options).unwrap();
    let last = last.unwrap();
    assert!((last.chi2() / batch.chi2() - 1.0).abs() < 1e-6);
    let accepted = |s: &pgo::AnySolution| s.loops().iter().map(|d| d.accepted).collect::<Vec<_>>();
    assert_eq!(accepted(&last), accepted(&batch));
}
