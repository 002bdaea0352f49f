use super::*;
use crate::stats::mixture::em;
use crate::stats::separation::tests::brute_force_crossing;
use proptest::prelude::*;
use rand::SeedableRng;
use rand::rngs::StdRng;
use rand_distr::{Distribution, LogNormal, Uniform};
use rayon::prelude::*;
use statrs::distribution::{
    Continuous, ContinuousCDF, LogNormal as StatrsLogNormal, Normal as StatrsNormal,
};

/// `n` integer counts whose logarithm is normal with this median and σ.
fn draw_counts(rng: &mut StdRng, n: usize, median: f64, sigma: f64) -> Vec<u64> {
    let d = LogNormal::new(median.ln(), sigma).unwrap();
    (0..n).map(|_| d.sample(rng).round() as u64).collect()
}

/// A realistic sample: many wrong candidates with few inliers, fewer true
/// loops with many.
fn two_population_counts(seed: u64) -> Vec<u64> {
    let mut rng = StdRng::seed_from_u64(seed);
    let mut counts = draw_counts(&mut rng, 2000, 25.0, 0.45);
    counts.extend(draw_counts(&mut rng, 400, 250.0, 0.25));
    counts
}

fn default_fit(counts: &[u64]) -> ThresholdFit {
    learn_threshold(counts, &MixtureOptions::default())
}

/// Every number in a fit is finite.
fn assert_all_finite(fit: &ThresholdFit) {
    if let Some(m) = &fit.mixture {
        let numbers = m.mu.iter().chain(&m.sigma).chain(&m.weight);
        assert!(numbers.copied().all(f64::is_finite), "{m:?}");
        assert!(
            m.log_likelihood.is_finite() && m.variance_floor.is_finite(),
            "{m:?}"
        );
    }
    if let Some(s) = &fit.separation {
        let numbers = [
            s.bic_one,
            s.bic_two,
            s.ashman_d,
            s.loop_weight,
            s.loop_expected_size,
        ];
        assert!(numbers.iter().all(|x| x.is_finite()), "{s:?}");
    }
    if let Some(t) = &fit.threshold {
        assert!(t.count.is_finite() && t.normalized.is_finite(), "{t:?}");
    }
    let text = serde_json::to_string(fit).unwrap();
    assert!(!text.contains("NaN") && !text.contains("inf"), "{text}");
}

/// A fitted-looking mixture with these parameters (in `ln v`).
fn two_normals(mu: [f64; 2], sigma: [f64; 2], weight: [f64; 2]) -> LogNormalMixture {
    LogNormalMixture {
        mu,
        sigma,
        weight,
        iterations: 0,
        converged: true,
        log_likelihood: 0.0,
        start: EmStart::Paper,
        variance_floor: MIN_VARIANCE_FLOOR,
    }
}

/// The crossing of a mixture's weighted densities found by a scan
/// ([`brute_force_crossing`]).
fn scanned_crossing(m: &LogNormalMixture) -> Option<f64> {
    let [not_loop, true_loop] = m.components();
    brute_force_crossing(&not_loop, &true_loop)
}

#[test]
fn soft_mode_keeps_everything_unless_degenerate() {
    let counts: Vec<Option<u64>> = two_population_counts(3).into_iter().map(Some).collect();
    let d = gate(
        &counts,
        GateMode::Soft,
        DegeneratePolicy::DropAll,
        &MixtureOptions::default(),
    );
    assert!(!d.degenerate && d.fit.is_some());
    assert_eq!(d.kept_count(), counts.len());
    assert_eq!(d.threshold, None);
    let equal = vec![Some(9u64); 40];
    let d = gate(
        &equal,
        GateMode::Soft,
        DegeneratePolicy::DropAll,
        &MixtureOptions::default(),
    );
    assert!(d.degenerate && d.kept_count() == 0);
}

#[test]
fn recovers_a_known_mixture_and_its_crossing() {
    for seed in [1, 2, 3] {
        let counts = two_population_counts(seed);
        let fit = default_fit(&counts);
        assert_all_finite(&fit);
        assert_eq!(fit.degeneracy, None, "seed {seed}");
        let m = fit.mixture.as_ref().unwrap();
        // The truth, on y = ln(count / max).
        let ln_max = (fit.max_count as f64).ln();
        let truth = two_normals(
            [25f64.ln() - ln_max, 250f64.ln() - ln_max],
            [0.45, 0.25],
            [2000.0 / 2400.0, 400.0 / 2400.0],
        );
        for k in 0..2 {
            assert!(
                (m.mu[k] - truth.mu[k]).abs() < 0.04,
                "seed {seed} μ{k}: {m:?}"
            );
            assert!(
                (m.sigma[k] - truth.sigma[k]).abs() < 0.03,
                "seed {seed} σ{k}: {m:?}"
            );
            assert!(
                (m.weight[k] - truth.weight[k]).abs() < 0.025,
                "seed {seed} π{k}: {m:?}"
            );
        }
        let true_crossing = scanned_crossing(&truth).unwrap();
        let t = fit.threshold.as_ref().unwrap();
        assert!(
            (t.normalized.ln() - true_crossing).abs() < 0.05,
            "seed {seed}: {t:?} vs {true_crossing}"
        );
        assert!((t.count - t.normalized * fit.max_count as f64).abs() < 1e-9 * t.count);
    }
}

