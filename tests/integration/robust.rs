//! The robust back end through the pipeline: simulated graphs with planted
//! wrong loop candidates whose labels the tests know.

use crate::common::{sample, temp_dir};
use pgo::gate::{DegeneratePolicy, GateMode};
use pgo::geometry::Se2;
use pgo::graph::{AnyPoseGraph, PoseGraph};
use pgo::io::g2o;
use pgo::pipeline::{self, OptimizeConfig};
use pgo::report::Report;
use pgo::robust::{RobustMethod, ScaleSearchOutcome};
use pgo::simulate::{InlierModel, OutlierPolicy, SimulationOptions, simulate_planar};
use std::path::{Path, PathBuf};

/// A simulated 2D graph written to `dir`: the noisy file, the clean file
/// (the same without the wrong candidates), and for every loop candidate
/// in file order whether it is wrong.
struct Case {
    noisy: PathBuf,
    clean: PathBuf,
    wrong: Vec<bool>,
}

fn case(dir: &Path, name: &str, options: SimulationOptions) -> Case {
    let sim = simulate_planar(&options).expect("simulate");
    let noisy = dir.join(format!("{name}.g2o"));
    write(&sim.noisy, &noisy);
    let mut clean_graph = sim.noisy.clone();
    clean_graph.edges = sim
        .noisy
        .edges
        .iter()
        .zip(&sim.wrong)
        .filter(|(_, w)| !**w)
        .map(|(e, _)| e.clone())
        .collect();
    let clean = dir.join(format!("{name}_clean.g2o"));
    write(&clean_graph, &clean);
    let wrong = candidate_labels(&sim.noisy, &sim.wrong);
    Case {
        noisy,
        clean,
        wrong,
    }
}

/// For every loop candidate in file order, whether it is wrong (`wrong` is
/// per edge).
fn candidate_labels(graph: &PoseGraph<Se2, 3>, wrong: &[bool]) -> Vec<bool> {
    graph
        .edges
        .iter()
        .zip(wrong)
        .filter(|(e, _)| e.is_candidate())
        .map(|(_, w)| *w)
        .collect()
}

fn write(graph: &PoseGraph<Se2, 3>, path: &Path) {
    let mut f = std::io::BufWriter::new(std::fs::File::create(path).expect("create"));
    g2o::write_graph(graph, &mut f).expect("write");
}

fn options(policy: OutlierPolicy, outliers: usize, seed: u64) -> SimulationOptions {
    SimulationOptions {
        poses: 400,
        loops: 100,
        outliers,
        outlier_policy: policy,
        inliers: Some(InlierModel::default()),
        seed,
        ..Default::default()
    }
}

fn run(input: &Path, gate: GateMode, robust: RobustMethod, output: Option<&Path>) -> Report {
    run_config(OptimizeConfig {
        gate,
        robust,
        output: output.map(Path::to_owned),
        ..OptimizeConfig::new(input)
    })
}

/// The defaults (gate auto, EM) without the rescue of dropped candidates.
fn run_without_rescue(input: &Path) -> Report {
    run_config(OptimizeConfig {
        rescue: false,
        ..OptimizeConfig::new(input)
    })
}

fn run_config(config: OptimizeConfig) -> Report {
    pipeline::run(&config, &mut |_| {}).expect("optimise")
}

/// Accepted (weight ≥ ½) true loops, accepted wrong ones, true loops that
/// passed the gate.
fn counts(report: &Report, wrong: &[bool]) -> (usize, usize, usize) {
    assert_eq!(report.loops.len(), wrong.len());
    let mut tp = 0;
    let mut fp = 0;
    let mut gated_true = 0;
    for (l, &w) in report.loops.iter().zip(wrong) {
        assert!((0.0..=1.0).contains(&l.weight), "weight {}", l.weight);
        if !l.kept {
            // Dropped by the gate: left out (0), or rescued by EM (≥ ½).
            assert!(
                l.weight == 0.0 || l.weight >= 0.5,
                "a candidate the gate dropped has weight {}",
                l.weight
            );
        }
        let accepted = l.weight >= 0.5;
        tp += usize::from(accepted && !w);
        fp += usize::from(accepted && w);
        gated_true += usize::from(l.kept && !w);
    }
    (tp, fp, gated_true)
}

