//! The outputs of the random, local and grouped policies must not change:
//! the benchmark caches results keyed on files made by `pgo corrupt`, and
//! g2o_samples/ holds files made by `pgo simulate`. These tests redo both
//! as the CLI does and compare bytes.

//!
//! They use the public API alone, as `pgo simulate` and `pgo corrupt` do:
//! the graphs are written by [`PoseGraph::write_g2o`].

use super::*;
use pgo::AnyPoseGraph;
use rand::{SeedableRng, rngs::StdRng};
use std::path::{Path, PathBuf};

fn sample(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../g2o_samples")
        .join(name)
}

/// The bytes [`PoseGraph::write_g2o`] writes.
pub(crate) fn g2o_text<P: GraphPose<D>, const D: usize>(g: &PoseGraph<P, D>) -> Vec<u8> {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("graph.g2o");
    g.write_g2o(&path).unwrap();
    std::fs::read(&path).unwrap()
}

fn labels_text<P: GraphPose<D>, const D: usize>(g: &PoseGraph<P, D>, wrong: &[bool]) -> Vec<u8> {
    let mut text = Vec::new();
    write_labels(g, wrong, &mut text).unwrap();
    text
}

/// Compares a simulation with the bundled files `NAME.g2o`, and when they
/// exist `NAME_truth.g2o` and `NAME_labels.csv`.
fn check_sample<P: GraphPose<D>, const D: usize>(sim: &Simulation<P, D>, name: &str) {
    let same = |file: String, text: Vec<u8>| {
        let path = sample(&file);
        if path.exists() {
            assert!(std::fs::read(&path).unwrap() == text, "{file} changed");
        }
    };
    same(format!("{name}.g2o"), g2o_text(&sim.noisy));
    same(format!("{name}_truth.g2o"), g2o_text(&sim.truth));
    same(
        format!("{name}_labels.csv"),
        labels_text(&sim.noisy, &sim.wrong),
    );
    assert!(sample(&format!("{name}.g2o")).exists());
}

#[test]
fn bundled_samples_are_reproduced_byte_for_byte() {
    // The commands of g2o_samples/make.sh, as `pgo simulate` maps them.
    let counts = Some(InlierModel::default());
    let cases = [
        (
            "grid2d",
            World::Grid2d,
            1000,
            300,
            100,
            OutlierPolicy::Random,
            counts,
            1,
        ),
        (
            "sphere3d",
            World::Sphere3d,
            900,
            200,
            50,
            OutlierPolicy::Grouped,
            counts,
            2,
        ),
        (
            "grid2d_clean",
            World::Grid2d,
            500,
            150,
            0,
            OutlierPolicy::Random,
            None,
            3,
        ),
    ];
    for (name, world, poses, loops, outliers, outlier_policy, inliers, seed) in cases {
        let options = SimulationOptions {
            world,
            poses,
            loops,
            outliers,
            outlier_policy,
            inliers,
            seed,
            ..Default::default()
        };
        match simulate(&options).unwrap() {
            AnySimulation::Planar(s) => check_sample(&s, name),
            AnySimulation::Spatial(s) => check_sample(&s, name),
        }
    }
    let degenerate = SimulationOptions {
        poses: 400,
        loops: 8,
        outliers: 200,
        outlier_policy: OutlierPolicy::Local,
        inliers: Some(InlierModel {
            true_median: 40.0,
            wrong_median: 30.0,
            ..Default::default()
        }),
        seed: 4,
        ..Default::default()
    };
    check_sample(&simulate_planar(&degenerate).unwrap(), "degenerate");
}

/// FNV-1a, 64 bits: a fingerprint of an output.
fn fnv1a(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325, |h, &b| {
        (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3)
    })
}

/// Corrupts a bundled sample as `pgo corrupt` does and fingerprints the
/// graph and the labels.
fn corrupt_sample(name: &str, options: &CorruptionOptions, seed: u64) -> (u64, u64) {
    fn run<P: ErrorCoordinates<D>, const D: usize>(
        mut g: PoseGraph<P, D>,
        options: &CorruptionOptions,
        seed: u64,
    ) -> (u64, u64) {
        g.compose_missing_poses();
        let corruption = corrupt(&g, options, &mut StdRng::seed_from_u64(seed)).unwrap();
        (
            fnv1a(&g2o_text(&corruption.graph)),
            fnv1a(&labels_text(&corruption.graph, &corruption.wrong)),
        )
    }
    match AnyPoseGraph::read_g2o(sample(name)).unwrap() {
        AnyPoseGraph::Planar(g) => run(g, options, seed),
        AnyPoseGraph::Spatial(g) => run(g, options, seed),
    }
}

#[test]
fn corrupt_outputs_of_the_existing_policies_are_unchanged() {
    // Fingerprints of `pgo corrupt g2o_samples/grid2d_clean.g2o --wrong 40
    // --wrong-mode MODE --seed 1` and of `pgo corrupt
    // g2o_samples/sphere3d_truth.g2o --wrong 0 --known-wrong-last 20 --seed
    // 2`, from the binary before aliasing was added.
    let cases = [
        (
            OutlierPolicy::Random,
            0x1d5c_a608_16a4_fd42,
            0x8544_f89a_08b3_0be7,
        ),
        (
            OutlierPolicy::Local,
            0x1c4d_fe94_9544_901e,
            0xf0c1_8bee_0a4c_9f63,
        ),
        (
            OutlierPolicy::Grouped,
            0xff2e_a1f0_6dfb_9275,
            0x0cb3_057a_1136_f039,
        ),
    ];
    for (policy, graph, labels) in cases {
        let options = CorruptionOptions {
            outliers: 40,
            policy,
            ..Default::default()
        };
        assert_eq!(
            corrupt_sample("grid2d_clean.g2o", &options, 1),
            (graph, labels),
            "{policy:?}"
        );
    }
    let known = CorruptionOptions {
        outliers: 0,
        known_wrong_last: 20,
        ..Default::default()
    };
    assert_eq!(
        corrupt_sample("sphere3d_truth.g2o", &known, 2),
        (0xbf2f_d676_fa69_26a3, 0x32f4_ffe2_c3e7_acdb)
    );
}
