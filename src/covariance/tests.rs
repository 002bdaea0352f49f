//! The covariances against a dense inverse of `H` built independently from
//! the edge Jacobians, the relative covariance against the gauge moved to
//! the first pose of the pair, and the poses a map leaves unbounded.

use super::*;
use crate::geometry::{Se2, Se3};
use nalgebra::{UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng, rngs::StdRng};

/// Entries may differ from the dense inverse by this much of the geometric
/// mean of their row's and column's variances: the sparse and the dense
/// factorisation round differently, and these small graphs are
/// conditioned to well within it.
const TOLERANCE: f64 = 1e-10;

fn random_se2(rng: &mut StdRng, scale: f64) -> Se2 {
    Se2::new(
        rng.random_range(-scale..scale),
        rng.random_range(-scale..scale),
        rng.random_range(-3.0..3.0),
    )
}

fn random_se3(rng: &mut StdRng, scale: f64) -> Se3 {
    let axis = Vector3::from_fn(|_, _| rng.random_range(-1.0..1.0));
    Se3::new(
        UnitQuaternion::from_scaled_axis(axis * 1.5),
        Vector3::from_fn(|_, _| rng.random_range(-scale..scale)),
    )
}

/// A random symmetric positive-definite information matrix.
fn random_information<const D: usize>(rng: &mut StdRng) -> SMatrix<f64, D, D> {
    let m = SMatrix::<f64, D, D>::from_fn(|_, _| rng.random_range(-1.0..1.0));
    m * m.transpose() * 20.0 + SMatrix::identity() * 5.0
}

/// A walk of `n` poses: odometry `k−1 → k`, `loops` edges between random
/// pairs, and the poses and measurements perturbed (the poses are no
/// optimum: `H⁻¹` is what it is at any poses).
fn random_graph<P: Pose<D>, const D: usize>(
    seed: u64,
    n: usize,
    loops: usize,
    random_pose: fn(&mut StdRng, f64) -> P,
) -> Graph<P, D> {
    let mut rng = StdRng::seed_from_u64(seed);
    let mut graph = Graph::<P, D>::new();
    for k in 0..n {
        graph
            .add_vertex(k as u64 * 10 + 3, random_pose(&mut rng, 5.0))
            .unwrap();
    }
    let mut pairs: Vec<(usize, usize)> = (1..n).map(|k| (k - 1, k)).collect();
    while pairs.len() < n - 1 + loops {
        let (a, b) = (rng.random_range(0..n), rng.random_range(0..n));
        if a + 1 < b {
            pairs.push((a, b));
        }
    }
    for (a, b) in pairs {
        let truth = graph.poses[a].inverse().compose(&graph.poses[b]);
        let z = truth.compose(&random_pose(&mut rng, 0.05));
        let info = random_information::<D>(&mut rng);
        graph
            .add_edge(graph.id(a), graph.id(b), z, info, None)
            .unwrap();
    }
    graph
}

/// `H⁻¹` of the edges `in_map` marks, dense, over the vertices that are
/// not in the gauge (`free[v]`: the block of vertex `v`), from the edges'
/// Jacobians ([`Pose::error_and_jacobians`], not the normal blocks the
/// covariances use).
fn dense_inverse<P: Pose<D>, const D: usize>(
    graph: &Graph<P, D>,
    in_map: &[bool],
) -> (DMatrix<f64>, Vec<Option<usize>>) {
    let gauge = graph.gauge();
    let mut free = vec![None; graph.num_vertices()];
    let mut n = 0;
    for (v, f) in free.iter_mut().enumerate() {
        if !gauge.contains(&v) {
            *f = Some(n);
            n += 1;
        }
    }
    let mut h = DMatrix::<f64>::zeros(D * n, D * n);
    for (e, _) in graph.edges.iter().zip(in_map).filter(|(_, m)| **m) {
        let (xi, xj) = (&graph.poses[e.from], &graph.poses[e.to]);
        let lin = P::error_and_jacobians(xi, xj, &e.measurement);
        let blocks = [(free[e.from], lin.jac_i), (free[e.to], lin.jac_j)];
        for (p, a) in blocks {
            for (q, b) in blocks {
                if let (Some(p), Some(q)) = (p, q) {
                    let mut view = h.view_mut((D * p, D * q), (D, D));
                    view += a.transpose() * e.information * b;
                }
            }
        }
    }
    (h.try_inverse().unwrap(), free)
}