/// RMS distance between the positions of two written graphs with the same
/// gauge, and the diagonal of the bounding box of the second.
fn position_rmse(a: &Path, b: &Path) -> (f64, f64) {
    let positions = |p: &Path| match g2o::read(p, Default::default()).expect("read").graph {
        AnyPoseGraph::Planar(g) => g.poses.iter().map(|x| x.translation()).collect::<Vec<_>>(),
        AnyPoseGraph::Spatial(_) => unreachable!("2D"),
    };
    let (a, b) = (positions(a), positions(b));
    let mse = a
        .iter()
        .zip(&b)
        .map(|(p, q)| (p - q).norm_squared())
        .sum::<f64>()
        / a.len() as f64;
    let lo = b.iter().fold(b[0], |m, p| m.inf(p));
    let hi = b.iter().fold(b[0], |m, p| m.sup(p));
    (mse.sqrt(), (hi - lo).norm())
}

#[test]
fn every_robust_method_down_weights_the_planted_wrong_loops() {
    let dir = temp_dir("robust-methods");
    let c = case(&dir, "random", options(OutlierPolicy::Random, 30, 11));
    let n_true = c.wrong.iter().filter(|w| !**w).count();
    // Without the gate every wrong candidate reaches the back end. Each
    // method gives every wrong loop a weight below ½; the share of true
    // loops it keeps at ≥ ½ depends on its kernel (DCS with Φ = 1 halves
    // an inlier's weight already at r² ≈ 1.8, below the median of χ²₃).
    for (method, min_recall) in [
        (RobustMethod::Em, 0.97),
        (RobustMethod::Gnc, 0.95),
        (RobustMethod::Cauchy, 0.9),
        (RobustMethod::Huber, 0.9),
        (RobustMethod::Dcs, 0.3),
    ] {
        let r = run(&c.noisy, GateMode::Off, method, None);
        assert_eq!(r.robust.method, method);
        let (tp, fp, _) = counts(&r, &c.wrong);
        for (l, &w) in r.loops.iter().zip(&c.wrong) {
            if w {
                assert!(
                    l.weight < 0.5,
                    "{method:?}: wrong loop {}–{} has weight {}",
                    l.from,
                    l.to,
                    l.weight
                );
            }
        }
        assert_eq!(fp, 0);
        assert!(
            tp as f64 >= min_recall * n_true as f64,
            "{method:?}: {tp} of {n_true} true loops accepted"
        );
        assert_eq!(r.robust.active_loops, tp);
        assert_eq!(r.robust.rejected_loops, c.wrong.len() - tp);
    }
}

#[test]
fn gate_and_em_recover_the_clean_map_for_every_outlier_policy() {
    let dir = temp_dir("robust-policies");
    for (k, policy) in [
        OutlierPolicy::Random,
        OutlierPolicy::Local,
        OutlierPolicy::Grouped,
    ]
    .into_iter()
    .enumerate()
    {
        let name = format!("{policy:?}");
        let c = case(&dir, &name, options(policy, 60, 20 + k as u64));
        let out = dir.join(format!("{name}_out.g2o"));
        let r = run(&c.noisy, GateMode::Auto, RobustMethod::Em, Some(&out));
        assert!(!r.gate.degenerate, "{name}: {:?}", r.gate.reason);
        let (tp, fp, gated_true) = counts(&r, &c.wrong);
        assert_eq!(fp, 0, "{name}: wrong loops accepted");
        assert!(
            tp as f64 >= 0.97 * gated_true as f64,
            "{name}: {tp} of the {gated_true} true loops that passed the gate accepted"
        );
        assert!(
            r.chi2_test.as_ref().unwrap().passed,
            "{name}: {:?}",
            r.chi2_test
        );
        // The map is the clean graph's optimum to within 0.5 % of the
        // trajectory's size (RMS, same gauge).
        let reference = dir.join(format!("{name}_ref.g2o"));
        run(
            &c.clean,
            GateMode::Off,
            RobustMethod::None,
            Some(&reference),
        );
        let (rmse, size) = position_rmse(&out, &reference);
        assert!(
            rmse < 0.005 * size,
            "{name}: the robust map is {rmse} m (RMS) from the clean one, size {size} m"
        );
    }
}

