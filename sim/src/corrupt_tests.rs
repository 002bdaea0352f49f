//! Tests of [`corrupt`](super::corrupt): existing loops become candidates,
//! wrong ones are appended, and a failure leaves the graph alone.

use super::tests::{check_grouped, is_odometry};
use super::*;
use crate::graph::{Graph, LoopCandidate};
use crate::testing::{Simulation, corrupt, simulate_planar, simulate_spatial};
use nalgebra::{Matrix3, Vector3};
use pgo::{Pose, Se2};
use rand::{SeedableRng, rngs::StdRng};

fn line_graph(n: u64, information: Matrix3<f64>) -> Graph<Se2, 3> {
    let mut g = Graph::new();
    for k in 0..n {
        g.add_vertex(k, Se2::new(k as f64, 0.0, 0.0));
    }
    for k in 1..n {
        g.add_edge(k - 1, k, Se2::new(1.0, 0.0, 0.0), information, None);
    }
    g
}

/// An 800-pose simulated graph with 120 loops to corrupt.
fn corruptible_graph() -> Simulation<Se2, 3> {
    simulate_planar(&SimulationOptions {
        poses: 800,
        loops: 120,
        ..Default::default()
    })
    .unwrap()
}

#[test]
fn corrupt_marks_existing_loops_and_appends_exactly_the_wrong_ones() {
    let sim = corruptible_graph();
    let mut graph = sim.noisy.clone();
    let before = graph.edges.clone();
    let options = CorruptionOptions {
        outliers: 37,
        policy: OutlierPolicy::Grouped,
        group_size: 10,
        ..Default::default()
    };
    let corruption = corrupt(&mut graph, &options, &mut StdRng::seed_from_u64(4)).unwrap();

    assert_eq!(corruption.marked, 120);
    assert_eq!(graph.edges.len(), before.len() + 37);
    assert_eq!(corruption.wrong.len(), graph.edges.len());
    assert!(corruption.wrong[..before.len()].iter().all(|&w| !w));
    assert!(corruption.wrong[before.len()..].iter().all(|&w| w));
    for (old, new) in before.iter().zip(&graph.edges) {
        assert_eq!(
            (old.from, old.to, old.measurement, old.information),
            (new.from, new.to, new.measurement, new.information)
        );
        if is_odometry(old) {
            assert!(new.candidate.is_none());
        } else {
            assert!(matches!(
                new.candidate,
                Some(LoopCandidate { inliers: Some(_) })
            ));
        }
    }
    let loop_information = before[before.len() - 1].information;
    for e in &graph.edges[before.len()..] {
        assert!(e.to - e.from >= 2);
        assert_eq!(e.information, loop_information);
        assert!(matches!(
            e.candidate,
            Some(LoopCandidate { inliers: Some(_) })
        ));
    }
    let as_sim = Simulation {
        noisy: graph,
        truth: sim.truth,
        wrong: corruption.wrong,
    };
    check_grouped(&as_sim, 37, 10);
}

#[test]
fn corrupt_works_on_spatial_graphs_with_local_outliers() {
    let sim = simulate_spatial(&SimulationOptions {
        world: World::Torus3d,
        poses: 500,
        loops: 80,
        ..Default::default()
    })
    .unwrap();
    let mut graph = sim.noisy;
    let options = CorruptionOptions {
        outliers: 40,
        policy: OutlierPolicy::Local,
        local_window: 5,
        inliers: None,
        ..Default::default()
    };
    let corruption = corrupt(&mut graph, &options, &mut StdRng::seed_from_u64(8)).unwrap();
    assert_eq!(corruption.marked, 80);
    assert_eq!(graph.num_candidates(), 120);
    let wrong: Vec<_> = graph
        .edges
        .iter()
        .zip(&corruption.wrong)
        .filter(|(_, w)| **w)
        .map(|(e, _)| e)
        .collect();
    assert_eq!(wrong.len(), 40);
    for e in wrong {
        assert!((2..=5).contains(&(e.to - e.from)));
        assert_eq!(e.candidate, Some(LoopCandidate { inliers: None }));
        assert!(e.measurement.is_finite());
    }
}

#[test]
fn corrupt_keeps_existing_counts_without_a_model() {
    let mut graph = line_graph(30, Matrix3::identity());
    graph.add_edge(
        0,
        20,
        Se2::new(20.0, 0.0, 0.0),
        Matrix3::identity(),
        Some(LoopCandidate { inliers: Some(77) }),
    );
    let options = CorruptionOptions {
        outliers: 0,
        inliers: None,
        ..Default::default()
    };
    let corruption = corrupt(&mut graph, &options, &mut StdRng::seed_from_u64(1)).unwrap();
    assert_eq!(corruption.marked, 1);
    assert_eq!(
        graph.edges[29].candidate,
        Some(LoopCandidate { inliers: Some(77) })
    );
}

#[test]
fn corrupt_copies_odometry_information_when_there_are_no_loops() {
    let information = Matrix3::from_diagonal(&Vector3::new(5.0, 6.0, 7.0));
    let mut graph = line_graph(40, information);
    let options = CorruptionOptions {
        outliers: 12,
        ..Default::default()
    };
    let corruption = corrupt(&mut graph, &options, &mut StdRng::seed_from_u64(2)).unwrap();
    assert_eq!(corruption.marked, 0);
    assert_eq!(graph.num_candidates(), 12);
    assert!(
        graph.edges[39..]
            .iter()
            .all(|e| e.information == information)
    );
}

