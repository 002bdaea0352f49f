//! The public benchmark datasets (../shared/datasets or $PGO_DATASETS)
//! through the public API: the optimum against g2o and GTSAM, and every
//! quirk in MANIFEST.md, and datasets with wrong candidates planted as
//! `pgo corrupt` plants them (`pgo_sim::corrupt`). Each test prints a
//! reason and passes when the datasets are absent (and fails when `CI` is
//! `true`).

use pgo::report::{LoopReport, Report, Start, StartEnd};
use pgo::{
    AnyPoseGraph, AnySolution, Error, GateMode, Initialization, MapStatus, Options, Pose,
    PoseGraph, PoseGraph2, PoseGraph3, Reason, RobustMethod, Se2, UpdateSolve,
};
use pgo_sim::{
    AliasOffsets, AliasPlace, CorruptionOptions, ErrorCoordinates, InlierModel, OutlierPolicy,
};
use rand::{SeedableRng, rngs::StdRng};
use std::path::Path;

mod common;
use common::{
    add_pose_and_edges, candidate_labels, datasets, edges_due, poses_apart, prefix, rebuilt,
    temp_dir, write,
};

/// Dataset `name` read as a graph of either dimension (`None` without the
/// datasets).
fn read(name: &str) -> Option<Result<AnyPoseGraph, Error>> {
    datasets().map(|d| AnyPoseGraph::read_g2o(d.join(name)))
}

/// Dataset `name` read as a planar graph.
fn read_planar(name: &str) -> Option<PoseGraph2> {
    datasets().map(|d| PoseGraph2::read_g2o(d.join(name)).unwrap_or_else(|e| panic!("{e}")))
}

/// Dataset `name` optimised with the default options but `init`.
fn optimise(name: &str, init: Initialization) -> Option<AnySolution> {
    let dir = datasets()?;
    let mut options = Options::default();
    options.solver.init = init;
    Some(
        AnyPoseGraph::read_g2o(dir.join(name))
            .and_then(|g| g.optimize(&options))
            .unwrap_or_else(|e| panic!("{name}: {e}")),
    )
}

/// `graph` evaluated at its own poses: no gate, no robust weighting, no
/// iteration (the report's `input_chi2` is the χ² of the poses given).
fn at_given_poses(graph: &AnyPoseGraph) -> AnySolution {
    let mut options = Options::default();
    for (flag, value) in [
        ("gate", "off"),
        ("robust", "none"),
        ("init", "file"),
        ("max-iters", "0"),
    ] {
        options.set(flag, value).unwrap();
    }
    graph.optimize(&options).unwrap()
}

/// How many vertices the file's edges named without a vertex line.
fn without_line(g: &AnyPoseGraph) -> usize {
    g.ids().iter().filter(|&&id| g.pose(id).is_none()).count()
}

/// The lowest final χ² (g2o's error definition) that g2o or GTSAM reached
/// with LM or GN from the file's own guess (../shared/peers/BASELINE.md).
const BEST_PEER: &[(&str, f64)] = &[
    ("intel.g2o", 45.0047),
    ("manhattan.g2o", 3549.037),
    ("city10000.g2o", 511.9852),
    ("kitti_00.g2o", 98.32201),
    ("CSAIL.g2o", 40.55513),
    ("sphere2500.g2o", 727.1497),
    ("torus3D.g2o", 19972.23),
    ("parking-garage.g2o", 1.238691),
    ("MIT.g2o", 526.331),
];

#[test]
fn default_options_reach_the_best_peer_optimum_on_every_standard_dataset() {
    for &(name, best) in BEST_PEER {
        let Some(s) = optimise(name, Initialization::default()) else {
            return;
        };
        let r = s.report();
        let chi2 = r.optimizer.final_chi2;
        eprintln!(
            "{name}: {chi2:.10} (best peer {best}), {} iterations",
            r.optimizer.iterations
        );
        assert!(
            chi2 <= best * (1.0 + 1e-5),
            "{name}: χ² {chi2} > best peer {best}"
        );
        assert!(
            r.optimizer.converged,
            "{name}: {:?}",
            r.optimizer.stop_reason
        );
    }
}

#[test]
fn from_the_files_own_guess_the_well_initialised_sets_match_the_peers() {
    for &(name, best) in &BEST_PEER[..6] {
        let Some(s) = optimise(name, Initialization::File) else {
            return;
        };
        let chi2 = s.report().optimizer.final_chi2;
        assert!(chi2 <= best * (1.0 + 1e-5), "{name}: {chi2}");
    }
}

#[test]
fn q1_square_root_information_files_load_and_give_tiny_chi2() {
    // city10000 carries sqrt-information: its optimum χ² per edge is far
    // below the edge dimension (3).
    let Some(s) = optimise("city10000.g2o", Initialization::Chordal) else {
        return;
    };
    let r = s.report();
    let per_edge = r.optimizer.final_chi2 / r.edges as f64;
    assert!(per_edge < 0.1, "χ² per edge {per_edge}");
}

#[test]
fn q2_indefinite_information_is_reported_and_repaired_on_request() {
    let Some(dir) = datasets() else { return };
    let err = PoseGraph3::read_g2o(dir.join("cubicle.g2o")).unwrap_err();
    assert!(err.to_string().contains("not positive definite"), "{err}");
    let Error::Read(read) = &err else {
        panic!("not a read error: {err:?}")
    };
    assert!(read.line().is_some());
    let repaired = PoseGraph3::read_g2o_repairing(dir.join("cubicle.g2o")).unwrap();
    assert_eq!(repaired.information_repaired(), 5021);
    // parking-garage: PD but condition numbers up to 2.7e9; loads as is.
    let g = PoseGraph3::read_g2o(dir.join("parking-garage.g2o")).unwrap();
    assert_eq!(g.information_repaired(), 0);
    let r = repaired
        .optimize(&Options::default())
        .unwrap()
        .into_report();
    assert_eq!(r.information_fixed, 5021);
    assert!(
        r.optimizer.converged && r.optimizer.final_chi2 < 2400.0,
        "{:?}",
        r.optimizer.final_chi2
    );
}

#[test]
fn q3_edge_only_files_get_every_vertex_from_a_spanning_tree() {
    for (name, poses) in [
        ("manhattan.g2o", 3500),
        ("CSAIL.g2o", 1045),
        ("kitti_00.g2o", 4541),
    ] {
        let Some(g) = read(name) else { return };
        let g = g.unwrap();
        assert_eq!(g.len(), poses, "{name}");
        assert_eq!(without_line(&g), poses, "{name}");
    }
    // The spanning-tree guess of kitti_00 is the odometry chain: its χ²
    // matches the peers' initial χ² (BASELINE.md, 7.53296e+07).
    let Some(s) = optimise("kitti_00.g2o", Initialization::File) else {
        return;
    };
    let r = s.report();
    assert_eq!(r.initialization.vertices_without_line, 4541);
    assert!(
        (r.input_chi2 / 7.53296e7 - 1.0).abs() < 1e-5,
        "{}",
        r.input_chi2
    );
}

#[test]
fn q4_edge2_files_are_skipped_with_a_clear_message() {
    let Some(dir) = datasets() else { return };
    for name in ["w100.graph", "city10000_groundtruth.txt", "sphere2500.txt"] {
        let err = AnyPoseGraph::read_g2o(dir.join(name)).unwrap_err();
        let text = err.to_string();
        assert!(
            text.contains("no VERTEX_SE2") && text.contains("skipped: EDGE"),
            "{text}"
        );
    }
}

#[test]
fn q5_unusual_tags_fix_mixture_edges_and_skipped_tags() {
    let Some(g) = read_planar("manhattanOlson3500-maxmix-n100-grp10.g2o") else {
        return;
    };
    // 3499 odometry + 3099 mixture edges, FIX 0.
    assert_eq!(g.num_edges(), 6598);
    assert_eq!(g.fixed(), vec![0]);
    // The mixture's first component is the measurement, with its information.
    assert!(g.edges().all(|e| e.information[(0, 0)] > 1.0));
    let dir = datasets().unwrap();
    let g = AnyPoseGraph::read_g2o(dir.join("example_with_vertices.g2o")).unwrap();
    assert_eq!((g.len(), g.num_edges()), (8, 0));
    // The report counts the skipped tags; the job needs the poses tied by
    // edges: the file with an odometry chain appended.
    let mut text = std::fs::read_to_string(dir.join("example_with_vertices.g2o")).unwrap();
    let identity = "0 0 0 0 0 0 1 1 0 0 0 0 0 1 0 0 0 0 1 0 0 0 1 0 0 1 0 1";
    for k in 1..8 {
        text += &format!("\nEDGE_SE3:QUAT {} {k} {identity}", k - 1);
    }
    let q5 = temp_dir("q5");
    let chained = write(&q5, "example_with_vertices.g2o", &text);
    let s = at_given_poses(&AnyPoseGraph::read_g2o(chained).unwrap());
    assert_eq!(s.report().skipped_tags.get("VERTEX_TRACKXYZ"), Some(&8));
    let Some(Ok(g)) = read("sphere2500-maxmix-n100-grp10.g2o") else {
        panic!("sphere maxmix")
    };
    assert_eq!(g.num_edges(), 5949);
}

#[test]
fn q6_whitespace_blank_lines_and_missing_final_newline() {
    for (name, edges) in [
        ("kitti_00.g2o", 4677),
        ("kitti_02.g2o", 4703),
        ("pose2example.txt", 12),
        ("pose3example-offdiagonal.txt", 1),
        ("torus3D.g2o", 9048),
    ] {
        let Some(g) = read(name) else { return };
        assert_eq!(g.unwrap().num_edges(), edges, "{name}");
    }
}

#[test]
fn q7_interleaved_vertices_and_edges() {
    let Some(g) = read_planar("intel-vertigo.g2o") else {
        return;
    };
    assert_eq!((g.len(), g.num_edges()), (943, 1837));
    assert!(g.ids().iter().all(|&id| g.pose(id).is_some()));
    // The first edge of the file is 441 → 442.
    let first = g.edges().next().unwrap();
    assert_eq!((first.from, first.to), (441, 442));
}

#[test]
fn q8_reversed_and_repeated_edges() {
    let Some(g) = read_planar("MIT.g2o") else {
        return;
    };
    let reversed = g.edges().filter(|e| e.from > e.to).count();
    assert_eq!(reversed, 20);
    let Some(s) = optimise("manhattanOlson3500-olson.g2o", Initialization::Chordal) else {
        return;
    };
    assert!(s.report().optimizer.converged);
}