#[test]
fn the_chi2_test_fails_when_a_wrong_loop_is_kept() {
    let dir = temp_dir("robust-chi2");
    let c = case(&dir, "random", options(OutlierPolicy::Random, 40, 31));
    // Every candidate in at full weight: the wrong loops are kept.
    let forced = run(&c.noisy, GateMode::Fixed(0), RobustMethod::None, None);
    assert_eq!(counts(&forced, &c.wrong).1, 40);
    let test = forced
        .chi2_test
        .unwrap_or_else(|| panic!("{:?}", forced.warnings));
    assert!(!test.passed, "D² = {} ≤ {}", test.d2, test.critical);
    // The robust default rejects them and passes.
    let robust = run(&c.noisy, GateMode::Auto, RobustMethod::Em, None);
    assert_eq!(counts(&robust, &c.wrong).1, 0);
    let test = robust
        .chi2_test
        .unwrap_or_else(|| panic!("{:?}", robust.warnings));
    assert!(test.passed, "D² = {} > {}", test.d2, test.critical);
    // The test counts exactly the accepted edges at their plain cost.
    let edges = robust.edges as u64 - robust.loops.iter().filter(|l| l.weight < 0.5).count() as u64;
    assert_eq!(test.dof_constraints, edges);
}

#[test]
fn degenerate_counts_are_flagged_before_optimisation_or_fail_the_chi2_test() {
    // 8 true loops among 200 wrong candidates whose counts look alike
    // (g2o_samples/make.sh).
    let input = PathBuf::from(sample("degenerate.g2o"));
    let labels = std::fs::read_to_string(sample("degenerate_labels.csv")).expect("labels");
    let wrong: Vec<bool> = labels
        .lines()
        .skip(1)
        .filter_map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            let (a, b): (u64, u64) = (f[1].parse().unwrap(), f[2].parse().unwrap());
            (a.abs_diff(b) != 1).then(|| f[3] == "1")
        })
        .collect();
    // Flagged before optimisation, whatever the policy.
    let r = run(&input, GateMode::Auto, RobustMethod::Em, None);
    assert!(r.gate.degenerate);
    assert!(
        r.warnings.iter().any(|w| w.contains("degenerate")),
        "{:?}",
        r.warnings
    );
    // drop-all: every candidate dropped.
    let config = OptimizeConfig {
        degenerate: DegeneratePolicy::DropAll,
        ..OptimizeConfig::new(&input)
    };
    let r = pipeline::run(&config, &mut |_| {}).expect("optimise");
    assert!(r.gate.degenerate);
    assert!(r.loops.iter().all(|l| l.weight == 0.0));
    // keep-all (the default): whatever EM keeps, a kept wrong loop fails
    // the χ² test; without a robust method the test fails. EM keeps the 8
    // true loops and no wrong one.
    for robust in [RobustMethod::Em, RobustMethod::None] {
        let config = OptimizeConfig {
            robust,
            ..OptimizeConfig::new(&input)
        };
        let r = pipeline::run(&config, &mut |_| {}).expect("optimise");
        let (_, fp, _) = counts(&r, &wrong);
        let passed = r.chi2_test.as_ref().unwrap().passed;
        assert!(
            fp == 0 || !passed,
            "{robust:?}: {fp} wrong loops kept and the χ² test passed"
        );
        if robust == RobustMethod::None {
            assert!(fp > 0 && !passed);
        } else {
            let (tp, _, _) = counts(&r, &wrong);
            assert_eq!((tp, fp), (8, 0));
        }
    }
}