/// The dense covariance of vertices `a` and `b` (zero rows for a fixed one).
fn dense_joint<const D: usize>(
    inverse: &DMatrix<f64>,
    free: &[Option<usize>],
    a: usize,
    b: usize,
) -> DMatrix<f64> {
    let mut out = DMatrix::zeros(2 * D, 2 * D);
    for (r, u) in [a, b].into_iter().enumerate() {
        for (c, v) in [a, b].into_iter().enumerate() {
            if let (Some(p), Some(q)) = (free[u], free[v]) {
                out.view_mut((D * r, D * c), (D, D))
                    .copy_from(&inverse.view((D * p, D * q), (D, D)));
            }
        }
    }
    out
}

/// Asserts `got` = `want` entry by entry, each to [`TOLERANCE`] of
/// `√(want_rr·want_cc)`.
fn assert_close(got: &DMatrix<f64>, want: &DMatrix<f64>, what: &str) {
    assert_eq!(got.shape(), want.shape(), "{what}");
    for r in 0..want.nrows() {
        for c in 0..want.ncols() {
            let scale = (want[(r, r)] * want[(c, c)]).sqrt();
            let diff = (got[(r, c)] - want[(r, c)]).abs();
            assert!(
                diff <= TOLERANCE * scale,
                "{what} ({r}, {c}): {} vs {} (scale {scale:e})",
                got[(r, c)],
                want[(r, c)]
            );
        }
    }
}

fn dynamic<const D: usize>(m: &SMatrix<f64, D, D>) -> DMatrix<f64> {
    DMatrix::from_column_slice(D, D, m.as_slice())
}

/// Every pose's covariance and the joint covariance of many pairs equal
/// the dense inverse, with some edges out of the map.
fn matches_the_dense_inverse<P: Pose<D>, const D: usize>(
    random_pose: fn(&mut StdRng, f64) -> P,
    threads: usize,
) {
    for seed in 0..3 {
        let graph = random_graph::<P, D>(seed, 40, 25, random_pose);
        // Every fifth loop out of the map (odometry keeps it connected).
        let in_map: Vec<bool> = (0..graph.edges.len())
            .map(|k| k < 39 || k % 5 != 0)
            .collect();
        let (inverse, free) = dense_inverse(&graph, &in_map);
        let graph = Arc::new(graph);
        let c = Covariances::new(graph.clone(), &in_map, threads).unwrap();
        assert_eq!(c.len(), 40);
        for (v, (id, got)) in c.iter().enumerate() {
            assert_eq!(id, graph.id(v));
            let want = dense_joint::<D>(&inverse, &free, v, v);
            let want = want.view((0, 0), (D, D)).into_owned();
            assert_close(&dynamic(&got.unwrap()), &want, &format!("pose {id}"));
            assert_eq!(c.pose(id).unwrap(), c.iter().nth(v).unwrap().1.unwrap());
        }
        let mut rng = StdRng::seed_from_u64(seed + 100);
        for _ in 0..60 {
            let (a, b) = (rng.random_range(0..40), rng.random_range(0..40));
            let got = c.joint(graph.id(a), graph.id(b)).unwrap();
            let want = dense_joint::<D>(&inverse, &free, a, b);
            assert_close(&got, &want, &format!("joint {a} {b}"));
        }
    }
}

#[test]
fn planar_covariances_are_the_dense_inverse() {
    matches_the_dense_inverse::<Se2, 3>(random_se2, 1);
}

#[test]
fn spatial_covariances_are_the_dense_inverse() {
    matches_the_dense_inverse::<Se3, 6>(random_se3, 1);
}

#[test]
fn threads_give_the_same_covariances() {
    matches_the_dense_inverse::<Se3, 6>(random_se3, 2);
}

