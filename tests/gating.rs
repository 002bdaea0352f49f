//! Gating alone (issue: "Loop gating"), through [`pgo::learn_threshold`]:
//! when the true and wrong candidates have inlier counts as far apart as
//! in the paper's figures, the learned `T_GV` keeps the true loops and
//! drops the wrong ones. (The job's gate on files — degenerate counts, the
//! χ² test with wrong loops let in — is tested with the samples in
//! `robust.rs` and through `pgo optimize` in the command line's tests.)

use pgo::{MixtureOptions, Threshold, learn_threshold};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use rand_distr::StandardNormal;
use statrs::distribution::{ContinuousCDF, Normal};

/// A log-normal model of a class's RANSAC inlier counts, as the simulator
/// draws them: `round(exp(ln median + σ·N(0, 1)))`.
#[derive(Clone, Copy)]
struct Counts {
    median: f64,
    sigma: f64,
}

impl Counts {
    fn draw(self, rng: &mut StdRng) -> u64 {
        let z: f64 = rng.sample(StandardNormal);
        (self.median.ln() + self.sigma * z).exp().round() as u64
    }

    /// The probability that a count of this class passes a threshold
    /// `t`, i.e. is at least `⌈t⌉`: that `exp(ln median + σ·N(0, 1))`
    /// rounds to `⌈t⌉` or more.
    fn passes(self, t: f64) -> f64 {
        let smallest = t.ceil().max(1.0) - 0.5;
        let z = (smallest.ln() - self.median.ln()) / self.sigma;
        1.0 - Normal::standard().cdf(z)
    }
}

/// The threshold learned from the counts of both classes.
fn learned(true_counts: &[u64], wrong_counts: &[u64]) -> Threshold {
    let all: Vec<u64> = true_counts.iter().chain(wrong_counts).copied().collect();
    let fit = learn_threshold(&all, &MixtureOptions::default());
    assert!(!fit.is_degenerate(), "{:?}", fit.degeneracy);
    fit.threshold
        .expect("a threshold where the fit is not degenerate")
}

#[test]
fn gating_alone_keeps_true_loops_and_drops_wrong_ones() {
    // The paper's figures: wrong candidates peak near v = 0.05 of the maximum
    // and the threshold sits near 0.1–0.2, i.e. medians a factor 10
    // apart in inliers (150 vs 15), σ 0.5 in ln for both.
    let true_model = Counts {
        median: 150.0,
        sigma: 0.5,
    };
    let wrong_model = Counts {
        median: 15.0,
        sigma: 0.5,
    };
    // Many true loops and few wrong candidates, as many of each, and four
    // times as many wrong ones; nine draws of each (the simulated graphs
    // this was first run on: three worlds × three placements of the wrong
    // candidates, whose counts are independent of either).
    for (loops, outliers) in [(300, 100), (200, 200), (100, 400)] {
        for seed in 0..9 {
            let mut rng = StdRng::seed_from_u64(1000 * loops + seed);
            let trues: Vec<u64> = (0..loops).map(|_| true_model.draw(&mut rng)).collect();
            let wrongs: Vec<u64> = (0..outliers).map(|_| wrong_model.draw(&mut rng)).collect();
            let t = learned(&trues, &wrongs);
            // The shares of each class the threshold keeps: of the classes'
            // count models (those of the draws scatter by a few per cent
            // about them: 7 of 100 wrong ones for one seed).
            let (kept_true, kept_wrong) = (true_model.passes(t.count), wrong_model.passes(t.count));
            let case = format!("seed {seed}: {loops} loops {outliers} wrong");
            eprintln!(
                "{case}: T_GV {:.1}, keeps {kept_true:.4} of true loops, {kept_wrong:.4} of wrong ones",
                t.count
            );
            assert!(
                kept_true >= 0.95,
                "{case}: keeps {kept_true} of true loops (T_GV {})",
                t.count
            );
            assert!(
                kept_wrong <= 0.05,
                "{case}: lets {kept_wrong} of wrong ones through (T_GV {})",
                t.count
            );
        }
    }
}