/// Counts from a known two-component log-normal mixture: each count is
/// a true loop with probability `w_loop`; `ln count` is normal with the
/// component's median and σ; rounded to an integer.
fn mixture_counts(rng: &mut StdRng, n: usize, truth: &LogNormalMixture) -> Vec<u64> {
    let unit = Uniform::new(0.0, 1.0).unwrap();
    let comps = [0, 1].map(|k| LogNormal::new(truth.mu[k], truth.sigma[k]).unwrap());
    (0..n)
        .map(|_| {
            let k = usize::from(unit.sample(rng) < truth.weight[1]);
            (comps[k].sample(rng).round() as u64).max(1)
        })
        .collect()
}

/// The fit in `ln count` (undoing the normalisation by the maximum), so
/// that it compares with a truth that does not depend on the sample.
fn fit_in_log_counts(fit: &ThresholdFit) -> Option<(LogNormalMixture, f64)> {
    let (m, t) = (fit.mixture.as_ref()?, fit.threshold.as_ref()?);
    let ln_max = (fit.max_count as f64).ln();
    let p = two_normals(m.mu.map(|mu| mu + ln_max), m.sigma, m.weight);
    Some((p, t.count.ln()))
}

#[test]
fn fit_and_threshold_converge_to_the_truth_as_the_sample_grows() {
    // Wrong candidates: median 30 inliers, σ 0.5 in ln; true loops
    // e^Δ times more, σ 0.35. Δ = 1.5, 2.25, 3 give Ashman's D = 3.5,
    // 5.2, 7.0; the loop share runs from 5 % to 95 %; N from 50 to 10⁵.
    let sizes = [50usize, 500, 5_000, 100_000];
    let mut cases = Vec::new();
    for delta in [1.5, 2.25, 3.0] {
        for w_loop in [0.05, 0.2, 0.5, 0.8, 0.95] {
            cases.push((delta, w_loop));
        }
    }
    let results: Vec<_> = cases
        .par_iter()
        .enumerate()
        .map(|(case, &(delta, w_loop))| {
            let truth = two_normals(
                [30f64.ln(), 30f64.ln() + delta],
                [0.5, 0.35],
                [1.0 - w_loop, w_loop],
            );
            // The Bayes-optimal threshold of the true mixture (ln count).
            let bayes = scanned_crossing(&truth).unwrap();
            let mut rng = StdRng::seed_from_u64(1000 + case as u64);
            let errors: Vec<Option<[f64; 4]>> = sizes
                .iter()
                .map(|&n| {
                    let counts = mixture_counts(&mut rng, n, &truth);
                    let fit = default_fit(&counts);
                    assert_all_finite(&fit);
                    if fit.is_degenerate() {
                        return None;
                    }
                    let (p, ln_t) = fit_in_log_counts(&fit).unwrap();
                    let e = |f: fn(&LogNormalMixture) -> [f64; 2]| {
                        let (a, b) = (f(&p), f(&truth));
                        (a[0] - b[0]).abs().max((a[1] - b[1]).abs())
                    };
                    Some([
                        e(|q| q.mu),
                        e(|q| q.sigma),
                        e(|q| q.weight),
                        (ln_t - bayes).abs(),
                    ])
                })
                .collect();
            (delta, w_loop, errors)
        })
        .collect();
    for (delta, w_loop, errors) in results {
        let label = format!("Δ = {delta}, loop share {w_loop}");
        // With ≥ 5000 counts the smaller component has ≥ 250 members:
        // never degenerate, and every error is within a statistical bound.
        for (&n, e) in sizes.iter().zip(&errors) {
            let Some([mu, sigma, weight, _]) = *e else {
                assert!(n < 5_000, "{label}, N = {n}: degenerate");
                continue;
            };
            // Standard error of the smaller component's mean ~ σ/√(nπ);
            // allow 6 of them plus the integer rounding of the counts.
            let smaller = n as f64 * w_loop.min(1.0 - w_loop);
            let bound = 6.0 * 0.5 / smaller.sqrt() + 0.01;
            if n >= 500 {
                assert!(mu < bound, "{label}, N = {n}: μ error {mu} ≥ {bound}");
                assert!(sigma < bound, "{label}, N = {n}: σ error {sigma} ≥ {bound}");
                assert!(
                    weight < 6.0 / (n as f64).sqrt(),
                    "{label}, N = {n}: π error {weight}"
                );
            }
        }
        // At N = 10⁵ the fit is the truth and T_GV the Bayes-optimal
        // crossing, to within the tolerances the tests state.
        let [mu, sigma, weight, threshold] = errors[3].unwrap();
        assert!(mu < 0.02, "{label}: μ error {mu}");
        assert!(sigma < 0.02, "{label}: σ error {sigma}");
        assert!(weight < 0.01, "{label}: π error {weight}");
        assert!(
            threshold < 0.03,
            "{label}: ln T_GV off the Bayes crossing by {threshold}"
        );
        // And it got there by converging: the large sample is at least as
        // close as the small ones on every measure that had a fit.
        for e in errors[..2].iter().flatten() {
            for (small, large) in e.iter().zip(&errors[3].unwrap()) {
                assert!(
                    large <= &(small + 0.005),
                    "{label}: {e:?} → {:?}",
                    errors[3]
                );
            }
        }
    }
}