/// The covariance of `b` relative to `a` is that of `b` with `a` the
/// gauge: the relative pose does not depend on which pose is fixed.
fn relative_is_the_marginal_with_the_first_pose_fixed<P: Pose<D>, const D: usize>(
    random_pose: fn(&mut StdRng, f64) -> P,
) {
    let graph = random_graph::<P, D>(7, 30, 20, random_pose);
    let in_map = vec![true; graph.edges.len()];
    let c = Covariances::new(Arc::new(graph.clone()), &in_map, 1).unwrap();
    for (a, b) in [(0, 29), (4, 17), (17, 4), (12, 13), (25, 2)] {
        let mut moved = graph.clone();
        moved.fix(moved.id(a)).unwrap();
        let fixed_at_a = Covariances::new(Arc::new(moved), &in_map, 1).unwrap();
        let (ia, ib) = (graph.id(a), graph.id(b));
        let want = dynamic(&fixed_at_a.pose(ib).unwrap());
        let got = dynamic(&c.relative(ia, ib).unwrap());
        assert_close(&got, &want, &format!("relative {a} {b}"));
        assert_eq!(fixed_at_a.pose(ia).unwrap(), SMatrix::<f64, D, D>::zeros());
    }
    // A pose relative to itself is certain.
    let id = graph.id(5);
    assert!(c.relative(id, id).unwrap().abs().max() < 1e-12);
}

#[test]
fn planar_relative_covariance_does_not_depend_on_the_gauge() {
    relative_is_the_marginal_with_the_first_pose_fixed::<Se2, 3>(random_se2);
}

#[test]
fn spatial_relative_covariance_does_not_depend_on_the_gauge() {
    relative_is_the_marginal_with_the_first_pose_fixed::<Se3, 6>(random_se3);
}

/// `(Xₐ·Δ(δₐ))⁻¹·X_b = A·Δ(−Ad(A⁻¹)·δₐ)` to first order: the difference
/// of the two sides shrinks as `δ²`.
fn inverse_adjoint_is_the_first_order_change<P: Pose<D>, const D: usize>(
    random_pose: fn(&mut StdRng, f64) -> P,
) {
    let mut rng = StdRng::seed_from_u64(3);
    for _ in 0..20 {
        let (xa, xb) = (random_pose(&mut rng, 5.0), random_pose(&mut rng, 5.0));
        let ad = inverse_adjoint(&xa, &xb);
        let a = xa.inverse().compose(&xb);
        let direction = SVector::<f64, D>::from_fn(|_, _| rng.random_range(-1.0..1.0));
        let gap = |h: f64| {
            let moved = xa.retract(&(direction * h)).inverse().compose(&xb);
            let predicted = a.retract(&(-(ad * direction) * h));
            predicted.inverse().compose(&moved).log().norm()
        };
        let (g1, g2) = (gap(1e-3), gap(5e-4));
        assert!(g1 < 1e-4 && g2 < g1 / 3.0, "{g1:e} {g2:e}");
    }
}

#[test]
fn inverse_adjoint_is_the_change_of_the_relative_pose() {
    inverse_adjoint_is_the_first_order_change::<Se2, 3>(random_se2);
    inverse_adjoint_is_the_first_order_change::<Se3, 6>(random_se3);
}

#[test]
fn fixed_poses_have_zero_covariance_and_several_may_be_fixed() {
    let mut graph = random_graph::<Se2, 3>(11, 20, 10, random_se2);
    for v in [3, 12] {
        graph.fix(graph.id(v)).unwrap();
    }
    let in_map = vec![true; graph.edges.len()];
    let (inverse, free) = dense_inverse(&graph, &in_map);
    let c = Covariances::new(Arc::new(graph.clone()), &in_map, 1).unwrap();
    // The first pose is free now: only the fixed ones are the gauge.
    assert!(c.pose(graph.id(0)).unwrap()[(0, 0)] > 0.0);
    for v in [3, 12] {
        assert_eq!(c.pose(graph.id(v)).unwrap(), SMatrix::<f64, 3, 3>::zeros());
    }
    let got = c.joint(graph.id(3), graph.id(7)).unwrap();
    assert_close(&got, &dense_joint::<3>(&inverse, &free, 3, 7), "joint");
    assert_eq!(got.view((0, 0), (3, 6)).abs().max(), 0.0);
}

