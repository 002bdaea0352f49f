//! Tests of the optimiser: exact optima, innovations, weights and cut-off
//! vertices, limits, errors.

use super::*;
use crate::geometry::{Se2, Se3};
use nalgebra::{Matrix3, Matrix6, UnitQuaternion, Vector3, Vector6};
use rand::{Rng, SeedableRng, rngs::StdRng};
use std::f64::consts::{FRAC_PI_2, PI};

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
            &SolverOptions {
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
    let s = optimize(&mut g, &SolverOptions::default()).unwrap();
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
    let mut opt = Optimizer::new(&g, Some(&without), SolverOptions::default()).unwrap();
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
    let s = optimize(&mut g, &SolverOptions::default()).unwrap();
    assert!((s.final_objective - 0.04).abs() < 1e-8);
    // A vertex no edge of non-zero weight ties to the gauge is held
    // fixed: the solution adds nothing to an edge at it.
    let mut g2 = g.clone();
    g2.add_vertex(9, Se2::new(5.0, 0.0, 0.0)).unwrap();
    g2.add_edge(3, 9, Se2::new(1.0, 0.0, 0.0), i, None).unwrap();
    let w = [1.0, 1.0, 1.0, 1.0, 0.0];
    let mut opt = Optimizer::new(&g2, Some(&[1.0; 5]), SolverOptions::default()).unwrap();
    let nu2 = opt.innovation_chi2(&g2, &w, &[4]).unwrap();
    assert_eq!(nu2[0], g2.edge_chi2(&g2.edges[4]));
    // Weights must match the edges.
    assert!(opt.innovation_chi2(&g2, &w[..2], &[4]).is_err());
}

#[test]
fn leave_one_out_innovation_is_the_innovation_without_the_edge() {
    // The open loop closed: any one edge left out leaves a chain that
    // fits exactly, and adding it back raises χ² by 0.04 (above). So
    // each edge's deleted residual at the optimum of all four is 0.04,
    // the innovation of the closing edge left out.
    let (mut g, i) = open_loop();
    optimize(&mut g, &SolverOptions::default()).unwrap();
    let all = [1.0; 4];
    let mut opt = Optimizer::new(&g, Some(&all), SolverOptions::default()).unwrap();
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
    let mut opt = Optimizer::new(&g2, Some(&w), SolverOptions::default()).unwrap();
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
    let s = optimize(&mut g, &SolverOptions::default()).unwrap();
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
    let mut opt = Optimizer::new(&g, None, SolverOptions::default()).unwrap();
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
    let mut opt = Optimizer::new(&g, None, SolverOptions::default()).unwrap();
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
    let err = optimize(&mut g, &SolverOptions::default()).unwrap_err();
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
            &SolverOptions {
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
        &SolverOptions {
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
        &SolverOptions {
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
        let mut opt = Optimizer::new(&g, None, SolverOptions::default()).unwrap();
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
        optimize(&mut g, &SolverOptions::default()).unwrap_err(),
        SolveError::NonFiniteStart
    );
}

#[test]
fn threads_start_a_private_pool_of_that_size_only_from_two() {
    let mut g = square(0.3, 6);
    for (threads, expected) in [(0, 1), (1, 1), (2, 2), (3, 3)] {
        let options = SolverOptions {
            threads,
            ..Default::default()
        };
        let opt = Optimizer::new(&g, None, options).unwrap();
        assert_eq!(opt.parallelism.threads(), expected, "threads {threads}");
        assert_eq!(opt.parallelism.is_parallel(), threads >= 2);
    }
    // Changing the option between runs starts or stops the pool.
    let mut opt = Optimizer::new(&g, None, SolverOptions::default()).unwrap();
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
    optimize(&mut g, &SolverOptions::default()).unwrap();
    let k = g.edges.len() - 1;
    g.edges[k].measurement.x += 0.05;
    let runs: Vec<(usize, f64)> = [None, Some(1e-8)]
        .into_iter()
        .map(|model_tolerance| {
            let mut h = g.clone();
            let options = SolverOptions {
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

#[test]
fn the_last_evaluation_gives_each_edges_chi2_at_the_map_while_it_is_there() {
    // A noisy loop (non-zero optimum), one edge weighted 0 with a huge cost.
    let mut g = square(0.3, 4);
    g.edges[1].measurement = Se2::new(0.5, -0.2, 0.1).compose(&g.edges[1].measurement);
    let weights = [1.0, 1.0, 0.5, 0.0];
    let mut opt = Optimizer::new(&g, Some(&weights), SolverOptions::default()).unwrap();
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
    let mut first = Optimizer::new(&g, None, SolverOptions::default()).unwrap();
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
        let mut opt = Optimizer::new(&g, None, SolverOptions::default()).unwrap();
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
