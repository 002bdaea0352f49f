use super::*;
use rand::SeedableRng;
use rand::rngs::StdRng;
use rand_distr::{Distribution, Normal, Uniform};
use statrs::distribution::{Continuous, Normal as StatrsNormal};

fn component(weight: f64, mean: f64, sigma: f64) -> NormalComponent {
    NormalComponent {
        weight,
        mean,
        sigma,
    }
}

fn mixture(components: &[(f64, f64, f64)]) -> NormalMixture {
    NormalMixture::new(
        components
            .iter()
            .map(|&(w, m, s)| component(w, m, s))
            .collect(),
    )
    .unwrap()
}

const OPTIONS: EmOptions = EmOptions {
    tolerance: 1e-9,
    max_iterations: 1000,
    variance_floor: 1e-12,
};

/// `n` values drawn from `truth`: each from component `k` with probability
/// `π_k`.
fn sample(rng: &mut StdRng, truth: &NormalMixture, n: usize) -> Vec<f64> {
    let unit = Uniform::new(0.0, 1.0).unwrap();
    let normals: Vec<Normal<f64>> = truth
        .components()
        .iter()
        .map(|c| Normal::new(c.mean, c.sigma).unwrap())
        .collect();
    (0..n)
        .map(|_| {
            let u: f64 = unit.sample(rng);
            let mut cumulative = 0.0;
            let k = truth
                .components()
                .iter()
                .position(|c| {
                    cumulative += c.weight;
                    u < cumulative
                })
                .unwrap_or(truth.len() - 1);
            normals[k].sample(rng)
        })
        .collect()
}

/// Three components, far apart and of different widths and weights.
fn three_components() -> NormalMixture {
    mixture(&[(0.2, -5.0, 0.5), (0.5, 0.0, 1.0), (0.3, 6.0, 0.7)])
}

/// The data-driven starts for `k` components.
fn data_starts(y: &[f64], k: usize) -> Vec<(&'static str, NormalMixture)> {
    [
        ("quantiles", quantile_start(y, k, OPTIONS.variance_floor)),
        ("k-means", kmeans_start(y, k, OPTIONS.variance_floor)),
    ]
    .into_iter()
    .filter_map(|(label, start)| Some((label, start?)))
    .collect()
}

#[test]
fn three_well_separated_components_are_recovered() {
    let truth = three_components();
    let mut rng = StdRng::seed_from_u64(3);
    let n = 6000;
    let y = sample(&mut rng, &truth, n);
    let starts = data_starts(&y, 3);
    assert_eq!(starts.len(), 2);
    let (_, fit) = best_fit(&y, &starts, &OPTIONS, (3.0, &|_| 0.0)).unwrap();
    assert!(fit.converged, "{fit:?}");
    let got = fit.mixture.components();
    assert_eq!(got.len(), 3);
    for (k, (g, t)) in got.iter().zip(truth.components()).enumerate() {
        // Six standard errors of a component's mean, σ and weight.
        let size = n as f64 * t.weight;
        assert!(
            (g.mean - t.mean).abs() < 6.0 * t.sigma / size.sqrt(),
            "{g:?} vs {t:?}"
        );
        assert!(
            (g.sigma - t.sigma).abs() < 6.0 * t.sigma / (2.0 * size).sqrt(),
            "{g:?} vs {t:?}"
        );
        let se_weight = (t.weight * (1.0 - t.weight) / n as f64).sqrt();
        assert!(
            (g.weight - t.weight).abs() < 6.0 * se_weight,
            "{g:?} vs {t:?}"
        );
        // At a component's mean it is the explanation.
        assert!(fit.mixture.posteriors(t.mean)[k] > 0.99);
    }
    let weights: f64 = got.iter().map(|c| c.weight).sum();
    assert!((weights - 1.0).abs() < 1e-12);
    // Three components explain these data better than two, by BIC.
    let (_, two) = best_fit(&y, &data_starts(&y, 2), &OPTIONS, (3.0, &|_| 0.0)).unwrap();
    let size = n as f64;
    assert!(bic(3, size, fit.log_likelihood) < bic(2, size, two.log_likelihood));
}