#[test]
fn a_pose_tied_only_by_edges_out_of_the_map_is_unbounded() {
    // 0 – 1 – 2 by odometry; 3 joined to 2 by a loop out of the map.
    let mut graph = Graph::<Se2, 3>::new();
    for k in 0..4 {
        graph.add_vertex(k, Se2::new(k as f64, 0.0, 0.0)).unwrap();
    }
    let step = Se2::new(1.0, 0.0, 0.0);
    for k in 1..3 {
        graph
            .add_edge(k - 1, k, step, SMatrix::identity(), None)
            .unwrap();
    }
    let candidate = Some(crate::graph::LoopCandidate { inliers: None });
    graph
        .add_edge(2, 3, step, SMatrix::identity(), candidate)
        .unwrap();
    let in_map = edges_in_map(&graph, [false]).unwrap();
    assert_eq!(in_map, [true, true, false]);
    let c = Covariances::new(Arc::new(graph), &in_map, 1).unwrap();
    assert!(matches!(c.pose(3), Err(Error::Unbounded { id: 3 })));
    assert!(matches!(c.joint(1, 3), Err(Error::Unbounded { id: 3 })));
    assert!(matches!(c.relative(3, 0), Err(Error::Unbounded { id: 3 })));
    assert!(matches!(c.pose(9), Err(Error::UnknownVertex { id: 9 })));
    let items: Vec<_> = c.iter().collect();
    assert!(items[..3].iter().all(|(_, c)| c.is_ok()));
    assert!(matches!(items[3], (3, Err(Error::Unbounded { id: 3 }))));
    // Two odometry steps of unit information: x adds up.
    assert!((c.pose(2).unwrap()[(0, 0)] - 2.0).abs() < 1e-12);
    // One flag per candidate, no more and no fewer.
    assert!(edges_in_map(&c.graph, []).is_none());
    assert!(edges_in_map(&c.graph, [true, true]).is_none());
}

#[test]
fn a_graph_of_one_pose_has_only_the_fixed_one() {
    let mut graph = Graph::<Se3, 6>::new();
    graph.add_vertex(5, Se3::identity()).unwrap();
    let c = Covariances::new(Arc::new(graph), &[], 1).unwrap();
    assert_eq!(c.pose(5).unwrap(), SMatrix::<f64, 6, 6>::zeros());
    assert_eq!(c.joint(5, 5).unwrap(), DMatrix::zeros(12, 12));
    assert_eq!(c.factor_values(), 0);
}

#[test]
fn the_solution_leaves_rejected_loops_out() {
    use crate::{Options, PoseGraph2};
    // A square driven twice, two true loops and a wrong one (the example
    // of `Graph`).
    let mut graph = PoseGraph2::new();
    let step = Se2::new(1.0, 0.0, std::f64::consts::FRAC_PI_2);
    let mut pose = Se2::new(0.0, 0.0, 0.0);
    for k in 0..9 {
        graph.add_pose(k, pose).unwrap();
        pose = pose.compose(&step);
    }
    let odometry = SMatrix::from_diagonal(&[100.0, 100.0, 400.0].into());
    for k in 1..9 {
        graph.add_edge(k - 1, k, step, odometry).unwrap();
    }
    let info = SMatrix::from_diagonal(&[50.0, 50.0, 200.0].into());
    let same = Se2::new(0.0, 0.0, 0.0);
    graph
        .add_loop_candidate(0, 4, same, info, Some(140))
        .unwrap();
    graph
        .add_loop_candidate(0, 8, same, info, Some(155))
        .unwrap();
    let wrong = Se2::new(4.0, -3.0, 2.0);
    graph
        .add_loop_candidate(2, 6, wrong, info, Some(9))
        .unwrap();
    let solution = graph.optimize(&Options::default()).unwrap();
    let accepted: Vec<bool> = solution.loops().iter().map(|l| l.accepted).collect();
    assert_eq!(accepted, [true, true, false]);
    let c = solution.covariances().unwrap();
    // The dense inverse of the map's edges at the solution's poses.
    let mut solved = Graph::<Se2, 3>::new();
    for (id, p) in solution.poses() {
        solved.add_vertex(id, *p).unwrap();
    }
    let all = [(0, 4, same), (0, 8, same), (2, 6, wrong)];
    let edges = (1..9)
        .map(|k| (k - 1, k, step, odometry))
        .chain(all.map(|(a, b, z)| (a, b, z, info)));
    for (a, b, z, omega) in edges {
        solved.add_edge(a, b, z, omega, None).unwrap();
    }
    let in_map = [vec![true; 10], vec![false]].concat();
    let (inverse, free) = dense_inverse(&solved, &in_map);
    for v in 0..9 {
        let want = dense_joint::<3>(&inverse, &free, v, 8);
        assert_close(
            &c.joint(v as u64, 8).unwrap(),
            &want,
            &format!("joint {v} 8"),
        );
    }
    // The numbers of AnySolution are the same, row by row.
    let any = crate::AnySolution::Planar(solution).covariances().unwrap();
    let flat = any.pose(5).unwrap();
    let m = c.pose(5).unwrap();
    assert_eq!(flat, (0..9).map(|k| m[(k / 3, k % 3)]).collect::<Vec<_>>());
    assert_eq!(any.poses(&[5, 0]).unwrap()[..9], flat[..]);
    assert_eq!(any.joint(2, 7).unwrap().len(), 36);
    assert_eq!(any.relative(2, 7).unwrap().len(), 9);
    assert_eq!(any.ids(), &[0, 1, 2, 3, 4, 5, 6, 7, 8]);
    assert!(matches!(
        any.poses(&[5, 77]),
        Err(Error::UnknownVertex { id: 77 })
    ));
}