#[test]
fn q9_graphs_missing_some_odometry_links_stay_connected() {
    let Some(g) = read_planar("ais2klinik.g2o") else {
        return;
    };
    // Every edge counts (no gate, no robust weighting): a vertex no chain
    // of them ties to the fixed one would be an `Error::Unconstrained`.
    at_given_poses(&AnyPoseGraph::Planar(g));
    // Which a pose on its own is.
    let mut g = PoseGraph2::new();
    g.add_pose(0, Se2::new(0.0, 0.0, 0.0)).unwrap();
    g.add_pose(1, Se2::new(1.0, 0.0, 0.0)).unwrap();
    let mut options = Options::default();
    options.gate.mode = GateMode::Off;
    options.robust.method = RobustMethod::None;
    assert!(matches!(
        g.optimize(&options),
        Err(Error::Unconstrained { .. })
    ));
}

#[test]
fn q10_unwrapped_angles_give_wrapped_errors() {
    let Some(g) = read_planar("ring-groundtruth.g2o") else {
        return;
    };
    // Vertex angles in [0, 2π) and exact measurements: χ² at the ground truth is ~0.
    let chi2 = at_given_poses(&AnyPoseGraph::Planar(g)).report().input_chi2;
    assert!(chi2 < 1e-6, "{chi2}");
    let Some(mut g) = read_planar("manhattanOlson3500-olson.g2o") else {
        return;
    };
    assert!(g.edges().any(|e| e.measurement.theta.abs() > 4.0));
    // The same graph with every measured angle wrapped into [−π, π] has
    // the same χ² at the same poses: the errors are wrapped.
    g.compose_missing_poses();
    let mut wrapped = PoseGraph2::new();
    for &id in g.ids() {
        wrapped.add_pose(id, *g.pose(id).unwrap()).unwrap();
    }
    for id in g.fixed() {
        wrapped.fix(id).unwrap();
    }
    for e in g.edges() {
        let m = e.measurement;
        let theta = m.theta.sin().atan2(m.theta.cos());
        let z = Se2::new(m.x, m.y, theta);
        if e.loop_candidate {
            let candidate = wrapped.add_loop_candidate(e.from, e.to, z, e.information, e.inliers);
            candidate.unwrap();
        } else {
            wrapped.add_edge(e.from, e.to, z, e.information).unwrap();
        }
    }
    let (a, b) = (
        at_given_poses(&AnyPoseGraph::Planar(g)).report().input_chi2,
        at_given_poses(&AnyPoseGraph::Planar(wrapped))
            .report()
            .input_chi2,
    );
    assert!(
        a.is_finite() && (a - b).abs() <= 1e-9 * a.max(b),
        "{a} ≠ {b}"
    );
}

#[test]
fn q11_same_name_different_data() {
    let (Some(a), Some(b)) = (read("intel.g2o"), read("intel-vertigo.g2o")) else {
        return;
    };
    assert_ne!(a.unwrap().len(), b.unwrap().len());
}

#[test]
fn q12_ring_loop_closures_are_exact_at_the_ground_truth() {
    let Some(g) = read_planar("ring-groundtruth.g2o") else {
        return;
    };
    let mut loops = 0;
    for e in g.edges().filter(|e| e.from.abs_diff(e.to) > 1) {
        let (from, to) = (g.pose(e.from).unwrap(), g.pose(e.to).unwrap());
        // The edge's error: the measurement against the relative pose.
        let error = e.measurement.inverse().compose(&from.inverse().compose(to));
        assert!(error.log().norm() < 1e-4, "{} → {}", e.from, e.to);
        loops += 1;
    }
    assert!(loops > 0);
}

/// A file whose information is ten times too tight fails the χ² test
/// whatever loops it keeps, and fewer loops fail by less. The χ² search's
/// restart (decide again from the trusted edges' map, at the learned and
/// at the file's scale) must not trade true loops for a smaller `D²`, nor
/// for a map without loops, which has no test at all. With random wrong
/// candidates and every information matrix ×10 over the calibrated scale,
/// the true loops that passed the gate are kept (all but 1 %), no wrong
/// one, and the failed test is reported. The restart used to be kept
/// whenever it failed by less: on manhattan 307 of 1954 true loops, the
/// map 12.6 % off. Kept whenever it did not fail, it dropped every loop of
/// city10000 and reported no test.
#[test]
fn information_too_tight_fails_the_test_without_dropping_true_loops() {
    tight_information_keeps_the_true_loops("manhattan.g2o", 1000, 3);
    tight_information_keeps_the_true_loops("city10000.g2o", 100, 14);
}

/// [`information_too_tight_fails_the_test_without_dropping_true_loops`] on
/// `name` with `wrong` random wrong candidates made with `seed`.
fn tight_information_keeps_the_true_loops(name: &str, wrong: usize, seed: u64) {
    let random = corruption(wrong, OutlierPolicy::Random);
    let Some((r, wrong)) = corrupted_and_decided(name, &random, seed, Some(10.0)) else {
        return;
    };
    let (accepted_true, gated_true) = true_loops_kept(&r, &wrong);
    assert!(
        accepted_true as f64 >= 0.99 * gated_true as f64,
        "{name}: {accepted_true} of the {gated_true} true loops that passed the gate accepted"
    );
    assert!(!r.chi2_test.expect("a χ² test").passed, "{name}");
}

/// Three cases of the outlier benchmark where true loops used to be lost
/// (`scripts/bench_robust.py`, random wrong candidates; the seeds are
/// the benchmark's). Intel, its published information: EM fitted the lower
/// bounds of wrong loops' innovations as a population among the true loops
/// and rejected a true loop with a low count; the model now sees exact
/// innovations. Manhattan, calibrated: an accepted wrong loop bent the map
/// and 41 true loops were rejected; the χ² search took it out, and the
/// decisions now run again on the map without it. Parking-garage with 10
/// wrong candidates, its published information: the counts are two
/// populations whose densities do not cross, and their posteriors now
/// speak for the three true loops in the innovations' far tail.
#[test]
fn random_wrong_candidates_cost_no_true_loop() {
    for (name, wrong, seed, calibrated) in [
        ("intel.g2o", 1000, 2, None),
        ("manhattan.g2o", 1000, 5, Some(1.0)),
        ("parking-garage.g2o", 10, 14, None),
    ] {
        let random = corruption(wrong, OutlierPolicy::Random);
        let Some((r, wrong)) = corrupted_and_decided(name, &random, seed, calibrated) else {
            return;
        };
        let (accepted_true, _) = true_loops_kept(&r, &wrong);
        let true_loops = wrong.iter().filter(|w| !**w).count();
        assert_eq!(accepted_true, true_loops, "{name}: true loops rejected");
        assert!(r.chi2_test.expect("a χ² test").passed, "{name}");
    }
}

/// An alias beside true loops of its cluster is judged against the map
/// with them, not only against the map without its cluster, which they
/// leave too: manhattan with 300 aliased candidates (the aliasing sweep's
/// seed 1, groups of 1, 30 % with true-like counts, information as
/// published) accepted an alias at ν² 46 (its residual at the clean
/// optimum 392) beside five true loops on the same stretch. Now every
/// true loop is kept and no alias.
#[test]
fn an_alias_among_true_loops_is_judged_against_them() {
    let aliased = CorruptionOptions {
        group_size: 1,
        true_like_share: 0.3,
        ..corruption(300, OutlierPolicy::Aliased)
    };
    let Some((r, wrong)) = corrupted_and_decided("manhattan.g2o", &aliased, 1_000_003, None) else {
        return;
    };
    let (accepted_true, _) = true_loops_kept(&r, &wrong);
    assert_eq!(accepted_true, wrong.iter().filter(|w| !**w).count());
}

/// torus3D with 300 aliases in groups of 10 placed anywhere, a share
/// `true_like` of the groups with counts like a true loop's, planted as
/// `pgo corrupt --seed SEED` plants them (information as published),
/// written and read back as `pgo corrupt` leaves it, and cut to its first
/// `n` poses; with whether each of its edges is a wrong candidate (`None`
/// without the datasets).
fn aliased_torus(n: u64, (true_like, seed): (f64, u64)) -> Option<(PoseGraph3, Vec<bool>)> {
    let Ok(AnyPoseGraph::Spatial(mut torus)) = read("torus3D.g2o")? else {
        panic!("torus3D is a 3D file");
    };
    let aliased = anywhere_in_groups(300, true_like);
    torus.compose_missing_poses();
    let rng = &mut StdRng::seed_from_u64(seed);
    let corruption = pgo_sim::corrupt(&torus, &aliased, rng).expect("corrupt");
    let dir = temp_dir("aliased-torus");
    let file = dir.join("torus.g2o");
    corruption.graph.write_g2o(&file).expect("write");
    let read = PoseGraph3::read_g2o(&file).expect("read");
    let (young, kept) = prefix(&read, n);
    Some((young, kept.iter().map(|&k| corruption.wrong[k]).collect()))
}

/// The places sweep's torus3D case of seed 2: every group's counts like a
/// true loop's.
const PLACES_SEED_2: (f64, u64) = (1.0, 1_000_003);

/// A map that passes the χ² test but whose decisions did not settle meets
/// EM's second start: [`aliased_torus`]'s ([`PLACES_SEED_2`]) first 1,000 poses (730 true
/// loops, 10 aliases). From the annealed start the decisions swing
/// between ~570 loops and all of them (the aliases bend the map until
/// ~160 true loops look wrong with them) and end with 155 true loops
/// `unsettled` and the χ² test passed; the kernel start's end keeps every
/// true loop and no alias, and ranks first. That is without the true
/// loops' reach (docs/method.md §4); with it the aliases are rejected
/// before they bend the map, and the annealed start alone keeps every
/// true loop and no alias.
#[test]
fn an_end_whose_decisions_did_not_settle_meets_the_second_start() {
    let Some((r, _)) = kernel_start_chosen(1000, PLACES_SEED_2) else {
        return;
    };
    let starts = &r.robust.starts;
    assert!(
        starts[0].passed == Some(true) && !starts[0].chosen,
        "{starts:?}"
    );
}

