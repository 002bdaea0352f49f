//! Tests of perceptual aliasing (wrong candidates measuring a place a few
//! steps away) and of wrong candidates with true-like counts.

use super::wrong::{WrongLoopPlan, wrong_groups};
use super::*;
use crate::graph::Edge;
use crate::testing::{corrupt, simulate_planar, simulate_spatial};
use pgo::{Pose, Se2, Se3};
use rand::{SeedableRng, rngs::StdRng};

/// The offsets `s` (within `offsets`) for which the edge's measurement is
/// the relative pose from its `from` to `to + s` among `poses`, to rounding.
fn matching_offsets<P: Pose<D>, const D: usize>(
    poses: &[P],
    e: &Edge<P, D>,
    offsets: AliasOffsets,
) -> Vec<isize> {
    let magnitudes = offsets.min as isize..=offsets.max as isize;
    magnitudes
        .flat_map(|m| [m, -m])
        .filter(|&s| {
            e.to.checked_add_signed(s)
                .filter(|&t| t < poses.len())
                .is_some_and(|t| P::error(&poses[e.from], &poses[t], &e.measurement).norm() < 1e-9)
        })
        .collect()
}

/// Checks that every wrong edge measures the pose `s` steps past its `to`
/// for a single `s` in range, and that runs of consecutive pairs sharing
/// `s` have the sizes of groups of `group` (the last one smaller).
fn check_aliases<P: Pose<D>, const D: usize>(
    poses: &[P],
    wrong: &[&Edge<P, D>],
    offsets: AliasOffsets,
    group: usize,
) {
    let mut keyed: Vec<(isize, usize, usize)> = wrong
        .iter()
        .map(|e| {
            let s = matching_offsets(poses, e, offsets);
            assert_eq!(s.len(), 1, "{}–{} matches offsets {s:?}", e.from, e.to);
            assert!(e.to - e.from >= 2);
            (s[0], e.from, e.to)
        })
        .collect();
    keyed.sort_unstable();
    let mut sizes = vec![1];
    for w in keyed.windows(2) {
        let ((s0, i0, j0), (s1, i1, j1)) = (w[0], w[1]);
        match sizes.last_mut() {
            Some(n) if s0 == s1 && i1 == i0 + 1 && j1 == j0 + 1 && *n < group => *n += 1,
            _ => sizes.push(1),
        }
    }
    sizes.sort_unstable();
    let count = wrong.len();
    let mut expected = vec![group; count / group];
    if count % group > 0 {
        expected.insert(0, count % group);
    }
    assert_eq!(sizes, expected);
}

fn wrong_edges<P, const D: usize>(graph: &Graph<P, D>, wrong: &[bool]) -> Vec<Edge<P, D>>
where
    P: Clone,
{
    (graph.edges.iter().zip(wrong))
        .filter(|(_, w)| **w)
        .map(|(e, _)| e.clone())
        .collect()
}

#[test]
fn aliased_measurements_are_the_relative_poses_to_the_offset_vertex() {
    // The smallest noise: the measurements are exact to rounding. On the
    // sphere and the torus no two poses coincide, so `s` is unique.
    let offsets = AliasOffsets { min: 7, max: 30 };
    for world in [World::Sphere3d, World::Torus3d] {
        let options = SimulationOptions {
            world,
            poses: 800,
            loops: 100,
            outliers: 47,
            outlier_policy: OutlierPolicy::Aliased,
            group_size: 5,
            alias_offsets: offsets,
            translation_noise: MIN_NOISE,
            rotation_noise: MIN_NOISE,
            seed: 3,
            ..Default::default()
        };
        let sim = simulate_spatial(&options).unwrap();
        let wrong = wrong_edges(&sim.noisy, &sim.wrong);
        assert_eq!(wrong.len(), 47);
        check_aliases(
            &sim.truth.poses,
            &wrong.iter().collect::<Vec<_>>(),
            offsets,
            5,
        );
        // The aliased vertex is another place: farther than the loop radius.
        let radius = match world {
            World::Sphere3d => super::world::sphere_trajectory(800).loop_radius,
            _ => super::world::torus_trajectory(800).loop_radius,
        };
        for e in &wrong {
            let s = matching_offsets(&sim.truth.poses, e, offsets)[0];
            let t = e.to.checked_add_signed(s).unwrap();
            let apart = (sim.truth.poses[t].position() - sim.truth.poses[e.to].position()).norm();
            assert!(
                apart > radius,
                "{}–{}: s = {s} is {apart} m away",
                e.from,
                e.to
            );
        }
    }
}