#[test]
fn one_component_is_the_sample_mean_and_variance() {
    let mut rng = StdRng::seed_from_u64(8);
    let normal = Normal::new(2.5, 0.8).unwrap();
    let y: Vec<f64> = (0..500).map(|_| normal.sample(&mut rng)).collect();
    let n = y.len() as f64;
    let mean = y.iter().sum::<f64>() / n;
    let var = y.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n;
    // From a start far off, one M-step lands on the moments, and the next
    // changes nothing.
    let start = mixture(&[(1.0, -40.0, 9.0)]);
    let fit = em(&y, start, &OPTIONS, |_| {}).unwrap();
    assert!(fit.converged && fit.iterations == 2, "{fit:?}");
    let [c] = fit.mixture.components() else {
        panic!("{fit:?}")
    };
    assert!((c.mean - mean).abs() < 1e-12 && (c.sigma.powi(2) - var).abs() < 1e-12);
    assert_eq!(c.weight, 1.0);
    let moments = NormalMixture::moments(&y, 0.0);
    // (EM sums the sorted distinct values: the same sum up to rounding.)
    assert!((moments.components()[0].mean - c.mean).abs() < 1e-14);
    assert!((moments.components()[0].sigma - c.sigma).abs() < 1e-14);
    // Its log-likelihood is that of the normal with these moments.
    let reference = StatrsNormal::new(mean, var.sqrt()).unwrap();
    let ll: f64 = y.iter().map(|&v| reference.ln_pdf(v)).sum();
    assert!((fit.log_likelihood - ll).abs() < 1e-9 * ll.abs());
    assert!((moments.log_likelihood(&y) - ll).abs() < 1e-9 * ll.abs());
    // The data-driven starts for one component agree.
    for (label, start) in data_starts(&y, 1) {
        let fit = em(&y, start, &OPTIONS, |_| {}).unwrap();
        let c = fit.mixture.components()[0];
        assert!((c.mean - mean).abs() < 1e-12, "{label}");
    }
    // No data: mean 0, σ at the floor.
    let empty = NormalMixture::moments(&[], 1e-4);
    assert_eq!(empty.components()[0], component(1.0, 0.0, 1e-2));
}

#[test]
fn the_log_likelihood_never_decreases_along_em() {
    let mut rng = StdRng::seed_from_u64(21);
    let y = sample(&mut rng, &three_components(), 800);
    for k in 1..=4 {
        for (label, start) in data_starts(&y, k) {
            let mut trace = Vec::new();
            let fit = em(&y, start, &OPTIONS, |ll| trace.push(ll)).unwrap();
            assert!(trace.len() >= 2, "K = {k}, {label}");
            for w in trace.windows(2) {
                assert!(
                    w[1] >= w[0] - 1e-9 * w[0].abs(),
                    "K = {k}, {label}: {} then {}",
                    w[0],
                    w[1]
                );
            }
            assert_eq!(trace.last().copied(), Some(fit.log_likelihood));
            assert_eq!(fit.log_likelihood, fit.mixture.log_likelihood(&y));
        }
    }
}

#[test]
fn posteriors_are_the_normalised_weighted_densities() {
    let m = three_components();
    for y in [-7.0, -2.5, 0.0, 3.1, 6.0, 9.0] {
        let p = m.posteriors(y);
        let densities: Vec<f64> = m
            .components()
            .iter()
            .map(|c| c.weight * StatrsNormal::new(c.mean, c.sigma).unwrap().pdf(y))
            .collect();
        let total: f64 = densities.iter().sum();
        for (p, d) in p.iter().zip(&densities) {
            assert!((p - d / total).abs() < 1e-12, "y {y}: {p} vs {}", d / total);
        }
        assert!((m.log_density(y) - total.ln()).abs() < 1e-12);
        let odds = m.log_odds(2, 0, y);
        assert!((odds - (densities[2] / densities[0]).ln()).abs() < 1e-9);
    }
    assert!(m.log_odds(0, 3, 0.0).is_nan());
}

