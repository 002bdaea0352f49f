//! Tests of the optimiser: exact optima, innovations, weights and cut-off
//! vertices, limits, errors.

use super::*;
use crate::geometry::{Se2, Se3};
use nalgebra::{Matrix3, Matrix6, UnitQuaternion, Vector3, Vector6};
use rand::{Rng, SeedableRng, rngs::StdRng};
use std::f64::consts::{FRAC_PI_2, PI};
use std::sync::Arc;

/// A square loop of 4 poses with one loop closure whose measurements are
/// consistent: the optimum has zero error.
fn square(noise: f64, seed: u64) -> Graph<Se2, 3> {
    let mut rng = StdRng::seed_from_u64(seed);
    let truth = [
        Se2::new(0.0, 0.0, 0.0),
        Se2::new(1.0, 0.0, FRAC_PI_2),
        Se2::new(1.0, 1.0, PI),
        Se2::new(0.0, 1.0, -FRAC_PI_2),
    ];
    let mut g = Graph::new();
    for (k, t) in truth.iter().enumerate() {
        let p = if k == 0 {
            *t
        } else {
            Se2::new(
                t.x + noise * rng.random_range(-1.0..1.0),
                t.y + noise * rng.random_range(-1.0..1.0),
                t.theta + noise * rng.random_range(-1.0..1.0),
            )
        };
        g.add_vertex(k as u64, p).unwrap();
    }
    for (i, j) in [(0, 1), (1, 2), (2, 3), (3, 0)] {
        let z = truth[i].inverse().compose(&truth[j]);
        g.add_edge(i as u64, j as u64, z, Matrix3::identity(), None)
            .unwrap();
    }
    g
}

#[test]
fn lm_and_gn_reach_the_exact_optimum_of_a_consistent_loop() {
    for method in [Method::LevenbergMarquardt, Method::GaussNewton] {
        let mut g = square(0.3, 1);
        let s = optimize(
            &mut g,
            &SolveSettings {
                method,
                ..Default::default()
            },
        )
        .unwrap();
        assert!(
            s.final_objective < 1e-16,
            "{method:?}: {}",
            s.final_objective
        );
        assert!(s.converged());
        assert!((g.poses[2].x - 1.0).abs() < 1e-8 && (g.poses[2].y - 1.0).abs() < 1e-8);
    }
}

/// Four collinear-free translations around a loop that does not close
/// by 0.4 in x, all rotations zero, and the information of its edges
/// (rotations pinned by a huge information: the problem is linear).
fn open_loop() -> (Graph<Se2, 3>, Matrix3<f64>) {
    let mut g = Graph::<Se2, 3>::new();
    for k in 0..4 {
        g.add_vertex(k, Se2::identity()).unwrap();
    }
    let i = Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, 1e8));
    g.add_edge(0, 1, Se2::new(1.0, 0.0, 0.0), i, None).unwrap();
    g.add_edge(1, 2, Se2::new(0.0, 1.0, 0.0), i, None).unwrap();
    g.add_edge(2, 3, Se2::new(-1.0, 0.0, 0.0), i, None).unwrap();
    g.add_edge(3, 0, Se2::new(0.4, -1.0, 0.0), i, None).unwrap();
    (g, i)
}

#[test]
fn inconsistent_loop_matches_the_closed_form_optimum() {
    // The optimum spreads the error equally: objective = 0.4² / 4.
    let (mut g, _) = open_loop();
    let s = optimize(&mut g, &SolveSettings::default()).unwrap();
    assert!(
        (s.final_objective - 0.04).abs() < 1e-8,
        "{}",
        s.final_objective
    );
}

#[test]
fn innovation_is_the_chi2_a_left_out_edge_adds_to_the_optimum() {
    // The open loop solved without its closing edge: the chain fits
    // exactly, the closing edge's plain error there is 0.4² = 0.16, and
    // adding it raises the optimum's χ² to 0.04 (the mismatch spread
    // over four edges). That rise is its innovation:
    // ν² = eᵀ(Ω⁻¹ + J·H⁻¹·Jᵀ)⁻¹e with H of the chain (exact here: the
    // problem is linear).
    let (mut g, i) = open_loop();
    let without = [1.0, 1.0, 1.0, 0.0];
    let mut opt = Optimizer::new(&g, Some(&without), SolveSettings::default()).unwrap();
    opt.run(&mut g, Some(&without), &mut |_: &IterationRecord| {})
        .unwrap();
    let plain = g.edge_chi2(&g.edges[3]);
    assert!((plain - 0.16).abs() < 1e-9, "{plain}");
    let nu2 = opt.innovation_chi2(&g, &without, &[3]).unwrap();
    assert!((nu2[0] - 0.04).abs() < 1e-8, "{nu2:?}");
    // An edge of the solution itself: J·H⁻¹·Jᵀ only adds, so ν² ≤ e²
    // (0 here: the chain fits exactly).
    let nu2 = opt.innovation_chi2(&g, &without, &[0, 1]).unwrap();
    assert!(nu2.iter().all(|&v| v.abs() < 1e-12), "{nu2:?}");
    // With the edge in the solution, the optimum's χ² is that rise.
    let s = optimize(&mut g, &SolveSettings::default()).unwrap();
    assert!((s.final_objective - 0.04).abs() < 1e-8);
    // A vertex no edge of non-zero weight ties to the gauge is held
    // fixed: the solution adds nothing to an edge at it.
    let mut g2 = g.clone();
    g2.add_vertex(9, Se2::new(5.0, 0.0, 0.0)).unwrap();
    g2.add_edge(3, 9, Se2::new(1.0, 0.0, 0.0), i, None).unwrap();
    let w = [1.0, 1.0, 1.0, 1.0, 0.0];
    let mut opt = Optimizer::new(&g2, Some(&[1.0; 5]), SolveSettings::default()).unwrap();
    let nu2 = opt.innovation_chi2(&g2, &w, &[4]).unwrap();
    assert_eq!(nu2[0], g2.edge_chi2(&g2.edges[4]));
    // Weights must match the edges.
    assert!(opt.innovation_chi2(&g2, &w[..2], &[4]).is_err());
}

