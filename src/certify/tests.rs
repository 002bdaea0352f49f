use super::problem::{IsotropicEdge, Map, exp_rotation, isotropic_weights};
use super::*;
use crate::geometry::{Pose, Se2, Se3};
use crate::{Initialization, Options, PoseGraph2, PoseGraph3};
use nalgebra::{Matrix3, Matrix6, Vector3, Vector6};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use rand_distr::{Distribution, Normal};
use std::f64::consts::PI;

/// A planar ring of `n` poses driven around a circle (odometry and one
/// closing edge), measurements perturbed by `noise` (standard deviation
/// of each error coordinate), poses as composed.
fn ring2(n: u64, noise: f64, seed: u64) -> PoseGraph2 {
    let mut rng = StdRng::seed_from_u64(seed);
    let normal = Normal::new(0.0, noise.max(1e-300)).unwrap();
    let step = Se2::new(1.0, 0.0, 2.0 * PI / n as f64);
    let info = Matrix3::from_diagonal(&Vector3::new(100.0, 50.0, 400.0));
    let mut graph = PoseGraph2::new();
    let mut pose = Se2::identity();
    for k in 0..n {
        graph.add_pose(k, pose).unwrap();
        pose = pose.compose(&step);
    }
    for k in 0..n {
        let e = Vector3::from_fn(|_, _| normal.sample(&mut rng));
        graph
            .add_edge(k, (k + 1) % n, step.compose(&Se2::exp(&e)), info)
            .unwrap();
    }
    graph
}

#[test]
fn three_d_isotropic_cost_is_pgos_chi2() {
    // With information diag(ω_t I, ω_r I) the isotropic problem is pgo's:
    // τ = ω_t and κ‖Rⱼ − RᵢR̃‖² = ω_r‖q_vec‖² exactly.
    let mut rng = StdRng::seed_from_u64(3);
    let mut random_pose = || {
        let v = Vector6::from_fn(|_, _| rng.random_range(-1.5..1.5));
        Se3::exp(&v)
    };
    let info = Matrix6::from_diagonal(&Vector6::new(4.0, 4.0, 4.0, 90.0, 90.0, 90.0));
    let mut graph = crate::graph::Graph3::new();
    for k in 0..6 {
        graph.add_vertex(k, random_pose()).unwrap();
    }
    for (i, j) in [(0, 1), (1, 2), (2, 3), (3, 4), (4, 5), (5, 0), (1, 4)] {
        graph.add_edge(i, j, random_pose(), info, None).unwrap();
    }
    let edges: Vec<IsotropicEdge<3>> = (graph.edges.iter())
        .map(|e| {
            let (kappa, tau) = isotropic_weights(&e.information);
            let w = problem::WeightedEdge {
                from: e.from,
                to: e.to,
                measurement: e.measurement,
                kappa,
                tau,
            };
            IsotropicEdge::lift(&w)
        })
        .collect();
    let f = Map::of(&graph.poses).cost(&edges);
    assert!(
        (f - graph.chi2()).abs() <= 1e-12 * f,
        "{f} vs {}",
        graph.chi2()
    );
}

#[test]
fn two_d_weights_match_pgos_cost_to_second_order() {
    let info = Matrix3::new(100.0, 10.0, 0.0, 10.0, 50.0, 0.0, 0.0, 0.0, 400.0);
    let (kappa, tau) = isotropic_weights(&info);
    assert_eq!(kappa, 200.0);
    // 2 / tr(I_tt⁻¹) = 2·det / (a + c) = 2·4900 / 150.
    assert!((tau - 2.0 * 4900.0 / 150.0).abs() < 1e-12);
    // κ·‖R(θ) − I‖² → I_θθ θ² for small θ.
    let theta = 1e-4;
    let r = exp_rotation::<2>(&[theta]);
    let chordal = kappa * (r - nalgebra::Matrix2::identity()).norm_squared();
    assert!((chordal / (400.0 * theta * theta) - 1.0).abs() < 1e-8);
}

#[test]
fn a_consistent_graph_certifies_with_its_own_map() {
    let graph = ring2(12, 0.0, 1);
    let c = graph
        .optimize(&Options::default())
        .unwrap()
        .certificate()
        .unwrap();
    assert!(c.certified, "{c:?}");
    assert!(c.cost < 1e-20 && c.map_cost < 1e-20, "{c:?}");
    assert!(c.max_translation_change < 1e-9 && c.max_rotation_change < 1e-9);
    assert!(c.gap_bound.unwrap() <= c.eta * 2.0 * 12.0 * (1.0 + 1e-9));
    assert!(c.lambda_min.is_none() && c.eigenvector_poses.is_empty());
    assert_eq!((c.poses, c.edges, c.parts), (12, 12, 1));
}

