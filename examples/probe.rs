//! One dataset's linear algebra in isolation: size of the factor, its
//! supernodes and flops, and the minimum time of one linearisation, one
//! numeric factorisation and one solve over `REPS` repetitions.
//!
//! `cargo run --release --features internals --example probe -- FILE.g2o
//! [REPS] [THREADS]` (pgo's insides, through the hidden `pgo::internals`
//! hook: no stability promise).
//! (`PROBE_LIN=1`: time only the linearisation, e.g. under `perf`).
use pgo::internals::{
    AnyGraph as AnyPoseGraph, ChordalInit, G2oPose, Graph as PoseGraph, Initialization, Optimizer,
    ReadOptions, SolveSettings, initialize, read,
};
use std::time::Instant;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let path = &args[1];
    let reps: usize = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(5);
    let threads: usize = args.get(3).and_then(|s| s.parse().ok()).unwrap_or(1);
    let fix = path.contains("cubicle");
    let file = read(
        std::path::Path::new(path),
        ReadOptions {
            fix_information: fix,
        },
    )
    .unwrap();
    match file.graph {
        AnyPoseGraph::Planar(g) => probe(g, &file.missing, reps, threads),
        AnyPoseGraph::Spatial(g) => probe(g, &file.missing, reps, threads),
    }
}

fn probe<P: G2oPose<D> + ChordalInit<D>, const D: usize>(
    mut g: PoseGraph<P, D>,
    missing: &[usize],
    reps: usize,
    threads: usize,
) {
    initialize(&mut g, missing, Initialization::File, None).unwrap();
    let t = Instant::now();
    let mut opt = Optimizer::new(
        &g,
        None,
        SolveSettings {
            threads,
            ..Default::default()
        },
    )
    .unwrap();
    let setup = t.elapsed().as_secs_f64();
    let (sn, flops) = opt.system().factor_stats();
    println!(
        "setup {:.4}s nnz_h {} nnz_l {} supernodes {} flops {:.3e}",
        setup,
        opt.system().nnz_hessian(),
        opt.system().nnz_factor(),
        sn,
        flops
    );
    if std::env::var_os("PROBE_LIN").is_some() {
        let t = Instant::now();
        for _ in 0..reps {
            opt.linearize(&g, None);
        }
        println!(
            "linearize x{reps}: {:.5}s each",
            t.elapsed().as_secs_f64() / reps as f64
        );
        return;
    }
    let mut lin = f64::MAX;
    let mut fac = f64::MAX;
    let mut sol = f64::MAX;
    let mut step = vec![0.0; opt.system().num_blocks() * D];
    for _ in 0..reps {
        let t = Instant::now();
        opt.linearize(&g, None);
        lin = lin.min(t.elapsed().as_secs_f64());
        let t = Instant::now();
        opt.system_mut().factorize(1e-6).unwrap();
        fac = fac.min(t.elapsed().as_secs_f64());
        let t = Instant::now();
        opt.system_mut().solve(&mut step);
        sol = sol.min(t.elapsed().as_secs_f64());
    }
    println!(
        "min over {reps}: linearize {:.5}s factorize {:.5}s ({:.2} Gflop/s) solve {:.5}s",
        lin,
        fac,
        flops / fac / 1e9,
        sol
    );
}