/// A run of true loops the decisions left out, which the loop model calls
/// a wrong population that the file's information calls consistent,
/// meets EM's second start: kitti_02 (43 true loops in three places) with
/// 300 aliases placed anywhere one by one, every count true-like (seed 13
/// of the scattered exploration in docs/benchmarks.md), information as
/// published. The annealed end keeps the 28 loops of one place; the 15 of
/// the other two fit its map only at `ν²` 8–17 on 3 dof and make a
/// population of their own within EM's kernel (30.7), and that map passed
/// its test 1.19 % off. The kernel start's end keeps all 43 and no alias,
/// and ranks first.
#[test]
fn a_wrong_population_the_file_calls_consistent_meets_the_second_start() {
    let Some(r) = scattered_kitti_02_keeps_its_43_true_loops(1_000_014) else {
        return;
    };
    let starts = &r.robust.starts;
    assert!(
        starts.len() == 2 && starts[0].passed == Some(true) && starts[1].chosen,
        "{starts:?}"
    );
}

/// The truncated start seeks the objective that ranks the ends, so it
/// reaches ends the others do not: kitti_02 with 300 aliases placed
/// anywhere one by one, every count true-like (seed 14 of the scattered
/// exploration in docs/benchmarks.md), information as published. The
/// annealed end leaves out two true loops and its decisions did not
/// settle; the Cauchy kernel's end is the same 41 loops. GNC's truncation
/// at `J`'s price holds every true loop and no alias, EM's decisions keep
/// them, and that end ranks first: nothing is left to question.
#[test]
fn the_truncated_start_keeps_what_the_others_leave_out() {
    let Some(r) = scattered_kitti_02_keeps_its_43_true_loops(1_000_015) else {
        return;
    };
    let starts = &r.robust.starts;
    assert!(
        starts.len() == 3
            && starts[0].accepted == 41
            && starts[1].accepted == 41
            && starts[2].chosen,
        "{starts:?}"
    );
    assert_eq!(r.status(), MapStatus::Ok);
}

/// An accepted loop that the file's information calls an outlier meets
/// EM's second start: CSAIL with 300 aliases placed anywhere one by one,
/// every count true-like (seed 15 of the scattered exploration in
/// docs/benchmarks.md), information as published. The annealed end accepts
/// 5 aliases with the 128 true loops, the largest at `ν²` 35.6 on 3 dof
/// (beyond `χ²₃(1 − α/K)` = 18.3, `K` = 133; the true loops reach 5.2),
/// and passed its test 7.25 % off. The kernel start's end leaves the two
/// largest out, keeps every true loop, and ranks first (0.82 % off;
/// without the recheck, `--expert no-recheck`, which then leaves out two
/// more).
#[test]
fn an_accepted_loop_the_information_calls_an_outlier_meets_the_second_start() {
    let by = without_recheck();
    let Some((r, wrong)) =
        corrupted_and_decided_by("CSAIL.g2o", &scattered(), 1_000_016, None, &by)
    else {
        return;
    };
    let starts = &r.robust.starts;
    assert!(
        starts.len() == 2 && starts[0].passed == Some(true) && starts[1].chosen,
        "{starts:?}"
    );
    let accepted = |alias: bool| {
        (r.loops.iter().zip(&wrong))
            .filter(|(l, w)| l.accepted && **w == alias)
            .count()
    };
    assert_eq!(accepted(false), 128);
    assert!(accepted(true) + 2 <= starts[0].accepted - 128, "{starts:?}");
}

/// manhattanOlson3500 replayed pose by pose, as a front end feeds it:
/// from 540 poses on, every update's map is the batch job's to within
/// 10⁻⁶ of the map's size in position and 10⁻⁶ rad in rotation. With any
/// chord step allowed to end a solve (one that lowered the χ² by less
/// than 10⁻⁹ of itself, however far it moved the poses) the update at 547
/// poses left positions 1.07·10⁻⁶ of the map's size and rotations
/// 1.65·10⁻⁶ rad from the batch job's (docs/method.md §7b).
#[test]
fn every_update_of_a_replay_ends_at_the_batch_map() {
    if let Some(full) = read_planar("manhattanOlson3500-g2o.g2o") {
        updates_end_at_the_batch_map(&full, 1, 540..600);
    }
}

/// parking-garage replayed every 10 poses: from 990 poses on, every
/// update's map is the batch job's to within 10⁻⁶ of the map's size and
/// 10⁻⁶ rad. Where the batch job's last solve ended by the relative
/// decrease alone, its last LM steps still moving the poses by
/// centimetres, the update at 1040 poses was 9.2·10⁻⁶ of the map's size
/// and 1.4·10⁻⁵ rad from it, the update's map the nearer the optimum
/// (docs/method.md §7b).
#[test]
fn every_update_of_a_flat_map_ends_at_the_batch_map() {
    let Some(dir) = datasets() else {
        return;
    };
    let full = PoseGraph3::read_g2o(dir.join("parking-garage.g2o")).unwrap();
    updates_end_at_the_batch_map(&full, 10, 990..1100);
}

/// Replays `full` as a front end feeds it, an update every `every` poses
/// up to the end of `compared`; checks each update in `compared` (by the
/// poses it has) against `optimize()` of the same graph: positions within
/// 10⁻⁶ of the map's size, rotations within 10⁻⁶ rad.
fn updates_end_at_the_batch_map<P: pgo::GraphPose<D>, const D: usize>(
    full: &PoseGraph<P, D>,
    every: usize,
    compared: std::ops::Range<usize>,
) {
    let (options, mut g) = (Options::default(), PoseGraph::<P, D>::new());
    for (k, edges) in edges_due(full).iter().enumerate().take(compared.end) {
        add_pose_and_edges(&mut g, full, k, edges);
        if (k + 1) % every != 0 {
            continue;
        }
        let u = g.update(&options).unwrap();
        if !compared.contains(&(k + 1)) {
            continue;
        }
        let b = g.optimize(&options).unwrap();
        let (apart, size, turned) = poses_apart(&u, &b);
        assert!(
            apart <= 1e-6 * size && turned <= 1e-6,
            "at {} poses: positions {apart:.2e} apart ({:.2e} of the size), rotations {turned:.2e} rad",
            k + 1,
            apart / size
        );
    }
}

/// The same map replayed by a front end: an update every 500 poses (and
/// after the last) gives the batch job's decisions at each, and at the end
/// all 43 true loops and no alias. (Up to 4,500 poses each update runs the
/// whole job, for a failed test, decisions that swung or no model to
/// resume from; the last resumes from the 4,500-pose job's decisions.)
#[test]
fn updates_of_a_map_with_such_a_population_are_the_batch_job() {
    updates_are_the_batch_job(("kitti_02.g2o", 1_000_014), 500, 43);
}

/// CSAIL with 300 aliases placed anywhere one by one, every count
/// true-like, information as published (seed 13 of the scattered
/// exploration), replayed by a front end: an update every 100 poses (and
/// after the last) gives the batch job's decisions at each, and the last
/// ends as the batch job does, with every true loop and no alias. From 600
/// poses on each update resumes EM from the last decisions, its outlying
/// check names aliases, and the recheck at the update's own end leaves
/// them out
/// ([`loops_the_outlying_check_names_are_left_out_where_the_end_without_them_ranks_first`]);
/// without it those updates ran the whole job, their end accepting a loop
/// the information calls an outlier.
#[test]
fn an_update_leaves_out_what_its_outlying_check_names_as_the_batch_job_does() {
    let Some(updates) = updates_are_the_batch_job(("CSAIL.g2o", 1_000_014), 100, 128) else {
        return;
    };
    let rechecked_warm = |u: &pgo::Solution<Se2>| {
        let warm = u
            .incremental()
            .is_some_and(|i| i.solve == UpdateSolve::Warm);
        let starts = &u.report().robust.starts;
        warm && starts
            .iter()
            .any(|s| s.chosen && s.start == Start::WithoutOutlying)
    };
    assert!(updates[5..].iter().all(rechecked_warm));
}

/// Replays dataset `name` with scattered aliases ([`scattered_planar`] of
/// `seed`) as a front end feeds it, checking that an update every `every`
/// poses and after the last gives `optimize()`'s decisions on the same
/// graph, and that the last keeps `true_loops` true loops and no alias;
/// returns the updates (`None` without the datasets).
fn updates_are_the_batch_job(
    (name, seed): (&str, u64),
    every: usize,
    true_loops: usize,
) -> Option<Vec<pgo::Solution<Se2>>> {
    let (full, edge_wrong) = scattered_planar(name, seed)?;
    let (steps, wrong) = replayed(&full, &edge_wrong, every);
    let mut updates = Vec::new();
    for (poses, u, b) in steps {
        let reason = u.incremental().map(|i| i.reason.clone());
        assert_eq!(decided(&u), decided(&b), "at {poses} poses ({reason:?})");
        updates.push(u);
    }
    let last = updates.last().expect("updates");
    assert_eq!(true_loops_kept(last.report(), &wrong).0, true_loops);
    Some(updates)
}

/// Whether a solution accepts each of its loop candidates.
fn decided(s: &pgo::Solution<Se2>) -> Vec<bool> {
    s.loops().iter().map(|l| l.accepted).collect()
}

/// One update of a replay: its poses, the update, and `optimize()` of the
/// same graph.
type Step = (usize, pgo::Solution<Se2>, pgo::Solution<Se2>);

/// `full` fed as a front end feeds it — poses in order, each edge once
/// both its ends exist — with an update every `every` poses and after the
/// last, each beside `optimize()` of the same graph: per update its poses,
/// the update and the batch job; and whether each candidate of the last
/// graph is wrong (`edge_wrong` per edge of `full`).
fn replayed(full: &PoseGraph2, edge_wrong: &[bool], every: usize) -> (Vec<Step>, Vec<bool>) {
    let (options, mut g, mut wrong) = (Options::default(), PoseGraph2::new(), Vec::new());
    let mut steps = Vec::new();
    let due = edges_due(full);
    for (k, edges) in due.iter().enumerate() {
        let added = add_pose_and_edges(&mut g, full, k, edges);
        wrong.extend(added.iter().map(|&i| edge_wrong[i]));
        if (k + 1) % every != 0 && k + 1 != due.len() {
            continue;
        }
        let u = g.update(&options).unwrap();
        steps.push((k + 1, u, g.optimize(&options).unwrap()));
    }
    (steps, wrong)
}