#[test]
fn an_evaluation_of_the_same_map_reuses_its_factorisation_and_nothing_else() {
    // The same map and weights: the factorisation and its selected inverse
    // are the last evaluation's (the same bits, one allocation).
    let mut g = square(0.3, 7);
    let w = [1.0, 1.0, 1.0, 0.0];
    let mut opt = Optimizer::new(&g, Some(&w), SolveSettings::default()).unwrap();
    let start = g.poses.clone();
    let first = opt.innovation_chi2(&g, &w, &[3]).unwrap();
    let inverse = opt.selected_inverse();
    assert_eq!(opt.innovation_chi2(&g, &w, &[3]).unwrap(), first);
    assert!(Arc::ptr_eq(&inverse, &opt.selected_inverse()));
    // A run factorises elsewhere (damped, at other poses): back at the
    // first poses the evaluation factorises again and finds what a fresh
    // optimiser does.
    opt.run(&mut g, Some(&w), &mut |_: &IterationRecord| {})
        .unwrap();
    assert_ne!(g.poses, start);
    g.poses = start;
    let again = opt.innovation_chi2(&g, &w, &[3]).unwrap();
    let mut fresh = Optimizer::new(&g, Some(&w), SolveSettings::default()).unwrap();
    assert_eq!(again, fresh.innovation_chi2(&g, &w, &[3]).unwrap());
    assert!(!Arc::ptr_eq(&inverse, &opt.selected_inverse()));
    // Other weights are another map.
    let all = [1.0; 4];
    let with = opt.innovation_chi2(&g, &all, &[3]).unwrap();
    let mut fresh = Optimizer::new(&g, Some(&all), SolveSettings::default()).unwrap();
    assert_eq!(with, fresh.innovation_chi2(&g, &all, &[3]).unwrap());
    assert_ne!(with, again);
}

#[test]
fn leave_one_out_innovation_is_the_innovation_without_the_edge() {
    // The open loop closed: any one edge left out leaves a chain that
    // fits exactly, and adding it back raises χ² by 0.04 (above). So
    // each edge's deleted residual at the optimum of all four is 0.04,
    // the innovation of the closing edge left out.
    let (mut g, i) = open_loop();
    optimize(&mut g, &SolveSettings::default()).unwrap();
    let all = [1.0; 4];
    let mut opt = Optimizer::new(&g, Some(&all), SolveSettings::default()).unwrap();
    let nu2 = opt.leave_one_out_chi2(&g, &all, &[0, 1, 2, 3]).unwrap();
    for v in &nu2 {
        let v = v.expect("every edge of a loop is checked by the others");
        assert!((v - 0.04).abs() < 1e-8, "{nu2:?}");
    }
    // Its plain residual at that optimum is far smaller: (0.4/4)².
    assert!((g.edge_chi2(&g.edges[3]) - 0.01).abs() < 1e-8);
    // A bridge (the only edge to vertex 9, or edge 0 with the closing
    // edge left out) is checked by nothing.
    let mut g2 = g.clone();
    g2.add_vertex(9, Se2::new(5.0, 0.0, 0.0)).unwrap();
    g2.add_edge(3, 9, Se2::new(1.0, 0.0, 0.0), i, None).unwrap();
    let w = [1.0, 1.0, 1.0, 0.0, 1.0];
    let mut opt = Optimizer::new(&g2, Some(&w), SolveSettings::default()).unwrap();
    let nu2 = opt.leave_one_out_chi2(&g2, &w, &[0, 4]).unwrap();
    assert_eq!(nu2, [None, None]);
    // An edge left out gets the innovation `innovation_chi2` gives it;
    // one of another weight nothing.
    let left_out = opt.leave_one_out_chi2(&g2, &w, &[3]).unwrap()[0];
    assert_eq!(
        left_out,
        Some(opt.innovation_chi2(&g2, &w, &[3]).unwrap()[0])
    );
    let half = [1.0, 1.0, 1.0, 0.5, 1.0];
    assert_eq!(opt.leave_one_out_chi2(&g2, &half, &[3]).unwrap(), [None]);
    assert!(opt.leave_one_out_chi2(&g2, &w[..2], &[4]).is_err());
}

#[test]
fn spatial_chain_with_loop_converges() {
    let mut rng = StdRng::seed_from_u64(3);
    let mut truth = vec![Se3::identity()];
    for k in 1..20 {
        let step = Se3::exp(&Vector6::new(1.0, 0.0, 0.1, 0.0, 0.05, 0.3));
        let prev: Se3 = truth[k - 1];
        truth.push(prev.compose(&step));
    }
    let mut g = Graph::<Se3, 6>::new();
    for (k, t) in truth.iter().enumerate() {
        let noise = Se3::new(
            UnitQuaternion::from_scaled_axis(Vector3::new(
                rng.random_range(-0.1..0.1),
                rng.random_range(-0.1..0.1),
                rng.random_range(-0.1..0.1),
            )),
            Vector3::new(
                rng.random_range(-0.3..0.3),
                rng.random_range(-0.3..0.3),
                rng.random_range(-0.3..0.3),
            ),
        );
        g.add_vertex(k as u64, if k == 0 { *t } else { t.compose(&noise) })
            .unwrap();
    }
    for k in 1..20 {
        g.add_edge(
            k as u64 - 1,
            k as u64,
            truth[k - 1].inverse().compose(&truth[k]),
            Matrix6::identity(),
            None,
        )
        .unwrap();
    }
    g.add_edge(
        0,
        19,
        truth[0].inverse().compose(&truth[19]),
        Matrix6::identity() * 10.0,
        None,
    )
    .unwrap();
    let s = optimize(&mut g, &SolveSettings::default()).unwrap();
    assert!(s.final_objective < 1e-14, "{}", s.final_objective);
    assert!((g.poses[19].translation - truth[19].translation).norm() < 1e-6);
}

