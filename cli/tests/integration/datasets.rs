//! The public benchmark datasets (../shared/datasets or $PGO_DATASETS):
//! the optimum against g2o and GTSAM, and every quirk in MANIFEST.md.
//! Each test prints a reason and passes when the datasets are absent.

use crate::common::{candidate_wrong, datasets, pgo, stderr, write_graph};
use pgo::graph::AnyGraph;
use pgo::io::g2o::{self, ReadError, ReadOptions};
use pgo::pipeline::{self, OptimizeConfig};
use pgo::solve::init::Initialization;

fn read(name: &str) -> Option<Result<g2o::G2oFile, ReadError>> {
    datasets().map(|d| g2o::read(&d.join(name), ReadOptions::default()))
}

fn optimise(name: &str, init: Initialization) -> Option<pgo::report::Report> {
    let dir = datasets()?;
    let mut config = OptimizeConfig::new(dir.join(name));
    config.initialization = init;
    Some(
        pipeline::run(&config, &mut |_: &pgo::solve::IterationRecord| {})
            .unwrap_or_else(|e| panic!("{name}: {e}")),
    )
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
        let Some(r) = optimise(name, Initialization::default()) else {
            return;
        };
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
        let Some(r) = optimise(name, Initialization::File) else {
            return;
        };
        assert!(
            r.optimizer.final_chi2 <= best * (1.0 + 1e-5),
            "{name}: {}",
            r.optimizer.final_chi2
        );
    }
}

#[test]
fn q1_square_root_information_files_load_and_give_tiny_chi2() {
    // city10000 carries sqrt-information: its optimum χ² per edge is far
    // below the edge dimension (3).
    let Some(r) = optimise("city10000.g2o", Initialization::Chordal) else {
        return;
    };
    let per_edge = r.optimizer.final_chi2 / r.edges as f64;
    assert!(per_edge < 0.1, "χ² per edge {per_edge}");
}

#[test]
fn q2_indefinite_information_is_reported_and_repaired_on_request() {
    let Some(dir) = datasets() else { return };
    let err = g2o::read(&dir.join("cubicle.g2o"), ReadOptions::default()).unwrap_err();
    assert!(err.to_string().contains("not positive definite"), "{err}");
    assert!(err.line().is_some());
    let f = g2o::read(
        &dir.join("cubicle.g2o"),
        ReadOptions {
            fix_information: true,
        },
    )
    .unwrap();
    assert_eq!(f.summary.information_fixed, 5021);
    // parking-garage: PD but condition numbers up to 2.7e9; loads as is.
    let f = g2o::read(&dir.join("parking-garage.g2o"), ReadOptions::default()).unwrap();
    assert_eq!(f.summary.information_fixed, 0);
    let mut config = OptimizeConfig::new(dir.join("cubicle.g2o"));
    config.fix_information = true;
    let r = pipeline::run(&config, &mut |_: &pgo::solve::IterationRecord| {}).unwrap();
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
        let Some(f) = read(name) else { return };
        let f = f.unwrap();
        assert_eq!(f.graph.num_vertices(), poses, "{name}");
        assert_eq!(f.missing.len(), poses, "{name}");
    }
    // The spanning-tree guess of kitti_00 is the odometry chain: its χ²
    // matches the peers' initial χ² (BASELINE.md, 7.53296e+07).
    let Some(r) = optimise("kitti_00.g2o", Initialization::File) else {
        return;
    };
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
        let err = g2o::read(&dir.join(name), ReadOptions::default()).unwrap_err();
        let text = err.to_string();
        assert!(
            text.contains("no VERTEX_SE2") && text.contains("skipped: EDGE"),
            "{text}"
        );
    }
}