/// A planar dataset with 300 aliases placed anywhere one by one, every
/// count true-like, planted as `pgo corrupt --seed SEED` plants them (seed
/// `SEED − 1` of the scattered exploration in docs/benchmarks.md;
/// information as published) ([`corrupted_planar`]).
fn scattered_planar(name: &str, seed: u64) -> Option<(PoseGraph2, Vec<bool>)> {
    corrupted_planar(name, &scattered(), seed)
}

/// Planar dataset `name` with wrong candidates planted as `pgo corrupt
/// --seed SEED` plants them (`options`), written and read back; with
/// whether each of its edges is a wrong candidate (`None` without the
/// datasets).
fn corrupted_planar(
    name: &str,
    options: &CorruptionOptions,
    seed: u64,
) -> Option<(PoseGraph2, Vec<bool>)> {
    let Ok(AnyPoseGraph::Planar(mut graph)) = read(name)? else {
        panic!("{name} is a 2D file");
    };
    graph.compose_missing_poses();
    let rng = &mut StdRng::seed_from_u64(seed);
    let corruption = pgo_sim::corrupt(&graph, options, rng).expect("corrupt");
    let dir = temp_dir(&format!("corrupted-planar-{name}-{seed}"));
    let file = dir.join("m.g2o");
    corruption.graph.write_g2o(&file).expect("write");
    let read = PoseGraph2::read_g2o(&file).expect("read");
    Some((read, corruption.wrong))
}

/// The report of `optimize()` on kitti_02 with scattered aliases
/// ([`scattered_planar`]) of `seed`, checked to keep all 43 true loops and
/// no alias.
fn scattered_kitti_02_keeps_its_43_true_loops(seed: u64) -> Option<Report> {
    let (kitti, edge_wrong) = scattered_planar("kitti_02.g2o", seed)?;
    let wrong = candidate_labels(&kitti, &edge_wrong);
    let r = kitti.optimize(&Options::default()).unwrap().into_report();
    assert_eq!(true_loops_kept(&r, &wrong), (43, 43));
    Some(r)
}

/// The options of the scattered exploration (docs/benchmarks.md): 300
/// aliases placed anywhere one by one, every count true-like.
fn scattered() -> CorruptionOptions {
    CorruptionOptions {
        group_size: 1,
        ..anywhere_in_groups(300, 1.0)
    }
}

/// The report of `optimize()` on [`aliased_torus`]'s first `n` poses (with
/// the true loops it accepted) without the true loops' reach (`--expert
/// no-reach`), checked to keep every true loop and no alias, from the
/// second of two starts; and checked to keep them from the first start
/// with every layer on (the only start sought; the end without the map's
/// keystone, where one is tried, ranks below it).
fn kernel_start_chosen(n: u64, case: (f64, u64)) -> Option<(Report, usize)> {
    let (young, edge_wrong) = aliased_torus(n, case)?;
    let wrong = candidate_labels(&young, &edge_wrong);
    let true_loops = wrong.iter().filter(|w| !**w).count();
    let mut options = Options::default();
    let whole = young.optimize(&options).unwrap().into_report();
    assert_eq!(true_loops_kept(&whole, &wrong).0, true_loops);
    let starts = &whole.robust.starts;
    assert!(
        starts[0].start == Start::Annealed && starts[0].chosen,
        "{starts:?}"
    );
    let tried = |s: &StartEnd| {
        matches!(
            s.start,
            Start::WithoutKeystone | Start::AnnealedWithoutKeystone
        ) && !s.chosen
    };
    assert!(starts[1..].iter().all(tried), "{starts:?}");
    assert_eq!(whole.status(), MapStatus::Ok);
    options.expert.layers.reach = false;
    let r = young.optimize(&options).unwrap().into_report();
    let (accepted, _) = true_loops_kept(&r, &wrong);
    assert_eq!(accepted, true_loops);
    let starts = &r.robust.starts;
    // The kernel start's end stands: the truncated start is not sought
    // (the end without the keystone, tried, ranks below it).
    assert!(
        starts[1].start == Start::Kernel && starts[1].chosen,
        "{starts:?}"
    );
    assert!(starts[2..].iter().all(tried), "{starts:?}");
    Some((r, accepted))
}

/// A set kept from a cycle of the decisions meets EM's second start too:
/// torus3D with half the alias groups' counts true-like (seed 5 of the 3D
/// exploration in docs/benchmarks.md), its first 4,000 poses (3,166 true
/// loops, 190 aliases). From the annealed start the decisions accept the
/// aliases with the true loops; the χ² search's restarts swing between
/// ~3,400 loops (~150 aliases) and a few hundred, and keep the few hundred,
/// whose map fits best and passes — judged at its own map, thousands of
/// true loops are `unsettled`. Without the second start that end was
/// returned (the whole file: 3 of 4,049 true loops, 22.9 % off); the kernel
/// start's end keeps every true loop and no alias, and ranks first. That
/// is without the true loops' reach; with it the annealed start alone
/// keeps every true loop and no alias.
#[test]
fn a_set_kept_from_a_cycle_meets_the_second_start() {
    let Some((r, accepted)) = kernel_start_chosen(4000, (0.5, 1_000_006)) else {
        return;
    };
    let starts = &r.robust.starts;
    assert!(starts[0].accepted < accepted / 2, "{starts:?}");
    assert_eq!(r.status(), MapStatus::Ok);
}

/// The same map replayed as a front end builds it, an update every 100
/// poses from 600 on: each update accepts what `optimize()` of the same
/// graph accepts — every true loop, no alias.
#[test]
fn updates_of_the_aliased_torus_are_the_batch_job() {
    let Some((young, edge_wrong)) = aliased_torus(1000, PLACES_SEED_2) else {
        return;
    };
    let decided = |s: &pgo::Solution<pgo::Se3>| -> Vec<bool> {
        s.loops().iter().map(|l| l.accepted).collect()
    };
    let options = Options::default();
    let mut g = PoseGraph3::new();
    // Whether each candidate of `g` is wrong, in the order they were added.
    let mut wrong = Vec::new();
    let mut last = None;
    for (k, due) in edges_due(&young).iter().enumerate() {
        let added = add_pose_and_edges(&mut g, &young, k, due);
        wrong.extend(added.iter().map(|&i| edge_wrong[i]));
        if (k + 1) % 100 != 0 || k + 1 < 600 {
            continue;
        }
        let u = g.update(&options).unwrap();
        let b = g.optimize(&options).unwrap();
        let reason = u.incremental().map(|i| i.reason.clone());
        let differ = (decided(&u).iter().zip(decided(&b)))
            .filter(|&(&x, y)| x != y)
            .count();
        assert_eq!(differ, 0, "at {} poses ({reason:?})", k + 1);
        let (cu, cb) = (u.chi2(), b.chi2());
        assert!(
            (cu - cb).abs() <= 1e-6 * cb,
            "at {}: χ² {cu} vs {cb}",
            k + 1
        );
        last = Some(u);
    }
    // The last update, at 1,000 poses: every true loop, no alias.
    let accepted = decided(&last.expect("updates ran"));
    assert_eq!(accepted.len(), wrong.len());
    assert!(accepted.iter().zip(&wrong).all(|(&a, &w)| a != w));
}

/// How many true loops `r` accepted, of those that passed the gate; no
/// wrong one accepted (`wrong`: the candidates' labels).
fn true_loops_kept(r: &Report, wrong: &[bool]) -> (usize, usize) {
    assert_eq!(r.loops.len(), wrong.len());
    let count = |keep: &dyn Fn(&LoopReport, bool) -> bool| {
        r.loops
            .iter()
            .zip(wrong)
            .filter(|(l, w)| keep(l, **w))
            .count()
    };
    assert_eq!(count(&|l, w| l.accepted && w), 0, "wrong loops accepted");
    (count(&|l, w| l.accepted && !w), count(&|l, w| l.kept && !w))
}

/// The options `pgo corrupt --wrong OUTLIERS --wrong-mode POLICY` gives
/// [`pgo_sim::corrupt`] (the other flags their defaults: counts for every
/// candidate from the default inlier model).
fn corruption(outliers: usize, policy: OutlierPolicy) -> CorruptionOptions {
    CorruptionOptions {
        outliers,
        policy,
        inliers: Some(InlierModel::default()),
        ..CorruptionOptions::default()
    }
}

/// The options of the places sweep's aliases (`bench_robust.py
/// --alias-place anywhere --alias-by-group`): `outliers` aliases in groups
/// of 10 placed anywhere, 5–50 poses off, a share `true_like` of the groups
/// with counts drawn like a true loop's.
fn anywhere_in_groups(outliers: usize, true_like: f64) -> CorruptionOptions {
    CorruptionOptions {
        group_size: 10,
        true_like_share: true_like,
        true_like_by_group: true,
        alias_place: AliasPlace::Anywhere,
        alias_offsets: AliasOffsets { min: 5, max: 50 },
        ..corruption(outliers, OutlierPolicy::Aliased)
    }
}

/// Dataset `name` with wrong candidates planted as `pgo corrupt --seed
/// SEED` plants them (`options`; the vertices a file named without a line
/// composed first; the corrupted graph written and read back), its
/// information as published or, with `calibrated`, scaled to that times
/// the clean optimum's `χ²/dof = 1`, optimised with the default options;
/// the report and the candidates' labels.
fn corrupted_and_decided(
    name: &str,
    options: &CorruptionOptions,
    seed: u64,
    calibrated: Option<f64>,
) -> Option<(Report, Vec<bool>)> {
    corrupted_and_decided_by(name, options, seed, calibrated, &Options::default())
}

/// [`corrupted_and_decided`] with the job's options `by`.
fn corrupted_and_decided_by(
    name: &str,
    options: &CorruptionOptions,
    seed: u64,
    calibrated: Option<f64>,
    by: &Options,
) -> Option<(Report, Vec<bool>)> {
    let src = datasets()?.join(name);
    let work = temp_dir(&format!("corrupted-{name}-{}-{seed}", options.outliers));
    let job = (options, seed, calibrated);
    Some(
        match AnyPoseGraph::read_g2o(&src).unwrap_or_else(|e| panic!("{name}: {e}")) {
            AnyPoseGraph::Planar(g) => corrupt_and_decide(g, job, by, &work),
            AnyPoseGraph::Spatial(g) => corrupt_and_decide(g, job, by, &work),
        },
    )
}