#[test]
fn aliased_measurements_carry_the_usual_noise() {
    // The χ² of an aliased measurement against the aliased pose has the
    // distribution of the odometry's: mean D.
    let options = SimulationOptions {
        poses: 2000,
        loops: 0,
        outliers: 1500,
        outlier_policy: OutlierPolicy::Aliased,
        group_size: 1,
        translation_noise: 0.1,
        rotation_noise: 0.05,
        ..Default::default()
    };
    let sim = simulate_planar(&options).unwrap();
    let poses = &sim.truth.poses;
    let mut total = 0.0;
    let wrong = wrong_edges(&sim.noisy, &sim.wrong);
    for e in &wrong {
        // The offset whose aliased pose explains the measurement best.
        let best = (5..=40isize)
            .flat_map(|m| [m, -m])
            .filter_map(|s| e.to.checked_add_signed(s).filter(|&t| t < poses.len()))
            .map(|t| {
                let err = Se2::error(&poses[e.from], &poses[t], &e.measurement);
                err.dot(&(e.information * err))
            })
            .fold(f64::INFINITY, f64::min);
        total += best;
    }
    let mean = total / wrong.len() as f64;
    // The best of ~70 offsets is the aliased one (others are metres off);
    // a mean of 1500 χ²₃ draws has standard deviation √(6/1500) ≈ 0.06.
    assert!((mean - 3.0).abs() < 0.3, "mean χ² {mean}");
}

#[test]
fn aliased_groups_share_an_offset_within_the_range() {
    let plan = WrongLoopPlan {
        count: 203,
        policy: OutlierPolicy::Aliased,
        group_size: 10,
        local_window: DEFAULT_LOCAL_WINDOW,
        alias_offsets: AliasOffsets::default(),
        alias_place: AliasPlace::Revisited,
        translation_scale: DEFAULT_OUTLIER_TRANSLATION,
        rotation_scale: DEFAULT_OUTLIER_ROTATION,
    };
    let mut rng = StdRng::seed_from_u64(11);
    let consecutive = |i: usize, j: usize| i.abs_diff(j) == 1;
    let groups = wrong_groups(&plan, 500, &[], consecutive, |_, _| true, &mut rng).unwrap();
    assert_eq!(groups.len(), 21);
    let (mut positive, mut negative) = (0, 0);
    for g in &groups {
        let alias = g.alias.as_ref().unwrap();
        let s = alias.offset;
        assert!((5..=40).contains(&s.unsigned_abs()), "s = {s}");
        positive += usize::from(s > 0);
        negative += usize::from(s < 0);
        let super::wrong::AliasFrame::Targets(targets) = &alias.frame else {
            panic!("a revisited alias measures vertices");
        };
        assert_eq!(targets.len(), g.pairs.len());
        for (k, (&(i, j), &t)) in g.pairs.iter().zip(targets).enumerate() {
            assert_eq!((i, j), (g.pairs[0].0 + k, g.pairs[0].1 + k));
            assert_eq!(t as isize, j as isize + s);
            assert!(t < 500 && t != i);
        }
    }
    assert!(positive > 3 && negative > 3, "{positive} vs {negative}");
    // Targets that must be another place than an unreachable distance away
    // leave no room.
    let far = |j: usize, t: usize| j.abs_diff(t) > 40;
    assert!(matches!(
        wrong_groups(&plan, 500, &[], consecutive, far, &mut rng),
        Err(SimulationError::NoRoomForOutliers { .. })
    ));
}