#[test]
fn em_rescues_the_true_loops_the_gate_dropped_and_no_wrong_one() {
    let dir = temp_dir("robust-rescue");
    // The default count models overlap: a few true loops fall below T_GV.
    let c = case(&dir, "overlap", options(OutlierPolicy::Random, 60, 41));
    let without = run_without_rescue(&c.noisy);
    let with = run(&c.noisy, GateMode::Auto, RobustMethod::Em, None);
    let (tp_without, fp_without, gated_true) = counts(&without, &c.wrong);
    let (tp_with, fp_with, _) = counts(&with, &c.wrong);
    let n_true = c.wrong.iter().filter(|w| !**w).count();
    assert!(gated_true < n_true, "the gate drops some true loops");
    assert_eq!((fp_without, fp_with), (0, 0));
    // Without the rescue a dropped candidate stays at weight 0.
    assert!(without.loops.iter().all(|l| l.kept || l.weight == 0.0));
    assert_eq!(without.robust.rescued_loops, 0);
    // With it, the dropped true loops consistent with the map come back.
    let rescued = with
        .loops
        .iter()
        .filter(|l| !l.kept && l.weight >= 0.5)
        .count();
    assert_eq!(with.robust.rescued_loops, rescued);
    assert!(rescued > 0);
    assert_eq!(tp_with, tp_without + rescued);
    assert!(
        tp_with as f64 >= 0.97 * n_true as f64,
        "{tp_with} of {n_true} true loops accepted"
    );
    // The wrong candidates the gate dropped stay out although some of them
    // would fit a map bent by them: they never shape it.
    for (l, &w) in with.loops.iter().zip(&c.wrong) {
        if w {
            assert_eq!(l.weight, 0.0, "wrong {}–{}", l.from, l.to);
        }
    }
}

#[test]
fn em_accepts_by_innovation_true_loops_the_plain_residual_leaves_out() {
    let dir = temp_dir("robust-innovation");
    // A dropped true loop between two poses the kept loops tie loosely:
    // far out by its plain residual, consistent once the map's uncertainty
    // is added (its innovation), and its count is not that of a wrong loop.
    let c = case(&dir, "loose", options(OutlierPolicy::Random, 60, 6));
    let plain = run_config(OptimizeConfig {
        innovation: false,
        ..OptimizeConfig::new(&c.noisy)
    });
    let with = run(&c.noisy, GateMode::Auto, RobustMethod::Em, None);
    let (tp_plain, fp_plain, _) = counts(&plain, &c.wrong);
    let (tp_with, fp_with, _) = counts(&with, &c.wrong);
    assert_eq!(plain.robust.innovation_accepted_loops, 0);
    let by_innovation = with.robust.innovation_accepted_loops;
    assert!(by_innovation > 0);
    assert_eq!((fp_plain, fp_with), (0, 0));
    assert_eq!(tp_with, tp_plain + by_innovation);
    // Dropped by the gate or rejected by EM: those dropped are rescued too.
    assert!(with.robust.rescued_loops > plain.robust.rescued_loops);
    assert!(with.robust.rescued_loops <= plain.robust.rescued_loops + by_innovation);
    assert_eq!(tp_with, c.wrong.iter().filter(|w| !**w).count());

    // The report says how each was judged: a prior of ½ for the kept ones,
    // the count's posterior (< ½) for the dropped ones; ν²/s² and log odds
    // for those the map was solved without, ≥ 0 for the ones taken back
    // (judged once: the map solved with them is the final one), < 0 for
    // those left out; nothing for the others.
    assert!(with.loops.iter().all(|l| {
        if l.kept {
            l.prior == 0.5
        } else {
            l.prior < 0.5
        }
    }));
    let judged: Vec<_> = with
        .loops
        .iter()
        .filter_map(|l| Some((l, l.judgement?)))
        .collect();
    let taken_back = judged.iter().filter(|(l, _)| l.weight >= 0.5).count();
    assert_eq!(taken_back, by_innovation);
    for (l, j) in &judged {
        assert!(j.innovation > 0.0 && j.innovation.is_finite());
        assert_eq!(j.ln_odds >= 0.0, l.weight >= 0.5, "{}–{}", l.from, l.to);
    }
    assert!(plain.loops.iter().all(|l| l.judgement.is_none()));
}