/// [`corrupted_and_decided`] on the dataset's graph `graph`, its files
/// written to `work`.
fn corrupt_and_decide<P: ErrorCoordinates<D>, const D: usize>(
    mut graph: PoseGraph<P, D>,
    (options, seed, calibrated): (&CorruptionOptions, u64, Option<f64>),
    by: &Options,
    work: &Path,
) -> (Report, Vec<bool>) {
    // The clean optimum, of the graph as the file gives it.
    let factor = calibrated.map(|times| {
        let mut plain = Options::default();
        plain.gate.mode = GateMode::Off;
        plain.robust.method = RobustMethod::None;
        let clean = graph.optimize(&plain).expect("clean");
        let t = clean.chi2_test().expect("test");
        times * t.dof_residual as f64 / t.d2
    });
    graph.compose_missing_poses();
    let corruption =
        pgo_sim::corrupt(&graph, options, &mut StdRng::seed_from_u64(seed)).expect("corrupt");
    let corrupted = work.join("m.g2o");
    corruption.graph.write_g2o(&corrupted).expect("write");
    let input = match factor {
        None => corrupted,
        Some(factor) => {
            let read = PoseGraph::<P, D>::read_g2o(&corrupted).expect("read");
            let scaled_graph = rebuilt(&read, |_, mut e| {
                e.information *= factor;
                Some(e)
            });
            let scaled = work.join("m-scaled.g2o");
            scaled_graph.write_g2o(&scaled).expect("write");
            scaled
        }
    };
    let graph = PoseGraph::<P, D>::read_g2o(&input).expect("read");
    let wrong = candidate_labels(&graph, &corruption.wrong);
    let solution = graph.optimize(by).expect("optimise");
    (solution.into_report(), wrong)
}

/// A young real map keeps its loops: MIT's loops made candidates (one
/// count for all: the gate learns nothing from them), and the map cut to
/// its first poses as a front end would have it. Every true loop is
/// accepted on each prefix but one, the first 300 poses, where the model
/// finds two loops at `ν²` 4.8 and 5.3 apart from six at 0.05–1.05 and
/// rejects them (docs/method.md §4, "Few candidates, all true").
#[test]
fn a_young_real_map_keeps_its_loops() {
    let Some(mit) = read_planar("MIT.g2o") else {
        return;
    };
    let as_candidates = rebuilt(&mit, |_, mut e| {
        e.loop_candidate = e.from.abs_diff(e.to) != 1;
        e.inliers = e.loop_candidate.then_some(150);
        Some(e)
    });
    for (n, want_rejected) in [(100, 0), (200, 0), (300, 2), (400, 0), (600, 0), (808, 0)] {
        let (young, _) = prefix(&as_candidates, n);
        let r = young.optimize(&Options::default()).unwrap();
        let loops = &r.report().loops;
        let rejected = loops.iter().filter(|l| !l.accepted).count();
        assert!(!loops.is_empty(), "{n} poses");
        assert_eq!(rejected, want_rejected, "{n} poses: {loops:?}");
    }
}

/// intel with every edge between non-consecutive poses a loop candidate
/// (`--candidates non-sequential`): its loops fit about 60 times better
/// than the file states, and none is a wrong loop, so none is rejected —
/// nine used to be, at `ν²` 0.57–1.62, consistent with their stated noise
/// (docs/method.md §4, "Few candidates, all true").
#[test]
fn loops_that_fit_their_stated_noise_are_kept_without_wrong_ones() {
    let Some(intel) = read_planar("intel.g2o") else {
        return;
    };
    let mut options = Options::default();
    options.set("candidates", "non-sequential").unwrap();
    let r = intel.optimize(&options).unwrap();
    let rejected: Vec<_> = r.report().loops.iter().filter(|l| !l.accepted).collect();
    assert_eq!(r.report().loops.len(), 785);
    assert!(rejected.is_empty(), "{rejected:?}");
}

/// Decisions that swing end no worse than they began: MIT with 30 aliases
/// in groups of 10 placed anywhere, half the groups with true-like counts
/// (`pgo corrupt` as seed 23 of the MIT sweep in docs/benchmarks.md runs
/// it). The gate keeps the 7 loops of the highest counts, all true; their
/// map's model cannot tell two alias groups at `ν²` 4–10 from the true
/// loops and accepts 40 candidates, whose map rejects all but 6, and the
/// decisions swing between 6 and 40. They used to keep the better fitting
/// of those two, without one of the 7, the map 18.9 % off; the set they
/// started from fits better, and is kept, with the warning that the
/// decisions did not settle.
#[test]
fn decisions_that_swing_end_no_worse_than_they_began() {
    let aliased = anywhere_in_groups(30, 0.5);
    for calibrated in [None, Some(1.0)] {
        let Some((r, wrong)) = corrupted_and_decided("MIT.g2o", &aliased, 1_000_024, calibrated)
        else {
            return;
        };
        let kept = r.loops.iter().filter(|l| l.kept).count();
        let (accepted, kept_true) = true_loops_kept(&r, &wrong);
        assert_eq!((kept, kept_true, accepted), (7, 7, 7), "{calibrated:?}");
        let warned = r.warnings.iter().any(|w| w.contains("did not settle"));
        assert!(warned, "{:?}", r.warnings);
        assert_eq!(r.status(), MapStatus::Unsettled);
    }
}

/// A failed test the χ² search cannot explain ends at the passing set of
/// least truncated least squares `J` that the decisions solved (from any
/// start), not at a passing map of a few loops: sphere2500 with 300
/// aliases in groups of 10 placed anywhere, half the groups with
/// true-like counts, its information as published (seed 6 of
/// `bench_robust.py --alias-place anywhere`). The decisions ran away from
/// the annealed set of 2,369 true loops and 11 aliases to 242 aliases, and
/// the test failed; the search's restart kept a map of one loop, which
/// passes, and the job returned it: 16 % off. The annealed, the kernel
/// and the truncated start's sets pass; the kernel's set was kept once
/// (2,442 true loops and 11 aliases, 0.44 % off, its decisions unsettled),
/// and since the truncated start the lowest `J` is its end's: every one of
/// the 2,450 true loops and no alias, exit 0. About five minutes in
/// release: `cargo test --release --test datasets -- --ignored`.
#[test]
#[ignore]
fn a_failed_test_ends_at_the_passing_set_that_leaves_out_least() {
    let aliased = anywhere_in_groups(300, 0.5);
    let Some((r, wrong)) = corrupted_and_decided("sphere2500.g2o", &aliased, 1_000_007, None)
    else {
        return;
    };
    let count = |wrong_ones: bool| {
        (r.loops.iter().zip(&wrong))
            .filter(|(l, w)| l.accepted && **w == wrong_ones)
            .count()
    };
    let true_loops = wrong.iter().filter(|w| !**w).count();
    assert_eq!(count(false), true_loops);
    assert_eq!(count(true), 0);
    assert!(r.chi2_test.as_ref().is_some_and(|t| t.passed));
    chosen_at_the_lowest_objective(&r, Start::Truncated);
    assert_eq!(r.status(), MapStatus::Ok);
}

/// An alias group the decisions accept in a map that passes its test is
/// named doubtful: MIT with 30 aliases in groups of 20 placed anywhere,
/// half the groups with true-like counts, its information as published
/// (seed 8 of the places sweep, `scripts/bench_aliasing_sweep.sh`). Ten
/// aliases twenty poses along one corridor sit at `ν²` 10–20 among true
/// loops up to 5; the map passes with them, 2.2 % off. Their errors share
/// one offset (F = 30.6 on 3 and 27 degrees of freedom) and the map would
/// move by 9.7 % of its size without them: the report names them, and
/// only them, and warns. (With the information calibrated, the χ² search
/// takes them out.)
#[test]
fn an_accepted_alias_group_that_bends_a_passing_map_is_doubtful() {
    let aliased = CorruptionOptions {
        group_size: 20,
        ..anywhere_in_groups(30, 0.5)
    };
    let Some((r, wrong)) = corrupted_and_decided("MIT.g2o", &aliased, 1_000_009, None) else {
        return;
    };
    assert!(r.chi2_test.as_ref().is_some_and(|t| t.passed));
    let doubtful = &r.robust.doubtful;
    assert_eq!(doubtful.len(), 1, "{doubtful:?}");
    let loops = &doubtful[0].loops;
    assert_eq!(loops.len(), 10, "{doubtful:?}");
    assert!(loops.iter().all(|&k| wrong[k]), "{doubtful:?}");
    assert!(doubtful[0].map_moves > 0.05, "{doubtful:?}");
    let warned = r.warnings.iter().any(|w| w.contains("one common offset"));
    assert!(warned, "{:?}", r.warnings);
    assert_eq!(r.status(), MapStatus::Questioned);
}

/// True loops that verification scored low are named when the map would
/// move with them: MIT with 30 aliases in groups of 20 placed anywhere,
/// half the groups with true-like counts, its information as published
/// (seed 13 of the places sweep over more seeds,
/// `scripts/bench_aliasing_sweep.sh`). The gate's count model, fitted to
/// 50 counts, has a narrow true-loop component (σ 0.24 in `ln n`) that
/// puts true loops of 51–109 inliers at priors of 2·10⁻⁷–0.06; their
/// innovations (ν² 0.7–4.7) speak for them, but MIT's loose odometry makes
/// that evidence too weak to outweigh the counts. The map passes its test
/// without six of its 20 true loops, 3.3 % off; the report names the true
/// loops whose addition would move it by over 1 % of its size, and no
/// alias, and warns.
#[test]
fn true_loops_kept_out_by_their_counts_alone_are_named_when_they_would_move_the_map() {
    let aliased = CorruptionOptions {
        group_size: 20,
        ..anywhere_in_groups(30, 0.5)
    };
    let Some((r, wrong)) = corrupted_and_decided("MIT.g2o", &aliased, 1_000_014, None) else {
        return;
    };
    assert!(r.chi2_test.as_ref().is_some_and(|t| t.passed));
    let held: Vec<usize> = (r.robust.held_back.iter())
        .flat_map(|h| h.loops.iter().copied())
        .collect();
    assert!(held.len() >= 2, "{:?}", r.robust.held_back);
    assert!(
        held.iter().all(|&k| !wrong[k] && !r.loops[k].accepted),
        "{held:?}"
    );
    assert!(
        r.robust
            .held_back
            .iter()
            .all(|h| h.map_moves > pgo::report::DOUBT_MOVE)
    );
    let warned = r.warnings.iter().any(|w| w.contains("kept out by"));
    assert!(warned, "{:?}", r.warnings);
    assert_eq!(r.status(), MapStatus::Questioned);
}