/// The share of wrong candidates whose count is the true median, with
/// counts that tell the two models apart.
fn true_like_share_of(graph_edges: &[Edge<Se2, 3>], wrong: &[bool]) -> f64 {
    let counts: Vec<u64> = (graph_edges.iter().zip(wrong))
        .filter(|(_, w)| **w)
        .map(|(e, _)| e.candidate.and_then(|c| c.inliers).unwrap())
        .collect();
    assert!(counts.iter().all(|&n| n == 1000 || n == 10));
    counts.iter().filter(|&&n| n == 1000).count() as f64 / counts.len() as f64
}

const SEPARATE: InlierModel = InlierModel {
    true_median: 1000.0,
    true_sigma: 0.0,
    wrong_median: 10.0,
    wrong_sigma: 0.0,
};

#[test]
fn a_share_of_wrong_candidates_gets_true_like_counts() {
    for (share, policy) in [
        (0.0, OutlierPolicy::Random),
        (0.3, OutlierPolicy::Aliased),
        (0.7, OutlierPolicy::Grouped),
        (1.0, OutlierPolicy::Local),
    ] {
        let options = SimulationOptions {
            poses: 3000,
            loops: 100,
            outliers: 2000,
            outlier_policy: policy,
            true_like_share: share,
            inliers: Some(SEPARATE),
            seed: 5,
            ..Default::default()
        };
        let sim = simulate_planar(&options).unwrap();
        let got = true_like_share_of(&sim.noisy.edges, &sim.wrong);
        // Binomial(2000, share): standard deviation at most 0.011.
        assert!((got - share).abs() < 0.04, "{policy:?}: {got} vs {share}");
        // True loops keep the true model.
        for (e, &w) in sim.noisy.edges.iter().zip(&sim.wrong) {
            if !w && e.candidate.is_some() {
                assert_eq!(e.candidate.and_then(|c| c.inliers), Some(1000));
            }
        }
    }
}

#[test]
fn corrupt_gives_known_and_appended_wrong_candidates_true_like_counts() {
    let sim = simulate_planar(&SimulationOptions {
        poses: 3000,
        loops: 1500,
        ..Default::default()
    })
    .unwrap();
    let mut graph = sim.noisy.clone();
    let options = CorruptionOptions {
        outliers: 1000,
        policy: OutlierPolicy::Aliased,
        group_size: 1,
        known_wrong_last: 500,
        inliers: Some(SEPARATE),
        true_like_share: 0.4,
        ..Default::default()
    };
    let corruption = corrupt(&mut graph, &options, &mut StdRng::seed_from_u64(9)).unwrap();
    assert_eq!(corruption.wrong.iter().filter(|&&w| w).count(), 1500);
    let got = true_like_share_of(&graph.edges, &corruption.wrong);
    assert!((got - 0.4).abs() < 0.04, "{got}");
}

#[test]
fn corrupt_aliases_measure_the_graphs_poses_with_the_copied_information() {
    // A graph whose loop information is 10³⁰⁰ (σ = 10⁻¹⁵⁰): the aliased
    // measurements are the relative poses of the graph's poses to rounding.
    let sim = simulate_spatial(&SimulationOptions {
        world: World::Sphere3d,
        poses: 700,
        loops: 100,
        translation_noise: MIN_NOISE,
        rotation_noise: MIN_NOISE,
        ..Default::default()
    })
    .unwrap();
    let mut graph = sim.noisy.clone();
    let before = graph.edges.len();
    let offsets = AliasOffsets { min: 5, max: 12 };
    let options = CorruptionOptions {
        outliers: 33,
        policy: OutlierPolicy::Aliased,
        group_size: 4,
        alias_offsets: offsets,
        ..Default::default()
    };
    let corruption = corrupt(&mut graph, &options, &mut StdRng::seed_from_u64(4)).unwrap();
    assert_eq!(corruption.marked, 100);
    let appended: Vec<&Edge<Se3, 6>> = graph.edges[before..].iter().collect();
    assert!(corruption.wrong[before..].iter().all(|&w| w));
    for e in &appended {
        assert_eq!(e.information, graph.edges[before - 1].information);
    }
    check_aliases(&graph.poses, &appended, offsets, 4);
}

