use super::*;
use statrs::distribution::{ChiSquared, Continuous};
use std::f64::consts::PI;

#[test]
fn digamma_matches_closed_forms() {
    // ψ(1) = −γ, ψ(3/2) = 2 − γ − 2 ln 2.
    let gamma = 0.577_215_664_901_532_9;
    assert!((digamma(1.0) + gamma).abs() < 1e-11);
    assert!((digamma(1.5) - (2.0 - gamma - 2.0 * std::f64::consts::LN_2)).abs() < 1e-11);
}

#[test]
fn trigamma_matches_closed_forms() {
    assert!((trigamma(1.0) - PI * PI / 6.0).abs() < 1e-11);
    assert!((trigamma(3.0) - (PI * PI / 6.0 - 1.25)).abs() < 1e-11);
    assert!((trigamma(0.5) - PI * PI / 2.0).abs() < 1e-10);
}

/// `∫ yᵏ f(y) dy` for k = 0, 1, 2 by the midpoint rule over ±60 around
/// `mean`.
fn moments(table: &LogChi2, mean: f64, sigma: f64) -> [f64; 3] {
    let h = 1e-3;
    let mut m = [0.0; 3];
    for i in 0..120_000 {
        let y = mean - 60.0 + (i as f64 + 0.5) * h;
        let f = table.ln_density(y, mean, sigma).exp() * h;
        m[0] += f;
        m[1] += f * y;
        m[2] += f * y * y;
    }
    m
}

#[test]
fn with_one_scale_it_is_the_density_of_the_log_of_a_scaled_chi2() {
    for dof in [3, 6] {
        let table = LogChi2::of(dof);
        let chi2 = ChiSquared::new(dof as f64).unwrap();
        // ν² = s²·χ²: y = ln s² + ln χ², f(y) = f_χ²(e^{y − ln s²})·e^{y − ln s²}.
        let ln_s2: f64 = 1.7;
        let mean = ln_s2 + ln_chi2_mean(dof);
        for y in [-4.0, -1.0, 0.0, 1.0, 2.0, 3.0, 4.0] {
            let x = (y - ln_s2).exp();
            let exact = (chi2.pdf(x) * x).ln();
            let got = table.ln_density(y, mean, ln_chi2_sigma(dof));
            assert!(
                (got - exact).abs() < 1e-2,
                "{dof} {y}: {got} against {exact}"
            );
        }
    }
}

#[test]
fn the_density_has_mass_one_and_the_mean_and_spread_it_is_given() {
    for dof in [3, 6] {
        let table = LogChi2::of(dof);
        let floor = ln_chi2_sigma(dof);
        for sigma in [floor, floor * 1.01, 1.2, 2.0, 3.5, 4.5] {
            let mean = -2.5;
            let [m0, m1, m2] = moments(&table, mean, sigma);
            let sd = (m2 / m0 - (m1 / m0).powi(2)).sqrt();
            assert!((m0 - 1.0).abs() < 1e-3, "{dof} {sigma}: mass {m0}");
            assert!(
                (m1 / m0 - mean).abs() < 1e-2,
                "{dof} {sigma}: mean {}",
                m1 / m0
            );
            assert!((sd - sigma).abs() < 1e-2, "{dof} {sigma}: sd {sd}");
        }
    }
}

#[test]
fn its_left_tail_is_heavier_than_a_normal_and_its_right_tail_lighter() {
    // What a normal of the same mean and spread gets wrong (module doc).
    let table = LogChi2::of(3);
    let sigma: f64 = 1.2;
    let normal = |z: f64| -0.5 * z * z - sigma.ln() - 0.5 * (2.0 * PI).ln();
    assert!(table.ln_density(-4.0 * sigma, 0.0, sigma) > normal(-4.0) + 2.0);
    assert!(table.ln_density(4.0 * sigma, 0.0, sigma) < normal(4.0) - 1.0);
}