#[test]
fn m_step_variance_is_taken_around_the_new_mean() {
    let mut rng = StdRng::seed_from_u64(11);
    let normal = Normal::new(-1.0, 0.7).unwrap();
    let unit = Uniform::new(0.0, 1.0).unwrap();
    let y: Vec<f64> = (0..60).map(|_| normal.sample(&mut rng)).collect();
    let resp: Vec<f64> = (0..60)
        .flat_map(|_| {
            let r: f64 = unit.sample(&mut rng);
            [1.0 - r, r]
        })
        .collect();
    let m = m_step(&y, &resp, 2, MIN_VARIANCE_FLOOR).unwrap();
    for (k, c) in m.components().iter().enumerate() {
        let w: Vec<f64> = resp.chunks(2).map(|r| r[k]).collect();
        let total: f64 = w.iter().sum();
        // Weighted variance from all pairs: Σ_ij w_i w_j (y_i − y_j)² / (2 W²),
        // which needs no mean at all.
        let mut pairs = 0.0;
        for i in 0..y.len() {
            for j in 0..y.len() {
                pairs += w[i] * w[j] * (y[i] - y[j]).powi(2);
            }
        }
        let var = pairs / (2.0 * total * total);
        assert!(
            (c.sigma.powi(2) - var).abs() < 1e-12,
            "k {k}: {} vs {var}",
            c.sigma.powi(2)
        );
        let mean = w.iter().zip(&y).map(|(w, y)| w * y).sum::<f64>() / total;
        assert!((c.mean - mean).abs() < 1e-12);
        assert!((c.weight - total / 60.0).abs() < 1e-12);

        // Algorithm 1 lines 25–26 of Lee & Pollefeys verbatim (μ_k still a
        // partial sum) gives something else entirely: this test tells the
        // two apart.
        let (mut mu, mut sigma) = (0.0, 0.0);
        for (wi, yi) in w.iter().zip(&y) {
            mu += wi * yi;
            sigma += wi * (yi - mu).powi(2);
        }
        assert!((sigma / total - var).abs() > 1e-3);
    }
}

#[test]
fn m_step_floors_the_variance_of_a_tied_component() {
    let y = [-1.0, -1.0, -1.0, -0.2, -0.1];
    let resp = [1.0, 0.0, 1.0, 0.0, 1.0, 0.0, 0.0, 1.0, 0.0, 1.0];
    let m = m_step(&y, &resp, 2, 1e-4).unwrap();
    assert_eq!(m.components()[0].sigma, 1e-2);
    assert!((m.components()[1].sigma - 0.05).abs() < 1e-12);
    // An empty component is reported, not divided by zero.
    let empty = [1.0, 0.0].repeat(5);
    assert_eq!(m_step(&y, &empty, 2, 1e-4), None);
}

#[test]
fn e_step_survives_values_far_from_every_component() {
    // ln N underflows below about −745: at 60σ both densities are 0 in
    // linear space, but not in log space.
    let m = mixture(&[(0.5, -2.0, 1.0), (0.5, 1.0, 1.0)]);
    let y = [-60.0, 45.0, -0.5];
    let mut r = [0.0; 6];
    let ll = e_step(&y, &m, &mut r);
    assert!(ll.is_finite() && ll < -1000.0, "{ll}");
    assert!(r.iter().all(|x| x.is_finite()), "{r:?}");
    assert!(r[0] > 0.999_999 && r[3] > 0.999_999, "{r:?}");
    assert!(r.chunks(2).all(|r| (r[0] + r[1] - 1.0).abs() < 1e-15));
    assert_eq!(
        log_sum_exp([f64::NEG_INFINITY; 2].into_iter()),
        f64::NEG_INFINITY
    );
}