#[test]
fn updates_and_non_sequential_candidates_have_covariances_too() {
    use crate::{Options, PoseGraph2};
    // A loop of 12 poses, its closing edge trusted but non-sequential: a
    // candidate under `--candidates non-sequential`.
    let step = Se2::new(1.0, 0.0, std::f64::consts::TAU / 12.0);
    let info = SMatrix::from_diagonal(&[100.0, 100.0, 400.0].into());
    let mut graph = PoseGraph2::new();
    let mut pose = Se2::new(0.0, 0.0, 0.0);
    for k in 0..12 {
        graph.add_pose(k, pose).unwrap();
        pose = pose.compose(&step);
        if k > 0 {
            graph.add_edge(k - 1, k, step, info).unwrap();
        }
    }
    graph.add_edge(11, 0, step, info).unwrap();
    let mut options = Options::default();
    options.set("candidates", "non-sequential").unwrap();
    let batch = graph.optimize(&options).unwrap();
    assert_eq!(batch.loops().len(), 1);
    let first = graph.update(&options).unwrap();
    // Odometry added: the update composes it (no solve).
    graph.add_pose(12, pose).unwrap();
    graph.add_edge(11, 12, step, info).unwrap();
    let second = graph.update(&options).unwrap();
    assert_eq!(
        second.incremental().unwrap().solve,
        crate::UpdateSolve::Extended
    );
    let (b, f, s) = (
        batch.covariances().unwrap(),
        first.covariances().unwrap(),
        second.covariances().unwrap(),
    );
    for id in [3, 6, 11] {
        let want = b.pose(id).unwrap();
        assert!((f.pose(id).unwrap() - want).abs().max() < 1e-9 * want.abs().max());
        assert!((s.pose(id).unwrap() - want).abs().max() < 1e-9 * want.abs().max());
    }
    // The new pose hangs on 11 by one step.
    let hung = s.relative(11, 12).unwrap();
    assert!((hung - info.try_inverse().unwrap()).abs().max() < 1e-12);
}

#[test]
fn queries_from_several_threads_agree() {
    let graph = Arc::new(random_graph::<Se3, 6>(5, 60, 30, random_se3));
    let in_map = vec![true; graph.edges.len()];
    let c = Covariances::new(graph.clone(), &in_map, 1).unwrap();
    let pairs: Vec<(u64, u64)> = (0..40)
        .map(|k| (graph.id(k), graph.id((k * 7 + 13) % 60)))
        .collect();
    let alone: Vec<DMatrix<f64>> = pairs.iter().map(|&(a, b)| c.joint(a, b).unwrap()).collect();
    std::thread::scope(|scope| {
        for _ in 0..4 {
            scope.spawn(|| {
                for (k, &(a, b)) in pairs.iter().enumerate() {
                    assert_eq!(c.joint(a, b).unwrap(), alone[k]);
                }
            });
        }
    });
}
