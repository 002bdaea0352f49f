//! The examples in the documentation of the crate-private modules, as unit
//! tests: rustdoc compiles a doc example against the public API, which
//! does not reach these modules, so their examples are marked `ignore`
//! there and run here, word for word but for the paths.

// Word for word: an example may import more than it uses.
#![allow(unused_imports)]

/// src/stats.rs: `chi2_critical`.
#[test]
fn stats_chi2_critical() {
    use crate::stats::chi2_critical;
    // Table I of the paper: 1589 constraints at α = 0.05 → 1.6828e3.
    let x = chi2_critical(1589, 0.05).unwrap();
    assert!((x - 1682.8).abs() < 0.05);
}

/// src/stats.rs: `normal_upper_quantile`.
#[test]
fn stats_normal_upper_quantile() {
    let z = crate::stats::normal_upper_quantile(0.025);
    assert!((z - 1.959964).abs() < 1e-6);
}

/// src/stats.rs: `new`.
#[test]
fn stats_chi2_test_new() {
    use crate::stats::{Chi2Test, DofConvention};
    // Table I, "Degenerated": D² = 4871.5 with 1589 constraints fails.
    let t = Chi2Test::new(4871.5, 1589, 1200, DofConvention::Constraints, 0.05).unwrap();
    assert_eq!(t.dof, 1589);
    assert!(!t.passed);
}

/// src/linear.rs: `BlockSystem`.
#[test]
fn linear_block_system() {
    use crate::linear::BlockSystem;
    use nalgebra::{Matrix1, Vector1};
    // Two scalar variables tied by one edge, plus a prior on the first:
    // H = [[2, −1], [−1, 1]], b = [0, −1], so δ = −H⁻¹b = [1, 2].
    let mut sys = BlockSystem::<1>::new(
        2,
        &[(Some(0), Some(1)), (Some(0), None)],
        crate::linear::Parallelism::sequential(),
    )
    .unwrap();
    sys.clear();
    let one = Matrix1::new(1.0);
    sys.add_edge(
        0,
        &one,
        &Matrix1::new(-1.0),
        &one,
        &Vector1::new(0.0),
        &Vector1::new(-1.0),
    );
    sys.add_edge(
        1,
        &one,
        &Matrix1::zeros(),
        &Matrix1::zeros(),
        &Vector1::new(0.0),
        &Vector1::zeros(),
    );
    sys.factorize(0.0).unwrap();
    let mut step = vec![0.0; 2];
    sys.solve(&mut step);
    assert!((step[0] - 1.0).abs() < 1e-12 && (step[1] - 2.0).abs() < 1e-12);
}

/// src/linear.rs: `propagate`.
#[test]
fn linear_propagate() {
    use crate::linear::BlockSystem;
    use nalgebra::{Matrix1, Vector1};
    // H = [[2, −1], [−1, 1]], so H⁻¹ = [[1, 1], [1, 2]]; for the edge
    // error e = x₁ − x₀, A = [−1, 1] and A·H⁻¹·Aᵀ = 1 − 2 + 2 = 1.
    let mut sys = BlockSystem::<1>::new(
        2,
        &[(Some(0), Some(1)), (Some(0), None)],
        crate::linear::Parallelism::sequential(),
    )
    .unwrap();
    sys.clear();
    let one = Matrix1::new(1.0);
    sys.add_edge(
        0,
        &one,
        &Matrix1::new(-1.0),
        &one,
        &Vector1::zeros(),
        &Vector1::zeros(),
    );
    sys.add_edge(
        1,
        &one,
        &Matrix1::zeros(),
        &Matrix1::zeros(),
        &Vector1::zeros(),
        &Vector1::zeros(),
    );
    sys.factorize(0.0).unwrap();
    let m = sys.propagate(Some(0), &Matrix1::new(-1.0), Some(1), &one);
    assert!((m[(0, 0)] - 1.0).abs() < 1e-12);
    // The variance of x₁ alone: (H⁻¹)₁₁ = 2.
    assert!((sys.propagate(None, &one, Some(1), &one)[(0, 0)] - 2.0).abs() < 1e-12);
}