#[test]
fn weights_switch_edges_off() {
    let mut g = square(0.0, 2);
    // A wrong edge 0→2 that would pull pose 2.
    g.add_edge(
        0,
        2,
        Se2::new(5.0, 5.0, 0.0),
        Matrix3::identity() * 100.0,
        None,
    )
    .unwrap();
    let mut opt = Optimizer::new(&g, None, SolveSettings::default()).unwrap();
    let w = [1.0, 1.0, 1.0, 1.0, 0.0];
    let s = opt
        .run(&mut g, Some(&w), &mut |_: &IterationRecord| {})
        .unwrap();
    assert!(s.final_objective < 1e-16);
    assert!(
        opt.run(&mut g, Some(&w[..3]), &mut |_: &IterationRecord| {})
            .is_err()
    );
}

#[test]
fn vertices_cut_off_by_weight_zero_are_held_and_come_back() {
    // A second part (40, 41) joined to the square by one edge 2→40.
    let mut g = square(0.0, 4);
    let held = Se2::new(7.0, -3.0, 0.4);
    g.add_vertex(40, held).unwrap();
    g.add_vertex(41, Se2::new(9.0, -3.0, 0.4)).unwrap();
    let z = Se2::new(1.0, 0.0, 0.0);
    g.add_edge(2, 40, z, Matrix3::identity(), None).unwrap();
    g.add_edge(40, 41, z, Matrix3::identity(), None).unwrap();
    let mut opt = Optimizer::new(&g, None, SolveSettings::default()).unwrap();
    let mut w = vec![1.0; g.edges.len()];
    w[4] = 0.0;
    let s = opt
        .run(&mut g, Some(&w), &mut |_: &IterationRecord| {})
        .unwrap();
    assert!(s.stop_reason.converged(), "{s:?}");
    // The part cut off the gauge stays where it was.
    assert_eq!(g.poses[4], held);
    assert_eq!(g.poses[5], Se2::new(9.0, -3.0, 0.4));
    // The joining edge back: the part moves next to pose 2.
    w[4] = 1.0;
    let s = opt
        .run(&mut g, Some(&w), &mut |_: &IterationRecord| {})
        .unwrap();
    assert!(s.final_objective < 1e-16, "{s:?}");
    let rel = g.poses[2].inverse().compose(&g.poses[4]);
    assert!((rel.x - 1.0).abs() < 1e-9 && rel.y.abs() < 1e-9);
}

#[test]
fn disconnected_vertices_are_named() {
    let mut g = square(0.0, 3);
    g.add_vertex(40, Se2::identity()).unwrap();
    g.add_vertex(41, Se2::identity()).unwrap();
    g.add_edge(40, 41, Se2::identity(), Matrix3::identity(), None)
        .unwrap();
    let err = optimize(&mut g, &SolveSettings::default()).unwrap_err();
    assert_eq!(
        err,
        SolveError::Unconstrained {
            gauge: 0,
            vertices: vec![40, 41]
        }
    );
    assert!(err.to_string().contains("40, 41"));
}

#[test]
fn rank_deficient_edges_are_a_named_error() {
    // Vertex 1 is tied to the gauge only through an edge whose
    // information ignores rotation: its heading is undetermined.
    let mut g = Graph::<Se2, 3>::new();
    g.add_vertex(0, Se2::identity()).unwrap();
    g.add_vertex(1, Se2::new(1.0, 0.0, 0.0)).unwrap();
    let info = Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, 0.0));
    g.add_edge(0, 1, Se2::new(1.5, 0.0, 0.0), info, None)
        .unwrap();
    for method in [Method::GaussNewton, Method::LevenbergMarquardt] {
        let err = optimize(
            &mut g.clone(),
            &SolveSettings {
                method,
                ..Default::default()
            },
        )
        .unwrap_err();
        assert_eq!(err, SolveError::NotPositiveDefinite { vertex: 1 });
    }
}

#[test]
fn iteration_and_time_limits_are_honoured_and_keep_the_best() {
    let mut g = square(0.5, 4);
    let start = g.chi2();
    let s = optimize(
        &mut g,
        &SolveSettings {
            max_iterations: 1,
            ..Default::default()
        },
    )
    .unwrap();
    assert_eq!(
        (s.iterations, s.stop_reason),
        (1, StopReason::MaxIterations)
    );
    assert!(s.final_objective <= start && (g.chi2() - s.final_objective).abs() < 1e-12);
    let s = optimize(
        &mut g,
        &SolveSettings {
            time_limit: Some(Duration::ZERO),
            ..Default::default()
        },
    )
    .unwrap();
    assert_eq!((s.iterations, s.stop_reason), (0, StopReason::TimeLimit));
}

#[test]
fn every_run_starts_undamped() {
    // A start where LM's first step is the undamped one, but later
    // steps are damped and the run ends with λ > 0.
    let mut found = None;
    for seed in 0..500 {
        let mut g = square(2.5, seed);
        let start = g.poses.clone();
        let mut opt = Optimizer::new(&g, None, SolveSettings::default()).unwrap();
        let mut records = Vec::new();
        opt.run(&mut g, None, &mut |r: &IterationRecord| records.push(*r))
            .unwrap();
        let (Some(first), Some(last)) = (records.first(), records.last()) else {
            continue;
        };
        if first.lambda == 0.0 && first.rejected == 0 && last.lambda > 0.0 {
            found = Some((g, start, opt, *first));
            break;
        }
    }
    let (mut g, start, mut opt, first) = found.expect("no start needed damping");
    // The same optimiser from the same start takes the same undamped
    // first step: it does not carry the last run's λ over.
    g.poses = start;
    let mut again = None;
    opt.run(&mut g, None, &mut |r: &IterationRecord| {
        again.get_or_insert(*r);
    })
    .unwrap();
    let again = again.unwrap();
    assert_eq!((again.lambda, again.objective), (0.0, first.objective));
}