#[test]
fn em_log_likelihood_never_decreases() {
    let counts = two_population_counts(7);
    let max = *counts.iter().max().unwrap();
    let y = log_normalized(&counts, max);
    let floor = VarianceFloor::Quantization.value(max);
    let options = MixtureOptions::default().em(floor);
    for (start, mixture) in em_starts(&y, floor) {
        let mut trace = Vec::new();
        let run = em(&y, mixture, &options, |ll| trace.push(ll)).unwrap();
        assert!(trace.len() >= 3, "{start:?}");
        for w in trace.windows(2) {
            assert!(
                w[1] >= w[0] - 1e-9 * w[0].abs(),
                "{start:?}: {} then {}",
                w[0],
                w[1]
            );
        }
        assert_eq!(trace.last().copied(), Some(run.log_likelihood));
    }
}

#[test]
fn counts_spanning_nineteen_orders_of_magnitude_are_fitted() {
    // Real counts spanning 19 orders of magnitude: the paper's start is at
    // ln v ≈ −2, some counts at ln v ≈ −44.
    let mut rng = StdRng::seed_from_u64(31);
    let mut counts = draw_counts(&mut rng, 200, 20.0, 0.4);
    counts.extend(draw_counts(&mut rng, 50, 1.5e19, 0.05));
    let max = *counts.iter().max().unwrap();
    let y = log_normalized(&counts, max);
    let floor = VarianceFloor::Quantization.value(max);
    let (start, paper) = em_starts(&y, floor).swap_remove(0);
    assert_eq!(start, EmStart::Paper);
    let run = em(&y, paper, &MixtureOptions::default().em(floor), |_| {}).unwrap();
    assert!(run.log_likelihood.is_finite());
    let fit = default_fit(&counts);
    assert_eq!(fit.degeneracy, None);
    assert!(fit.threshold.unwrap().count > 1e6);
}

#[test]
fn zero_counts_are_counted_but_not_fitted() {
    let counts = two_population_counts(3);
    let mut with_zeros = Vec::new();
    for (i, &c) in counts.iter().enumerate() {
        with_zeros.push(c);
        if i % 50 == 0 {
            with_zeros.push(0);
        }
    }
    let zeros = with_zeros.len() - counts.len();
    let a = default_fit(&counts);
    let b = default_fit(&with_zeros);
    assert_eq!(
        (b.zero_counts, b.fitted_counts, b.total_counts),
        (zeros, counts.len(), with_zeros.len())
    );
    assert_eq!(a.mixture, b.mixture);
    assert_eq!(a.threshold, b.threshold);
    assert!(!b.threshold.unwrap().keeps(0));
}

#[test]
fn trivial_inputs_are_degenerate_for_the_right_reason() {
    let cases: [(Vec<u64>, Degeneracy); 6] = [
        (vec![], Degeneracy::NoCandidates),
        (vec![0; 12], Degeneracy::AllZero { zero_counts: 12 }),
        (
            vec![42],
            Degeneracy::TooFewCounts {
                fitted_counts: 1,
                min_counts: 8,
            },
        ),
        (
            vec![0, 5, 9, 0, 17, 3, 0],
            Degeneracy::TooFewCounts {
                fitted_counts: 4,
                min_counts: 8,
            },
        ),
        (
            vec![7; 30],
            Degeneracy::AllEqual {
                count: 7,
                fitted_counts: 30,
            },
        ),
        (
            [vec![0; 5], vec![u64::MAX; 10]].concat(),
            Degeneracy::AllEqual {
                count: u64::MAX,
                fitted_counts: 10,
            },
        ),
    ];
    for (counts, reason) in cases {
        let fit = default_fit(&counts);
        assert_all_finite(&fit);
        assert_eq!(fit.degeneracy.as_ref(), Some(&reason), "{counts:?}");
        assert!(fit.mixture.is_none() && fit.threshold.is_none());
        assert!(!reason.to_string().is_empty());
    }
}