/// src/robust/mod.rs: `cauchy_weight`.
#[test]
fn robust_cauchy_weight() {
    assert_eq!(crate::robust::cauchy_weight(4.0, 2.0), 0.5);
}

/// src/gate.rs: `learn_threshold`.
#[test]
fn gate_learn_threshold() {
    use crate::gate::{MixtureOptions, learn_threshold};
    // Many weakly supported candidates (8..=32 inliers) and some strong ones
    // (150..=209 inliers).
    let mut counts: Vec<u64> = (0..200).map(|i| 8 + (i * 7919) % 25).collect();
    counts.extend((0..40).map(|i| 150 + (i * 31) % 60));
    let fit = learn_threshold(&counts, &MixtureOptions::default());
    assert!(!fit.is_degenerate(), "{:?}", fit.degeneracy);
    let t = fit.threshold.unwrap();
    assert!(t.count > 32.0 && t.count < 150.0);
    assert!(t.keeps(150) && !t.keeps(32));
}

/// src/gate.rs: `fit_two_normals`.
#[test]
fn gate_fit_two_normals() {
    use crate::gate::{MixtureOptions, fit_two_normals};
    // ln of two well-separated groups.
    let mut y: Vec<f64> = (0..200).map(|i| (i % 20) as f64 * 0.1).collect();
    y.extend((0..20).map(|i| 10.0 + (i % 5) as f64 * 0.2));
    let fit = fit_two_normals(&y, 1e-6, &MixtureOptions::default());
    assert!(fit.degeneracy.is_none());
    let t = fit.crossing_log.unwrap();
    assert!(t > 1.9 && t < 10.0);
}

/// src/gate.rs: `gate`.
#[test]
fn gate_gate() {
    use crate::gate::{DegeneratePolicy, GateMode, MixtureOptions, gate};
    let mut counts: Vec<Option<u64>> = (0..200).map(|i| Some(8 + (i * 7919) % 25)).collect();
    counts.extend((0..40).map(|i| Some(150 + (i * 31) % 60)));
    counts.push(None);
    let d = gate(
        &counts,
        GateMode::Auto,
        DegeneratePolicy::DropAll,
        &MixtureOptions::default(),
    );
    assert!(!d.degenerate);
    assert_eq!(d.kept_count(), 41); // the 40 strong candidates and the uncounted one

    let all_equal = vec![Some(12); 30];
    let d = gate(
        &all_equal,
        GateMode::Auto,
        DegeneratePolicy::DropAll,
        &MixtureOptions::default(),
    );
    assert!(d.degenerate && d.kept_count() == 0);
    println!("{}", d.reason.unwrap()); // all 30 non-zero inlier counts equal 12: ...
}

/// src/solve/mod.rs: `optimize`.
#[test]
fn solve_optimize() {
    use crate::geometry::{Pose, Se2};
    use crate::graph::Graph;
    use crate::solve::{SolverOptions, optimize};
    use nalgebra::Matrix3;
    let mut g = Graph::<Se2, 3>::new();
    for k in 0..3 {
        g.add_vertex(k, Se2::new(0.3 * k as f64, 0.0, 0.0)).unwrap();
    }
    let step = Se2::new(1.0, 0.0, 0.0);
    g.add_edge(0, 1, step, Matrix3::identity(), None).unwrap();
    g.add_edge(1, 2, step, Matrix3::identity(), None).unwrap();
    let summary = optimize(&mut g, &SolverOptions::default()).unwrap();
    assert!(summary.final_objective < 1e-20);
    assert!((g.poses[2].x - 2.0).abs() < 1e-9);
}

/// src/graph.rs: `Graph`.
#[test]
fn graph_pose_graph() {
    use crate::geometry::{Pose, Se2};
    use crate::graph::Graph;
    use nalgebra::Matrix3;
    let mut g = Graph::<Se2, 3>::new();
    g.add_vertex(0, Se2::identity()).unwrap();
    g.add_vertex(1, Se2::new(1.0, 0.0, 0.0)).unwrap();
    g.add_edge(0, 1, Se2::new(1.0, 0.0, 0.0), Matrix3::identity(), None)
        .unwrap();
    assert_eq!(g.chi2(), 0.0);
}

