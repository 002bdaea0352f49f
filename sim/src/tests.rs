//! Tests of whole simulations: reproducibility, the truth graph, noise
//! calibration, odometry, true loops, wrong loops and their counts.

use super::world::{sphere_trajectory, torus_trajectory};
use super::*;
use crate::graph::Edge;
use crate::graph::LoopCandidate;
use crate::testing::{AnySimulation, Simulation, simulate, simulate_planar, simulate_spatial};
use nalgebra::SVector;
use pgo::{Pose, Se2};

const WORLDS: [World; 3] = [World::Grid2d, World::Sphere3d, World::Torus3d];

pub(super) fn options(world: World, poses: usize) -> SimulationOptions {
    SimulationOptions {
        world,
        poses,
        ..Default::default()
    }
}

/// Runs a check on the simulation of any world.
fn for_each_world(base: SimulationOptions, check: impl Fn(&AnySimulation, &SimulationOptions)) {
    for world in WORLDS {
        let options = SimulationOptions { world, ..base };
        let sim = simulate(&options).unwrap();
        check(&sim, &options);
    }
}

fn loop_radius(options: &SimulationOptions) -> f64 {
    match options.world {
        World::Grid2d => GRID_LOOP_RADIUS,
        World::Sphere3d => sphere_trajectory(options.poses).loop_radius,
        World::Torus3d => torus_trajectory(options.poses).loop_radius,
    }
}

pub(super) fn is_odometry<P, const D: usize>(e: &Edge<P, D>) -> bool {
    e.to == e.from + 1 && e.candidate.is_none()
}

/// Mean of `eₖ² Ωₖₖ` per component and of `eᵀΩe` over the edges that are
/// not wrong, at the true poses.
fn chi2_at_truth<P: Pose<D>, const D: usize>(sim: &Simulation<P, D>) -> (SVector<f64, D>, f64) {
    let mut at_truth = sim.noisy.clone();
    at_truth.poses.clone_from(&sim.truth.poses);
    let kept: Vec<&Edge<P, D>> = at_truth
        .edges
        .iter()
        .zip(&sim.wrong)
        .filter(|(_, w)| !**w)
        .map(|(e, _)| e)
        .collect();
    let n = kept.len() as f64;
    let mut per_component = SVector::<f64, D>::zeros();
    let mut total = 0.0;
    for e in &kept {
        let err = at_truth.edge_error(e);
        for k in 0..D {
            per_component[k] += err[k] * err[k] * e.information[(k, k)] / n;
        }
        total += at_truth.edge_chi2(e) / n;
    }
    (per_component, total)
}

fn same_graphs<P: Pose<D>, const D: usize>(a: &Simulation<P, D>, b: &Simulation<P, D>) -> bool {
    a.noisy.poses == b.noisy.poses
        && a.noisy.edges == b.noisy.edges
        && a.truth.poses == b.truth.poses
        && a.truth.edges == b.truth.edges
        && a.wrong == b.wrong
}

#[test]
fn same_seed_gives_the_same_graphs() {
    let base = SimulationOptions {
        poses: 600,
        outliers: 25,
        outlier_policy: OutlierPolicy::Grouped,
        inliers: Some(InlierModel::default()),
        seed: 42,
        ..Default::default()
    };
    for world in WORLDS {
        let options = SimulationOptions { world, ..base };
        let other_seed = SimulationOptions {
            seed: 43,
            ..options
        };
        match (
            simulate(&options).unwrap(),
            simulate(&options).unwrap(),
            simulate(&other_seed).unwrap(),
        ) {
            (AnySimulation::Planar(a), AnySimulation::Planar(b), AnySimulation::Planar(c)) => {
                assert!(same_graphs(&a, &b));
                assert!(!same_graphs(&a, &c));
            }
            (AnySimulation::Spatial(a), AnySimulation::Spatial(b), AnySimulation::Spatial(c)) => {
                assert!(same_graphs(&a, &b));
                assert!(!same_graphs(&a, &c));
            }
            _ => panic!("{world:?} changed dimension"),
        }
    }
}

#[test]
fn truth_graph_has_zero_chi2_and_no_wrong_edges() {
    let base = SimulationOptions {
        poses: 800,
        outliers: 30,
        inliers: Some(InlierModel::default()),
        ..Default::default()
    };
    for_each_world(base, |sim, options| {
        let (truth_chi2, truth_edges, noisy_edges, wrong) = match sim {
            AnySimulation::Planar(s) => (
                s.truth.chi2(),
                s.truth.edges.len(),
                s.noisy.edges.len(),
                s.num_wrong(),
            ),
            AnySimulation::Spatial(s) => (
                s.truth.chi2(),
                s.truth.edges.len(),
                s.noisy.edges.len(),
                s.num_wrong(),
            ),
        };
        assert!(
            truth_chi2 < 1e-12,
            "{:?}: truth χ² = {truth_chi2:e}",
            options.world
        );
        assert_eq!(wrong, 30);
        assert_eq!(truth_edges + wrong, noisy_edges);
    });
}