#[test]
fn a_single_log_normal_is_degenerate() {
    for seed in 0..4 {
        let mut rng = StdRng::seed_from_u64(100 + seed);
        let counts = draw_counts(&mut rng, 2000, 40.0, 0.5);
        let fit = default_fit(&counts);
        assert_all_finite(&fit);
        assert!(
            matches!(
                fit.degeneracy,
                Some(Degeneracy::OneComponent { .. } | Degeneracy::Overlapping { .. })
            ),
            "seed {seed}: {:?}",
            fit.degeneracy
        );
    }
}

/// The counts of a young simulated map (`pgo simulate --world grid2d
/// --poses 400 --loops 60 --inliers --seed 61`, `pgo corrupt` with 40
/// aliases in groups of 10 placed anywhere, every group's counts like a
/// true loop's, seed 61; its first 143 poses): 22 true loops and 10
/// aliases, all drawn from one population. Two components fit them
/// better by a BIC of only 0.17, and their crossing at 180 would drop 11
/// of the 22 true loops.
#[test]
fn a_chance_split_of_one_population_is_no_second_component() {
    let counts = [
        115, 134, 150, 88, 96, 221, 280, 121, 371, 276, 273, 123, 133, 217, 264, 83, 134, 156, 343,
        235, 113, 121, 115, 159, 95, 216, 141, 108, 220, 103, 169, 112,
    ];
    let fit = default_fit(&counts);
    assert!(
        matches!(fit.degeneracy, Some(Degeneracy::OneComponent { .. })),
        "{:?}",
        fit.degeneracy
    );
    let s = fit.separation.expect("a mixture was fitted");
    let gain = s.bic_one - s.bic_two;
    assert!(gain > 0.0 && gain <= MIN_BIC_GAIN, "{gain}");
    let eager = MixtureOptions {
        min_bic_gain: 0.0,
        ..Default::default()
    };
    let split = learn_threshold(&counts, &eager);
    assert!(split.degeneracy.is_none(), "{:?}", split.degeneracy);
}

#[test]
fn heavy_ties_neither_collapse_nor_produce_nan() {
    for seed in 0..10 {
        let mut rng = StdRng::seed_from_u64(seed);
        let n = [10, 30, 100, 1000, 5000][seed as usize % 5];
        let values = Uniform::new_inclusive(1u64, 5).unwrap();
        let counts: Vec<u64> = (0..n).map(|_| values.sample(&mut rng)).collect();
        let fit = default_fit(&counts);
        assert_all_finite(&fit);
        if let Some(m) = &fit.mixture {
            let floor = m.variance_floor;
            for k in 0..2 {
                assert!(m.sigma[k].powi(2) >= floor * (1.0 - 1e-12), "{m:?}");
                assert!(m.weight[k] * n as f64 >= 1.0, "{m:?}");
            }
        }
        assert!(fit.is_degenerate() || fit.threshold.is_some());
    }
}

/// The counts of a young simulated map (a sphere's first 180 poses, 28
/// candidates, all true loops): the two lowest, 54 and 55, are neighbours,
/// and a "component" of σ 0.009 on them had the highest likelihood of any
/// start and a threshold of 56 that dropped both. Two neighbouring counts
/// are as good as tied: that fit is a collapse, and the counts show one
/// population.
#[test]
fn two_neighbouring_counts_are_no_component() {
    let counts = [
        54u64, 55, 80, 106, 115, 118, 122, 129, 140, 145, 148, 151, 152, 169, 171, 171, 173, 184,
        196, 197, 203, 220, 222, 228, 272, 277, 341, 445,
    ];
    let fit = default_fit(&counts);
    assert_all_finite(&fit);
    assert!(
        fit.threshold.as_ref().is_none_or(|t| t.keeps(54)),
        "{fit:?}"
    );
    // No component of fewer than three counts is narrower than a count's
    // step there.
    let m = fit.mixture.expect("a fit from some start");
    for k in 0..2 {
        assert!(
            m.weight[k] * counts.len() as f64 >= 3.0 || m.sigma[k] > 0.02,
            "{m:?}"
        );
    }
    // Far from each other, two low counts are a component of their own.
    let mut apart = counts;
    (apart[0], apart[1]) = (9, 14);
    let t = default_fit(&apart).threshold.expect("a split");
    assert!(!t.keeps(14) && t.keeps(80), "{t:?}");
}

