//! Benchmarks of the library, one stage at a time, on the public datasets
//! (`$PGO_DATASETS`, else `../shared/datasets`; skipped with a message when
//! absent) and on graphs made by `pgo simulate` (`sim2d-…`: grid world,
//! `sim3d-…`: sphere world; loop closures on 10 % of the poses):
//!
//! * `parse`: reading the g2o file (simulated graphs are written to the
//!   temporary directory first);
//! * `linearize`: errors, Jacobians and assembly of `H` and `b` once;
//! * `factorize`: one numeric sparse Cholesky of `H`;
//! * `factorize_faer`: the same numeric factorisation of the same matrix
//!   (`BlockSystem::upper_csc`, same ordering) by faer's own supernodal
//!   sparse Cholesky, which pgo used before its block-supernodal one;
//! * `solve`: the two triangular solves;
//! * `iteration`: one LM iteration as [`Optimizer::run`] does it (with
//!   `max_iterations = 1`, from the chordal guess): linearisation, one
//!   factorisation, the solves, the objective at the trial point and the
//!   linearisation at the accepted point — so one linearisation more than a
//!   steady-state iteration, to compare with `factorize`;
//! * `optimize`: initial guess (chordal) and LM to convergence, from a fresh
//!   copy of the graph each time.
//!
//! Cases: the seven datasets and simulated graphs of 10⁴ and 10⁵ poses in
//! 2D and 3D; 10⁶ poses too with `PGO_BENCH_MILLION=1` (minutes).
//!
//! The stages are pgo's insides, reached through the hidden
//! `pgo::internals` hook of the `internals` feature (no stability promise).
//!
//! Run: `cargo bench --features internals --bench pipeline` (all) or e.g.
//! `cargo bench --features internals --bench pipeline -- factorize`. The linear algebra runs in
//! rayon's pool: `RAYON_NUM_THREADS=1 cargo bench --bench pipeline` for one
//! thread. `cargo test` does not build or run these.

use divan::Bencher;
use pgo::internals::read;
use pgo::internals::{
    AnyGraph as AnyPoseGraph, ChordalInit, G2oPose, Graph as PoseGraph, Initialization,
    IterationRecord, Optimizer, ReadOptions, SolveSettings, initialize,
};
use pgo::{Se2, Se3};
use pgo_sim::{AnySimulation, SimulationOptions, World};
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

fn cases() -> Vec<&'static str> {
    let mut cases = DATASETS.to_vec();
    cases.extend(["sim2d-1e4", "sim2d-1e5", "sim3d-1e4", "sim3d-1e5"]);
    if std::env::var_os("PGO_BENCH_MILLION").is_some() {
        cases.extend(["sim2d-1e6", "sim3d-1e6"]);
    }
    cases
}