#[test]
fn truth_edges_match_the_noisy_edges_that_are_not_wrong() {
    let options = SimulationOptions {
        poses: 400,
        outliers: 15,
        inliers: Some(InlierModel::default()),
        ..Default::default()
    };
    let sim = simulate_planar(&options).unwrap();
    let kept: Vec<_> = sim
        .noisy
        .edges
        .iter()
        .zip(&sim.wrong)
        .filter(|(_, w)| !**w)
        .map(|(e, _)| e)
        .collect();
    assert_eq!(kept.len(), sim.truth.edges.len());
    for (n, t) in kept.iter().zip(&sim.truth.edges) {
        assert_eq!(
            (n.from, n.to, n.information, n.candidate),
            (t.from, t.to, t.information, t.candidate)
        );
    }
    assert_eq!(sim.noisy.ids(), sim.truth.ids());
    assert!(sim.noisy.ids().iter().copied().eq(0..400));
    assert!(sim.noisy.is_connected());
}

#[test]
fn noise_is_calibrated_to_the_information() {
    let base = SimulationOptions {
        poses: 3000,
        loops: 2000,
        translation_noise: 0.1,
        rotation_noise: 0.05,
        ..Default::default()
    };
    for_each_world(base, |sim, options| {
        let (per_component, total, dim) = match sim {
            AnySimulation::Planar(s) => {
                let (c, t) = chi2_at_truth(s);
                (c.iter().copied().collect::<Vec<_>>(), t, 3.0)
            }
            AnySimulation::Spatial(s) => {
                let (c, t) = chi2_at_truth(s);
                (c.iter().copied().collect::<Vec<_>>(), t, 6.0)
            }
        };
        assert!(
            (total - dim).abs() < 0.05 * dim,
            "{:?}: mean χ² {total} vs {dim}",
            options.world
        );
        for (k, c) in per_component.iter().enumerate() {
            assert!(
                (c - 1.0).abs() < 0.1,
                "{:?}: component {k} has normalised variance {c}",
                options.world
            );
        }
    });
}

fn check_dead_reckoning<P: Pose<D>, const D: usize>(sim: &Simulation<P, D>) {
    assert_eq!(sim.noisy.poses[0], P::identity());
    let odometry: Vec<_> = sim.noisy.edges.iter().filter(|e| is_odometry(e)).collect();
    assert_eq!(odometry.len(), sim.noisy.num_vertices() - 1);
    for (k, e) in odometry.iter().enumerate() {
        assert_eq!((e.from, e.to), (k, k + 1));
        let composed = sim.noisy.poses[k].compose(&e.measurement);
        assert!(P::error(&composed, &sim.noisy.poses[k + 1], &P::identity()).norm() < 1e-9);
    }
}

#[test]
fn odometry_composes_to_the_dead_reckoning_guess() {
    for_each_world(options(World::Grid2d, 500), |sim, _| match sim {
        AnySimulation::Planar(s) => check_dead_reckoning(s),
        AnySimulation::Spatial(s) => check_dead_reckoning(s),
    });
}

fn check_loops<P: Pose<D>, const D: usize>(sim: &Simulation<P, D>, options: &SimulationOptions) {
    let radius = loop_radius(options);
    let loops: Vec<_> = sim.truth.edges.iter().filter(|e| !is_odometry(e)).collect();
    assert_eq!(loops.len(), options.loops, "{:?}", options.world);
    for e in loops {
        assert!(e.to >= e.from + MIN_LOOP_SEPARATION);
        let d = (sim.truth.poses[e.from].position() - sim.truth.poses[e.to].position()).norm();
        assert!(
            d <= radius,
            "{:?}: loop {}–{} is {d} m long",
            options.world,
            e.from,
            e.to
        );
        // No outliers and no inlier model: loops are trusted.
        assert!(e.candidate.is_none());
    }
    // Edges come in the order of their later vertex, odometry first.
    let keys: Vec<_> = sim
        .noisy
        .edges
        .iter()
        .map(|e| (e.to, !is_odometry(e)))
        .collect();
    assert!(keys.windows(2).all(|w| w[0] <= w[1]));
}

#[test]
fn loops_are_close_in_space_and_far_in_time() {
    let base = SimulationOptions {
        poses: 1500,
        loops: 400,
        ..Default::default()
    };
    for_each_world(base, |sim, options| match sim {
        AnySimulation::Planar(s) => check_loops(s, options),
        AnySimulation::Spatial(s) => check_loops(s, options),
    });
}