#[test]
fn tied_clusters_at_two_values_are_separated() {
    // Saturated counts: a spike of strong candidates at the maximum.
    let mut counts = vec![200u64; 25];
    let mut rng = StdRng::seed_from_u64(9);
    counts.extend(draw_counts(&mut rng, 300, 12.0, 0.5));
    let fit = default_fit(&counts);
    assert_all_finite(&fit);
    assert_eq!(fit.degeneracy, None);
    let t = fit.threshold.unwrap();
    assert!(t.keeps(200) && !t.keeps(40), "{t:?}");
}

#[test]
fn counts_near_u64_max_do_not_overflow() {
    let mut rng = StdRng::seed_from_u64(21);
    let mut counts = draw_counts(&mut rng, 500, 1e17, 0.4);
    let strong = draw_counts(&mut rng, 100, 5e18, 0.2);
    counts.extend(&strong);
    counts.push(u64::MAX);
    let fit = default_fit(&counts);
    assert_all_finite(&fit);
    assert_eq!(fit.max_count, u64::MAX);
    assert_eq!(fit.degeneracy, None);
    let t = fit.threshold.unwrap();
    assert!(t.count > 1e17 && t.count < 5e18, "{t:?}");
    let kept = strong.iter().filter(|&&c| t.keeps(c)).count();
    assert!(kept >= 95, "{kept} of 100 strong candidates kept");

    // Small counts and one astronomically large one.
    // The lone huge count can only be a component of one: a collapse.
    let mut odd: Vec<u64> = (1..=60).collect();
    odd.push(u64::MAX);
    let fit = default_fit(&odd);
    assert_all_finite(&fit);
    assert_eq!(fit.degeneracy, Some(Degeneracy::Collapsed { starts: 3 }));
    assert!(VarianceFloor::Quantization.value(u64::MAX) >= MIN_VARIANCE_FLOOR);
    assert!(VarianceFloor::Quantization.value(1).is_finite());
}

#[test]
fn variance_floor_options() {
    // Δ = ln(100/99): Δ²/12.
    let q = VarianceFloor::Quantization.value(100);
    assert!((q - (100f64 / 99.0).ln().powi(2) / 12.0).abs() < 1e-15);
    assert_eq!(VarianceFloor::Absolute(1e-3).value(100), 1e-3);
    for bad in [0.0, -1.0, f64::NAN, f64::INFINITY] {
        assert_eq!(VarianceFloor::Absolute(bad).value(100), MIN_VARIANCE_FLOOR);
    }
    let options = MixtureOptions {
        variance_floor: VarianceFloor::Absolute(1e-3),
        ..Default::default()
    };
    let fit = learn_threshold(&two_population_counts(4), &options);
    assert_eq!(fit.mixture.unwrap().variance_floor, 1e-3);
}

#[test]
fn bic_or_ashman_report_their_numbers() {
    let d = Degeneracy::OneComponent {
        bic_one: 123.4,
        bic_two: 130.1,
        min_gain: 2.0,
    };
    assert_eq!(
        d.to_string(),
        "the counts show one component: BIC 1-comp 123.4 is not above 2-comp 130.1 by more than 2"
    );
    let d = Degeneracy::Overlapping {
        ashman_d: 1.234,
        min_ashman_d: 2.0,
    };
    assert!(d.to_string().contains("1.23 < 2.00"));
    let json = serde_json::to_string(&d).unwrap();
    assert!(json.contains("\"reason\":\"overlapping\""), "{json}");
}

#[test]
fn separation_checks_come_in_the_documented_order() {
    let counts = two_population_counts(2);
    let strict = MixtureOptions {
        min_ashman_d: 1e6,
        min_loop_weight: 0.9,
        ..Default::default()
    };
    let fit = learn_threshold(&counts, &strict);
    assert!(
        matches!(fit.degeneracy, Some(Degeneracy::Overlapping { .. })),
        "{:?}",
        fit.degeneracy
    );
    let strict = MixtureOptions {
        min_loop_weight: 0.9,
        min_loop_size: 1e9,
        ..Default::default()
    };
    let fit = learn_threshold(&counts, &strict);
    assert!(matches!(
        fit.degeneracy,
        Some(Degeneracy::LightLoopComponent { .. })
    ));
    let strict = MixtureOptions {
        min_loop_size: 1e9,
        ..Default::default()
    };
    let fit = learn_threshold(&counts, &strict);
    assert!(matches!(
        fit.degeneracy,
        Some(Degeneracy::SmallLoopComponent { .. })
    ));
    // Degenerate or not, the crossing is still reported.
    assert!(fit.threshold.is_some());
    let s = fit.separation.unwrap();
    assert!(s.bic_two < s.bic_one && s.crossing_exists);
    // BIC = k ln n − 2 ln L with k = 2 (one normal) and k = 5 (mixture).
    let y = log_normalized(&counts, fit.max_count);
    let n = y.len() as f64;
    let mean = y.iter().sum::<f64>() / n;
    let sd = (y.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n).sqrt();
    let one = StatrsNormal::new(mean, sd).unwrap();
    let ll_one: f64 = y.iter().map(|&v| one.ln_pdf(v)).sum();
    assert!((s.bic_one - (2.0 * n.ln() - 2.0 * ll_one)).abs() < 1e-8 * s.bic_one.abs());
    let m = fit.mixture.unwrap();
    assert!((s.bic_two - (5.0 * n.ln() - 2.0 * m.log_likelihood)).abs() < 1e-8 * s.bic_two.abs());
    assert!((s.loop_expected_size - s.loop_weight * counts.len() as f64).abs() < 1e-9);
}