#[test]
fn noisy_rings_certify_and_the_refined_map_is_no_worse() {
    for seed in 0..4 {
        let graph = ring2(40, 0.05, seed);
        let c = graph
            .optimize(&Options::default())
            .unwrap()
            .certificate()
            .unwrap();
        assert!(c.certified, "seed {seed}: {c:?}");
        assert!(c.refinement_converged);
        assert!(c.cost <= c.map_cost * (1.0 + 1e-12), "{c:?}");
        // The gap bound is the shift's, η·d·n, and what rounding leaves.
        let shift = c.eta * 2.0 * 40.0;
        assert!(c.gap_bound.unwrap() - shift < 1e-8 * c.cost, "{c:?}");
    }
}

#[test]
fn a_three_d_graph_certifies() {
    let mut rng = StdRng::seed_from_u64(9);
    let normal = Normal::new(0.0, 0.02).unwrap();
    let step = Se3::exp(&Vector6::new(1.0, 0.0, 0.1, 0.0, 0.1, 0.3));
    let info = Matrix6::from_diagonal(&Vector6::new(50.0, 50.0, 50.0, 800.0, 800.0, 800.0));
    let mut graph = PoseGraph3::new();
    let mut pose = Se3::identity();
    for k in 0..30 {
        graph.add_pose(k, pose).unwrap();
        pose = pose.compose(&step);
    }
    let mut noisy =
        |m: Se3| m.compose(&Se3::exp(&Vector6::from_fn(|_, _| normal.sample(&mut rng))));
    for k in 1..30 {
        graph.add_edge(k - 1, k, noisy(step), info).unwrap();
    }
    // Loops back to poses 20 steps earlier (a helix of period ~21).
    for k in 20..30 {
        let rel = graph
            .pose(k - 20)
            .unwrap()
            .inverse()
            .compose(graph.pose(k).unwrap());
        graph.add_edge(k - 20, k, noisy(rel), info).unwrap();
    }
    let c = graph
        .optimize(&Options::default())
        .unwrap()
        .certificate()
        .unwrap();
    assert!(c.certified, "{c:?}");
    assert!(c.cost <= c.map_cost * (1.0 + 1e-12));
}

/// A ring of `n` poses at one place whose measurements all say "no
/// motion", with the map twisted once around: `θₖ = 2πk/n`. For `n > 4`
/// this is a strict local minimum of the rotation cost (a twisted state of
/// the XY model on a ring), far from the global one (all headings equal,
/// cost 0).
fn twisted_ring(n: u64) -> PoseGraph2 {
    let info = Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, 100.0));
    let mut graph = PoseGraph2::new();
    for k in 0..n {
        graph
            .add_pose(k, Se2::new(0.0, 0.0, 2.0 * PI * k as f64 / n as f64))
            .unwrap();
    }
    for k in 0..n {
        graph
            .add_edge(k, (k + 1) % n, Se2::identity(), info)
            .unwrap();
    }
    graph
}

#[test]
fn a_map_in_a_wrong_basin_is_not_certified_and_says_where() {
    let graph = twisted_ring(10);
    let mut options = Options::default();
    options.solver.init = Initialization::File;
    let solution = graph.optimize(&options).unwrap();
    let c = solution.certificate().unwrap();
    assert!(!c.certified, "{c:?}");
    assert!(c.gap_bound.is_none());
    // Still the twisted map: Newton's refinement stays in its basin.
    assert!(c.max_rotation_change < 1e-6, "{c:?}");
    assert!(c.cost > 10.0, "{c:?}");
    let lambda = c.lambda_min.unwrap();
    let [lower, upper] = c.lambda_min_bounds.unwrap();
    assert!(
        lambda < -c.eta && lower <= lambda && upper < -c.eta,
        "{c:?}"
    );
    // The ring is symmetric: the vector spreads over all ten poses.
    assert_eq!(c.eigenvector_poses.len(), 10);
    let total: f64 = c.eigenvector_poses.iter().map(|p| p.share).sum();
    assert!((total - 1.0).abs() < 1e-9, "{total}");
    // The same graph from its chordal initial guess is certified.
    let c = graph
        .optimize(&Options::default())
        .unwrap()
        .certificate()
        .unwrap();
    assert!(c.certified && c.cost < 1e-12, "{c:?}");
}

#[test]
fn the_smallest_eigenvalue_of_the_twisted_ring_is_the_analytic_one() {
    // No translation measured and all tᵢ equal: the translations decouple
    // and the check's λ_min is that of the rotation block of Q − Λ, here
    // computed densely.
    let n = 8;
    let graph = twisted_ring(n);
    let mut options = Options::default();
    options.solver.init = Initialization::File;
    let c = graph.optimize(&options).unwrap().certificate().unwrap();
    let kappa = 100.0 / 2.0;
    let angle = 2.0 * PI / n as f64;
    let dense = dense_smallest(n as usize, kappa, angle);
    let lambda = c.lambda_min.unwrap();
    assert!(
        (lambda - dense).abs() < 1e-6 * dense.abs(),
        "{lambda} vs {dense}"
    );
}