#[test]
fn loop_innovations_set_the_wrong_loops_apart() {
    let dir = temp_dir("robust-loop-innovations");
    // Local wrong loops (within 20 poses): some pass the gate and some
    // fit a map that odometry alone ties; the innovation against the map
    // without each one says which ones the others contradict.
    let c = case(&dir, "local", options(OutlierPolicy::Local, 60, 11));
    let plain = run(&c.noisy, GateMode::Auto, RobustMethod::Em, None);
    assert!(plain.loops.iter().all(|l| l.innovation.is_none()));
    let r = run_config(OptimizeConfig {
        loop_innovations: true,
        ..OptimizeConfig::new(&c.noisy)
    });
    // The report is the same but for the innovations.
    let weights = |r: &Report| r.loops.iter().map(|l| l.weight).collect::<Vec<_>>();
    assert_eq!(weights(&r), weights(&plain));
    // Every candidate EM weighed has one: the loops of a simulated map all
    // close cycles, so none is a bridge.
    assert!(
        r.loops
            .iter()
            .all(|l| l.innovation.is_some_and(|v| v >= 0.0))
    );
    let (true_max, wrong_min) =
        r.loops
            .iter()
            .zip(&c.wrong)
            .fold((0.0f64, f64::INFINITY), |(t, w), (l, &wrong)| {
                let v = l.innovation.unwrap();
                if wrong { (t, w.min(v)) } else { (t.max(v), w) }
            });
    // A true loop's ν²/s² is χ²₃-like (below ~40 for 1 in 10⁶); every wrong
    // one is beyond it.
    assert!(true_max < 40.0, "true loops up to {true_max}");
    assert!(wrong_min > true_max, "wrong loops from {wrong_min}");
}

#[test]
fn the_soft_gate_recovers_true_loops_below_the_threshold() {
    let dir = temp_dir("robust-soft");
    // The default count models overlap: a few true loops fall below T_GV.
    let c = case(&dir, "overlap", options(OutlierPolicy::Random, 60, 41));
    let hard = run_without_rescue(&c.noisy);
    let soft = run(&c.noisy, GateMode::Soft, RobustMethod::Em, None);
    let (hard_tp, hard_fp, gated_true) = counts(&hard, &c.wrong);
    let (soft_tp, soft_fp, _) = counts(&soft, &c.wrong);
    let n_true = c.wrong.iter().filter(|w| !**w).count();
    assert!(gated_true < n_true, "the gate drops some true loops");
    assert_eq!((hard_fp, soft_fp), (0, 0));
    assert!(
        soft_tp > hard_tp,
        "soft {soft_tp}, hard {hard_tp} of {n_true}"
    );
    // Every candidate entered EM: none was dropped by the gate.
    assert!(soft.loops.iter().all(|l| l.kept));
}