#[test]
fn ashman_d_and_the_keep_rule() {
    let m = LogNormalMixture {
        mu: [-3.0, -1.0],
        sigma: [0.5, 0.5],
        weight: [0.8, 0.2],
        iterations: 0,
        converged: true,
        log_likelihood: 0.0,
        start: EmStart::Paper,
        variance_floor: MIN_VARIANCE_FLOOR,
    };
    // √2 · 2 / √(0.25 + 0.25) = 4.
    assert!((m.ashman_d() - 4.0).abs() < 1e-15);
    // "count < T_GV is dropped": a count equal to the threshold is kept.
    let t = Threshold {
        count: 10.0,
        normalized: 0.1,
        max_count: 100,
    };
    assert!(t.keeps(10) && t.keeps(11) && !t.keeps(9));
    assert!(Rule::Learned(10.0).keeps(10) && !Rule::Learned(10.0).keeps(9));
    assert!(Rule::AtLeast(10).keeps(10) && !Rule::AtLeast(10).keeps(9));
}

#[test]
fn gate_modes() {
    let opts = MixtureOptions::default();
    let counts = [Some(3), None, Some(10), Some(11), Some(0)];
    let off = gate(&counts, GateMode::Off, DegeneratePolicy::DropAll, &opts);
    assert_eq!(off.kept, vec![true; 5]);
    assert_eq!(
        (off.threshold, off.degenerate, off.fit.is_none()),
        (None, false, true)
    );
    let fixed = gate(
        &counts,
        GateMode::Fixed(10),
        DegeneratePolicy::DropAll,
        &opts,
    );
    assert_eq!(fixed.kept, vec![false, true, true, true, false]);
    assert_eq!(fixed.threshold, Some(10.0));
    assert_eq!((fixed.kept_count(), fixed.dropped_count()), (3, 2));
    // Exact integer comparison even where f64 cannot tell counts apart.
    let huge = [Some(u64::MAX - 1), Some(u64::MAX)];
    let fixed = gate(
        &huge,
        GateMode::Fixed(u64::MAX),
        DegeneratePolicy::DropAll,
        &opts,
    );
    assert_eq!(fixed.kept, vec![false, true]);
    assert_eq!(GateMode::default(), GateMode::Auto);
    assert_eq!(DegeneratePolicy::default(), DegeneratePolicy::KeepAll);
}

#[test]
fn auto_gate_applies_the_learned_threshold() {
    let raw = two_population_counts(8);
    let mut counts: Vec<Option<u64>> = raw.iter().map(|&c| Some(c)).collect();
    counts.insert(10, None);
    counts.push(None);
    let d = gate(
        &counts,
        GateMode::Auto,
        DegeneratePolicy::DropAll,
        &MixtureOptions::default(),
    );
    assert!(!d.degenerate && d.reason.is_none());
    let t = d.fit.as_ref().unwrap().threshold.as_ref().unwrap().count;
    assert_eq!(d.threshold, Some(t));
    for (c, &k) in counts.iter().zip(&d.kept) {
        assert_eq!(k, c.is_none_or(|c| c as f64 >= t), "{c:?}");
    }
    // The 400 strong candidates are the last 400 counts (plus a None).
    let strong_kept = d.kept[d.kept.len() - 401..].iter().filter(|&&k| k).count();
    assert!(strong_kept >= 390, "{strong_kept}");
    assert!(d.kept_count() < 480, "{}", d.kept_count());
}

