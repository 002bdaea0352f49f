use super::*;
use rand::SeedableRng;
use rand::rngs::StdRng;
use rand_distr::{Distribution, Uniform};
use statrs::distribution::{Continuous, Normal as StatrsNormal};

fn component(weight: f64, mean: f64, sigma: f64) -> NormalComponent {
    NormalComponent {
        weight,
        mean,
        sigma,
    }
}

/// The crossing of two weighted normals by scanning the log-odds for a
/// sign change from − to + between the means and bisecting: no use of the
/// quadratic.
pub(crate) fn brute_force_crossing(low: &NormalComponent, high: &NormalComponent) -> Option<f64> {
    let n0 = StatrsNormal::new(low.mean, low.sigma).unwrap();
    let n1 = StatrsNormal::new(high.mean, high.sigma).unwrap();
    let log_odds = |y: f64| (high.weight.ln() + n1.ln_pdf(y)) - (low.weight.ln() + n0.ln_pdf(y));
    let steps = 20_000;
    let h = (high.mean - low.mean) / steps as f64;
    let mut crossing = None;
    for i in 0..steps {
        let (mut lo, mut hi) = (low.mean + i as f64 * h, low.mean + (i + 1) as f64 * h);
        if !(log_odds(lo) < 0.0 && log_odds(hi) >= 0.0) {
            continue;
        }
        for _ in 0..200 {
            let mid = 0.5 * (lo + hi);
            if log_odds(mid) < 0.0 {
                lo = mid
            } else {
                hi = mid
            }
        }
        assert!(
            crossing.is_none(),
            "two ascending crossings in {low:?}, {high:?}"
        );
        crossing = Some(0.5 * (lo + hi));
    }
    crossing
}

#[test]
fn closed_form_crossing_matches_a_brute_force_scan() {
    let mut rng = StdRng::seed_from_u64(5);
    let u = |rng: &mut StdRng, a: f64, b: f64| Uniform::new(a, b).unwrap().sample(rng);
    let (mut with, mut without) = (0, 0);
    for _ in 0..300 {
        let m0 = u(&mut rng, -4.0, -1.0);
        let w1 = u(&mut rng, 0.02, 0.98);
        let m1 = m0 + u(&mut rng, 0.2, 4.0);
        let (s0, s1) = (u(&mut rng, 0.05, 1.5), u(&mut rng, 0.05, 1.5));
        let (low, high) = (component(1.0 - w1, m0, s0), component(w1, m1, s1));
        match (crossing(&low, &high), brute_force_crossing(&low, &high)) {
            (Some(a), Some(b)) => {
                assert!((a - b).abs() < 1e-9, "{low:?} {high:?}: {a} vs {b}");
                let odds = high.log_weighted_density(a) - low.log_weighted_density(a);
                assert!(odds.abs() < 1e-9);
                with += 1;
            }
            (None, None) => without += 1,
            (a, b) => panic!("{low:?} {high:?}: closed form {a:?}, scan {b:?}"),
        }
    }
    assert!(
        with > 50 && without > 10,
        "{with} with, {without} without a crossing"
    );
}

#[test]
fn equal_sigmas_use_the_linear_formula() {
    let (m0, m1, s) = (-3.0, -1.0, 0.4);
    let (w0, w1) = (0.7, 0.3);
    // Equal σ: y* = (μ₀ + μ₁)/2 − σ² ln(π₁/π₀) / (μ₁ − μ₀).
    let expected = 0.5 * (m0 + m1) - s * s * f64::ln(w1 / w0) / (m1 - m0);
    let low = component(w0, m0, s);
    for s1 in [s, s * (1.0 + 1e-15), s * (1.0 - 1e-13)] {
        let y = crossing(&low, &component(w1, m1, s1)).unwrap();
        assert!((y - expected).abs() < 1e-10, "σ₁ = {s1}: {y} vs {expected}");
    }
    // Nearly equal σ: still the quadratic, with a tiny leading coefficient,
    // where the root is prone to cancellation.
    for s1 in [s * (1.0 + 1e-9), s * (1.0 - 1e-8), s * (1.0 + 1e-6)] {
        let high = component(w1, m1, s1);
        let (y, scan) = (
            crossing(&low, &high).unwrap(),
            brute_force_crossing(&low, &high).unwrap(),
        );
        assert!((y - scan).abs() < 1e-11, "σ₁ = {s1}: {y} vs {scan}");
    }
    // The upper component given first: no crossing between the means.
    assert_eq!(crossing(&component(w1, m1, s), &low), None);
}

#[test]
fn quadratic_roots_are_stable() {
    // t² − 1e8 t + 1 = 0: the small root 1e-8 is lost to cancellation by
    // the textbook formula.
    let roots = quadratic_roots(1.0, -1e8, 1.0);
    let small = roots
        .iter()
        .flatten()
        .copied()
        .fold(f64::INFINITY, f64::min);
    assert!((small - 1e-8).abs() < 1e-22, "{roots:?}");
    // The same with b > 0, where the other sign of the formula cancels.
    let roots = quadratic_roots(1.0, 1e8, 1.0);
    let small = roots
        .iter()
        .flatten()
        .copied()
        .fold(f64::NEG_INFINITY, f64::max);
    assert!((small + 1e-8).abs() < 1e-22, "{roots:?}");
    assert_eq!(quadratic_roots(1.0, 0.0, 1.0), [None, None]);
    assert_eq!(linear_root(2.0, -3.0), [Some(1.5), None]);
    assert_eq!(linear_root(0.0, 1.0), [None, None]);
}

#[test]
fn ashman_d_of_two_components() {
    // √2 · 2 / √(0.25 + 0.25) = 4, whichever comes first.
    let (a, b) = (component(0.8, -3.0, 0.5), component(0.2, -1.0, 0.5));
    assert!((ashman_d(&a, &b) - 4.0).abs() < 1e-15);
    assert!((ashman_d(&b, &a) - 4.0).abs() < 1e-15);
}
