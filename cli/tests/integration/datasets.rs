//! The public benchmark datasets (../shared/datasets or $PGO_DATASETS)
//! through the binary: no file makes `pgo` panic, and datasets with wrong
//! candidates planted by `pgo corrupt`. (The optimum against g2o and GTSAM
//! and the quirks of MANIFEST.md are the library's tests/datasets.rs.)
//! Each test prints a reason and passes when the datasets are absent
//! (and fails when `CI` is `true`).

use crate::common::{candidate_wrong, datasets, pgo, stderr, write_graph};
use pgo::graph::AnyGraph;
use pgo::io::g2o::{self, ReadOptions};
use pgo::pipeline::{self, OptimizeConfig};

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