#[test]
fn non_finite_start_is_an_error_not_a_nan_result() {
    let mut g = square(0.0, 5);
    g.poses[1].x = f64::NAN;
    assert_eq!(
        optimize(&mut g, &SolveSettings::default()).unwrap_err(),
        SolveError::NonFiniteStart
    );
}

#[test]
fn threads_start_a_private_pool_of_that_size_only_from_two() {
    let mut g = square(0.3, 6);
    for (threads, expected) in [(0, 1), (1, 1), (2, 2), (3, 3)] {
        let options = SolveSettings {
            threads,
            ..Default::default()
        };
        let opt = Optimizer::new(&g, None, options).unwrap();
        assert_eq!(opt.parallelism.threads(), expected, "threads {threads}");
        assert_eq!(opt.parallelism.is_parallel(), threads >= 2);
    }
    // Changing the option between runs starts or stops the pool.
    let mut opt = Optimizer::new(&g, None, SolveSettings::default()).unwrap();
    opt.options_mut().threads = 2;
    opt.run(&mut g, None, &mut |_: &IterationRecord| {})
        .unwrap();
    assert_eq!(opt.parallelism.threads(), 2);
    opt.options_mut().threads = 0;
    opt.run(&mut g, None, &mut |_: &IterationRecord| {})
        .unwrap();
    assert!(!opt.parallelism.is_parallel());
}
#[test]
fn a_step_the_model_foresaw_ends_the_run_when_asked() {
    // From a solved square with one loop moved a little (a nearby start, as
    // an incremental update has), the model tolerance spares the
    // confirming iteration and lands on the same optimum.
    let mut g = square(0.3, 6);
    optimize(&mut g, &SolveSettings::default()).unwrap();
    let k = g.edges.len() - 1;
    g.edges[k].measurement.x += 0.05;
    let runs: Vec<(usize, f64)> = [None, Some(1e-8)]
        .into_iter()
        .map(|model_tolerance| {
            let mut h = g.clone();
            let options = SolveSettings {
                model_tolerance,
                ..Default::default()
            };
            let s = optimize(&mut h, &options).unwrap();
            assert!(s.converged(), "{s:?}");
            (s.iterations, h.chi2())
        })
        .collect();
    assert!(runs[1].0 < runs[0].0, "{runs:?}");
    assert!((runs[1].1 / runs[0].1 - 1.0).abs() < 1e-8, "{runs:?}");
}

/// The tests on simulated graphs (from `pgo-sim`, a dev-dependency:
/// written as g2o and read back, the library's own types being this
/// build's).
mod simulated {
    use super::*;

    /// The first `n` poses of `g` and the edges among them.
    fn prefix(g: &Graph<Se2, 3>, n: usize) -> Graph<Se2, 3> {
        let mut h = Graph::new();
        for v in 0..n {
            h.add_vertex(g.id(v), g.poses[v]).unwrap();
        }
        for e in g.edges.iter().filter(|e| e.from < n && e.to < n) {
            h.add_edge(g.id(e.from), g.id(e.to), e.measurement, e.information, None)
                .unwrap();
        }
        h
    }

    #[test]
    fn a_kept_order_is_followed_while_its_fill_stays_close() {
        let (g, _) = simulated_grid();
        let small = prefix(&g, 3000);
        let o = Optimizer::with_ordering(
            &small,
            None,
            SolveSettings::default(),
            Some(Ordering::default()),
        )
        .unwrap();
        let kept = o.ordering().unwrap().clone();
        let small_path = o.system().mean_path_values();
        // Grown by 50 poses: the old vertices keep their order, the new
        // ones come last, and the factor is at most 10 % above AMD's.
        let grown = prefix(&g, 3050);
        let fresh = Optimizer::new(&grown, None, SolveSettings::default()).unwrap();
        let o =
            Optimizer::with_ordering(&grown, None, SolveSettings::default(), Some(kept.clone()))
                .unwrap();
        let positions = o.system().positions();
        let (old, new) = positions.split_at(2999);
        assert!(old.iter().max() < new.iter().min());
        let fill = o.system().nnz_factor() as f64 / fresh.system().nnz_factor() as f64;
        assert!(fill <= 1.1 * 3050.0 / 3000.0, "{fill}");
        // Where innovations are needed, the paths to the root count too:
        // the order is kept only while they stay within 10 %.
        let options = SolveSettings::default();
        let with_paths = Some(kept.clone().for_innovations(true));
        let p = Optimizer::with_ordering(&grown, None, options, with_paths).unwrap();
        let reordered = p.system().positions() == fresh.system().positions();
        assert!(reordered || p.system().mean_path_values() <= 1.1 * small_path);
        assert!(reordered || p.system().positions() == o.system().positions());
        // The same optimum either way.
        let (mut a, mut b) = (grown.clone(), grown.clone());
        let mut fresh = fresh;
        let mut o = o;
        fresh
            .run(&mut a, None, &mut |_: &IterationRecord| {})
            .unwrap();
        o.run(&mut b, None, &mut |_: &IterationRecord| {}).unwrap();
        assert!((a.chi2() / b.chi2() - 1.0).abs() < 1e-9);
    }

    /// A simulated grid of 4000 poses with 40 wrong loops, and weights that
    /// switch half of them off and halve the others (as a robust round would).
    fn simulated_grid() -> (Graph<Se2, 3>, Vec<f64>) {
        let options = pgo_sim::SimulationOptions {
            poses: 4000,
            loops: 400,
            outliers: 40,
            seed: 11,
            ..Default::default()
        };
        let sim = pgo_sim::simulate_planar(&options).unwrap();
        let weights = (sim.wrong.iter().enumerate())
            .map(|(k, &wrong)| match (wrong, k % 2) {
                (false, _) => 1.0,
                (true, 0) => 0.0,
                (true, _) => 0.5,
            })
            .collect();
        (read_back(&sim.noisy), weights)
    }