#[test]
fn q5_unusual_tags_fix_mixture_edges_and_skipped_tags() {
    let Some(f) = read("manhattanOlson3500-maxmix-n100-grp10.g2o") else {
        return;
    };
    let f = f.unwrap();
    // 3499 odometry + 3099 mixture edges, FIX 0.
    assert_eq!(f.graph.num_edges(), 6598);
    let AnyGraph::Planar(g) = &f.graph else {
        panic!("2D")
    };
    assert!(g.is_fixed(g.index_of(0).unwrap()));
    // The mixture's first component is the measurement, with its information.
    assert!(g.edges.iter().all(|e| e.information[(0, 0)] > 1.0));
    let f = read("example_with_vertices.g2o").unwrap().unwrap();
    assert_eq!(f.graph.num_vertices(), 8);
    assert_eq!(f.summary.skipped_tags.get("VERTEX_TRACKXYZ"), Some(&8));
    let Some(Ok(f)) = read("sphere2500-maxmix-n100-grp10.g2o") else {
        panic!("sphere maxmix")
    };
    assert_eq!(f.graph.num_edges(), 5949);
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
        let Some(f) = read(name) else { return };
        assert_eq!(f.unwrap().graph.num_edges(), edges, "{name}");
    }
}

#[test]
fn q7_interleaved_vertices_and_edges() {
    let Some(f) = read("intel-vertigo.g2o") else {
        return;
    };
    let f = f.unwrap();
    assert_eq!((f.graph.num_vertices(), f.graph.num_edges()), (943, 1837));
    assert!(f.missing.is_empty());
    let AnyGraph::Planar(g) = &f.graph else {
        panic!("2D")
    };
    // The first edge of the file is 441 → 442.
    assert_eq!((g.id(g.edges[0].from), g.id(g.edges[0].to)), (441, 442));
}

#[test]
fn q8_reversed_and_repeated_edges() {
    let Some(f) = read("MIT.g2o") else { return };
    let AnyGraph::Planar(g) = &f.unwrap().graph else {
        panic!("2D")
    };
    let reversed = g.edges.iter().filter(|e| g.id(e.from) > g.id(e.to)).count();
    assert_eq!(reversed, 20);
    let Some(r) = optimise("manhattanOlson3500-olson.g2o", Initialization::Chordal) else {
        return;
    };
    assert!(r.optimizer.converged);
}

#[test]
fn q9_graphs_missing_some_odometry_links_stay_connected() {
    let Some(f) = read("ais2klinik.g2o") else {
        return;
    };
    let AnyGraph::Planar(g) = &f.unwrap().graph else {
        panic!("2D")
    };
    assert!(g.unconstrained_vertices(None).is_empty());
}

#[test]
fn q10_unwrapped_angles_give_wrapped_errors() {
    let Some(f) = read("ring-groundtruth.g2o") else {
        return;
    };
    // Vertex angles in [0, 2π) and exact measurements: χ² at the ground truth is ~0.
    assert!(f.unwrap().graph.chi2() < 1e-6);
    let Some(f) = read("manhattanOlson3500-olson.g2o") else {
        return;
    };
    let AnyGraph::Planar(g) = &f.unwrap().graph else {
        panic!("2D")
    };
    assert!(g.edges.iter().any(|e| e.measurement.theta.abs() > 4.0));
    assert!(
        g.edges
            .iter()
            .all(|e| g.edge_error(e)[2].abs() <= std::f64::consts::PI)
    );
}

#[test]
fn q11_same_name_different_data() {
    let (Some(a), Some(b)) = (read("intel.g2o"), read("intel-vertigo.g2o")) else {
        return;
    };
    assert_ne!(
        a.unwrap().graph.num_vertices(),
        b.unwrap().graph.num_vertices()
    );
}

#[test]
fn q12_ring_loop_closures_are_exact_at_the_ground_truth() {
    let Some(f) = read("ring-groundtruth.g2o") else {
        return;
    };
    let AnyGraph::Planar(g) = &f.unwrap().graph else {
        panic!("2D")
    };
    for e in g
        .edges
        .iter()
        .filter(|e| g.id(e.from).abs_diff(g.id(e.to)) > 1)
    {
        assert!(g.edge_error(e).norm() < 1e-4);
    }
}