#[test]
fn loops_are_capped_by_what_the_trajectory_offers() {
    // Ten poses cannot close a loop MIN_LOOP_SEPARATION steps apart.
    let sim = simulate_planar(&SimulationOptions {
        poses: 10,
        loops: 5,
        ..Default::default()
    })
    .unwrap();
    assert_eq!(sim.noisy.edges.len(), 9);
    let sim = simulate_spatial(&SimulationOptions {
        world: World::Sphere3d,
        poses: 200,
        loops: 100_000,
        ..Default::default()
    })
    .unwrap();
    let loops = sim.noisy.edges.len() - 199;
    assert!(loops > 100 && loops <= 200 - MIN_LOOP_SEPARATION);
}

#[test]
fn true_loops_are_candidates_when_wrong_ones_are_planted() {
    let sim = simulate_planar(&SimulationOptions {
        poses: 500,
        loops: 50,
        outliers: 10,
        ..Default::default()
    })
    .unwrap();
    let loops = sim.noisy.edges.iter().filter(|e| e.to > e.from + 1).count();
    assert_eq!(sim.noisy.num_candidates(), loops);
    assert!(
        sim.noisy
            .edges
            .iter()
            .all(|e| e.candidate.is_none_or(|c| c.inliers.is_none()))
    );
}

pub(super) fn wrong_edges<P: Pose<D>, const D: usize>(sim: &Simulation<P, D>) -> Vec<&Edge<P, D>> {
    sim.noisy
        .edges
        .iter()
        .zip(&sim.wrong)
        .filter(|(_, w)| **w)
        .map(|(e, _)| e)
        .collect()
}

#[test]
fn random_and_local_outliers_are_placed_by_policy() {
    for (policy, max_gap) in [
        (OutlierPolicy::Random, usize::MAX),
        (OutlierPolicy::Local, DEFAULT_LOCAL_WINDOW),
    ] {
        let options = SimulationOptions {
            poses: 700,
            outliers: 57,
            outlier_policy: policy,
            ..Default::default()
        };
        let sim = simulate_planar(&options).unwrap();
        let wrong = wrong_edges(&sim);
        assert_eq!(wrong.len(), 57);
        for e in wrong {
            assert!(
                e.from < e.to && e.to - e.from >= 2 && e.to - e.from <= max_gap,
                "{policy:?}: {}–{}",
                e.from,
                e.to
            );
            assert_eq!(e.candidate, Some(LoopCandidate { inliers: None }));
            assert_eq!(
                e.information,
                Se2::information(options.translation_noise, options.rotation_noise)
            );
        }
    }
}

pub(super) fn check_grouped<P: Pose<D>, const D: usize>(
    sim: &Simulation<P, D>,
    count: usize,
    group: usize,
) {
    let mut wrong = wrong_edges(sim);
    assert_eq!(wrong.len(), count);
    wrong.sort_by_key(|e| (e.from, e.to));
    // Members of a group share their measurement and are (i+k, j+k).
    let mut groups: Vec<Vec<&Edge<P, D>>> = Vec::new();
    for e in wrong {
        match groups
            .iter_mut()
            .find(|g| g[0].measurement == e.measurement)
        {
            Some(g) => g.push(e),
            None => groups.push(vec![e]),
        }
    }
    let mut sizes: Vec<usize> = groups.iter().map(Vec::len).collect();
    sizes.sort_unstable();
    let mut expected = vec![group; count / group];
    if count % group > 0 {
        expected.insert(0, count % group);
    }
    assert_eq!(sizes, expected);
    for g in &groups {
        for (k, e) in g.iter().enumerate() {
            assert_eq!((e.from, e.to), (g[0].from + k, g[0].to + k));
            assert!(e.to - e.from >= 2);
        }
    }
}

#[test]
fn grouped_outliers_share_one_wrong_transform() {
    let base = SimulationOptions {
        poses: 600,
        outliers: 25,
        outlier_policy: OutlierPolicy::Grouped,
        group_size: 10,
        ..Default::default()
    };
    for_each_world(base, |sim, _| match sim {
        AnySimulation::Planar(s) => check_grouped(s, 25, 10),
        AnySimulation::Spatial(s) => check_grouped(s, 25, 10),
    });
}