/// The smallest eigenvalue of `Q − Λ` of the twisted ring with pure
/// rotation terms (translation weight 1 but zero measured translations
/// and all `tᵢ` equal: the translation block decouples from the
/// rotations), densely.
fn dense_smallest(n: usize, kappa: f64, angle: f64) -> f64 {
    let rot = |a: f64| nalgebra::Matrix2::new(a.cos(), -a.sin(), a.sin(), a.cos());
    let mut q = nalgebra::DMatrix::<f64>::zeros(2 * n, 2 * n);
    let r: Vec<_> = (0..n).map(|k| rot(angle * k as f64)).collect();
    for i in 0..n {
        let j = (i + 1) % n;
        // κ‖Rⱼ − Rᵢ‖²: blocks κI on both diagonals, −κI off-diagonal
        // (R̃ = I), on the columns of X (Q acts from the right).
        for a in 0..2 {
            q[(2 * i + a, 2 * i + a)] += kappa;
            q[(2 * j + a, 2 * j + a)] += kappa;
            q[(2 * i + a, 2 * j + a)] -= kappa;
            q[(2 * j + a, 2 * i + a)] -= kappa;
        }
    }
    // Λᵢ = sym(Rᵢᵀ (X Q)ᵢ).
    for i in 0..n {
        let mut g = nalgebra::Matrix2::zeros();
        for j in 0..n {
            let block = q.view((2 * j, 2 * i), (2, 2));
            g += r[j] * block;
        }
        let l = r[i].transpose() * g;
        let l = (l + l.transpose()) * 0.5;
        for a in 0..2 {
            for b in 0..2 {
                q[(2 * i + a, 2 * i + b)] -= l[(a, b)];
            }
        }
    }
    q.symmetric_eigen().eigenvalues.min()
}

#[test]
fn several_fixed_poses_are_refused_by_name() {
    let mut graph = ring2(6, 0.01, 2);
    graph.fix(0).unwrap();
    graph.fix(3).unwrap();
    let err = graph
        .optimize(&Options::default())
        .unwrap()
        .certificate()
        .unwrap_err();
    assert!(
        matches!(&err, crate::Error::Certify(CertifyError::SeveralFixed { ids }) if ids == &[0, 3]),
        "{err}"
    );
    assert!(err.to_string().contains("[0, 3]"));
}

#[test]
fn parts_joined_by_no_edge_of_the_map_each_get_a_gauge() {
    // Two rings, one fixed pose: the certificate's problem has two parts.
    let a = ring2(8, 0.02, 4);
    let poses: Vec<Se2> = (0..8).map(|k| *a.pose(k).unwrap()).collect();
    let solution = a.optimize(&Options::default()).unwrap();
    let mut problem = solution_problem(&solution);
    let shifted: Vec<_> = (problem.edges.iter())
        .map(|e| problem::WeightedEdge {
            from: e.from + 8,
            to: e.to + 8,
            ..*e
        })
        .collect();
    problem.edges.extend(shifted);
    let mut both: Vec<Se2> = solution.poses().map(|(_, p)| *p).collect();
    both.extend(poses.iter().map(|p| p.compose(&Se2::new(50.0, 0.0, 1.0))));
    let ids: Vec<u64> = (0..16).collect();
    let c = certify::<Se2, 2, 3, 3>(&problem, &both, &ids).unwrap();
    assert_eq!(c.parts, 2);
    assert!(c.certified, "{c:?}");
}

fn solution_problem(s: &crate::Solution<Se2>) -> Problem<Se2> {
    s.certificate_problem::<3>().unwrap()
}

#[test]
fn the_refinement_reaches_a_critical_point() {
    let graph = ring2(30, 0.1, 7);
    let solution = graph.optimize(&Options::default()).unwrap();
    let problem = solution_problem(&solution);
    let edges: Vec<IsotropicEdge<2>> = problem.edges.iter().map(IsotropicEdge::lift).collect();
    let poses: Vec<Se2> = solution.poses().map(|(_, p)| *p).collect();
    let mut pinned = vec![false; poses.len()];
    pinned[0] = true;
    let r = refine::refine::<2, 3>(Map::of(&poses), &edges, &pinned).unwrap();
    assert!(r.converged && r.newton_steps >= 1);
    let (gt, gr) = r.map.gradient(&edges);
    let scale = r.cost.max(1.0);
    for v in 1..poses.len() {
        assert!(gt[v].norm() < 1e-8 * scale, "{}", gt[v].norm());
        // Gᴿ = R Λ with Λ symmetric: RᵀGᴿ symmetric.
        let l = r.map.r[v].transpose() * gr[v];
        assert!((l - l.transpose()).norm() < 1e-8 * scale);
    }
}
