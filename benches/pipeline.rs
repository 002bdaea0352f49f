//! Benchmarks of the library, one stage at a time, on the public datasets
//! (`$PGO_DATASETS`, else `../shared/datasets`; skipped with a message when
//! absent) and on `pgo simulate` graphs:
//!
//! * `parse`: reading the g2o file;
//! * `linearize`: errors, Jacobians and assembly of `H` and `b` once;
//! * `factorize`: one numeric sparse Cholesky of `H`;
//! * `solve`: the two triangular solves;
//! * `optimize`: initial guess (chordal) and LM to convergence, from a fresh
//!   copy of the file's graph each time;
//! * `optimize_simulated_*`: the same on simulated graphs of 10⁴ and 10⁵
//!   poses (10⁶ with `PGO_BENCH_MILLION=1`).
//!
//! Run: `cargo bench --bench pipeline` (all) or e.g.
//! `cargo bench --bench pipeline -- factorize`. Single-threaded runs:
//! `RAYON_NUM_THREADS=1 PGO_BENCH_THREADS=1 cargo bench --bench pipeline`.

use divan::Bencher;
use pgo::graph::{AnyPoseGraph, PoseGraph};
use pgo::io::g2o::{self, G2oPose, ReadOptions};
use pgo::simulate::{AnySimulation, SimulationOptions, World};
use pgo::solve::init::{ChordalInit, Initialization, initialize};
use pgo::solve::{IterationRecord, Optimizer, SolverOptions};
use std::path::PathBuf;

fn main() {
    divan::main();
}

const DATASETS: &[&str] = &[
    "intel",
    "manhattan",
    "city10000",
    "sphere2500",
    "torus3D",
    "parking-garage",
    "cubicle",
];

fn threads() -> usize {
    std::env::var("PGO_BENCH_THREADS")
        .ok()
        .and_then(|t| t.parse().ok())
        .unwrap_or(0)
}

fn dataset(name: &str) -> Option<PathBuf> {
    let dir = std::env::var_os("PGO_DATASETS")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/datasets"));
    let path = dir.join(format!("{name}.g2o"));
    if path.is_file() {
        Some(path)
    } else {
        eprintln!(
            "skipped {name}: {} not found (set PGO_DATASETS)",
            path.display()
        );
        None
    }
}

fn read(name: &str) -> Option<g2o::G2oFile> {
    let path = dataset(name)?;
    // cubicle.g2o has indefinite information matrices (MANIFEST quirk 2).
    let options = ReadOptions {
        fix_information: name == "cubicle",
    };
    Some(g2o::read(&path, options).expect("dataset reads"))
}

fn solver_options() -> SolverOptions {
    SolverOptions {
        threads: threads(),
        ..SolverOptions::default()
    }
}

/// The graph at its chordal initial guess and an optimiser for it.
fn prepared<P: G2oPose<D> + ChordalInit<D>, const D: usize>(
    mut g: PoseGraph<P, D>,
    missing: &[usize],
) -> (PoseGraph<P, D>, Optimizer<P, D>) {
    initialize(&mut g, missing, Initialization::File, None).expect("spanning tree");
    initialize(&mut g, missing, Initialization::Chordal, None).expect("chordal");
    let opt = Optimizer::new(&g, None, solver_options()).expect("optimiser");
    (g, opt)
}

#[divan::bench(args = DATASETS)]
fn parse(bencher: Bencher, name: &str) {
    let Some(path) = dataset(name) else { return };
    let options = ReadOptions {
        fix_information: name == "cubicle",
    };
    bencher.bench(|| g2o::read(&path, options).expect("reads"));
}

/// Runs `$body` with `$g` and `$opt` bound for either pose type.
macro_rules! with_prepared {
    ($name:expr, |$g:ident, $opt:ident| $body:expr) => {{
        let Some(file) = read($name) else { return };
        match file.graph {
            AnyPoseGraph::Planar(g) => {
                let (mut $g, mut $opt) = prepared(g, &file.missing);
                $body
            }
            AnyPoseGraph::Spatial(g) => {
                let (mut $g, mut $opt) = prepared(g, &file.missing);
                $body
            }
        }
    }};
}

#[divan::bench(args = DATASETS)]
fn linearize(bencher: Bencher, name: &str) {
    with_prepared!(name, |g, opt| {
        let _ = &mut g;
        bencher.bench_local(|| opt.linearize(&g, None));
    });
}

#[divan::bench(args = DATASETS)]
fn factorize(bencher: Bencher, name: &str) {
    with_prepared!(name, |g, opt| {
        let _ = &mut g;
        opt.linearize(&g, None);
        bencher.bench_local(|| opt.system_mut().factorize(0.0).expect("PD"));
    });
}

#[divan::bench(args = DATASETS)]
fn solve(bencher: Bencher, name: &str) {
    with_prepared!(name, |g, opt| {
        let _ = &mut g;
        opt.linearize(&g, None);
        opt.system_mut().factorize(0.0).expect("PD");
        let mut step = vec![0.0; g.num_vertices() * 6];
        bencher.bench_local(|| opt.system_mut().solve(&mut step));
    });
}

#[divan::bench(args = DATASETS, sample_count = 5, sample_size = 1)]
fn optimize(bencher: Bencher, name: &str) {
    let Some(file) = read(name) else { return };
    match file.graph {
        AnyPoseGraph::Planar(g) => optimize_from_file(bencher, g, &file.missing),
        AnyPoseGraph::Spatial(g) => optimize_from_file(bencher, g, &file.missing),
    }
}

/// Chordal initial guess and LM, from a fresh copy of the graph each time.
fn optimize_from_file<P: G2oPose<D> + ChordalInit<D>, const D: usize>(
    bencher: Bencher,
    g: PoseGraph<P, D>,
    missing: &[usize],
) {
    bencher
        .with_inputs(|| g.clone())
        .bench_local_values(|mut g| {
            initialize(&mut g, missing, Initialization::File, None).expect("spanning tree");
            initialize(&mut g, missing, Initialization::Chordal, None).expect("chordal");
            let mut opt = Optimizer::new(&g, None, solver_options()).expect("optimiser");
            opt.run(&mut g, None, &mut |_: &IterationRecord| {})
                .expect("converges")
        });
}

fn simulated_sizes() -> Vec<usize> {
    let mut sizes = vec![10_000, 100_000];
    if std::env::var_os("PGO_BENCH_MILLION").is_some() {
        sizes.push(1_000_000);
    }
    sizes
}

fn simulated(world: World, poses: usize) -> AnySimulation {
    let options = SimulationOptions {
        world,
        poses,
        loops: poses / 10,
        seed: 7,
        ..SimulationOptions::default()
    };
    pgo::simulate::simulate(&options).expect("simulates")
}

#[divan::bench(args = simulated_sizes(), sample_count = 3, sample_size = 1)]
fn optimize_simulated_2d(bencher: Bencher, poses: usize) {
    if let AnySimulation::Planar(s) = simulated(World::Grid2d, poses) {
        optimize_from_file(bencher, s.noisy, &[]);
    }
}

#[divan::bench(args = simulated_sizes(), sample_count = 3, sample_size = 1)]
fn optimize_simulated_3d(bencher: Bencher, poses: usize) {
    if let AnySimulation::Spatial(s) = simulated(World::Sphere3d, poses) {
        optimize_from_file(bencher, s.noisy, &[]);
    }
}