#[test]
fn beyond_the_table_the_density_continues_smoothly() {
    let table = LogChi2::of(3);
    // In τ: the normal taken beyond MAX_TAU is close to the table's last row.
    let sigma = (MAX_TAU * MAX_TAU + trigamma(1.5)).sqrt();
    for y in [-3.0, 0.0, 3.0] {
        let inside = table.ln_density(y, 0.0, sigma - 1e-9);
        let outside = table.ln_density(y, 0.0, sigma + 1e-9);
        assert!((inside - outside).abs() < 0.02, "{y}: {inside} {outside}");
    }
    // In y: far left it keeps rising along its exponential tail, far
    // right it keeps falling.
    let s = 1.5;
    let (a, b, c) = (
        table.ln_density(-30.0, 0.0, s),
        table.ln_density(-25.0, 0.0, s),
        table.ln_density(-20.0, 0.0, s),
    );
    assert!(
        a < b && b < c && ((c - b) - (b - a)).abs() < 0.1,
        "{a} {b} {c}"
    );
    assert!(table.ln_density(40.0, 0.0, s) <= table.ln_density(30.0, 0.0, s));
    assert!(table.ln_density(30.0, 0.0, s) < table.ln_density(10.0, 0.0, s));
}

#[test]
fn ln_chi2_sigma_is_the_root_of_trigamma_at_half_the_dof() {
    // ψ₁(3/2) = π²/2 − 4.
    let s = ln_chi2_sigma(3);
    assert!((s * s - (PI * PI / 2.0 - 4.0)).abs() < 1e-10);
}

#[test]
fn the_blended_row_is_the_density_it_was_blended_from() {
    for dof in [3, 6] {
        let table = LogChi2::of(dof);
        // Spreads on a row of the table, between two, and beyond it.
        let floor = ln_chi2_sigma(dof);
        for sigma in [floor, floor + 0.013, 1.7, 2.9, 5.0] {
            let density = table.with(0.4, sigma);
            let blended = density.blended();
            for i in 0..=2000 {
                let y = -30.0 + 0.0271 * i as f64;
                let (a, b) = (density.ln(y), blended.ln(y));
                if a.is_finite() || b.is_finite() {
                    assert!(
                        (a - b).abs() <= 1e-12 * a.abs().max(1.0),
                        "{dof} {sigma} {y}: {a} {b}"
                    );
                }
            }
        }
    }
}

#[test]
fn the_upper_tail_of_one_scale_is_the_chi2_survival_function() {
    use statrs::distribution::ContinuousCDF;
    for dof in [3, 6] {
        let table = LogChi2::of(dof);
        let chi2 = ChiSquared::new(dof as f64).unwrap();
        let ln_s2: f64 = -2.3;
        let density = table.with(ln_s2 + ln_chi2_mean(dof), ln_chi2_sigma(dof));
        // From the bulk far out into the tail where the loop model tests
        // the accepted loops (χ² tails down to 10⁻¹⁵).
        for y in [-6.0, -3.0, -1.0, 0.0, 0.5, 1.0, 1.5, 2.0] {
            let exact = chi2.sf((y - ln_s2).exp());
            let got = density.upper_tail(y);
            assert!(
                (got / exact - 1.0).abs() < 2e-2,
                "{dof} {y}: {got} against {exact}"
            );
        }
        assert!((density.upper_tail(-40.0) - 1.0).abs() < 1e-3);
    }
}

#[test]
fn the_upper_tail_is_the_mass_above_and_falls_with_y() {
    for dof in [3, 6] {
        let table = LogChi2::of(dof);
        for sigma in [1.2, 2.0, 4.5] {
            let density = table.with(1.0, sigma);
            // The midpoint rule on ln f from y up, against the tail.
            let h = 1e-3;
            let mut previous = f64::INFINITY;
            for y in [-3.0, 0.0, 1.0, 3.0, 5.0, 8.0] {
                let mass: f64 = (0..40_000)
                    .map(|i| (table.ln_density(y + (i as f64 + 0.5) * h, 1.0, sigma)).exp() * h)
                    .sum();
                let tail = density.upper_tail(y);
                assert!(
                    (tail - mass).abs() < 1e-4 * mass.max(1e-3),
                    "{dof} {sigma} {y}: {tail} against {mass}"
                );
                assert!(tail < previous);
                previous = tail;
            }
        }
    }
}