#[test]
fn corrupt_avoids_pairs_consecutive_in_id() {
    // Ids 0, 10, 11, 20, 21, …: index neighbours are not id neighbours
    // and some index-distance-2 pairs are id neighbours.
    let mut graph = Graph::<Se2, 3>::new();
    let ids: Vec<u64> = (0..60u64).map(|k| k / 2 * 10 + k % 2).collect();
    for &id in &ids {
        graph.add_vertex(id, Se2::identity());
    }
    for w in ids.windows(2) {
        graph.add_edge(w[0], w[1], Se2::identity(), Matrix3::identity(), None);
    }
    let options = CorruptionOptions {
        outliers: 200,
        policy: OutlierPolicy::Local,
        local_window: 3,
        ..Default::default()
    };
    let corruption = corrupt(&mut graph, &options, &mut StdRng::seed_from_u64(6)).unwrap();
    // Edges whose ids differ by 10 or 9 are non-sequential loops already.
    assert!(corruption.marked > 0);
    for e in graph
        .edges
        .iter()
        .zip(&corruption.wrong)
        .filter(|(_, w)| **w)
        .map(|(e, _)| e)
    {
        assert_ne!(graph.id(e.from).abs_diff(graph.id(e.to)), 1);
    }
}

#[test]
fn corrupt_labels_the_last_loops_known_wrong_with_wrong_counts() {
    let sim = corruptible_graph();
    let mut graph = sim.noisy.clone();
    let n = graph.edges.len();
    let loops: Vec<usize> = (0..n).filter(|&k| !is_odometry(&graph.edges[k])).collect();
    // Counts far apart, so that the model each was drawn from shows.
    let model = InlierModel {
        true_median: 1000.0,
        true_sigma: 0.0,
        wrong_median: 10.0,
        wrong_sigma: 0.0,
    };
    let options = CorruptionOptions {
        outliers: 0,
        known_wrong_last: 20,
        inliers: Some(model),
        ..Default::default()
    };
    let corruption = corrupt(&mut graph, &options, &mut StdRng::seed_from_u64(2)).unwrap();
    assert_eq!(corruption.marked, loops.len() - 20);
    assert_eq!(graph.edges.len(), n);
    for (k, e) in graph.edges.iter().enumerate() {
        let known_wrong = loops[loops.len() - 20..].contains(&k);
        assert_eq!(corruption.wrong[k], known_wrong, "edge {k}");
        let expected = if is_odometry(e) {
            None
        } else if known_wrong {
            Some(10)
        } else {
            Some(1000)
        };
        assert_eq!(e.candidate.and_then(|c| c.inliers), expected, "edge {k}");
    }

    let too_many = CorruptionOptions {
        known_wrong_last: loops.len() + 1,
        ..options
    };
    let mut untouched = sim.noisy.clone();
    assert_eq!(
        corrupt(&mut untouched, &too_many, &mut StdRng::seed_from_u64(2)),
        Err(SimulationError::TooManyKnownWrong {
            asked: loops.len() + 1,
            available: loops.len()
        })
    );
    assert_eq!(untouched.edges, sim.noisy.edges);
}

#[test]
fn corrupt_fails_without_changing_the_graph() {
    let mut tiny = line_graph(2, Matrix3::identity());
    let before = tiny.edges.clone();
    let err = corrupt(
        &mut tiny,
        &CorruptionOptions::default(),
        &mut StdRng::seed_from_u64(1),
    );
    assert_eq!(
        err,
        Err(SimulationError::NoRoomForOutliers {
            policy: OutlierPolicy::Random,
            vertices: 2
        })
    );
    assert_eq!(tiny.edges, before);

    let mut edgeless = Graph::<Se2, 3>::new();
    for k in 0..5 {
        edgeless.add_vertex(k, Se2::identity());
    }
    let err = corrupt(
        &mut edgeless,
        &CorruptionOptions::default(),
        &mut StdRng::seed_from_u64(1),
    );
    assert_eq!(err, Err(SimulationError::NoInformationSource));
    assert!(edgeless.edges.is_empty());

    let grouped = CorruptionOptions {
        policy: OutlierPolicy::Grouped,
        group_size: 10,
        ..Default::default()
    };
    let mut short = line_graph(11, Matrix3::identity());
    assert!(matches!(
        corrupt(&mut short, &grouped, &mut StdRng::seed_from_u64(1)),
        Err(SimulationError::NoRoomForOutliers { .. })
    ));
    assert_eq!(short.edges.len(), 10);

    for bad in [
        CorruptionOptions {
            group_size: 0,
            ..Default::default()
        },
        CorruptionOptions {
            local_window: 1,
            ..Default::default()
        },
        CorruptionOptions {
            translation_scale: f64::NAN,
            ..Default::default()
        },
        CorruptionOptions {
            rotation_scale: -1.0,
            ..Default::default()
        },
        CorruptionOptions {
            inliers: Some(InlierModel {
                wrong_median: 0.0,
                ..Default::default()
            }),
            ..Default::default()
        },
    ] {
        let mut g = line_graph(30, Matrix3::identity());
        assert!(
            corrupt(&mut g, &bad, &mut StdRng::seed_from_u64(1)).is_err(),
            "{bad:?}"
        );
        assert_eq!(g.edges.len(), 29);
    }
}