    /// The graph as this build of the library reads it from its g2o file.
    fn read_back(graph: &pgo_sim::pgo::PoseGraph2) -> Graph<Se2, 3> {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("simulated.g2o");
        graph.write_g2o(&path).unwrap();
        match crate::io::g2o::read(&path, Default::default())
            .unwrap()
            .graph
        {
            crate::graph::AnyGraph::Planar(g) => g,
            crate::graph::AnyGraph::Spatial(_) => unreachable!("a grid is planar"),
        }
    }

    /// The poses and the bits of every objective of two runs with `threads`:
    /// unit weights, then [`simulated_grid`]'s.
    fn two_rounds(threads: usize) -> (Vec<Se2>, Vec<u64>) {
        let (mut g, weights) = simulated_grid();
        let options = SolveSettings {
            threads,
            ..Default::default()
        };
        let mut opt = Optimizer::new(&g, None, options).unwrap();
        let mut bits = Vec::new();
        for w in [None, Some(weights.as_slice())] {
            let s = opt.run(&mut g, w, &mut |_: &IterationRecord| {}).unwrap();
            assert!(s.iterations > 1, "{s:?}");
            bits.extend(s.history.iter().map(|r| r.objective.to_bits()));
            bits.push(s.final_objective.to_bits());
        }
        (g.poses, bits)
    }

    #[test]
    fn chord_steps_reach_the_same_optimum_with_fewer_factorisations() {
        // The grid solved with a robust round's weights, then solved again
        // from there with one more loop switched off (a nearby start, as
        // an incremental update has): chord steps confirm the convergence
        // with the last factor instead of new ones, and stop at the
        // optimum the Gauss–Newton steps stop at.
        let (mut g, mut weights) = simulated_grid();
        let mut opt = Optimizer::new(&g, None, SolveSettings::default()).unwrap();
        (opt.run(&mut g, Some(&weights), &mut |_: &IterationRecord| {})).unwrap();
        let last_loop = (0..g.edges.len())
            .rev()
            .find(|&k| weights[k] == 1.0 && g.edges[k].from.abs_diff(g.edges[k].to) != 1);
        weights[last_loop.unwrap()] = 0.0;
        for method in [Method::LevenbergMarquardt, Method::GaussNewton] {
            let runs: Vec<(Summary, Graph<Se2, 3>)> = [false, true]
                .into_iter()
                .map(|reuse_factor| {
                    let mut h = g.clone();
                    let options = SolveSettings {
                        method,
                        reuse_factor,
                        ..Default::default()
                    };
                    let mut opt = Optimizer::new(&h, None, options).unwrap();
                    let s = opt
                        .run(&mut h, Some(&weights), &mut |_: &IterationRecord| {})
                        .unwrap();
                    assert!(s.converged(), "{method:?} {s:?}");
                    (s, h)
                })
                .collect();
            let (plain, chord) = (&runs[0].0, &runs[1].0);
            assert!(
                chord.factorizations < plain.factorizations,
                "{method:?}: {} vs {} factorisations",
                chord.factorizations,
                plain.factorizations
            );
            assert!(chord.factorizations < chord.iterations, "{chord:?}");
            let relative = chord.final_objective / plain.final_objective - 1.0;
            assert!(relative.abs() < 1e-8, "{method:?}: {relative}");
            let apart = (runs[0].1.poses.iter().zip(&runs[1].1.poses))
                .map(|(p, q)| (p.x - q.x).hypot(p.y - q.y))
                .fold(0.0, f64::max);
            // Within the plain run's resolution: its last step's length
            // (here a large-residual problem, converging linearly).
            let resolution = plain.history.last().unwrap().step_max;
            assert!(apart < resolution, "{method:?}: poses {apart} apart");
        }
    }

    #[test]
    fn same_input_options_and_threads_give_the_same_bits() {
        // Large enough that a parallel sum split by work stealing would differ
        // between runs (it did in one run of two before the objective was
        // summed in edge order).
        for threads in [1, 2] {
            let (poses, objectives) = two_rounds(threads);
            let (poses_again, objectives_again) = two_rounds(threads);
            let differ =
                |a: &[u64], b: &[u64]| (0..a.len().max(b.len())).find(|&k| a.get(k) != b.get(k));
            assert_eq!(
                differ(&objectives, &objectives_again),
                None,
                "threads {threads}: the first objective that differs"
            );
            assert!(poses == poses_again, "threads {threads}: the poses differ");
        }
    }

    /// A simulated grid of `poses` poses from its dead-reckoning guess, which LM
    /// takes many iterations to solve.
    fn dead_reckoned_grid(poses: usize) -> Graph<Se2, 3> {
        let options = pgo_sim::SimulationOptions {
            poses,
            seed: 3,
            ..Default::default()
        };
        read_back(&pgo_sim::simulate_planar(&options).unwrap().noisy)
    }

    /// Stops the run at the first question after `after` iterations; keeps the
    /// records.
    struct StopAfter {
        after: usize,
        records: Vec<IterationRecord>,
    }

    impl Observer for StopAfter {
        fn iteration(&mut self, record: &IterationRecord) {
            self.records.push(*record);
        }

        fn should_stop(&mut self) -> bool {
            self.records.len() >= self.after
        }
    }

    #[test]
    fn an_observer_stops_the_run_after_k_iterations_with_the_best_poses() {
        let start = dead_reckoned_grid(300);
        let k = 3;
        // The same run limited to k iterations: where the cancelled one must be.
        let mut limited = start.clone();
        let options = SolveSettings {
            max_iterations: k,
            ..Default::default()
        };
        let expected = optimize(&mut limited, &options).unwrap();
        assert_eq!(expected.stop_reason, StopReason::MaxIterations);
        let mut g = start.clone();
        let mut opt = Optimizer::new(&g, None, SolveSettings::default()).unwrap();
        let mut observer = StopAfter {
            after: k,
            records: Vec::new(),
        };
        let s = opt.run(&mut g, None, &mut observer).unwrap();
        assert_eq!((s.iterations, s.stop_reason), (k, StopReason::Cancelled));
        assert!(!s.converged());
        assert!(g.poses == limited.poses);
        assert_eq!(s.final_objective, expected.final_objective);
        assert!(s.final_objective < s.initial_objective);
        // Each record has the time since the start, growing, within the run's.
        let times: Vec<Duration> = observer.records.iter().map(|r| r.elapsed).collect();
        assert!(times.windows(2).all(|w| w[0] <= w[1]), "{times:?}");
        assert!(times.last().is_some_and(|&t| t <= s.time));
    }