#[test]
fn em_learns_its_decision_width_from_heavy_tailed_true_loops() {
    use pgo::geometry::Pose;
    let dir = temp_dir("robust-width");
    // Ten true loops with ~11σ errors (r² ≈ 120 against c² = 30.7): true,
    // but beyond the calibrated width; the wrong loops are far further out.
    let mut sim = simulate_planar(&options(OutlierPolicy::Random, 60, 7)).expect("simulate");
    // Candidate index (file order) of each bent loop.
    let mut candidate_of = Vec::new();
    let candidates = sim
        .noisy
        .edges
        .iter_mut()
        .zip(&sim.wrong)
        .filter(|(e, _)| e.is_candidate());
    for (i, (e, &w)) in candidates.enumerate() {
        if !w && candidate_of.len() < 10 {
            let d = nalgebra::Vector3::from_fn(|k, _| (40.0 / e.information[(k, k)]).sqrt());
            e.measurement = e.measurement.compose(&Se2::exp(&d));
            candidate_of.push(i);
        }
    }
    let path = dir.join("heavy.g2o");
    write(&sim.noisy, &path);
    let wrong = candidate_labels(&sim.noisy, &sim.wrong);

    let learned = run(&path, GateMode::Off, RobustMethod::Em, None);
    let fixed = run_config(OptimizeConfig {
        gate: GateMode::Off,
        learn_width: false,
        ..OptimizeConfig::new(&path)
    });
    let c = learned.robust.c;
    let c_d = learned.robust.decision_c.expect("EM reports its width");
    let mixture = learned.robust.residual_mixture.as_ref().expect("a fit");
    assert!(mixture.degeneracy.is_none(), "{:?}", mixture.degeneracy);
    assert!(c_d > c, "learned {c_d}, c {c}");
    assert_eq!(fixed.robust.decision_c, Some(c));
    // Learned: every bent true loop accepted, no wrong one.
    let (tp, fp, _) = counts(&learned, &wrong);
    assert_eq!(fp, 0);
    assert_eq!(tp, wrong.iter().filter(|w| !**w).count());
    // At c some bent loops are rejected (4 of them; the others pull the map
    // far enough to fit), still no wrong one.
    let (_, fp_fixed, _) = counts(&fixed, &wrong);
    assert_eq!(fp_fixed, 0);
    let rejected = candidate_of
        .iter()
        .filter(|&&i| fixed.loops[i].weight < 0.5)
        .count();
    assert!(rejected >= 3, "{rejected} of 10 bent loops rejected at c");
}

#[test]
fn em_without_the_gate_searches_the_noise_scale_of_under_confident_information() {
    // As many wrong candidates as true loops, no gate, and information 100×
    // under-confident (as square-root information is): at the file's scale
    // the weighting ends in a map the wrong loops bent, whose accepted set
    // repeats with all of them; that map does not fit the information, and
    // the trial scales find the one at which it does.
    let dir = temp_dir("robust-scale-search");
    let mut sim = simulate_planar(&options(OutlierPolicy::Random, 100, 1)).expect("simulate");
    for e in &mut sim.noisy.edges {
        e.information *= 0.01;
    }
    let noisy = dir.join("under_confident.g2o");
    write(&sim.noisy, &noisy);
    let wrong = candidate_labels(&sim.noisy, &sim.wrong);
    let report = run(&noisy, GateMode::Off, RobustMethod::Em, None);
    let (tp, fp, true_loops) = counts(&report, &wrong);
    assert_eq!(report.robust.scale_search, Some(ScaleSearchOutcome::Found));
    assert!(report.robust.scale_trials > 0);
    assert_eq!(fp, 0, "wrong loops accepted");
    assert_eq!(tp, true_loops, "true loops rejected");
    assert!(report.chi2_test.as_ref().expect("χ² test").passed);
    // Without the search, the wrong loops stay in, and the χ² test says so.
    let config = OptimizeConfig {
        gate: GateMode::Off,
        scale_search: false,
        ..OptimizeConfig::new(&noisy)
    };
    let report = pipeline::run(&config, &mut |_| {}).expect("optimise");
    let (_, fp, _) = counts(&report, &wrong);
    assert_eq!(
        report.robust.scale_search,
        Some(ScaleSearchOutcome::NotNeeded)
    );
    assert!(fp > 50, "{fp} wrong loops accepted without the search");
    assert!(!report.chi2_test.as_ref().expect("χ² test").passed);
}