#[test]
fn inlier_counts_of_true_and_wrong_candidates_separate() {
    let model = InlierModel::default();
    let options = SimulationOptions {
        poses: 2000,
        loops: 800,
        outliers: 400,
        inliers: Some(model),
        ..Default::default()
    };
    let sim = simulate_planar(&options).unwrap();
    let (mut true_counts, mut wrong_counts) = (Vec::new(), Vec::new());
    for (e, &w) in sim.noisy.edges.iter().zip(&sim.wrong) {
        match (e.candidate, w) {
            (None, false) => assert!(is_odometry(e)),
            (None, true) => panic!("a wrong loop is trusted"),
            (Some(LoopCandidate { inliers: None }), _) => panic!("a candidate without a count"),
            (Some(LoopCandidate { inliers: Some(n) }), false) => true_counts.push(n as f64),
            (Some(LoopCandidate { inliers: Some(n) }), true) => wrong_counts.push(n as f64),
        }
    }
    assert_eq!((true_counts.len(), wrong_counts.len()), (800, 400));
    let median = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let (mt, mw) = (median(&mut true_counts), median(&mut wrong_counts));
    assert!(
        (mt / model.true_median - 1.0).abs() < 0.1,
        "true median {mt}"
    );
    assert!(
        (mw / model.wrong_median - 1.0).abs() < 0.1,
        "wrong median {mw}"
    );
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    assert!(mean(&true_counts) > 3.0 * mean(&wrong_counts));
    // σ of the log count.
    let log_sd = |v: &[f64]| {
        let logs: Vec<f64> = v.iter().map(|x| x.max(1.0).ln()).collect();
        let m = mean(&logs);
        (logs.iter().map(|l| (l - m).powi(2)).sum::<f64>() / logs.len() as f64).sqrt()
    };
    assert!((log_sd(&true_counts) - 0.5).abs() < 0.05);
    assert!((log_sd(&wrong_counts) - 0.5).abs() < 0.05);
}

#[test]
fn bad_options_are_errors() {
    for poses in [0, 1] {
        for world in WORLDS {
            assert_eq!(
                simulate(&options(world, poses)).err(),
                Some(SimulationError::TooFewPoses(poses))
            );
        }
    }
    let invalid = |o: SimulationOptions| simulate(&o).err();
    let base = options(World::Grid2d, 100);
    for bad in [
        SimulationOptions {
            translation_noise: 0.0,
            ..base
        },
        SimulationOptions {
            translation_noise: f64::INFINITY,
            ..base
        },
        SimulationOptions {
            rotation_noise: -0.1,
            ..base
        },
        SimulationOptions {
            rotation_noise: f64::NAN,
            ..base
        },
        SimulationOptions {
            rotation_noise: 0.6,
            ..base
        },
        SimulationOptions {
            inliers: Some(InlierModel {
                true_sigma: -1.0,
                ..Default::default()
            }),
            ..base
        },
    ] {
        assert!(
            matches!(
                invalid(bad),
                Some(SimulationError::OutOfRange { .. } | SimulationError::InvalidOption { .. })
            ),
            "{bad:?}"
        );
    }
    assert_eq!(
        invalid(SimulationOptions {
            group_size: 0,
            ..base
        }),
        Some(SimulationError::ZeroGroupSize)
    );
    assert!(matches!(
        simulate_planar(&options(World::Torus3d, 100)),
        Err(SimulationError::WrongWorld { .. })
    ));
    assert!(matches!(
        simulate_spatial(&options(World::Grid2d, 100)),
        Err(SimulationError::WrongWorld { .. })
    ));
    // Two poses leave no room for a non-consecutive wrong loop.
    assert_eq!(
        invalid(SimulationOptions {
            poses: 2,
            outliers: 1,
            ..base
        }),
        Some(SimulationError::NoRoomForOutliers {
            policy: OutlierPolicy::Random,
            vertices: 2
        })
    );
    let grouped = SimulationOptions {
        poses: 11,
        outliers: 10,
        outlier_policy: OutlierPolicy::Grouped,
        ..base
    };
    assert!(matches!(
        invalid(grouped),
        Some(SimulationError::NoRoomForOutliers { .. })
    ));
    // …but three poses do, and two poses simulate fine without outliers.
    assert!(
        simulate(&SimulationOptions {
            poses: 3,
            outliers: 4,
            ..base
        })
        .is_ok()
    );
    assert!(simulate(&SimulationOptions { poses: 2, ..base }).is_ok());
    assert!(
        simulate(&SimulationOptions {
            poses: 12,
            outliers: 10,
            outlier_policy: OutlierPolicy::Grouped,
            ..base
        })
        .is_ok()
    );
}

/// `cargo test -p pgo-sim --release --lib tests::million -- --ignored --nocapture`
#[test]
#[ignore = "a million poses: run in release mode"]
fn million_poses_are_fast() {
    for world in WORLDS {
        let start = std::time::Instant::now();
        let options = SimulationOptions {
            world,
            poses: 1_000_000,
            loops: 300_000,
            outliers: 10_000,
            inliers: Some(InlierModel::default()),
            ..Default::default()
        };
        let edges = match simulate(&options).unwrap() {
            AnySimulation::Planar(s) => s.noisy.edges.len(),
            AnySimulation::Spatial(s) => s.noisy.edges.len(),
        };
        println!("{world:?}: {edges} edges in {:.2?}", start.elapsed());
        assert_eq!(edges, 999_999 + 300_000 + 10_000);
    }
}