/// An accepted alias whose innovation lies beyond every true loop's is
/// named when the map would move without it: parking-garage with 300
/// aliases in groups of 10 placed anywhere, half the groups with
/// true-like counts, its information as published (seed 3 of the
/// exploration of docs/method.md §4). One alias (88–694, 130 inliers) is
/// accepted alone among 4,616 loops, at the largest innovation of them
/// (`ν²` 0.035 where the true loops' fit centres on 1.4·10⁻⁴); the map
/// passes its test with it, 1.4 % off. Its upper tail under the true
/// loops' fitted density is 8·10⁻⁶, below the χ² test's α over the 4,616
/// tested, and the map would move by 4.6 % of its size without it: the
/// report names it, and only it, and warns (without the recheck,
/// `--expert no-recheck`, which then leaves it out). The decisions' own
/// reach (docs/method.md §4) leaves it alone: its `ν²`, 0.035 on 6 dof,
/// is below its information's mean.
#[test]
fn an_accepted_alias_beyond_the_true_loops_reach_is_named_when_it_moves_the_map() {
    let aliased = anywhere_in_groups(300, 0.5);
    let by = without_recheck();
    let Some((r, wrong)) =
        corrupted_and_decided_by("parking-garage.g2o", &aliased, 1_000_004, None, &by)
    else {
        return;
    };
    assert!(r.chi2_test.as_ref().is_some_and(|t| t.passed));
    assert!(r.robust.doubtful.is_empty(), "{:?}", r.robust.doubtful);
    let outlying = &r.robust.outlying;
    assert_eq!(outlying.len(), 1, "{outlying:?}");
    assert_eq!(outlying[0].loops.len(), 1, "{outlying:?}");
    let alias = outlying[0].loops[0];
    assert!(wrong[alias] && r.loops[alias].accepted, "{outlying:?}");
    assert!(outlying[0].p_value < 0.05, "{outlying:?}");
    assert!(outlying[0].map_moves > 0.02, "{outlying:?}");
    let warned = r
        .warnings
        .iter()
        .any(|w| w.contains("by more than any true loop"));
    assert!(warned, "{:?}", r.warnings);
    assert_eq!(r.status(), MapStatus::Questioned);
}

/// kitti_00 with 300 aliases placed anywhere one by one, every count
/// true-like (seed 16 of the scattered exploration in docs/benchmarks.md),
/// information as published. One alias (347–2452) sits at `ν²` 86 among
/// 137 true loops that reach 9: between the true loops' wide fit and the
/// wrong loops' narrow one far out, its posterior is near 1, but no true
/// loop of the map reaches it. It is rejected as `outlying`, and the map
/// keeps every true loop and no alias, where it ended 0.18 % off with the
/// alias and exit status 0.
#[test]
fn an_alias_beyond_the_true_loops_reach_is_rejected_whatever_its_posterior() {
    let Some((r, wrong)) = corrupted_and_decided("kitti_00.g2o", &scattered(), 1_000_017, None)
    else {
        return;
    };
    assert_eq!(true_loops_kept(&r, &wrong).0, 137);
    let outlying: Vec<usize> = (0..wrong.len())
        .filter(|&k| r.loops[k].reason == Reason::Outlying)
        .collect();
    assert_eq!(outlying.len(), 1, "{outlying:?}");
    let alias = &r.loops[outlying[0]];
    assert!(wrong[outlying[0]] && !alias.accepted, "{alias:?}");
    assert!(alias.posterior.is_some_and(|p| p > 0.5), "{alias:?}");
    assert_eq!(r.status(), MapStatus::Ok);
}

/// An accepted alias that the file's information calls an outlier, where
/// the true loops' fitted density expects none as far out, is named when
/// it moves the map: CSAIL with 300 aliases placed anywhere one by one,
/// every count true-like (seed 13 of the scattered exploration in
/// docs/benchmarks.md), information as published. Both starts end at the
/// 128 true loops and two aliases at `ν²` 22.4 and 22.9 on 3 dof, where
/// the true loops reach 5.2 and the information as stated bounds 130
/// accepted loops at 18.2; the true loops' fitted spread, widened by the
/// aliases, still expects only 0.1 of them that far out. The map passed
/// its test 0.66 % off and exited 0. Without the recheck (`--expert
/// no-recheck`) it is questioned; with it, the end without them is kept
/// ([`loops_the_outlying_check_names_are_left_out_where_the_end_without_them_ranks_first`]).
#[test]
fn an_alias_beyond_the_stated_information_is_named_when_it_moves_the_map() {
    let by = without_recheck();
    let Some((r, wrong)) =
        corrupted_and_decided_by("CSAIL.g2o", &scattered(), 1_000_014, None, &by)
    else {
        return;
    };
    assert!(r.chi2_test.as_ref().is_some_and(|t| t.passed));
    let accepted_aliases: Vec<usize> = (0..wrong.len())
        .filter(|&k| wrong[k] && r.loops[k].accepted)
        .collect();
    let mut named: Vec<usize> = (r.robust.outlying.iter())
        .inspect(|o| assert!(o.stated && o.p_value < 0.05 && o.map_moves > 0.01, "{o:?}"))
        .flat_map(|o| o.loops.clone())
        .collect();
    named.sort_unstable();
    assert_eq!(named, accepted_aliases, "{:?}", r.robust.outlying);
    assert_eq!(named.len(), 2);
    let warned =
        (r.warnings.iter()).any(|w| w.contains("by more than the file's information allows"));
    assert!(warned, "{:?}", r.warnings);
    assert_eq!(r.status(), MapStatus::Questioned);
}

/// The information's tail is judged on the scale the true loops show,
/// also where that is tighter than the file states: CSAIL with 300
/// aliases placed anywhere one by one, every count true-like (seeds 16 and
/// 17 of the scattered exploration in docs/benchmarks.md), information as
/// published, whose true loops err 11 times less than it states (their
/// fitted mean `ln ν²` −1.67 on 3 dof). Seed 16 accepts aliases at `ν²`
/// 13.8 and 16.8 and seed 17 one at 11.0, within the stated bound for
/// about 130 accepted loops (18.2) but far beyond the true loops' largest
/// (5.2); the maps passed their tests 0.91 % and 0.76 % off and exited 0.
/// Each alias moves the map by 1.7–2.5 %: named, questioned (without the
/// recheck, `--expert no-recheck`, which leaves them out).
#[test]
fn aliases_within_the_stated_information_but_beyond_the_loops_own_scale_are_named() {
    let by = without_recheck();
    for seed in [1_000_017, 1_000_018] {
        let Some((r, wrong)) = corrupted_and_decided_by("CSAIL.g2o", &scattered(), seed, None, &by)
        else {
            return;
        };
        assert!(
            r.chi2_test.as_ref().is_some_and(|t| t.passed),
            "seed {seed}"
        );
        let named: Vec<usize> = (r.robust.outlying.iter())
            .inspect(|o| assert!(o.stated && o.p_value < 0.05 && o.map_moves > 0.01, "{o:?}"))
            .flat_map(|o| o.loops.clone())
            .collect();
        assert!(!named.is_empty(), "seed {seed}: {:?}", r.robust);
        for &k in &named {
            assert!(
                wrong[k] && r.loops[k].accepted,
                "seed {seed}: {:?}",
                r.loops[k]
            );
        }
        let warned =
            (r.warnings.iter()).any(|w| w.contains("on the scale of the map's true loops"));
        assert!(warned, "seed {seed}: {:?}", r.warnings);
        assert_eq!(r.status(), MapStatus::Questioned, "seed {seed}");
    }
}

/// The job's default options with the layer `recheck` off: the outlying
/// check names what it finds and the map stands.
fn without_recheck() -> Options {
    let mut by = Options::default();
    by.expert.layers.recheck = false;
    by
}

/// The loops the outlying check names are left out where the end without
/// them ranks first. Named without the recheck (`--expert no-recheck`,
/// the tests above): CSAIL with 300 aliases placed anywhere one by one,
/// every count true-like, information as published (seeds 13, 16 and 17 of
/// the scattered exploration in docs/benchmarks.md; two, two and one
/// aliases named, the maps 0.66–0.91 % off), and parking-garage's single
/// alias (seed 3 of the exploration of docs/method.md §4, 1.4 % off).
/// EM's decisions from the map without them, holding them out, end where
/// the aliases that fitted the bent map no longer fit: the end's
/// objective `J` is below every other end's (the named aliases' `ν²` lie
/// far above the price of leaving a loop out on the map's own scale), it
/// is kept, every named loop is rejected as `outlying`, and nothing
/// questions the map. Seed 13 and parking-garage end with every true loop
/// and no alias; seeds 16 and 17 keep two and one aliases at `ν²` where
/// true loops lie too, and seed 16 leaves one true loop out.
#[test]
fn loops_the_outlying_check_names_are_left_out_where_the_end_without_them_ranks_first() {
    let (scattered, grouped) = (scattered(), anywhere_in_groups(300, 0.5));
    for (name, aliased, seed, exact) in [
        ("CSAIL.g2o", &scattered, 1_000_014, true),
        ("CSAIL.g2o", &scattered, 1_000_017, false),
        ("CSAIL.g2o", &scattered, 1_000_018, false),
        ("parking-garage.g2o", &grouped, 1_000_004, true),
    ] {
        let case = format!("{name} seed {seed}");
        let Some((named, _)) =
            corrupted_and_decided_by(name, aliased, seed, None, &without_recheck())
        else {
            return;
        };
        let named: Vec<usize> = named
            .robust
            .outlying
            .iter()
            .flat_map(|o| o.loops.clone())
            .collect();
        let (r, wrong) = corrupted_and_decided(name, aliased, seed, None).expect("read");
        assert!(!named.is_empty(), "{case}");
        for &k in &named {
            assert!(wrong[k], "{case}: {:?}", r.loops[k]);
            assert_eq!(
                r.loops[k].reason,
                Reason::Outlying,
                "{case}: {:?}",
                r.loops[k]
            );
        }
        let starts = &r.robust.starts;
        let chosen: Vec<&StartEnd> = starts.iter().filter(|s| s.chosen).collect();
        assert_eq!(chosen.len(), 1, "{case}: {starts:?}");
        assert_eq!(
            chosen[0].start,
            Start::WithoutOutlying,
            "{case}: {starts:?}"
        );
        // The starts that reached an end, each ranked.
        let others = (starts.iter())
            .filter(|s| s.start != Start::WithoutOutlying)
            .filter_map(|s| s.objective)
            .fold(f64::INFINITY, f64::min);
        let kept = chosen[0].objective.expect("ranked");
        assert!(kept < others, "{case}: {starts:?}");
        if exact {
            true_loops_kept(&r, &wrong);
            let rejected = (r.loops.iter().zip(&wrong)).filter(|(l, w)| !l.accepted && !**w);
            assert_eq!(rejected.count(), 0, "{case}");
        }
        assert!(
            r.robust.outlying.is_empty(),
            "{case}: {:?}",
            r.robust.outlying
        );
        assert_eq!(r.status(), MapStatus::Ok, "{case}");
    }
}

