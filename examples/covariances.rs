//! Times pgo's marginal covariances on a g2o file and prints them, as JSON
//! on stdout, for `scripts/bench_covariance.py` and
//! `scripts/gtsam_covariance.py` (which compare them with GTSAM's
//! `Marginals` side by side).
//!
//! ```text
//! cargo run --release --example covariances -- FILE [--pairs 100 1000] [--seed 1]
//!     [--dump 12] [--threads 1] [--map]
//! ```
//!
//! Optimises the file with the default options (one thread unless
//! `--threads`), then times [`pgo::AnySolution::covariances`] (factorisation
//! and selected inverse), reading every pose's covariance, and the joint
//! covariance of each of `--pairs` random pairs of distinct poses (drawn
//! from `--seed`). Prints the times, the factor's size, the process's
//! resident memory before the covariances and its peak after them
//! (`/proc/self/status`), the pairs, the edges out of the map (rejected
//! loop candidates, by edge index), the covariances of `--dump` poses
//! spread over the graph and the joint and relative covariances of the
//! first `--dump` pairs (each matrix row by row), and with `--map` the
//! optimised poses.

use pgo::{AnyPoseGraph, Options};
use serde_json::{Value, json};
use std::time::Instant;

/// The command line: the file and the options above.
struct Args {
    file: String,
    pairs: Vec<usize>,
    seed: u64,
    dump: usize,
    threads: usize,
    map: bool,
}

fn parse_args() -> Result<Args, String> {
    let mut args = Args {
        file: String::new(),
        pairs: vec![100, 1000],
        seed: 1,
        dump: 12,
        threads: 1,
        map: false,
    };
    let mut it = std::env::args().skip(1).peekable();
    let number = |v: Option<String>, name: &str| -> Result<u64, String> {
        v.and_then(|v| v.parse().ok())
            .ok_or_else(|| format!("{name} takes a number"))
    };
    while let Some(a) = it.next() {
        match a.as_str() {
            "--pairs" => {
                args.pairs.clear();
                while let Some(n) = it.next_if(|v| !v.starts_with("--")) {
                    args.pairs.push(number(Some(n), "--pairs")? as usize);
                }
            }
            "--seed" => args.seed = number(it.next(), "--seed")?,
            "--dump" => args.dump = number(it.next(), "--dump")? as usize,
            "--threads" => args.threads = number(it.next(), "--threads")? as usize,
            "--map" => args.map = true,
            _ if args.file.is_empty() && !a.starts_with("--") => args.file = a,
            _ => return Err(format!("unexpected argument {a}")),
        }
    }
    if args.file.is_empty() {
        return Err(
            "usage: covariances FILE [--pairs N…] [--seed S] [--dump K] [--threads T] [--map]"
                .into(),
        );
    }
    Ok(args)
}

/// A line of `/proc/self/status` in MB (`VmRSS`, `VmHWM`); 0 elsewhere.
fn memory_mb(key: &str) -> f64 {
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    status
        .lines()
        .find_map(|l| {
            l.strip_prefix(key)?
                .trim()
                .strip_suffix("kB")?
                .trim()
                .parse::<f64>()
                .ok()
        })
        .map_or(0.0, |kb| kb * 1024.0 / 1e6)
}

/// `count` pairs of distinct ids, drawn by a 64-bit LCG from `seed`.
fn random_pairs(ids: &[u64], count: usize, seed: u64) -> Vec<(u64, u64)> {
    let mut state = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
    let mut next = |n: usize| {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((state >> 11) % n as u64) as usize
    };
    let mut pairs = Vec::with_capacity(count);
    while pairs.len() < count && ids.len() > 1 {
        let (a, b) = (next(ids.len()), next(ids.len()));
        if a != b {
            pairs.push((ids[a], ids[b]));
        }
    }
    pairs
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args = parse_args()?;
    let graph = AnyPoseGraph::read_g2o(&args.file)?;
    let mut options = Options::default();
    options.solver.threads = args.threads;
    let start = Instant::now();
    let solution = graph.optimize(&options)?;
    let optimize_s = start.elapsed().as_secs_f64();
    let rss_before = memory_mb("VmRSS:");

    let start = Instant::now();
    let covariances = solution.covariances()?;
    let factorize_s = start.elapsed().as_secs_f64();
    let ids = covariances.ids().to_vec();
    let start = Instant::now();
    let mut trace = 0.0;
    for &id in &ids {
        let c = covariances.pose(id)?;
        trace += (0..covariances.size())
            .map(|k| c[k * covariances.size() + k])
            .sum::<f64>();
    }
    let all_poses_s = start.elapsed().as_secs_f64();
    let mut pair_runs = Vec::new();
    for &count in &args.pairs {
        let pairs = random_pairs(&ids, count, args.seed);
        let start = Instant::now();
        for &(a, b) in &pairs {
            trace += covariances.joint(a, b)?[0];
        }
        pair_runs
            .push(json!({"count": count, "time_s": start.elapsed().as_secs_f64(), "pairs": pairs}));
    }
    let peak = memory_mb("VmHWM:");

    // Spread over the graph, the first and the last pose among them.
    let mut dump_ids: Vec<u64> = (0..args.dump)
        .map(|k| ids[k * (ids.len() - 1) / (args.dump - 1).max(1)])
        .collect();
    dump_ids.dedup();
    let dump_pairs = random_pairs(&ids, args.dump, args.seed + 1);
    let dump = json!({
        "poses": dump_ids.iter().map(|&id| Ok(json!([id, covariances.pose(id)?])))
            .collect::<Result<Vec<Value>, pgo::Error>>()?,
        "joint": dump_pairs.iter().map(|&(a, b)| Ok(json!([a, b, covariances.joint(a, b)?])))
            .collect::<Result<Vec<Value>, pgo::Error>>()?,
        "relative": dump_pairs.iter().map(|&(a, b)| Ok(json!([a, b, covariances.relative(a, b)?])))
            .collect::<Result<Vec<Value>, pgo::Error>>()?,
    });
    let out_of_map: Vec<usize> = (solution.loops().iter())
        .filter(|l| !l.accepted)
        .map(|l| l.index)
        .collect();
    let mut out = json!({
        "file": args.file,
        "dimension": graph.dimension(),
        "poses": ids.len(),
        "edges": graph.num_edges(),
        "loop_candidates": graph.num_loop_candidates(),
        "out_of_map": out_of_map,
        "first_id": graph.ids()[0],
        "threads": args.threads,
        "optimize_s": optimize_s,
        "factorize_s": factorize_s,
        "all_poses_s": all_poses_s,
        "pairs": pair_runs,
        "factor_values": covariances.factor_values(),
        "rss_before_mb": rss_before,
        "peak_rss_mb": peak,
        "trace": trace,
        "dump": dump,
    });
    if args.map {
        let poses: Vec<Value> = ids
            .iter()
            .map(|&id| json!([id, solution.pose(id).unwrap_or_default()]))
            .collect();
        out["map"] = Value::from(poses);
    }
    println!("{out}");
    Ok(())
}