#[test]
fn collapse_and_the_start_helpers() {
    let m = mixture(&[(0.99, -2.0, 0.5), (0.01, 0.0, 0.01)]);
    // 0.01 · 100 = 1 value at the floor: a collapse onto one value.
    assert!(m.is_collapsed(100, (1e-4, &|_| 0.0), 3.0));
    // The same spike holding 10 values is a component.
    assert!(!m.is_collapsed(1000, (1e-4, &|_| 0.0), 3.0));
    // Less than one value's worth of weight, floor or not.
    let light = mixture(&[(0.9995, -2.0, 0.5), (0.0005, 0.0, 0.3)]);
    assert!(light.is_collapsed(1000, (1e-4, &|_| 0.0), 3.0));
    let sorted = [-3.0, -2.9, -2.8, -0.2, -0.1];
    assert_eq!(two_means_split(&sorted).map(|s| s.0), Some(3));
    assert_eq!(two_means_split(&[-1.0, -1.0]), None);
    assert_eq!(quantile(&sorted, 0.5), -2.8);
    assert!((quantile(&sorted, 0.875) - -0.15).abs() < 1e-12);
}

#[test]
fn starts_split_the_data_into_k_groups() {
    let y = [7.0, 0.1, 3.0, 0.0, 3.2, 6.9, 0.2, 3.1, 7.1];
    let start = kmeans_start(&y, 3, 1e-12).unwrap();
    let means: Vec<f64> = start.components().iter().map(|c| c.mean).collect();
    for (got, want) in means.iter().zip([0.1, 3.1, 7.0]) {
        assert!((got - want).abs() < 1e-12, "{means:?}");
    }
    assert!(start.components().iter().all(|c| c.weight == 1.0 / 3.0));
    let start = quantile_start(&y, 3, 1e-12).unwrap();
    let means: Vec<f64> = start.components().iter().map(|c| c.mean).collect();
    assert!(means.windows(2).all(|w| w[0] < w[1]), "{means:?}");
    // Fewer distinct values than components: no start.
    assert_eq!(kmeans_start(&[1.0, 1.0, 2.0], 3, 1e-12), None);
    assert_eq!(
        quantile_start(&[1.0, 1.0, 1.0, 1.0, 1.0, 2.0], 2, 1e-12),
        None
    );
    assert_eq!(kmeans_start(&y, 0, 1e-12), None);
    assert_eq!(quantile_start(&y, 0, 1e-12), None);
}

#[test]
fn collapsed_fits_lose_even_with_a_higher_likelihood() {
    // 50 values around −2 and one well above them.
    let mut rng = StdRng::seed_from_u64(17);
    let normal = Normal::new(-2.0, 0.3).unwrap();
    let mut y: Vec<f64> = (0..50).map(|_| normal.sample(&mut rng)).collect();
    y.push(-1.0);
    // Cut short, the broad start below is still two broad components;
    // left to run, EM walks it onto the spike too.
    let options = EmOptions {
        variance_floor: 1e-6,
        max_iterations: 30,
        ..OPTIONS
    };
    // A start with a spike on the lone top value stays there: a likelihood
    // the floor alone makes large.
    let spike = mixture(&[(50.0 / 51.0, -2.0, 0.3), (1.0 / 51.0, -1.0, 1e-3)]);
    let broad = mixture(&[(0.5, -2.2, 0.5), (0.5, -1.8, 0.5)]);
    let spike_run = em(&y, spike.clone(), &options, |_| {}).unwrap();
    let broad_run = em(&y, broad.clone(), &options, |_| {}).unwrap();
    assert!(
        spike_run.log_likelihood > broad_run.log_likelihood,
        "{spike_run:?} {broad_run:?}"
    );
    assert!(
        spike_run
            .mixture
            .is_collapsed(y.len(), (1e-6, &|_| 0.0), 3.0)
    );
    let (label, _) = best_fit(
        &y,
        &[("spike", spike.clone()), ("broad", broad)],
        &options,
        (3.0, &|_| 0.0),
    )
    .unwrap();
    assert_eq!(label, "broad");
    assert_eq!(
        best_fit(&y, &[("spike", spike)], &options, (3.0, &|_| 0.0)),
        None
    );
}