    #[test]
    fn a_token_cancelled_before_the_run_stops_it_at_once() {
        let start = dead_reckoned_grid(300);
        let mut g = start.clone();
        let cancel = Cancel::new();
        let mut opt = Optimizer::new(&g, None, SolveSettings::default()).unwrap();
        let mut seen = 0;
        let mut progress = |_: &IterationRecord| seen += 1;
        // Not cancelled: the run goes on (and reports) ...
        let mut observer = Cancellable::new(cancel.clone(), &mut progress);
        let s = opt.run(&mut g, None, &mut observer).unwrap();
        assert!(s.converged() && s.iterations > 3, "{s:?}");
        let reported = s.iterations;
        // ... cancelled from another thread: the next run does nothing.
        let handle = cancel.clone();
        std::thread::spawn(move || handle.cancel()).join().unwrap();
        assert!(cancel.is_cancelled());
        g.poses.clone_from(&start.poses);
        let s = opt.run(&mut g, None, &mut observer).unwrap();
        assert_eq!((s.iterations, s.stop_reason), (0, StopReason::Cancelled));
        assert_eq!(s.final_objective, s.initial_objective);
        assert!(g.poses == start.poses);
        // The token alone is an observer too.
        let s = opt.run(&mut g, None, &mut cancel.clone()).unwrap();
        assert_eq!((s.iterations, s.stop_reason), (0, StopReason::Cancelled));
        drop(observer);
        assert_eq!(seen, reported);
    }

    /// Stops the run at the first question asked between two LM trials (the
    /// second question without an iteration between).
    #[derive(Default)]
    struct StopBetweenTrials {
        records: Vec<IterationRecord>,
        asked_since_record: usize,
    }

    impl Observer for StopBetweenTrials {
        fn iteration(&mut self, record: &IterationRecord) {
            self.records.push(*record);
            self.asked_since_record = 0;
        }

        fn should_stop(&mut self) -> bool {
            self.asked_since_record += 1;
            self.asked_since_record > 1
        }
    }

    #[test]
    fn an_observer_stops_the_run_between_lm_trials() {
        // A start where LM rejects a trial after at least one iteration.
        let found = (0..500).find_map(|seed| {
            let g = square(2.5, seed);
            let mut records = Vec::new();
            optimize_observed(&mut g.clone(), &mut |r: &IterationRecord| records.push(*r));
            let k = records.iter().skip(1).position(|r| r.rejected > 0)?;
            Some((g, records, k + 1))
        });
        let (mut g, full, k) = found.expect("no start with a rejected trial");
        let mut opt = Optimizer::new(&g, None, SolveSettings::default()).unwrap();
        let mut observer = StopBetweenTrials::default();
        let s = opt.run(&mut g, None, &mut observer).unwrap();
        // Stopped in iteration k + 1, after its first rejected trial: the poses
        // and objective of iteration k, one factorisation more than those.
        assert_eq!((s.iterations, s.stop_reason), (k, StopReason::Cancelled));
        let trials: usize = full[..k].iter().map(|r| r.rejected + 1).sum();
        assert_eq!(s.factorizations, trials + 1);
        assert_eq!(s.final_objective, full[k - 1].objective);
        assert!((g.chi2() - s.final_objective).abs() <= 1e-12 * s.final_objective.max(1.0));
    }

    /// [`optimize`] with an observer.
    fn optimize_observed(g: &mut Graph<Se2, 3>, observer: &mut dyn Observer) -> Summary {
        let mut opt = Optimizer::new(g, None, SolveSettings::default()).unwrap();
        opt.run(g, None, observer).unwrap()
    }

    /// [`dead_reckoned_grid`] of 300 poses with every pose but the gauge moved
    /// up to `reach` metres and given a random heading.
    fn far_start(seed: u64, reach: f64) -> Graph<Se2, 3> {
        let mut g = dead_reckoned_grid(300);
        let mut rng = StdRng::seed_from_u64(seed);
        for p in g.poses.iter_mut().skip(1) {
            *p = Se2::new(
                rng.random_range(-reach..reach),
                rng.random_range(-reach..reach),
                rng.random_range(-PI..PI),
            );
        }
        g
    }

    /// The decrease of χ² that the undamped Gauss–Newton model foresees from
    /// the graph's poses, relative to χ² there.
    fn newton_decrement(g: &Graph<Se2, 3>) -> f64 {
        let mut opt = Optimizer::new(g, None, SolveSettings::default()).unwrap();
        let chi2 = opt.linearize(g, None);
        opt.system_mut().factorize(0.0).unwrap();
        let mut step = vec![0.0; 3 * opt.system().num_blocks()];
        opt.system_mut().solve(&mut step);
        opt.system().predicted_decrease(&step) / chi2
    }

    #[test]
    fn a_damped_crawl_ends_the_run_only_when_asked() {
        // A far start: the first undamped step is rejected and LM goes on
        // damped, each step lowering the objective a little.
        let options = SolveSettings {
            initial_lambda: 1e2,
            ..Default::default()
        };
        let s = optimize(&mut far_start(0, 1e3), &options).unwrap();
        assert!(s.history.iter().any(|r| r.lambda > 0.0), "{s:?}");
        let crawl = |t: f64| SolveSettings {
            crawl_tolerance: Some(Crawl {
                damped: t,
                linear: t,
            }),
            ..options.clone()
        };
        let s = optimize(&mut far_start(0, 1e3), &crawl(0.5)).unwrap();
        assert_eq!(s.stop_reason, StopReason::Crawling, "{s:?}");
        assert!(!s.converged() && s.iterations >= 1);
        let last = s.history.last().unwrap();
        assert!(last.lambda > 0.0);
        // Gauss–Newton converging quadratically is never a crawl.
        let s = optimize(&mut square(0.3, 1), &crawl(0.5)).unwrap();
        assert!(s.converged(), "{s:?}");
        assert!(s.history.iter().all(|r| r.lambda == 0.0));
    }