#[test]
fn no_file_in_the_datasets_makes_pgo_panic() {
    let Some(dir) = datasets() else { return };
    let mut names: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    names.sort();
    for path in names {
        let p = path.to_str().unwrap();
        let out = pgo(&["optimize", p, "--max-iters", "2", "--init", "file", "-q"]);
        let code = out.status.code();
        assert!(
            matches!(code, Some(0) | Some(2) | Some(3)),
            "{p}: exit {code:?}: {}",
            stderr(&out)
        );
        if code == Some(2) {
            assert!(stderr(&out).starts_with("error: "), "{p}: {}", stderr(&out));
        }
    }
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
    let Some((r, wrong)) = corrupted_and_decided(name, (wrong, seed, RANDOM), Some(10.0)) else {
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
        let Some((r, wrong)) = corrupted_and_decided(name, (wrong, seed, RANDOM), calibrated)
        else {
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
    let aliased: &[&str] = &[
        "--wrong-mode",
        "aliased",
        "--group-size",
        "1",
        "--true-like-counts",
        "0.3",
    ];
    let Some((r, wrong)) = corrupted_and_decided("manhattan.g2o", (300, 1_000_003, aliased), None)
    else {
        return;
    };
    let (accepted_true, _) = true_loops_kept(&r, &wrong);
    assert_eq!(accepted_true, wrong.iter().filter(|w| !**w).count());
}

/// How many true loops `r` accepted, of those that passed the gate; no
/// wrong one accepted (`wrong`: the candidates' labels).
fn true_loops_kept(r: &pgo::report::Report, wrong: &[bool]) -> (usize, usize) {
    assert_eq!(r.loops.len(), wrong.len());
    let count = |keep: &dyn Fn(&pgo::report::LoopReport, bool) -> bool| {
        r.loops
            .iter()
            .zip(wrong)
            .filter(|(l, w)| keep(l, **w))
            .count()
    };
    assert_eq!(count(&|l, w| l.accepted && w), 0, "wrong loops accepted");
    (count(&|l, w| l.accepted && !w), count(&|l, w| l.kept && !w))
}

/// Random wrong candidates (`pgo corrupt`'s flags).
const RANDOM: &[&str] = &["--wrong-mode", "random"];

/// Dataset `name` with `wrong` wrong candidates made with `seed` and the
/// `pgo corrupt` flags `mode`, its information as published or, with
/// `calibrated`, scaled to that times the clean optimum's `χ²/dof = 1`,
/// optimised with the default options; the report and the candidates'
/// labels.
fn corrupted_and_decided(
    name: &str,
    (wrong, seed, mode): (usize, u64, &[&str]),
    calibrated: Option<f64>,
) -> Option<(pgo::report::Report, Vec<bool>)> {
    let dir = datasets()?;
    let work = crate::common::temp_dir(&format!("corrupted-{name}-{wrong}-{seed}"));
    let (corrupted, labels) = (work.join("m.g2o"), work.join("m.labels.csv"));
    let src = dir.join(name);
    let (wrong, seed) = (wrong.to_string(), seed.to_string());
    let mut args = vec![
        "corrupt",
        src.to_str().unwrap(),
        "-o",
        corrupted.to_str().unwrap(),
        "--labels",
        labels.to_str().unwrap(),
        "--wrong",
        &wrong,
        "--seed",
        &seed,
    ];
    args.extend(mode);
    let out = pgo(&args);
    assert!(out.status.success(), "{}", stderr(&out));
    let input = match calibrated {
        None => corrupted,
        Some(times) => {
            let clean = pipeline::run(
                &OptimizeConfig {
                    gate: pgo::gate::GateMode::Off,
                    robust: pgo::robust::RobustMethod::None,
                    ..OptimizeConfig::new(&src)
                },
                &mut |_: &_| {},
            )
            .expect("clean");
            let t = clean.chi2_test.expect("test");
            let factor = times * t.dof_residual as f64 / t.d2;
            let AnyGraph::Planar(mut g) = g2o::read(&corrupted, ReadOptions::default())
                .expect("read")
                .graph
            else {
                unreachable!("{name} is 2D")
            };
            for e in &mut g.edges {
                e.information *= factor;
            }
            let scaled = work.join("m-scaled.g2o");
            write_graph(&g, &scaled);
            scaled
        }
    };
    let wrong = candidate_wrong(&std::fs::read_to_string(&labels).expect("labels"));
    let r = pipeline::run(&OptimizeConfig::new(&input), &mut |_: &_| {}).expect("optimise");
    Some((r, wrong))
}