#[test]
fn components_sort_by_mean_and_invalid_ones_are_refused() {
    let m = mixture(&[(0.3, 0.0, 0.1), (0.7, -1.0, 0.2)]).sorted_by_mean();
    assert_eq!(
        m.components(),
        &[component(0.7, -1.0, 0.2), component(0.3, 0.0, 0.1)]
    );
    assert_eq!(NormalMixture::new(vec![]), Err(MixtureError::NoComponents));
    for bad in [
        component(0.0, 0.0, 1.0),
        component(f64::INFINITY, 0.0, 1.0),
        component(0.5, f64::NAN, 1.0),
        component(0.5, 0.0, 0.0),
        component(0.5, 0.0, -1.0),
    ] {
        let error = NormalMixture::new(vec![component(0.5, 0.0, 1.0), bad]);
        assert!(
            matches!(error, Err(MixtureError::InvalidComponent { index: 1, .. })),
            "{bad:?}"
        );
    }
}

#[test]
fn bic_counts_three_parameters_per_component_less_one() {
    let (n, ll) = (100.0, -250.0);
    for (k, parameters) in [(1, 2.0), (2, 5.0), (3, 8.0)] {
        assert_eq!(bic(k, n, ll), parameters * f64::ln(n) + 500.0);
    }
}

#[test]
fn accelerated_em_over_distinct_counts_reaches_plain_em_over_every_count() {
    // Log counts tie often; EM runs over the distinct values, weighed.
    let mut rng = StdRng::seed_from_u64(3);
    let y: Vec<f64> = (0..400)
        .map(|k| {
            let median: f64 = if k % 3 == 0 { 25.0 } else { 150.0 };
            let noise: f64 = Normal::new(0.0, 0.5).unwrap().sample(&mut rng);
            let count = (median.ln() + noise).exp().round().max(1.0);
            (count / 600.0).ln()
        })
        .collect();
    let start = mixture(&[(0.5, -3.0, 1.0), (0.5, -1.0, 1.0)]);
    let options = EmOptions {
        tolerance: 1e-11,
        max_iterations: 10_000,
        variance_floor: 1e-6,
    };
    let fit = em(&y, start.clone(), &options, |_| {}).unwrap();
    assert!(fit.converged, "{fit:?}");
    // The textbook iteration over every value, once each, unaccelerated,
    // to the same tolerance: the same fixed point, in more iterations.
    let mut naive = start;
    let mut r = vec![0.0; y.len() * 2];
    let mut iterations = 0;
    loop {
        iterations += 1;
        e_step(&y, &naive, &mut r);
        let next = m_step(&y, &r, 2, 1e-6).unwrap();
        let change = naive.max_abs_change(&next);
        naive = next;
        if change < 1e-11 {
            break;
        }
    }
    for (a, b) in fit.mixture.components().iter().zip(naive.components()) {
        assert!((a.weight - b.weight).abs() < 1e-8, "{a:?} {b:?}");
        assert!((a.mean - b.mean).abs() < 1e-8 && (a.sigma - b.sigma).abs() < 1e-8);
    }
    assert!(
        3 * fit.iterations < iterations,
        "{} iterations accelerated, {iterations} plain",
        fit.iterations
    );
    assert!((fit.log_likelihood - naive.log_likelihood(&y)).abs() < 1e-9);
}

#[test]
fn two_groups_of_near_ties_get_their_shares() {
    let y: Vec<f64> = (0..100)
        .map(|i| if i < 60 { -2.0 } else { 3.0 } + (i % 7) as f64 * 0.1)
        .collect();
    let options = EmOptions {
        tolerance: 1e-9,
        max_iterations: 500,
        variance_floor: 1e-6,
    };
    let fit = em(&y, quantile_start(&y, 2, 1e-6).unwrap(), &options, |_| {}).unwrap();
    let c = fit.mixture.components();
    assert!((c[0].weight - 0.6).abs() < 1e-6 && (c[1].mean - 3.3).abs() < 0.05);
}