    #[test]
    fn gauss_newton_converging_linearly_is_a_crawl_only_when_asked() {
        let g = square(0.3, 1);
        let settings = |crawl_tolerance| SolveSettings {
            crawl_tolerance,
            ..Default::default()
        };
        let tolerance = Crawl {
            damped: 0.0,
            linear: 1e-2,
        };
        let asked = Optimizer::new(&g, None, settings(Some(tolerance))).unwrap();
        // 0.5 % after 0.8 %: the decreases shrink by less than half.
        let step = (100.0, 99.5);
        let crawl = Some(StopReason::Crawling);
        assert_eq!(asked.stop_after_step(step, 0.0, Some(0.008)), crawl);
        assert_eq!(asked.stop_after_step(step, 0.0, Some(0.01)), crawl);
        // After 1.1 %: quadratic, or the first Gauss–Newton step: go on.
        assert_eq!(asked.stop_after_step(step, 0.0, Some(0.011)), None);
        assert_eq!(asked.stop_after_step(step, 0.0, None), None);
        // 2 % is no crawl, however it shrinks.
        assert_eq!(asked.stop_after_step((100.0, 98.0), 0.0, Some(0.03)), None);
        let not_asked = Optimizer::new(&g, None, settings(None)).unwrap();
        assert_eq!(not_asked.stop_after_step(step, 0.0, Some(0.008)), None);
    }

    #[test]
    fn a_far_start_converges_only_where_the_model_is_trusted() {
        // Far starts end in local minima of the wrapped angles (converged, the
        // model foreseeing nothing more), or not converged.
        let mut converged = 0;
        for seed in 0..4 {
            for method in [Method::LevenbergMarquardt, Method::GaussNewton] {
                let mut g = far_start(seed, 1e3);
                let options = SolveSettings {
                    method,
                    ..Default::default()
                };
                let Ok(s) = optimize(&mut g, &options) else {
                    continue;
                };
                if s.converged() {
                    converged += 1;
                    let decrement = newton_decrement(&g);
                    assert!(
                        decrement < 1e-6,
                        "{method:?} seed {seed}: {decrement:e} {s:?}"
                    );
                }
            }
        }
        assert!(converged > 0);
        // Damped hard after the first rejected step, LM crawls: the objective
        // barely decreases (less than the relative tolerance) while the model
        // still foresees a large decrease. That is no convergence.
        let mut g = far_start(0, 1e3);
        let options = SolveSettings {
            initial_lambda: 1e12,
            ..Default::default()
        };
        let s = optimize(&mut g, &options).unwrap();
        assert_eq!(s.stop_reason, StopReason::Stalled, "{s:?}");
        assert!(!s.converged() && s.iterations >= 1);
        assert!(s.final_objective < s.initial_objective);
        assert!(s.history.iter().all(|r| r.lambda > 1e6), "{s:?}");
        let decrement = newton_decrement(&g);
        assert!(decrement > 1e-3, "{decrement:e}");
        // So is a step below the step tolerance because the damping made it so.
        let mut g = far_start(0, 1e3);
        let options = SolveSettings {
            initial_lambda: 1e12,
            step_tolerance: 1e-3,
            ..Default::default()
        };
        let s = optimize(&mut g, &options).unwrap();
        assert_eq!((s.iterations, s.stop_reason), (0, StopReason::Stalled));
        // An undamped step below it is convergence.
        let (mut g, _) = open_loop();
        optimize(&mut g, &SolveSettings::default()).unwrap();
        let options = SolveSettings {
            step_tolerance: 1e-3,
            ..Default::default()
        };
        let s = optimize(&mut g, &options).unwrap();
        assert_eq!((s.iterations, s.stop_reason), (0, StopReason::SmallStep));
    }
}

#[test]
fn the_last_evaluation_gives_each_edges_chi2_at_the_map_while_it_is_there() {
    // A noisy loop (non-zero optimum), one edge weighted 0 with a huge cost.
    let mut g = square(0.3, 4);
    g.edges[1].measurement = Se2::new(0.5, -0.2, 0.1).compose(&g.edges[1].measurement);
    let weights = [1.0, 1.0, 0.5, 0.0];
    let mut opt = Optimizer::new(&g, Some(&weights), SolveSettings::default()).unwrap();
    opt.run(&mut g, Some(&weights), &mut |_: &IterationRecord| {})
        .unwrap();
    let reused = opt
        .edge_chi2s_at(&g)
        .expect("the run ended at an evaluated map");
    let fresh = g.edge_chi2s();
    assert!(fresh.iter().all(|&c| c > 0.0), "{fresh:?}");
    let bits = |v: &[f64]| v.iter().map(|c| c.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(reused), bits(&fresh));
    g.poses[2].x += 1e-9;
    assert!(opt.edge_chi2s_at(&g).is_none());
    // Linearised there since: its poses are prepared, their χ² is not.
    opt.linearize(&g, Some(&weights));
    assert!(opt.edge_chi2s_at(&g).is_none());
}

#[test]
fn an_optimiser_of_the_grown_graph_given_the_last_ones_spare_solves_alike() {
    let mut g = square(0.3, 5);
    let mut first = Optimizer::new(&g, None, SolveSettings::default()).unwrap();
    first
        .run(&mut g, None, &mut |_: &IterationRecord| {})
        .unwrap();
    let spare = first.take_spare();
    // Grown by a vertex and an edge; one old pose moved since (its
    // preparation in the spare is stale).
    g.add_vertex(4, Se2::new(0.5, 1.5, 0.3)).unwrap();
    let z = Se2::new(0.5, 0.4, 0.2);
    g.add_edge(3, 4, z, Matrix3::identity(), None).unwrap();
    g.poses[2].theta += 0.05;
    let run = |spare: Option<Spare<Se2, 3>>| {
        let mut g = g.clone();
        let mut opt = Optimizer::new(&g, None, SolveSettings::default()).unwrap();
        if let Some(s) = spare {
            opt.reuse_spare(s);
        }
        let s = opt
            .run(&mut g, None, &mut |_: &IterationRecord| {})
            .unwrap();
        (s.final_objective.to_bits(), g.poses)
    };
    assert_eq!(run(Some(spare)), run(None));
}