/// A simulated case's world and size.
fn simulated(case: &str) -> Option<(World, usize)> {
    let (world, size) = case.strip_prefix("sim")?.split_once('-')?;
    let world = match world {
        "2d" => World::Grid2d,
        "3d" => World::Sphere3d,
        _ => return None,
    };
    let poses = size.parse::<f64>().ok()? as usize;
    Some((world, poses))
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

fn read_options(name: &str) -> ReadOptions {
    // cubicle.g2o has indefinite information matrices (MANIFEST quirk 2).
    ReadOptions {
        fix_information: name == "cubicle",
    }
}

/// The graph of a case and its vertices without a line in the file
/// (simulated graphs are read back from the file `pgo simulate` would
/// write: the same numbers, bit for bit).
fn load(case: &str) -> Option<(AnyPoseGraph, Vec<usize>)> {
    let path = file_of(case)?;
    let file = read(&path, read_options(case)).expect("graph reads");
    Some((file.graph, file.missing))
}

/// The file to parse for a case (simulated graphs written once to the
/// temporary directory).
fn file_of(case: &str) -> Option<PathBuf> {
    let Some((world, poses)) = simulated(case) else {
        return dataset(case);
    };
    let path = std::env::temp_dir().join(format!("pgo-bench-{case}.g2o"));
    if !path.is_file() {
        let options = SimulationOptions {
            world,
            poses,
            loops: poses / 10,
            seed: 7,
            ..SimulationOptions::default()
        };
        match pgo_sim::simulate(&options).expect("simulates") {
            AnySimulation::Planar(s) => s.noisy.write_g2o(&path),
            AnySimulation::Spatial(s) => s.noisy.write_g2o(&path),
        }
        .expect("writes");
    }
    Some(path)
}

/// The graph at its chordal initial guess and an optimiser for it.
fn prepared<P: G2oPose<D> + ChordalInit<D>, const D: usize>(
    mut g: PoseGraph<P, D>,
    missing: &[usize],
) -> (PoseGraph<P, D>, Optimizer<P, D>) {
    initialize(&mut g, missing, Initialization::File, None).expect("spanning tree");
    initialize(&mut g, missing, Initialization::Chordal, None).expect("chordal");
    let opt = Optimizer::new(&g, None, SolveSettings::default()).expect("optimiser");
    (g, opt)
}

#[divan::bench(args = cases(), sample_count = 10)]
fn parse(bencher: Bencher, case: &str) {
    let Some(path) = file_of(case) else { return };
    let options = read_options(case);
    bencher.bench(|| read(&path, options).expect("reads"));
}

/// Runs `$body` with `$g` (the graph at its chordal guess) and `$opt` bound
/// for either pose type.
macro_rules! with_prepared {
    ($case:expr, |$g:ident, $opt:ident| $body:expr) => {{
        let Some((graph, missing)) = load($case) else {
            return;
        };
        match graph {
            AnyPoseGraph::Planar(g) => {
                let ($g, mut $opt) = prepared::<Se2, 3>(g, &missing);
                $body
            }
            AnyPoseGraph::Spatial(g) => {
                let ($g, mut $opt) = prepared::<Se3, 6>(g, &missing);
                $body
            }
        }
    }};
}

#[divan::bench(args = cases(), sample_count = 20)]
fn linearize(bencher: Bencher, case: &str) {
    with_prepared!(case, |g, opt| {
        bencher.bench_local(|| opt.linearize(&g, None));
    });
}

#[divan::bench(args = cases(), sample_count = 20)]
fn factorize(bencher: Bencher, case: &str) {
    with_prepared!(case, |g, opt| {
        opt.linearize(&g, None);
        bencher.bench_local(|| opt.system_mut().factorize(0.0).expect("PD"));
    });
}

#[divan::bench(args = cases(), sample_count = 20)]
fn factorize_faer(bencher: Bencher, case: &str) {
    use faer::dyn_stack::{MemBuffer, MemStack};
    use faer::sparse::linalg::SupernodalThreshold;
    use faer::sparse::linalg::cholesky::{
        CholeskySymbolicParams, SymmetricOrdering, factorize_symbolic_cholesky,
    };
    use faer::sparse::{SparseColMatRef, SymbolicSparseColMatRef};
    use faer::{Par, Side};
    with_prepared!(case, |g, opt| {
        opt.linearize(&g, None);
        let (col_ptr, rows, values) = opt.system().upper_csc();
        let n = col_ptr.len() - 1;
        let pattern = SymbolicSparseColMatRef::new_checked(n, n, &col_ptr, None, &rows);
        let params = CholeskySymbolicParams {
            supernodal_flop_ratio_threshold: SupernodalThreshold::FORCE_SUPERNODAL,
            ..Default::default()
        };
        let symbolic =
            factorize_symbolic_cholesky(pattern, Side::Upper, SymmetricOrdering::Identity, params)
                .expect("symbolic");
        let mut l = vec![0.0; symbolic.len_val()];
        let mut mem = MemBuffer::new(
            symbolic.factorize_numeric_llt_scratch::<f64>(Par::Seq, Default::default()),
        );
        let a = SparseColMatRef::new(pattern, &values);
        bencher.bench_local(|| {
            symbolic
                .factorize_numeric_llt::<f64>(
                    &mut l,
                    a,
                    Side::Upper,
                    Default::default(),
                    Par::Seq,
                    MemStack::new(&mut mem),
                    Default::default(),
                )
                .map(|_| ())
                .expect("PD")
        });
    });
}

#[divan::bench(args = cases(), sample_count = 20)]
fn solve(bencher: Bencher, case: &str) {
    with_prepared!(case, |g, opt| {
        opt.linearize(&g, None);
        opt.system_mut().factorize(0.0).expect("PD");
        let mut step = vec![0.0; g.num_vertices() * 6];
        bencher.bench_local(|| opt.system_mut().solve(&mut step));
    });
}

#[divan::bench(args = cases(), sample_count = 20)]
fn iteration(bencher: Bencher, case: &str) {
    with_prepared!(case, |g, opt| {
        opt.options_mut().max_iterations = 1;
        let start = g.poses.clone();
        let mut g = g;
        bencher.bench_local(|| {
            g.poses.clone_from(&start);
            opt.run(&mut g, None, &mut |_: &IterationRecord| {})
                .expect("iterates")
        });
    });
}

#[divan::bench(args = cases(), sample_count = 5, sample_size = 1)]
fn optimize(bencher: Bencher, case: &str) {
    let Some((graph, missing)) = load(case) else {
        return;
    };
    match graph {
        AnyPoseGraph::Planar(g) => optimize_from(bencher, g, &missing),
        AnyPoseGraph::Spatial(g) => optimize_from(bencher, g, &missing),
    }
}

/// Chordal initial guess and LM, from a fresh copy of the graph each time.
fn optimize_from<P: G2oPose<D> + ChordalInit<D>, const D: usize>(
    bencher: Bencher,
    g: PoseGraph<P, D>,
    missing: &[usize],
) {
    bencher
        .with_inputs(|| g.clone())
        .bench_local_values(|mut g| {
            initialize(&mut g, missing, Initialization::File, None).expect("spanning tree");
            initialize(&mut g, missing, Initialization::Chordal, None).expect("chordal");
            let mut opt = Optimizer::new(&g, None, SolveSettings::default()).expect("optimiser");
            opt.run(&mut g, None, &mut |_: &IterationRecord| {})
                .expect("converges")
        });
}