/// A cluster the doubt check names is tried without, and that end is kept
/// where it ranks first and nothing questions it: Vertigo's ring (434
/// poses; its 26 true loops all close the ring at one place) with 30
/// aliases placed anywhere in groups of 10, half the groups with true-like
/// counts, information as published (seed 2 of the exploration of
/// docs/benchmarks.md, "A ring with one revisited place"). The annealed
/// start ends with one group of 10 aliases and every true loop, its χ²
/// test passed, 33.9 % off: a ring bends cheaply, and each of the two
/// clusters errs by an offset common to its members (doubtful). EM's
/// decisions from the map without the group keep every true loop and no
/// alias, at `J` 142.8 against 180.8 on the scale that end's fit shows;
/// without the recheck (`--expert no-recheck`) the group stays and the
/// report names both clusters.
#[test]
fn a_cluster_named_doubtful_is_left_out_where_the_end_without_it_ranks_first() {
    let aliased = anywhere_in_groups(30, 0.5);
    let decided =
        |by: &Options| corrupted_and_decided_by("ring.g2o", &aliased, 1_000_003, None, by);
    let Some((r, wrong)) = decided(&Options::default()) else {
        return;
    };
    let accepted = |r: &Report, alias: bool| {
        (r.loops.iter().zip(&wrong))
            .filter(|(l, w)| l.accepted && **w == alias)
            .count()
    };
    assert_eq!((accepted(&r, false), accepted(&r, true)), (26, 0));
    chosen_at_the_lowest_objective(&r, Start::WithoutDoubtful);
    assert_eq!(r.status(), MapStatus::Ok);
    let Some((named, _)) = decided(&without_recheck()) else {
        return;
    };
    assert_eq!((accepted(&named, false), accepted(&named, true)), (26, 10));
    assert_eq!(
        named.robust.doubtful.len(),
        2,
        "{:?}",
        named.robust.doubtful
    );
    assert_eq!(named.status(), MapStatus::Questioned);
}

/// A loop the outlying check flags whose removal moves the map by more
/// than it may be off (0.5 %) but too little to name it (1 %) is tried
/// without, and left out where the end without it ranks first: seed 15 of
/// the scattered exploration in docs/benchmarks.md (300 aliases placed
/// anywhere one by one, every count true-like) on CSAIL with its
/// information as published — one alias at `ν²` 14 (the true loops reach
/// 5.2) whose removal moves the map by 0.67 %, 0.23 % off with it — and
/// on intel, both scales. Each ends with every true loop and no alias,
/// and names nothing: the map exits 0. (Without the recheck, CSAIL also
/// keeps two aliases the check names.)
#[test]
fn a_flagged_loop_too_light_to_name_is_tried_without() {
    for (name, calibrated, true_loops) in [
        ("CSAIL.g2o", None, 128),
        ("intel.g2o", None, 785),
        ("intel.g2o", Some(1.0), 785),
    ] {
        let case = format!("{name} {calibrated:?}");
        let Some((r, wrong)) = corrupted_and_decided(name, &scattered(), 1_000_016, calibrated)
        else {
            return;
        };
        assert_eq!(true_loops_kept(&r, &wrong).0, true_loops, "{case}");
        let chosen = (r.robust.starts.iter()).find(|s| s.chosen);
        assert_eq!(
            chosen.map(|s| s.start),
            Some(Start::WithoutOutlying),
            "{case}: {:?}",
            r.robust.starts
        );
        assert!(r.robust.outlying.is_empty(), "{case}");
        assert_eq!(r.status(), MapStatus::Ok, "{case}");
        // Without the recheck (`--expert no-recheck`) the aliases stay, and
        // the outlying check names all but that one.
        let by = without_recheck();
        let (plain, _) =
            corrupted_and_decided_by(name, &scattered(), 1_000_016, calibrated, &by).expect("read");
        let aliases = (plain.loops.iter().zip(&wrong)).filter(|(l, w)| l.accepted && **w);
        let named = (plain.robust.outlying.iter())
            .map(|o| o.loops.len())
            .sum::<usize>();
        assert_eq!(
            aliases.count(),
            named + 1,
            "{case}: {:?}",
            plain.robust.outlying
        );
    }
}

/// Where `start` ended in the report `r` (it ran).
fn start_of(r: &Report, start: Start) -> &StartEnd {
    let starts = &r.robust.starts;
    (starts.iter().find(|s| s.start == start)).unwrap_or_else(|| panic!("{start:?}: {starts:?}"))
}

/// The options of the fresh MIT runs (`scripts/tail_shape_scan.py`): 30
/// aliases in groups of 5 at revisited places, 30 % of them with counts
/// drawn like a true loop's.
fn revisited_in_fives() -> CorruptionOptions {
    CorruptionOptions {
        group_size: 5,
        true_like_share: 0.3,
        ..corruption(30, OutlierPolicy::Aliased)
    }
}

/// A group of aliases at a revisited place that outnumbers the true loop
/// beside it: MIT (20 true loops) with 30 aliases in groups of 5 at
/// revisited places, 30 % of them with true-like counts, information as
/// published (seed 25 of `scripts/tail_shape_scan.py`). Four members of the
/// group at poses 45–365 have counts of 93–557; judged against the map with
/// the members that agree better, the true loop 365–45 loses to them, and
/// the annealed end leaves out four true loops and holds an alias: its
/// decisions do not settle, and its map is 15 % off. The decisions from its
/// map with every member judged against the map without its cluster only,
/// then with every layer, keep every true loop and no alias, and that end
/// ranks first by `J`.
#[test]
fn a_group_that_outnumbers_the_true_loop_beside_it_meets_the_start_without_agreement() {
    let revisited = revisited_in_fives();
    let Some((r, wrong)) = corrupted_and_decided("MIT.g2o", &revisited, 1_000_026, None) else {
        return;
    };
    let starts = &r.robust.starts;
    assert!(start_of(&r, Start::Annealed).accepted < 20, "{starts:?}");
    let others = chosen_at_the_lowest_objective(&r, Start::WithoutAgreement);
    assert!(others >= 2, "{starts:?}");
    assert_eq!(true_loops_kept(&r, &wrong), (20, 20));
    assert_eq!(r.status(), MapStatus::Ok);
}

/// A group of aliases the map rests on is tried out: MIT with 30 aliases
/// in groups of 5 at revisited places, information as published, fresh
/// seed 30. Three members of a group (273–537, 274–538, 275–539: the
/// true loop 537–273 read the other way round) bend the map into a
/// basin where they fit (`ν²` 8.2–11.2) and three true loops of that
/// corridor do not (`ν²` 539–17,145); the annealed end passes its χ² test
/// and settles, 25.9 % off, and no start was sought. Removing the group
/// would move the map by 55 % of its size: it is the map's keystone. EM's
/// decisions from the map without it keep all 20 true loops and no alias,
/// at a lower `J`, and that end is kept. Without the layer
/// (`--expert no-keystone`) the annealed end stands.
#[test]
fn a_keystone_group_of_aliases_is_tried_out() {
    let revisited = revisited_in_fives();
    let Some((r, wrong)) = corrupted_and_decided("MIT.g2o", &revisited, 1_000_031, None) else {
        return;
    };
    let starts = &r.robust.starts;
    assert_eq!(start_of(&r, Start::Annealed).accepted, 20, "{starts:?}");
    chosen_at_the_lowest_objective(&r, Start::WithoutKeystone);
    assert_eq!(true_loops_kept(&r, &wrong), (20, 20));
    assert_eq!(r.status(), MapStatus::Ok);
    let mut by = Options::default();
    by.expert.layers.keystone = false;
    let (r, wrong) = corrupted_and_decided_by("MIT.g2o", &revisited, 1_000_031, None, &by).unwrap();
    let aliases_in = (r.loops.iter().zip(&wrong)).filter(|(l, w)| **w && l.accepted);
    assert_eq!(aliases_in.count(), 3);
}

/// A keystone alias whose map EM's decisions do not leave from where it
/// stands is tried out from the start: MIT with 30 aliases placed
/// anywhere one by one, every count true-like, information calibrated,
/// fresh seed 30. The alias 9–550 (`ν²` 6.9) bends the map so that 7 true
/// loops do not fit (`ν²` 130–211); the annealed end passes and settles,
/// 19.7 % off. Removing the alias would move the map by 72 % of its size.
/// EM's decisions from the map without it end at 9 loops, above the
/// annealed end's `J`; the annealed start again without it keeps all 20
/// true loops and no alias, at the lowest `J`, and that end is kept.
#[test]
fn a_keystone_alias_is_tried_out_from_the_start() {
    let scattered = CorruptionOptions {
        group_size: 1,
        ..anywhere_in_groups(30, 1.0)
    };
    let Some((r, wrong)) = corrupted_and_decided("MIT.g2o", &scattered, 1_000_031, Some(1.0))
    else {
        return;
    };
    let starts = &r.robust.starts;
    assert_eq!(start_of(&r, Start::Annealed).accepted, 14, "{starts:?}");
    assert!(
        start_of(&r, Start::WithoutKeystone).accepted < 14,
        "{starts:?}"
    );
    chosen_at_the_lowest_objective(&r, Start::AnnealedWithoutKeystone);
    assert_eq!(true_loops_kept(&r, &wrong), (20, 20));
    assert_eq!(r.status(), MapStatus::Ok);
}

