//! Replays of dataset files with aliased candidates (skipped without the
//! datasets): the map and decisions of the last update are the batch
//! job's, and an update whose EM decisions swing from the last update's
//! runs the whole job instead.

use crate::common::{TempDir, datasets, pgo, stderr, temp_dir};
use pgo::{AnyPoseGraph, Options, UpdateSolve};
use std::path::{Path, PathBuf};

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

fn numbers(t: &[&str]) -> Vec<f64> {
    t.iter().map(|s| s.parse::<f64>().unwrap()).collect()
}

/// The dataset `name` with 100 aliased candidates in groups of 5, half of
/// them with true-loop-like counts (`pgo corrupt` with `seed`): the
/// temporary directory that holds it and its path; `None` without the
/// datasets.
fn aliased(name: &str, seed: u64) -> Option<(TempDir, PathBuf)> {
    let dir = datasets()?;
    let work = temp_dir("replays");
    let file = work.join(format!("{name}-aliased-{seed}.g2o"));
    let src = dir.join(format!("{name}.g2o"));
    let seed = seed.to_string();
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
        &seed,
    ]);
    assert!(out.status.success(), "{}", stderr(&out));
    Some((work, file))
}

/// A g2o file's vertices (id, numbers) and edge lines (split).
type Records = (Vec<(u64, Vec<f64>)>, Vec<Vec<String>>);

/// The [`Records`] of `file`, for the 2D (`dimension` 2) or 3D tags.
fn read(file: &Path, dimension: usize) -> Records {
    let (vertex, edge, n) = match dimension {
        2 => ("VERTEX_SE2", "EDGE_SE2", 3),
        _ => ("VERTEX_SE3:QUAT", "EDGE_SE3:QUAT", 7),
    };
    let text = std::fs::read_to_string(file).unwrap();
    let (mut poses, mut edges) = (Vec::new(), Vec::new());
    for line in text.lines() {
        let t: Vec<&str> = line.split_whitespace().collect();
        match t.first() {
            Some(&tag) if tag == vertex => {
                poses.push((t[1].parse::<u64>().unwrap(), numbers(&t[2..2 + n])))
            }
            Some(&tag) if tag == edge => edges.push(t.iter().map(|s| s.to_string()).collect()),
            _ => {}
        }
    }
    (poses, edges)
}

/// Adds edge line `t` (measurement `m` numbers, information of a `d × d`
/// matrix) to `graph`: a loop candidate when it has a count.
fn add(graph: &mut AnyPoseGraph, t: &[String], (m, d): (usize, usize)) {
    let t: Vec<&str> = t.iter().map(String::as_str).collect();
    let (i, j): (u64, u64) = (t[1].parse().unwrap(), t[2].parse().unwrap());
    let upper = d * (d + 1) / 2;
    let (z, info) = (
        numbers(&t[3..3 + m]),
        full(&numbers(&t[3 + m..3 + m + upper]), d),
    );
    match t.get(3 + m + upper) {
        Some(n) => graph.add_loop_candidate(i, j, &z, &info, Some(n.parse().unwrap())),
        None => graph.add_edge(i, j, &z, &info),
    }
    .unwrap();
}

/// Adds the edges (g2o lines) whose later end is in `ids`, as [`add`] does.
fn add_ending_in(
    graph: &mut AnyPoseGraph,
    edges: &[Vec<String>],
    ids: std::ops::Range<u64>,
    sizes: (usize, usize),
) {
    for t in edges {
        let (i, j): (u64, u64) = (t[1].parse().unwrap(), t[2].parse().unwrap());
        if ids.contains(&i.max(j)) {
            add(graph, t, sizes);
        }
    }
}

/// The aliasing benchmark's intel file, replayed every 100 poses, ends
/// with the batch job's decisions and map. Its last updates judge clusters
/// whose own loops are nearly all that ties the newest poses to the map
/// (`S = Σ_A − M_AA` close to singular): judged from the factorisation of
/// `H` one step before the map, as updates once did, `S` came out
/// indefinite, those candidates unchecked, an aliased group accepted and
/// the true loops next to it rejected.
#[test]
fn an_aliased_intel_replay_ends_with_the_batch_decisions() {
    let Some((_work, file)) = aliased("intel", 1_000_002) else {
        return;
    };
    let (poses, edges) = read(&file, 2);
    // Poses in file order (ids 0, 1, …), each edge once both its ends
    // exist, an update every 100 poses and after the last.
    let mut graph = AnyPoseGraph::new(2).unwrap();
    let options = Options::default();
    let mut last = None;
    for (k, (id, pose)) in poses.iter().enumerate() {
        graph.add_pose(*id, pose).unwrap();
        add_ending_in(&mut graph, &edges, *id..*id + 1, (3, 3));
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

/// On sphere2500's first 800 poses with aliased candidates, updated every
/// 100 poses: every update after the first resumes EM from the last
/// decisions, or runs the whole job (its decisions swung, or its map failed
/// the χ² test), says why, and lists exactly the earlier decisions it
/// changed; the last map is the batch job's. (Its updates at 600 and 700
/// poses swung while innovations were read at the map LM stopped at; read
/// at the exact map of the linearisation, none does.)
#[test]
fn updates_of_an_aliased_sphere_resume_em_or_say_why_and_end_at_the_batch_map() {
    let Some((_work, file)) = aliased("sphere2500", 1_000_001) else {
        return;
    };
    let (poses, edges) = read(&file, 3);
    let mut graph = AnyPoseGraph::new(3).unwrap();
    let options = Options::default();
    let mut swung = Vec::new();
    let mut reasons = Vec::new();
    let mut last: Option<pgo::AnySolution> = None;
    for end in (1..=8u64).map(|k| 100 * k) {
        for (id, pose) in poses.iter().filter(|(id, _)| (end - 100..end).contains(id)) {
            graph.add_pose(*id, pose).unwrap();
        }
        add_ending_in(&mut graph, &edges, end - 100..end, (7, 6));
        let s = graph.update(&options).unwrap();
        let inc = s.incremental().unwrap().clone();
        reasons.push(inc.reason.clone());
        if end > 100 && inc.solve != UpdateSolve::Batch {
            assert!(
                inc.reason.contains("EM's decisions from the last ones"),
                "{inc:?}"
            );
        }
        if end > 100 && inc.solve == UpdateSolve::Batch {
            assert!(
                inc.reason.contains("swung") || inc.reason.contains("failed the χ² test"),
                "{inc:?}"
            );
            // Counted since the last update, with the changes against it.
            assert_eq!(inc.new_poses, 100);
            assert!(inc.new_candidates > 0, "{inc:?}");
            let before = last.as_ref().unwrap().loops();
            let flipped: Vec<(usize, bool)> = (before.iter().zip(s.loops()))
                .filter(|(b, now)| b.accepted != now.accepted)
                .map(|(_, now)| (now.index, now.accepted))
                .collect();
            let listed: Vec<(usize, bool)> = (inc.changed.iter())
                .map(|c| (c.index, c.accepted))
                .collect();
            assert_eq!(listed, flipped);
            swung.push(end);
        }
        last = Some(s);
    }
    eprintln!("updates: {reasons:#?}; whole jobs after the first at {swung:?}");
    // The last map is the batch job's.
    let batch = graph.optimize(&options).unwrap();
    let last = last.unwrap();
    assert!((last.chi2() / batch.chi2() - 1.0).abs() < 1e-6);
    let accepted = |s: &pgo::AnySolution| s.loops().iter().map(|d| d.accepted).collect::<Vec<_>>();
    assert_eq!(accepted(&last), accepted(&batch));
}
