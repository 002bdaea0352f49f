//! The ranges of the options: values at the bounds simulate (or corrupt)
//! and read back; values beyond them are errors naming the option and the
//! range.

use super::*;
use crate::testing::{AnySimulation, Simulation, corrupt, simulate};
use nalgebra::Matrix3;
use pgo::AnyPoseGraph;
use pgo::Se2;
use rand::{SeedableRng, rngs::StdRng};
use std::f64::consts::PI;

/// Writes a graph as g2o text, as the library does, and reads it back.
fn read_back<P: ErrorCoordinates<D>, const D: usize>(g: &Graph<P, D>) -> AnyPoseGraph {
    let graph = g
        .to_pose_graph()
        .unwrap_or_else(|e| panic!("is refused: {e}"));
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("written.g2o");
    graph.write_g2o(&path).unwrap();
    AnyPoseGraph::read_g2o(&path).unwrap_or_else(|e| panic!("does not read back: {e}"))
}

fn check_reads_back<P: ErrorCoordinates<D>, const D: usize>(sim: &Simulation<P, D>) {
    for g in [&sim.noisy, &sim.truth] {
        let edges = read_back(g).num_edges();
        assert_eq!(edges, g.edges.len());
        for e in &g.edges {
            let diagonal = e.information.diagonal();
            assert!(diagonal.iter().all(|x| x.is_normal()), "{diagonal}");
        }
    }
}

#[test]
fn noise_at_its_bounds_simulates_and_reads_back() {
    for world in [World::Grid2d, World::Torus3d] {
        for (translation_noise, rotation_noise) in
            [(MIN_NOISE, MIN_NOISE), (MAX_LENGTH, MAX_ROTATION_NOISE)]
        {
            let options = SimulationOptions {
                world,
                poses: 120,
                loops: 20,
                outliers: 6,
                outlier_policy: OutlierPolicy::Aliased,
                group_size: 3,
                translation_noise,
                rotation_noise,
                inliers: Some(InlierModel::default()),
                ..Default::default()
            };
            match simulate(&options).unwrap() {
                AnySimulation::Planar(s) => check_reads_back(&s),
                AnySimulation::Spatial(s) => check_reads_back(&s),
            }
        }
    }
}

fn out_of_range(err: Option<SimulationError>) -> (&'static str, f64, f64) {
    match err {
        Some(SimulationError::OutOfRange { name, min, max, .. }) => (name, min, max),
        other => panic!("expected OutOfRange, got {other:?}"),
    }
}

#[test]
fn simulation_options_beyond_their_ranges_are_errors() {
    let base = SimulationOptions {
        poses: 100,
        ..Default::default()
    };
    let err = |o: SimulationOptions| o.validate().err();
    // The values at the bounds are accepted.
    for ok in [
        SimulationOptions {
            poses: MAX_POSES,
            outliers: MAX_POSES,
            group_size: MAX_POSES,
            ..base
        },
        SimulationOptions {
            translation_noise: MAX_LENGTH,
            rotation_noise: MIN_NOISE,
            ..base
        },
        SimulationOptions {
            alias_offsets: AliasOffsets { min: 1, max: 1 },
            true_like_share: 1.0,
            inliers: Some(InlierModel::default()),
            ..base
        },
        SimulationOptions {
            alias_offsets: AliasOffsets {
                min: MAX_POSES,
                max: MAX_POSES,
            },
            ..base
        },
    ] {
        assert_eq!(err(ok), None, "{ok:?}");
    }
    let beyond = [
        (
            "poses",
            SimulationOptions {
                poses: MAX_POSES + 1,
                ..base
            },
        ),
        (
            "poses",
            SimulationOptions {
                poses: usize::MAX,
                ..base
            },
        ),
        (
            "translation_noise",
            SimulationOptions {
                translation_noise: 1e300,
                ..base
            },
        ),
        (
            "translation_noise",
            SimulationOptions {
                translation_noise: MAX_LENGTH * 1.01,
                ..base
            },
        ),
        (
            "translation_noise",
            SimulationOptions {
                translation_noise: MIN_NOISE / 2.0,
                ..base
            },
        ),
        (
            "rotation_noise",
            SimulationOptions {
                rotation_noise: MIN_NOISE / 2.0,
                ..base
            },
        ),
        (
            "rotation_noise",
            SimulationOptions {
                rotation_noise: f64::NAN,
                ..base
            },
        ),
        (
            "outliers",
            SimulationOptions {
                outliers: MAX_POSES + 1,
                ..base
            },
        ),
        (
            "group_size",
            SimulationOptions {
                group_size: MAX_POSES + 1,
                ..base
            },
        ),
        (
            "alias_offsets.min",
            SimulationOptions {
                alias_offsets: AliasOffsets { min: 0, max: 40 },
                ..base
            },
        ),
        (
            "alias_offsets.max",
            SimulationOptions {
                alias_offsets: AliasOffsets { min: 6, max: 5 },
                ..base
            },
        ),
        (
            "alias_offsets.max",
            SimulationOptions {
                alias_offsets: AliasOffsets {
                    min: 5,
                    max: MAX_POSES + 1,
                },
                ..base
            },
        ),
        (
            "true_like_share",
            SimulationOptions {
                true_like_share: 1.0 + 1e-9,
                ..base
            },
        ),
        (
            "true_like_share",
            SimulationOptions {
                true_like_share: -1e-9,
                ..base
            },
        ),
        (
            "true_like_share",
            SimulationOptions {
                true_like_share: f64::NAN,
                ..base
            },
        ),
    ];
    for (name, bad) in beyond {
        assert_eq!(out_of_range(err(bad)).0, name, "{bad:?}");
    }
    // A share of true-like counts needs a count model.
    assert!(matches!(
        err(SimulationOptions {
            true_like_share: 0.5,
            ..base
        }),
        Some(SimulationError::InvalidOption {
            name: "true_like_share",
            ..
        })
    ));
}