#[test]
fn corrupt_refuses_information_that_cannot_draw_noise() {
    let mut graph = Graph::<Se2, 3>::new();
    for k in 0..60u64 {
        graph.add_vertex(k, Se2::new(k as f64, 0.0, 0.0));
    }
    let singular = nalgebra::Matrix3::from_diagonal(&nalgebra::Vector3::new(1.0, 1.0, 0.0));
    for k in 1..60u64 {
        graph.add_edge(k - 1, k, Se2::new(1.0, 0.0, 0.0), singular, None);
    }
    let options = CorruptionOptions {
        outliers: 5,
        policy: OutlierPolicy::Aliased,
        ..Default::default()
    };
    let before = graph.edges.clone();
    assert!(matches!(
        corrupt(&mut graph, &options, &mut StdRng::seed_from_u64(1)),
        Err(SimulationError::UnusableInformation { .. })
    ));
    assert_eq!(graph.edges, before);
}

/// The offset `s` (within `offsets`) and group start `(i, j)` for which the
/// edge measures `X_from⁻¹·X_{i+s}·X_j⁻¹·X_to` among `poses`, to rounding,
/// with `from − i = to − j` (the rigid move of [`AliasPlace::Anywhere`]).
fn rigid_alias<P: Pose<D>, const D: usize>(
    poses: &[P],
    e: &Edge<P, D>,
    offsets: AliasOffsets,
    group: usize,
) -> Vec<(isize, usize, usize)> {
    let mut found = Vec::new();
    for k in 0..group.min(e.from + 1) {
        let (i, j) = (e.from - k, e.to - k);
        for m in offsets.min as isize..=offsets.max as isize {
            for s in [m, -m] {
                let Some(anchor) = i.checked_add_signed(s).filter(|&t| t < poses.len()) else {
                    continue;
                };
                let claimed = poses[anchor]
                    .compose(&poses[j].inverse())
                    .compose(&poses[e.to]);
                if P::error(&poses[e.from], &claimed, &e.measurement).norm() < 1e-9 {
                    found.push((s, i, j));
                }
            }
        }
    }
    found
}

#[test]
fn aliases_anywhere_move_a_stretch_rigidly_onto_another_place() {
    // The smallest noise: the measurements are exact to rounding.
    let offsets = AliasOffsets { min: 5, max: 50 };
    for world in [World::Sphere3d, World::Torus3d] {
        let options = SimulationOptions {
            world,
            poses: 800,
            loops: 100,
            outliers: 45,
            outlier_policy: OutlierPolicy::Aliased,
            alias_place: AliasPlace::Anywhere,
            group_size: 15,
            alias_offsets: offsets,
            translation_noise: MIN_NOISE,
            rotation_noise: MIN_NOISE,
            seed: 5,
            ..Default::default()
        };
        let sim = simulate_spatial(&options).unwrap();
        let wrong = wrong_edges(&sim.noisy, &sim.wrong);
        assert_eq!(wrong.len(), 45);
        let radius = match world {
            World::Sphere3d => super::world::sphere_trajectory(800).loop_radius,
            _ => super::world::torus_trajectory(800).loop_radius,
        };
        let truth = &sim.truth.poses;
        let mut groups: Vec<(isize, usize, usize)> = Vec::new();
        for e in &wrong {
            let found = rigid_alias(truth, e, offsets, 15);
            assert!(!found.is_empty(), "{}–{} is no rigid alias", e.from, e.to);
            // The claim is wrong: the stretch moves by more than the loop
            // radius, and the pair's ends are other places.
            let (s, i, j) = found[0];
            let anchor = i.checked_add_signed(s).unwrap();
            assert!((truth[anchor].position() - truth[j].position()).norm() > radius);
            assert!((truth[e.from].position() - truth[e.to].position()).norm() > radius);
            if !groups.contains(&found[0]) {
                groups.push(found[0]);
            }
        }
        // Three groups of 15 consecutive pairs, each sharing one move.
        assert_eq!(groups.len(), 3, "{groups:?}");
    }
}