/// src/io/mod.rs: `write_atomically`.
#[test]
fn io_write_atomically() {
    let dir = std::env::temp_dir().join(format!("pgo-doc-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("out.txt");
    crate::io::write_atomically(&path, |w| {
        use std::io::Write;
        writeln!(w, "hello")
    })
    .unwrap();
    assert_eq!(std::fs::read_to_string(&path).unwrap(), "hello\n");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// src/io/mod.rs: the example at line 118.
#[test]
fn io_write_atomically_with_tempfile() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("out.txt");
    crate::io::write_atomically(&path, |w| {
        use std::io::Write;
        writeln!(w, "hello")
    })
    .unwrap();
    assert_eq!(std::fs::read_to_string(&path).unwrap(), "hello\n");
}

/// src/io/output/mod.rs: the example at line 401.
#[test]
fn io_output_write() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("out.txt");
    crate::output::write(&path, |w| {
        use std::io::Write;
        writeln!(w, "hello")
    })
    .unwrap();
    assert_eq!(std::fs::read_to_string(&path).unwrap(), "hello\n");
    // A directory is no output.
    let err = crate::output::write(dir.path(), |_| Ok(())).unwrap_err();
    assert!(
        err.to_string()
            .ends_with("is a directory; pgo writes only regular files (use - for stdout)")
    );
}

/// src/robust/mod.rs: the example at line 147.
#[test]
fn robust_layers_parse() {
    let l = crate::robust::Layers::parse("no-clusters,no-search").unwrap();
    assert!(!l.clusters && !l.search && l.decisions);
    assert!(crate::robust::Layers::parse("no-magic").is_err());
}

/// src/robust/model.rs: the example at line 112.
#[test]
fn robust_ln_chi2_sigma() {
    // ψ₁(3/2) = π²/2 − 4.
    let s = crate::robust::ln_chi2_sigma(3);
    assert!((s * s - (std::f64::consts::PI.powi(2) / 2.0 - 4.0)).abs() < 1e-10);
}

/// src/stats/mixture.rs: the example at line 106.
#[test]
fn stats_normal_mixture_new() {
    use crate::stats::mixture::{NormalComponent, NormalMixture};
    let c = |weight, mean, sigma| NormalComponent {
        weight,
        mean,
        sigma,
    };
    let m = NormalMixture::new(vec![c(0.5, -2.0, 1.0), c(0.5, 1.0, 1.0)]).unwrap();
    assert_eq!(m.len(), 2);
    assert!(NormalMixture::new(vec![c(0.0, 0.0, 1.0)]).is_err());
}

/// src/stats/mixture.rs: the example at line 294.
#[test]
fn stats_mixture_em() {
    use crate::stats::mixture::{EmOptions, em, quantile_start};
    let y: Vec<f64> = (0..100)
        .map(|i| if i < 60 { -2.0 } else { 3.0 } + (i % 7) as f64 * 0.1)
        .collect();
    let options = EmOptions {
        tolerance: 1e-9,
        max_iterations: 500,
        variance_floor: 1e-6,
    };
    let fit = em(&y, quantile_start(&y, 2, 1e-6).unwrap(), &options, |_| {}).unwrap();
    let c = fit.mixture.components();
    assert!((c[0].weight - 0.6).abs() < 1e-6 && (c[1].mean - 3.3).abs() < 0.05);
}

/// src/stats/separation.rs: the example at line 29.
#[test]
fn stats_separation_crossing() {
    use crate::stats::mixture::NormalComponent;
    use crate::stats::separation::crossing;
    let low = NormalComponent {
        weight: 0.5,
        mean: -1.0,
        sigma: 0.5,
    };
    let high = NormalComponent {
        weight: 0.5,
        mean: 1.0,
        sigma: 0.5,
    };
    // Equal weights and widths: half-way.
    assert!(crossing(&low, &high).unwrap().abs() < 1e-12);
    assert_eq!(crossing(&high, &low), None);
}