#[test]
fn the_weighted_log_likelihood_is_the_sum_of_each_values_whatever_its_multiplicity() {
    // The E-step multiplies each value's share sums, in powers of its
    // multiplicity, and takes their logarithm once per run: the same as
    // the log-likelihood value by value, with multiplicities from 1 to
    // far beyond where a power would overflow.
    let m = mixture(&[(0.3, -2.0, 0.5), (0.5, 0.0, 1.0), (0.2, 1.5, 0.3)]);
    let values: Vec<f64> = (0..40).map(|k| -4.0 + 0.2 * k as f64).collect();
    let times: Vec<f64> = (0..40).map(|k| [1.0, 7.0, 900.0, 5000.0][k % 4]).collect();
    let mut r = vec![0.0; values.len() * 3];
    let ll = weighted_e_step(&values, &times, &m, &mut r);
    let mut terms = [0.0; 3];
    let expected: f64 = (values.iter().zip(&times))
        .map(|(&v, &t)| t * m.log_terms(v, &mut terms))
        .sum();
    assert!(
        (ll - expected).abs() <= 1e-12 * expected.abs(),
        "{ll} against {expected}"
    );
    let mut p = LnProduct::default();
    p.push_power(2.0, 3000.0, LnProduct::largest_power(2.0));
    assert!((p.ln() - 3000.0 * 2f64.ln()).abs() < 1e-9, "{}", p.ln());
}

/// Two overlapping components, 600 values: EM's rate is close to 1 there.
fn overlapping() -> (Vec<f64>, NormalMixture) {
    let mut rng = StdRng::seed_from_u64(11);
    let truth = mixture(&[(0.6, 0.0, 1.0), (0.4, 0.9, 0.6)]);
    let start = mixture(&[(0.5, -0.5, 1.0), (0.5, 1.5, 1.0)]);
    (sample(&mut rng, &truth, 600), start)
}

/// The free parameters' gradient is the log-likelihood's: against central
/// differences of it.
#[test]
fn the_gradient_is_the_log_likelihoods() {
    let (y, _) = overlapping();
    let (values, times) = tally(&y);
    let m = mixture(&[(0.3, -0.2, 0.8), (0.7, 0.7, 0.9)]);
    let mut run = EmRun {
        values: &values,
        times: &times,
        responsibilities: vec![0.0; values.len() * 2],
        floor: 1e-12,
        tolerance: 1e-9,
        iterations: 0,
    };
    let (_, g) = run.gradient(&m);
    let x = reduced(&m);
    for i in 0..x.len() {
        let at = |d: f64| {
            let mut z = x.clone();
            z[i] += d;
            from_reduced(&z, 0.0).unwrap().log_likelihood(&y)
        };
        let numeric = (at(1e-6) - at(-1e-6)) / 2e-6;
        assert!(
            (numeric - g[i]).abs() < 1e-5 * (1.0 + g[i].abs()),
            "{i}: {numeric} {}",
            g[i]
        );
    }
    // At the variance floor no Newton step is taken.
    let floored = mixture(&[(0.3, -0.2, 1e-6), (0.7, 0.7, 0.9)]);
    assert!(run.newton_step(&floored).is_none());
}

/// Where the components overlap, EM with SQUAREM creeps towards its fixed
/// point and stops when an iteration moves it by less than the tolerance,
/// still some way off; Newton steps near it land on it. The fit matches
/// plain EM run until it no longer moves, to a far tighter tolerance.
#[test]
fn newton_steps_land_on_the_fixed_point_em_creeps_towards() {
    let (y, start) = overlapping();
    let fit = em(&y, start.clone(), &OPTIONS, |_| {}).unwrap();
    assert!(fit.converged, "{fit:?}");
    let mut naive = start;
    let mut r = vec![0.0; y.len() * 2];
    for _ in 0..100_000 {
        e_step(&y, &naive, &mut r);
        let next = m_step(&y, &r, 2, OPTIONS.variance_floor).unwrap();
        let change = naive.max_abs_change(&next);
        naive = next;
        if change < 1e-15 {
            break;
        }
    }
    let off = fit.mixture.max_abs_change(&naive);
    assert!(off < 1e-9, "{off:e}: {fit:?} against {naive:?}");
}