#[test]
fn aliases_anywhere_fall_away_from_the_true_loops_of_a_corrupted_graph() {
    // Corrupting a graph: with the revisited placement every group starts
    // at a true loop; anywhere, at most by chance.
    let sim = simulate_planar(&SimulationOptions {
        poses: 600,
        loops: 30,
        ..Default::default()
    })
    .unwrap();
    let revisits: Vec<(usize, usize)> = (sim.noisy.edges.iter())
        .filter(|e| e.to != e.from + 1)
        .map(|e| (e.from.min(e.to), e.from.max(e.to)))
        .collect();
    let at_revisits = |place: AliasPlace| {
        let mut graph = sim.noisy.clone();
        let options = CorruptionOptions {
            outliers: 40,
            policy: OutlierPolicy::Aliased,
            group_size: 4,
            alias_place: place,
            ..Default::default()
        };
        let out = corrupt(&mut graph, &options, &mut StdRng::seed_from_u64(9)).unwrap();
        (graph.edges.iter().zip(&out.wrong))
            .filter(|(e, w)| **w && revisits.contains(&(e.from.min(e.to), e.from.max(e.to))))
            .count()
    };
    assert_eq!(at_revisits(AliasPlace::Revisited), 10);
    assert!(at_revisits(AliasPlace::Anywhere) <= 1);
}

#[test]
fn a_group_draws_its_true_like_counts_together_when_asked() {
    // Counts without spread: 150 for a true-like count, 25 for a wrong one.
    let model = InlierModel {
        true_median: 150.0,
        true_sigma: 0.0,
        wrong_median: 25.0,
        wrong_sigma: 0.0,
    };
    let sim = simulate_planar(&SimulationOptions {
        poses: 800,
        loops: 40,
        ..Default::default()
    })
    .unwrap();
    let groups_of = |by_group: bool| {
        let mut graph = sim.noisy.clone();
        let options = CorruptionOptions {
            outliers: 400,
            policy: OutlierPolicy::Aliased,
            alias_place: AliasPlace::Anywhere,
            group_size: 10,
            inliers: Some(model),
            true_like_share: 0.5,
            true_like_by_group: by_group,
            ..Default::default()
        };
        let out = corrupt(&mut graph, &options, &mut StdRng::seed_from_u64(4)).unwrap();
        let counts: Vec<u64> = (graph.edges.iter().zip(&out.wrong))
            .filter(|(_, w)| **w)
            .map(|(e, _)| e.candidate.unwrap().inliers.unwrap())
            .collect();
        // Appended in group order: 40 groups of 10.
        counts.chunks(10).map(|g| g.to_vec()).collect::<Vec<_>>()
    };
    let together = groups_of(true);
    assert!(together.iter().all(|g| g.iter().all(|&c| c == g[0])));
    let like = together.iter().filter(|g| g[0] == 150).count();
    assert!((10..=30).contains(&like), "{like} of 40 groups true-like");
    // Each candidate alone: groups mix the two.
    let apart = groups_of(false);
    assert!(
        apart
            .iter()
            .filter(|g| g.iter().any(|&c| c != g[0]))
            .count()
            > 30
    );
}
