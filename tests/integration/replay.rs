//! A replay of intel with aliased candidates (the aliasing benchmark's
//! file), an update every 100 poses, ends with the batch job's decisions
//! and map (skipped without the datasets). Its last updates judge clusters whose own loops are nearly
//! all that ties the newest poses to the map (`S = Σ_A − M_AA` close to
//! singular): judged from the factorisation of `H` one step before the
//! map, as updates once did, `S` came out indefinite, those candidates
//! unchecked, an aliased group accepted and the true loops next to it
//! rejected.

use crate::common::{datasets, pgo, stderr, temp_dir};
use pgo::{AnyPoseGraph, Options};

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
fn an_aliased_intel_replay_ends_with_the_batch_decisions() {
    let Some(dir) = datasets() else { return };
    let file = temp_dir("replay").join("intel-aliased.g2o");
    let src = dir.join("intel.g2o");
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
        "1000002",
    ]);
    assert!(out.status.success(), "{}", stderr(&out));
    let text = std::fs::read_to_string(&file).unwrap();
    let numbers = |t: &[&str]| {
        t.iter()
            .map(|s| s.parse::<f64>().unwrap())
            .collect::<Vec<_>>()
    };
    let (mut poses, mut edges) = (Vec::new(), Vec::new());
    for line in text.lines() {
        let t: Vec<&str> = line.split_whitespace().collect();
        match t.first().copied() {
            Some("VERTEX_SE2") => poses.push((t[1].parse::<u64>().unwrap(), numbers(&t[2..5]))),
            Some("EDGE_SE2") => edges.push(t),
            _ => {}
        }
    }
    // Poses in file order (ids 0, 1, …), each edge once both its ends
    // exist, an update every 100 poses and after the last.
    let mut graph = AnyPoseGraph::new(2).unwrap();
    let options = Options::default();
    let mut last = None;
    for (k, (id, pose)) in poses.iter().enumerate() {
        graph.add_pose(*id, pose).unwrap();
        for t in &edges {
            let (i, j): (u64, u64) = (t[1].parse().unwrap(), t[2].parse().unwrap());
            if i.max(j) != *id {
                continue;
            }
            let (z, info) = (numbers(&t[3..6]), full(&numbers(&t[6..12]), 3));
            match t.get(12) {
                Some(n) => graph.add_loop_candidate(i, j, &z, &info, Some(n.parse().unwrap())),
                None => graph.add_edge(i, j, &z, &info),
            }
            .unwrap();
        }
        if (k + 1) % 100 == 0 || k + 1 == poses.len() {
            last = Some(graph.update(&options).unwrap());
        }
    }
    let batch = graph.optimize(&options).unwrap();
    let last = last.unwrap();
    let differ = (last.loops().iter().zip(batch.loops()))
        .filter(|(u, b)| u.accepted != b.accepted)
        .count();
    assert_eq!(differ, 0, "decisions differing from batch");
    assert!((last.chi2() / batch.chi2() - 1.0).abs() < 1e-6);
    // No candidate went unchecked for want of a positive definite `S`.
    let unchecked = |s: &pgo::AnySolution| {
        (s.loops().iter())
            .filter(|d| d.innovation.is_none() && d.accepted)
            .count()
    };
    assert_eq!(unchecked(&last), unchecked(&batch));
}