/// A few low counts among thousands of high ones, the shape of
/// parking-garage with 10 random wrong candidates (the outlier benchmark's
/// case): two populations, but the larger one's weighted density is the
/// higher everywhere between the means. No threshold, every candidate
/// kept, and the counts still tell the priors.
#[test]
fn counts_without_a_crossing_still_give_their_posteriors() {
    // At the quantiles of the fit to that file's counts (ln(n / 778)).
    let population = |n: usize, mu: f64, sigma: f64| {
        let normal = StatrsNormal::new(mu, sigma).unwrap();
        (0..n).map(move |i| {
            let y = normal.inverse_cdf((i as f64 + 0.5) / n as f64);
            (778.0 * y.exp()).round() as u64
        })
    };
    let mut raw: Vec<u64> = population(4602, -1.635, 0.497).collect();
    raw.extend(population(23, -3.165, 0.549));
    let counts: Vec<Option<u64>> = raw.iter().map(|&c| Some(c)).collect();
    let d = gate(
        &counts,
        GateMode::Auto,
        DegeneratePolicy::KeepAll,
        &MixtureOptions::default(),
    );
    assert!(
        matches!(d.reason, Some(Degeneracy::NoCrossing { .. })),
        "{:?}",
        d.reason
    );
    assert_eq!((d.kept_count(), d.threshold), (counts.len(), None));
    let m = d.count_model().expect("the counts' posteriors");
    let max = *raw.iter().max().unwrap();
    assert!(m.posterior_true_loop(12, max) < 0.05);
    assert!(m.posterior_true_loop(150, max) > 0.99);
    // A fit degenerate for another reason gives no posteriors.
    let equal = vec![Some(9u64); 40];
    let one = gate(
        &equal,
        GateMode::Auto,
        DegeneratePolicy::KeepAll,
        &MixtureOptions::default(),
    );
    assert!(one.degenerate && one.count_model().is_none());
}

#[test]
fn degenerate_policies() {
    let opts = MixtureOptions::default();
    let mut counts = vec![Some(12); 30];
    counts.push(None);
    let run = |policy| gate(&counts, GateMode::Auto, policy, &opts);
    let keep = run(DegeneratePolicy::KeepAll);
    assert!(keep.degenerate && keep.kept.iter().all(|&k| k) && keep.threshold.is_none());
    assert!(matches!(keep.reason, Some(Degeneracy::AllEqual { .. })));
    let drop = run(DegeneratePolicy::DropAll);
    assert_eq!(
        drop.kept_count(),
        1,
        "only the uncounted candidate survives"
    );
    assert!(*drop.kept.last().unwrap());
    // No crossing to fall back on: Threshold drops too.
    let thr = run(DegeneratePolicy::Threshold);
    assert_eq!(thr.kept, drop.kept);

    // Degenerate with a crossing: Threshold uses it.
    let raw = two_population_counts(6);
    let counts: Vec<Option<u64>> = raw.iter().map(|&c| Some(c)).collect();
    let picky = MixtureOptions {
        min_ashman_d: 1e6,
        ..Default::default()
    };
    let thr = gate(&counts, GateMode::Auto, DegeneratePolicy::Threshold, &picky);
    assert!(thr.degenerate);
    let t = thr.fit.as_ref().unwrap().threshold.as_ref().unwrap().count;
    assert_eq!(thr.threshold, Some(t));
    assert!(thr.kept_count() > 0 && thr.dropped_count() > 0);
    let drop = gate(&counts, GateMode::Auto, DegeneratePolicy::DropAll, &picky);
    assert_eq!(drop.kept_count(), 0);
    // No counted candidates at all.
    let none = gate(
        &[None, None],
        GateMode::Auto,
        DegeneratePolicy::DropAll,
        &opts,
    );
    assert_eq!(
        (none.kept, none.reason),
        (vec![true, true], Some(Degeneracy::NoCandidates))
    );
}

#[test]
fn posterior_is_a_monotone_probability_for_a_separated_fit() {
    let counts = two_population_counts(12);
    let fit = default_fit(&counts);
    let m = fit.mixture.as_ref().unwrap();
    assert!(
        m.sigma[1] < m.sigma[0],
        "the test relies on a narrower loop component"
    );
    let max = fit.max_count;
    let mut previous = 0.0;
    for c in 0..=max {
        let p = m.posterior_true_loop(c, max);
        assert!(
            (0.0..=1.0).contains(&p) && p >= previous,
            "count {c}: {p} after {previous}"
        );
        previous = p;
    }
    assert_eq!(m.posterior_true_loop(0, max), 0.0);
    assert!(m.posterior_true_loop(max, max) > 0.99);
    assert!(m.posterior_true_loop(5, max) < 0.01);
    let t = fit.threshold.unwrap();
    let at = m.log_odds(t.normalized.ln());
    assert!(at.abs() < 1e-9, "log-odds {at} at the threshold");
    assert!(m.posterior_true_loop(t.count.ceil() as u64, max) >= 0.5);
    assert!(m.posterior_true_loop(t.count.floor() as u64, max) < 0.5);
}