/// An end its checks question is not annealed again without its
/// keystone: MIT with 30 aliases in groups of 5 at revisited places,
/// information calibrated, fresh seed 40. The annealed end holds 5
/// aliases, which the doubtful check names (exit 5); EM's decisions from
/// the map without its keystone end above its `J`. The annealed start
/// again without it ended with 10 aliases at a lower `J`, questioned by
/// nothing (exit 0).
#[test]
fn a_questioned_end_is_not_annealed_again_without_its_keystone() {
    let revisited = revisited_in_fives();
    let Some((r, wrong)) = corrupted_and_decided("MIT.g2o", &revisited, 1_000_041, Some(1.0))
    else {
        return;
    };
    let starts = &r.robust.starts;
    let annealed_again = |s: &&StartEnd| s.start == Start::AnnealedWithoutKeystone;
    assert_eq!(
        starts.iter().filter(annealed_again).count(),
        0,
        "{starts:?}"
    );
    assert!(!r.robust.doubtful.is_empty());
    assert_eq!(r.status(), MapStatus::Questioned);
    let aliases_in = (r.loops.iter().zip(&wrong)).filter(|(l, w)| **w && l.accepted);
    assert_eq!(aliases_in.count(), 5);
}

/// The map above replayed by a front end, an update every 10 poses: the
/// young map's updates keep true loops the batch jobs of the same graph
/// leave out (docs/method.md §7b), at 10 of the 81 updates (14 before the
/// end without the keystone, 21 before the start with the loops left out
/// put back, 32 before the start without the agreement layer); the last
/// update is the batch job's, with every true loop and no alias. Fails if
/// more updates differ. About a minute in a debug build: run with
/// `--ignored`.
#[test]
#[ignore]
fn a_young_map_with_a_group_beside_its_loops_is_the_batch_job_at_the_end() {
    let Some(differ) = mit_replayed_every_10(1_000_026) else {
        return;
    };
    eprintln!("updates that differ from the batch job: {differ:?}");
    assert!(differ.len() <= 10, "{differ:?}");
}

/// MIT with aliases in groups of 5 at revisited places, corrupted with
/// `seed`, replayed every 10 poses: the numbers of poses at the updates
/// whose decisions differ from the batch job's, checked to end at the
/// batch job's with every true loop and no alias. `None` where the
/// dataset is absent.
fn mit_replayed_every_10(seed: u64) -> Option<Vec<usize>> {
    let (mit, edge_wrong) = corrupted_planar("MIT.g2o", &revisited_in_fives(), seed)?;
    let (steps, wrong) = replayed(&mit, &edge_wrong, 10);
    let differ: Vec<usize> = (steps.iter())
        .filter(|(_, u, b)| decided(u) != decided(b))
        .map(|(poses, _, _)| *poses)
        .collect();
    let (_, last, batch) = steps.last().expect("updates");
    assert_eq!(decided(last), decided(batch));
    assert_eq!(true_loops_kept(last.report(), &wrong), (20, 20));
    Some(differ)
}

/// The keystone's map (MIT seed 30 above) replayed every 10 poses: every
/// update is the batch job's, the last with every true loop and no alias
/// (docs/method.md §7b). Before the end without the keystone, 23 of the 81
/// differed, the last among them: the batch job held three aliases, 25.9 %
/// off. Run with `--ignored`.
#[test]
#[ignore]
fn the_keystone_s_map_replayed_is_the_batch_job_at_every_update() {
    let Some(differ) = mit_replayed_every_10(1_000_031) else {
        return;
    };
    assert!(differ.is_empty(), "{differ:?}");
}

/// Checks that the end of `start` is the one kept, at an objective `J`
/// below every other ranked end's; returns how many others were ranked.
fn chosen_at_the_lowest_objective(r: &Report, start: Start) -> usize {
    let starts = &r.robust.starts;
    let end = start_of(r, start);
    assert!(end.chosen, "{starts:?}");
    let kept = end.objective.expect("ranked");
    let others: Vec<f64> = (starts.iter())
        .filter(|s| !s.chosen)
        .filter_map(|s| s.objective)
        .collect();
    assert!(others.iter().all(|&j| j > kept), "{starts:?}");
    others.len()
}

/// The first `poses` poses of MIT with aliases in groups of 5 at revisited
/// places (fresh seed 25) decided with the defaults: the report, and
/// whether each candidate is wrong. `None` where the dataset is absent.
fn young_revisited_mit(poses: u64) -> Option<(Report, Vec<bool>)> {
    let (mit, edge_wrong) = corrupted_planar("MIT.g2o", &revisited_in_fives(), 1_000_026)?;
    let (young, kept) = prefix(&mit, poses);
    let edge_wrong: Vec<bool> = kept.iter().map(|&k| edge_wrong[k]).collect();
    let wrong = candidate_labels(&young, &edge_wrong);
    Some((
        young.optimize(&Options::default()).unwrap().into_report(),
        wrong,
    ))
}

/// A question the kernel start leaves unanswered stays open: the first 580
/// poses of the map above (MIT, aliases in groups of 5 at revisited
/// places, fresh seed 25). The annealed end passes its χ² test and
/// settles with 10 of the 16 true loops, its loop model calling wrong a
/// population that the information as stated calls consistent; the Cauchy
/// kernel's weights do not stand within the annealed start's share of
/// iterations, so no end answers what the second start was sought for.
/// Before, the annealed end stood (exit 0, six true loops out); now the
/// truncated start runs, and the start without the agreement layer from
/// its end keeps all 16 and no alias, at the lowest `J`.
#[test]
fn a_question_the_kernel_start_leaves_unanswered_stays_open() {
    let Some((r, wrong)) = young_revisited_mit(580) else {
        return;
    };
    let starts = &r.robust.starts;
    assert_eq!(start_of(&r, Start::Annealed).accepted, 10, "{starts:?}");
    assert!(!start_of(&r, Start::Kernel).settled, "{starts:?}");
    start_of(&r, Start::Truncated);
    assert!(start_of(&r, Start::WithoutAgreement).chosen, "{starts:?}");
    assert_eq!(true_loops_kept(&r, &wrong), (16, 16));
    assert_eq!(r.status(), MapStatus::Ok);
}

/// Loops the model calls wrong and the stated information calls
/// consistent are tried in: the first 620 poses of the map above. The
/// annealed end passes and settles with 10 of the 16 true loops, its model
/// calling a population wrong within EM's kernel; the Cauchy start reaches
/// no end and the truncated one passes at 9, so nothing is left open for
/// the start without the agreement layer. From the best end's map solved
/// with the rejected candidates within the kernel (six true loops and
/// eight aliases), EM's decisions keep all 16 and no alias, at the lowest
/// `J`. Before, the annealed end stood (exit 0, six true loops out).
#[test]
fn loops_called_wrong_within_the_kernel_are_tried_in() {
    let Some((r, wrong)) = young_revisited_mit(620) else {
        return;
    };
    let starts = &r.robust.starts;
    assert_eq!(start_of(&r, Start::Annealed).accepted, 10, "{starts:?}");
    assert!(!start_of(&r, Start::Kernel).settled, "{starts:?}");
    chosen_at_the_lowest_objective(&r, Start::Readmitted);
    assert_eq!(true_loops_kept(&r, &wrong), (16, 16));
    assert_eq!(r.status(), MapStatus::Ok);
}

/// A true loop beyond the file's information where the map's other true
/// loops lie as far out is not named, though it carries the map:
/// ais2klinik (two sessions) with 300 aliases in groups of 10 placed
/// anywhere (seed 1 of the places sweep), information calibrated. A loop
/// between the sessions (7716–13822) has `ν²` 26.0 on 3 dof, beyond the
/// stated bound for its 1,614 accepted loops (`K·p` 0.015), and removing
/// it moves the map by 1.6 %; but the true loops reach 57, and their
/// fitted density expects 30 of them beyond 26. Every decision is right.
#[test]
fn a_true_loop_beyond_the_stated_information_among_as_many_is_not_named() {
    let aliased = anywhere_in_groups(300, 0.3);
    let Some((r, wrong)) = corrupted_and_decided("ais2klinik.g2o", &aliased, 1_000_002, Some(1.0))
    else {
        return;
    };
    let (accepted, _) = true_loops_kept(&r, &wrong);
    assert_eq!(accepted, wrong.iter().filter(|w| !**w).count());
    assert!(r.robust.outlying.is_empty(), "{:?}", r.robust.outlying);
    assert_eq!(r.status(), MapStatus::Ok);
}

/// True clusters whose errors share an offset — a real map's scan
/// matcher errs alike in one place — are not doubtful where the map does
/// not lean on them: parking-garage with 300 aliases in groups of 10
/// placed anywhere (seed 1 of the places sweep), its information
/// calibrated. Clusters of up to 32 true loops there share offsets at F
/// tests of `p` below 10⁻⁷, but none moves the map by more than 0.04 %.
#[test]
fn true_clusters_that_share_an_offset_but_hold_little_are_not_doubtful() {
    let aliased = anywhere_in_groups(300, 0.3);
    let Some((r, _)) = corrupted_and_decided("parking-garage.g2o", &aliased, 1_000_002, Some(1.0))
    else {
        return;
    };
    assert!(r.chi2_test.as_ref().is_some_and(|t| t.passed));
    assert!(r.robust.doubtful.is_empty(), "{:?}", r.robust.doubtful);
    assert!(r.robust.outlying.is_empty(), "{:?}", r.robust.outlying);
}

/// The map a job returns is converged, not cut at the limit of 100
/// iterations each solve of the robust methods has: CSAIL with 300
/// aliases in groups of 10 placed anywhere, half the groups with
/// true-like counts, its information as published (as seed 10 of
/// `bench_robust.py --alias-place anywhere` makes it). Its decisions keep
/// every true loop and no alias; the last solve still lowered its
/// objective by 2.5 % per iteration at the 100th, and the job ended there,
/// unconverged (exit status 4, naming a `--max-iters` it was not given).
#[test]
fn the_map_returned_is_converged() {
    let aliased = anywhere_in_groups(300, 0.5);
    let Some((r, wrong)) = corrupted_and_decided("CSAIL.g2o", &aliased, 1_000_011, None) else {
        return;
    };
    let (accepted, _) = true_loops_kept(&r, &wrong);
    assert_eq!(accepted, wrong.iter().filter(|w| !**w).count());
    assert!(r.optimizer.stop_reason.converged(), "{:?}", r.optimizer);
}