#[test]
fn range_errors_name_the_option_and_the_range() {
    let noisy = SimulationOptions {
        translation_noise: 1e300,
        ..Default::default()
    };
    assert_eq!(
        noisy.validate().unwrap_err().to_string(),
        "option translation_noise = 1e300 is outside its range [1e-49, 1e49]"
    );
    let huge = SimulationOptions {
        poses: 2_000_000,
        ..Default::default()
    };
    assert_eq!(
        huge.validate().unwrap_err().to_string(),
        "option poses = 2000000 is outside its range [2, 1000000]"
    );
    let share = CorruptionOptions {
        true_like_share: 1.5,
        ..Default::default()
    };
    assert_eq!(
        share.validate().unwrap_err().to_string(),
        "option true_like_share = 1.5 is outside its range [0, 1]"
    );
}

#[test]
fn corruption_options_beyond_their_ranges_are_errors() {
    let base = CorruptionOptions::default();
    let ok = CorruptionOptions {
        outliers: MAX_POSES,
        group_size: MAX_POSES,
        local_window: 2,
        translation_scale: MAX_LENGTH,
        rotation_scale: PI,
        true_like_share: 1.0,
        ..base
    };
    assert_eq!(ok.validate(), Ok(()));
    let beyond = [
        (
            "outliers",
            CorruptionOptions {
                outliers: MAX_POSES + 1,
                ..base
            },
        ),
        (
            "group_size",
            CorruptionOptions {
                group_size: MAX_POSES + 1,
                ..base
            },
        ),
        (
            "local_window",
            CorruptionOptions {
                local_window: 1,
                ..base
            },
        ),
        (
            "local_window",
            CorruptionOptions {
                local_window: MAX_POSES + 1,
                ..base
            },
        ),
        (
            "translation_scale",
            CorruptionOptions {
                translation_scale: MAX_LENGTH * 1.01,
                ..base
            },
        ),
        (
            "translation_scale",
            CorruptionOptions {
                translation_scale: -1.0,
                ..base
            },
        ),
        (
            "rotation_scale",
            CorruptionOptions {
                rotation_scale: PI + 1e-9,
                ..base
            },
        ),
        (
            "alias_offsets.min",
            CorruptionOptions {
                alias_offsets: AliasOffsets { min: 0, max: 0 },
                ..base
            },
        ),
        (
            "true_like_share",
            CorruptionOptions {
                true_like_share: 2.0,
                ..base
            },
        ),
    ];
    for (name, bad) in beyond {
        assert_eq!(out_of_range(bad.validate().err()).0, name, "{bad:?}");
    }
    let without_model = CorruptionOptions {
        inliers: None,
        true_like_share: 0.1,
        ..base
    };
    assert!(matches!(
        without_model.validate(),
        Err(SimulationError::InvalidOption {
            name: "true_like_share",
            ..
        })
    ));
}

#[test]
fn corruption_at_the_largest_scales_reads_back() {
    let mut graph = Graph::<Se2, 3>::new();
    for k in 0..40u64 {
        graph.add_vertex(k, Se2::new(k as f64, 0.0, 0.0));
    }
    for k in 1..40u64 {
        let information = Matrix3::identity();
        graph.add_edge(k - 1, k, Se2::new(1.0, 0.0, 0.0), information, None);
    }
    let options = CorruptionOptions {
        outliers: 30,
        translation_scale: MAX_LENGTH,
        rotation_scale: PI,
        ..Default::default()
    };
    corrupt(&mut graph, &options, &mut StdRng::seed_from_u64(3)).unwrap();
    match read_back(&graph) {
        AnyPoseGraph::Planar(r) => assert_eq!(r.num_edges(), 39 + 30),
        AnyPoseGraph::Spatial(_) => panic!("an SE(2) graph read back as SE(3)"),
    }
}