/// A chain of `n` SE(2) poses with one loop, at extreme scales: positions
/// up to 10^±`pos_exp`, information 10^±`info_exp`, measurements that
/// disagree with the guess.
fn extreme_graph(
    n: usize,
    pos_exp: i32,
    info_exp: i32,
    seeds: &[(f64, f64, f64)],
) -> Graph<Se2, 3> {
    let scale = 10f64.powi(pos_exp);
    let info = Matrix3::identity() * 10f64.powi(info_exp);
    let mut g = Graph::new();
    for k in 0..n {
        let (a, b, c) = seeds[k % seeds.len()];
        g.add_vertex(k as u64, Se2::new(a * scale * k as f64, b * scale, c * 3.0))
            .expect("new id");
    }
    for k in 1..n {
        let (a, b, c) = seeds[(k * 7) % seeds.len()];
        g.add_edge(
            (k - 1) as u64,
            k as u64,
            Se2::new(scale * (1.0 + a), scale * b, c),
            info,
            None,
        )
        .expect("edge");
    }
    let (a, b, c) = seeds[0];
    g.add_edge(
        0,
        (n - 1) as u64,
        Se2::new(scale * a * n as f64, scale * b, c * 2.0),
        info,
        None,
    )
    .expect("loop");
    g
}

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig::with_cases(200))]

    /// LM and GN at scales where χ² overflows at some trial points (beyond
    /// the information range the job accepts, so only the solver sees
    /// them): the result is finite poses with an objective no worse than
    /// the start, or a named error; never NaN.
    #[test]
    fn lm_never_returns_non_finite_poses(
        n in 3usize..8,
        pos_exp in -5i32..160,
        info_exp in -200i32..200,
        seeds in proptest::collection::vec(
            (-1.0f64..1.0, -1.0f64..1.0, -1.0f64..1.0),
            1..8,
        ),
        gn in proptest::prelude::any::<bool>(),
    ) {
        use proptest::prelude::prop_assert;
        let mut g = extreme_graph(n, pos_exp, info_exp, &seeds);
        let start = g.chi2();
        let options = SolveSettings {
            method: if gn { Method::GaussNewton } else { Method::LevenbergMarquardt },
            max_iterations: 30,
            ..SolveSettings::default()
        };
        match optimize(&mut g, &options) {
            Ok(s) => {
                prop_assert!(g.poses.iter().all(|p| p.is_finite()), "{:?}", g.poses);
                prop_assert!(s.final_objective.is_finite());
                prop_assert!(s.final_objective <= s.initial_objective, "{s:?}");
                prop_assert!(s.history.iter().all(|r| r.objective.is_finite()));
                prop_assert!(s.final_objective <= start || !start.is_finite());
            }
            Err(SolveError::NonFiniteStart) => prop_assert!(!start.is_finite()),
            Err(SolveError::NotPositiveDefinite { vertex }) => prop_assert!(vertex < n as u64),
            Err(e) => prop_assert!(false, "unexpected error {e}"),
        }
    }
}

#[test]
fn a_factorisation_without_a_few_edges_solves_as_one_made_afresh() {
    // A noisy ring of 40 poses with chords: a factor of many supernodes,
    // most of which a chord left out does not reach.
    let mut rng = StdRng::seed_from_u64(5);
    let n = 40;
    let truth: Vec<Se2> = (0..n)
        .map(|k| {
            let a = 2.0 * PI * k as f64 / n as f64;
            Se2::new(10.0 * a.cos(), 10.0 * a.sin(), a + FRAC_PI_2)
        })
        .collect();
    let mut g = Graph::new();
    for (k, t) in truth.iter().enumerate() {
        let jitter = if k == 0 { 0.0 } else { 0.05 };
        let p = Se2::new(
            t.x + jitter * rng.random_range(-1.0..1.0),
            t.y + jitter * rng.random_range(-1.0..1.0),
            t.theta + jitter * rng.random_range(-1.0..1.0),
        );
        g.add_vertex(k as u64, p).unwrap();
    }
    let pairs = (0..n).map(|k| (k, (k + 1) % n));
    let chords = (0..n).step_by(4).map(|k| (k, (k + 5) % n));
    for (i, j) in pairs.chain(chords) {
        let z = truth[i].inverse().compose(&truth[j]);
        g.add_edge(i as u64, j as u64, z, Matrix3::identity(), None)
            .unwrap();
    }
    let all = vec![1.0; g.edges.len()];
    let mut opt = Optimizer::new(&g, Some(&all), SolveSettings::default()).unwrap();
    opt.factor_at(&g, &all).unwrap();
    // Two chords out, then two others out and the first two back.
    for out in [[n, n + 3], [n + 5, n + 8]] {
        let mut w = all.clone();
        out.iter().for_each(|&k| w[k] = 0.0);
        opt.factor_without(&g, &w).unwrap();
        let step = opt.remaining_step();
        let mut fresh = Optimizer::new(&g, Some(&w), SolveSettings::default()).unwrap();
        fresh.factor_at(&g, &w).unwrap();
        let want = fresh.remaining_step();
        let scale = want.iter().fold(0.0f64, |m, x| m.max(x.abs()));
        assert!(scale > 1e-3, "a step to compare: {scale}");
        for (a, b) in step.iter().zip(&want) {
            assert!((a - b).abs() < 1e-9 * scale, "{a} against {b}");
        }
    }
}