#[test]
fn densities_are_weighted_log_normals_in_v() {
    let fit = default_fit(&two_population_counts(13));
    let m = fit.mixture.unwrap();
    for component in [Component::NotLoop, Component::Loop] {
        let k = component.index();
        let reference = StatrsLogNormal::new(m.mu[k], m.sigma[k]).unwrap();
        for v in [0.01, 0.05, 0.2, 0.5, 0.9, 1.0] {
            let got = m.weighted_density(component, v);
            let want = m.weight[k] * reference.pdf(v);
            assert!(
                (got - want).abs() <= 1e-12 * want.max(1e-300),
                "{component:?} at {v}: {got} vs {want}"
            );
        }
        // ∫ f(v) dv = ∫ f(e^y) e^y dy = π_k.
        let (lo, hi) = (m.mu[k] - 12.0 * m.sigma[k], m.mu[k] + 12.0 * m.sigma[k]);
        let steps = 20_000;
        let h = (hi - lo) / steps as f64;
        let integral: f64 = (0..steps)
            .map(|i| lo + (i as f64 + 0.5) * h)
            .map(|y| m.weighted_density(component, y.exp()) * y.exp() * h)
            .sum();
        assert!(
            (integral - m.weight[k]).abs() < 1e-6,
            "{component:?}: {integral}"
        );
        assert_eq!(m.weighted_density(component, 0.0), 0.0);
        assert_eq!(m.weighted_density(component, -0.5), 0.0);
    }
    let v = 0.3;
    let sum = m.weighted_density(Component::NotLoop, v) + m.weighted_density(Component::Loop, v);
    assert_eq!(m.density(v), sum);
}

#[test]
fn the_paper_start_is_tried_first_and_components_are_ordered() {
    let fit = default_fit(&two_population_counts(14));
    let m = fit.mixture.unwrap();
    assert!(m.mu[0] < m.mu[1] && m.converged && m.iterations > 1);
    assert!((m.weight[0] + m.weight[1] - 1.0).abs() < 1e-12);
    let starts = em_starts(&[-3.0, -2.0, -1.0, 0.0], 1e-6);
    let kinds: Vec<EmStart> = starts.iter().map(|s| s.0).collect();
    assert_eq!(
        kinds,
        vec![EmStart::Paper, EmStart::Quartiles, EmStart::TwoMeans]
    );
    let paper: Vec<f64> = starts[0].1.components().iter().map(|c| c.mean).collect();
    assert_eq!(paper, [-2.0, 1.0]);
}

/// Counts in 0..10 000 with the odd astronomically large one.
fn arbitrary_counts() -> impl Strategy<Value = Vec<u64>> {
    prop::collection::vec(prop_oneof![40 => 0u64..10_000, 1 => any::<u64>()], 1..500)
}

/// Two clusters of counts with random positions, spreads and sizes.
fn clustered_counts() -> impl Strategy<Value = Vec<u64>> {
    (
        1u64..50,
        2u64..40,
        1usize..300,
        1u64..2000,
        2u64..400,
        1usize..100,
    )
        .prop_map(|(low, low_spread, n_low, high, high_spread, n_high)| {
            let mut counts: Vec<u64> = (0..n_low)
                .map(|i| low + (i as u64 * 7919) % low_spread)
                .collect();
            counts.extend((0..n_high).map(|i| low + high + (i as u64 * 104_729) % high_spread));
            counts
        })
}

fn check_invariants(counts: &[u64]) -> Result<(), TestCaseError> {
    let fit = default_fit(counts);
    assert_all_finite(&fit);
    let min_nonzero = counts.iter().copied().filter(|&c| c > 0).min();
    match (&fit.threshold, &fit.degeneracy, min_nonzero) {
        (_, Some(_), _) => {}
        (Some(t), None, Some(min)) => {
            prop_assert!(
                t.count > min as f64 && t.count <= fit.max_count as f64,
                "{t:?}, min {min}"
            );
        }
        _ => prop_assert!(false, "neither a threshold nor a verdict: {fit:?}"),
    }
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn never_nan_and_threshold_in_range(counts in arbitrary_counts()) {
        check_invariants(&counts)?;
    }

    #[test]
    fn clustered_counts_never_nan_and_threshold_in_range(counts in clustered_counts()) {
        check_invariants(&counts)?;
    }
}

#[test]
fn two_normals_fit_two_well_separated_groups() {
    // ln of two well-separated groups.
    let mut y: Vec<f64> = (0..200).map(|i| (i % 20) as f64 * 0.1).collect();
    y.extend((0..20).map(|i| 10.0 + (i % 5) as f64 * 0.2));
    let fit = fit_two_normals(&y, (1e-6, &|_| 0.0), &MixtureOptions::default());
    assert!(fit.degeneracy.is_none());
    let t = fit.crossing_log.unwrap();
    assert!(t > 1.9 && t < 10.0);
}
