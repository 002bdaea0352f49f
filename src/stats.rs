//! The χ² goodness-of-fit test of an optimised pose graph (Lee & Pollefeys,
//! ICRA 2014, §II-C and Table I).
//!
//! After optimisation, the total Mahalanobis distance
//! `D² = Σ ‖z_ij − h(x_i*, x_j*)‖²_Q` (the paper's Eq. 9, i.e. the graph's χ²)
//! is compared with the upper-α critical value of χ²(dof). If every
//! measurement is right and the covariances are honest, `D²` follows that
//! distribution, so `D² > critical` means "more misfit than chance explains":
//! the paper's sign that wrong loop closures got in (its *degenerate case*).
//!
//! Two conventions for the degrees of freedom are in use, see
//! [`DofConvention`].
//!
//! # Accuracy of the critical value
//!
//! [`chi2_critical`] starts from statrs' `ChiSquared::inverse_cdf`, which is
//! accurate (relative error ≤ 2e-10 against SciPy, better than 1e-13 for
//! dof ≥ 1000 up to 10⁶) and fast (< 1 ms at dof = 10⁶). Two things are
//! added on top: a few guarded Newton steps on the log tail probability,
//! which bring it to machine precision, and a Wilson–Hilferty start for
//! α < ~1e-16, where `1 − α` rounds to 1 and statrs would return +∞.

use serde::Serialize;
use statrs::distribution::{ChiSquared, Continuous, ContinuousCDF};
use statrs::function::erf::erfc_inv;
use std::f64::consts::SQRT_2;

/// Errors from the χ² test.
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
pub enum StatsError {
    /// χ² with zero degrees of freedom has no critical value.
    #[error("the chi-squared test needs at least one degree of freedom, got 0")]
    ZeroDof,
    /// The residual degrees of freedom (`Σ edge dimensions − free pose
    /// parameters`) are not positive: the graph has no redundancy, so `D²`
    /// carries no evidence either way.
    #[error(
        "the residual degrees of freedom are {0} (no more residuals than free parameters); \
         the chi-squared test has nothing to test"
    )]
    NoResidualDof(i64),
    /// The significance level must lie strictly between 0 and 1.
    #[error("the significance level alpha must lie in (0, 1), got {0}")]
    InvalidAlpha(f64),
    /// `D²` must be a finite, non-negative number.
    #[error("the Mahalanobis distance D² must be finite and non-negative, got {0}")]
    InvalidDistance(f64),
    /// The quantile could not be computed (should not happen for valid input).
    #[error("could not compute the chi-squared critical value for dof {dof}, alpha {alpha}")]
    Numerical {
        /// Degrees of freedom asked for.
        dof: u64,
        /// Significance level asked for.
        alpha: f64,
    },
}

/// Which degrees of freedom the χ² test uses.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum DofConvention {
    /// The paper's choice (§II-C): `K` = the number of measured constraints.
    Constraints,
    /// The textbook choice: `Σ edge dimensions − free pose parameters`, the
    /// number of residuals minus the number of parameters fitted to them.
    /// It is the expected value of `D²` at the optimum when the model is
    /// right.
    #[default]
    Residual,
}

/// The upper-α critical value of χ²(`dof`): the `x` with `P(χ² > x) = α`,
/// i.e. the `(1 − α)` quantile.
///
/// Errors for `dof = 0` or `alpha` outside `(0, 1)`.
///
/// ```ignore
/// use pgo::stats::chi2_critical;
/// // Table I of the paper: 1589 constraints at α = 0.05 → 1.6828e3.
/// let x = chi2_critical(1589, 0.05).unwrap();
/// assert!((x - 1682.8).abs() < 0.05);
/// ```
pub fn chi2_critical(dof: u64, alpha: f64) -> Result<f64, StatsError> {
    if dof == 0 {
        return Err(StatsError::ZeroDof);
    }
    if !(alpha > 0.0 && alpha < 1.0) {
        return Err(StatsError::InvalidAlpha(alpha));
    }
    let numerical = StatsError::Numerical { dof, alpha };
    // u64 → f64 is exact up to 2⁵³, far beyond any pose graph.
    let k = dof as f64;
    let dist = ChiSquared::new(k).map_err(|_| numerical.clone())?;

    let from_statrs = dist.inverse_cdf(1.0 - alpha);
    let start = if from_statrs.is_finite() && from_statrs > 0.0 {
        from_statrs
    } else {
        wilson_hilferty(k, alpha)
    };
    if !(start.is_finite() && start > 0.0) {
        return Err(numerical);
    }
    let x = polish_quantile(&dist, start, alpha);
    if x.is_finite() && x > 0.0 {
        Ok(x)
    } else {
        Err(numerical)
    }
}

/// The upper-α standard normal quantile `z = Φ⁻¹(1 − α)`, written with
/// erfc⁻¹ so that it stays accurate for tiny α.
///
/// ```ignore
/// let z = pgo::stats::normal_upper_quantile(0.025);
/// assert!((z - 1.959964).abs() < 1e-6);
/// ```
pub fn normal_upper_quantile(alpha: f64) -> f64 {
    SQRT_2 * erfc_inv(2.0 * alpha)
}

/// The Wilson–Hilferty approximation of the upper-α critical value:
/// `(χ²/k)^(1/3)` is close to normal with mean `1 − 2/(9k)` and variance
/// `2/(9k)`. Relative error is O(1/k); used as a start and as a check.
/// May be ≤ 0 for small `k` and `alpha` near 1.
fn wilson_hilferty(k: f64, alpha: f64) -> f64 {
    let z = normal_upper_quantile(alpha);
    let h = 2.0 / (9.0 * k);
    k * (1.0 - h + z * h.sqrt()).powi(3)
}

/// Newton steps on the log of the tail probability on the better-conditioned
/// side (`ln sf(x) = ln α` for α ≤ ½, `ln cdf(x) = ln(1 − α)` otherwise; both
/// right-hand sides are exact there). A step is kept only if it reduces the
/// residual, so this can only improve `x`.
fn polish_quantile(dist: &ChiSquared, mut x: f64, alpha: f64) -> f64 {
    let upper = alpha <= 0.5;
    let target = if upper {
        alpha.ln()
    } else {
        (1.0 - alpha).ln()
    };
    let residual = |x: f64| {
        let tail = if upper { dist.sf(x) } else { dist.cdf(x) };
        (tail, tail.ln() - target)
    };
    let (mut tail, mut r) = residual(x);
    for _ in 0..20 {
        let pdf = dist.pdf(x);
        if !(tail > 0.0 && pdf > 0.0 && r.is_finite()) || r == 0.0 {
            break;
        }
        // d/dx ln sf = −pdf/sf, d/dx ln cdf = pdf/cdf.
        let step = r * tail / pdf;
        let next = if upper { x + step } else { x - step };
        if !(next.is_finite() && next > 0.0) {
            break;
        }
        let (next_tail, next_r) = residual(next);
        // Stop once rounding noise stops the residual from shrinking.
        if next_r.is_nan() || next_r.abs() >= r.abs() {
            break;
        }
        (x, tail, r) = (next, next_tail, next_r);
    }
    x
}

/// The outcome of the χ² goodness-of-fit test on an optimised graph.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Chi2Test {
    /// Total Mahalanobis distance `D²` after optimisation (Eq. 9).
    pub d2: f64,
    /// Degrees of freedom actually used (chosen by `dof_convention`).
    pub dof: u64,
    /// Which convention chose `dof`.
    pub dof_convention: DofConvention,
    /// The paper's degrees of freedom: the number of constraints.
    pub dof_constraints: u64,
    /// Residual degrees of freedom: `Σ edge dimensions − free pose
    /// parameters` (may be ≤ 0 when reported under the other convention).
    pub dof_residual: i64,
    /// Significance level α.
    pub alpha: f64,
    /// Upper-α critical value of χ²(`dof`).
    pub critical: f64,
    /// `P(χ²(dof) > D²)`: how likely this much misfit is by chance.
    pub p_value: f64,
    /// Whether the graph passes: `D² ≤ critical`.
    pub passed: bool,
}

impl Chi2Test {
    /// Runs the test: `passed = d2 ≤ χ²_critical(dof, alpha)`.
    ///
    /// `dof_residual ≤ 0` is an error ([`StatsError::NoResidualDof`]) only
    /// under [`DofConvention::Residual`]; under `Constraints` it is just
    /// reported.
    ///
    /// ```ignore
    /// use pgo::stats::{Chi2Test, DofConvention};
    /// // Table I, "Degenerated": D² = 4871.5 with 1589 constraints fails.
    /// let t = Chi2Test::new(4871.5, 1589, 1200, DofConvention::Constraints, 0.05).unwrap();
    /// assert_eq!(t.dof, 1589);
    /// assert!(!t.passed);
    /// ```
    pub fn new(
        d2: f64,
        dof_constraints: u64,
        dof_residual: i64,
        dof_convention: DofConvention,
        alpha: f64,
    ) -> Result<Chi2Test, StatsError> {
        if !(d2.is_finite() && d2 >= 0.0) {
            return Err(StatsError::InvalidDistance(d2));
        }
        let dof = match dof_convention {
            DofConvention::Constraints => dof_constraints,
            DofConvention::Residual => match u64::try_from(dof_residual) {
                Ok(dof) if dof > 0 => dof,
                _ => return Err(StatsError::NoResidualDof(dof_residual)),
            },
        };
        let critical = chi2_critical(dof, alpha)?;
        let p_value = ChiSquared::new(dof as f64)
            .map(|d| d.sf(d2))
            .map_err(|_| StatsError::Numerical { dof, alpha })?;
        Ok(Chi2Test {
            d2,
            dof,
            dof_convention,
            dof_constraints,
            dof_residual,
            alpha,
            critical,
            p_value,
            passed: d2 <= critical,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Reference values from SciPy 1.17.1, `scipy.stats.chi2.isf(alpha, dof)`.
    const SCIPY: &[(u64, f64, f64)] = &[
        (1, 0.05, 3.8414588206941285),
        (1, 1e-6, 23.928126976934827),
        (1, 0.95, 0.003932140000019531),
        (2, 0.05, 5.991464547107983),
        (5, 0.025, 12.83250199403003),
        (10, 0.01, 23.20925115895436),
        (100, 0.5, 99.33412923598846),
        (1589, 0.05, 1682.8496020082057),
        (1589, 1e-6, 1871.5060764034274),
        (9713, 0.05, 9943.386455227124),
        (12840, 0.05, 13104.719594668884),
        (17506, 0.05, 17814.909511763613),
        (17506, 0.95, 17199.364532127165),
        (100_000, 0.05, 100736.736177319),
        (1_000_000, 0.05, 1002327.310781219),
        (1_000_000, 1e-6, 1006736.7596362906),
        (1_000_000, 0.95, 997674.9632764738),
    ];

    #[test]
    fn critical_values_match_scipy() {
        for &(dof, alpha, expected) in SCIPY {
            let x = chi2_critical(dof, alpha).unwrap();
            let rel = (x - expected).abs() / expected;
            assert!(
                rel < 1e-12,
                "dof {dof} alpha {alpha}: {x} vs {expected} (rel {rel:e})"
            );
        }
    }

    #[test]
    fn two_dof_has_a_closed_form() {
        // χ²(2) is exponential with mean 2: the critical value is −2 ln α,
        // also for α so small that 1 − α rounds to 1.
        for alpha in [0.5, 0.05, 1e-3, 1e-10, 1e-16, 1e-20, 1e-100] {
            let x = chi2_critical(2, alpha).unwrap();
            let expected = -2.0 * f64::ln(alpha);
            assert!(
                (x - expected).abs() <= 1e-12 * expected,
                "alpha {alpha}: {x} vs {expected}"
            );
        }
    }

    #[test]
    fn large_dof_agrees_with_wilson_hilferty() {
        // Wilson–Hilferty's relative error shrinks like 1/dof; at these sizes
        // it is far below 1e-4.
        for dof in [1000u64, 1589, 9713, 12840, 17506, 100_000, 1_000_000] {
            for alpha in [0.1, 0.05, 0.025, 0.01] {
                let x = chi2_critical(dof, alpha).unwrap();
                let wh = wilson_hilferty(dof as f64, alpha);
                let rel = (x - wh).abs() / x;
                assert!(rel < 1e-5, "dof {dof} alpha {alpha}: {x} vs WH {wh}");
            }
        }
    }

    /// `table` is given to 5 significant digits: it must be the rounding of `x`.
    fn rounds_to(x: f64, table: f64) -> bool {
        let ulp = 10f64.powf(table.abs().log10().floor() - 4.0);
        (x - table).abs() <= 0.5 * ulp
    }

    #[test]
    fn paper_table_one() {
        // (dataset, DOF, χ²_{α=0.05}, D², passes)
        let table = [
            ("Wolfsburg", 12840, 1.3105e4, 4.1249e3, true),
            ("Carpark", 17506, 1.7815e4, 1.0325e4, true),
            ("New College", 9713, 9.9434e3, 644.7097, true),
            ("Degenerated", 1589, 1.6828e3, 4.8715e3, false),
        ];
        for (name, dof, critical, d2, passes) in table {
            let t = Chi2Test::new(d2, dof, 0, DofConvention::Constraints, 0.05).unwrap();
            assert!(
                rounds_to(t.critical, critical),
                "{name}: {} vs {critical}",
                t.critical
            );
            assert_eq!(t.passed, passes, "{name}");
            assert_eq!(t.dof, dof);
            assert!((t.p_value < 0.05) != passes, "{name}: p = {}", t.p_value);
        }
    }

    #[test]
    fn rounding_check_is_strict() {
        assert!(rounds_to(13104.72, 1.3105e4));
        assert!(!rounds_to(13104.0, 1.3105e4));
    }

    #[test]
    fn critical_value_decreases_with_alpha_and_grows_with_dof() {
        let alphas = [0.9, 0.5, 0.2, 0.1, 0.05, 0.025, 0.01, 1e-3, 1e-6, 1e-12];
        for dof in [1u64, 3, 30, 1589, 100_000] {
            let xs: Vec<f64> = alphas
                .iter()
                .map(|&a| chi2_critical(dof, a).unwrap())
                .collect();
            assert!(xs.windows(2).all(|w| w[0] < w[1]), "dof {dof}: {xs:?}");
        }
        for alpha in [0.5, 0.05, 1e-6] {
            let xs: Vec<f64> = [1u64, 2, 5, 50, 500, 5000, 50_000]
                .iter()
                .map(|&k| chi2_critical(k, alpha).unwrap())
                .collect();
            assert!(xs.windows(2).all(|w| w[0] < w[1]), "alpha {alpha}: {xs:?}");
        }
    }

    #[test]
    fn critical_value_has_the_right_tail_probability() {
        for dof in [1u64, 4, 77, 3000] {
            for alpha in [0.3, 0.05, 1e-4] {
                let x = chi2_critical(dof, alpha).unwrap();
                let sf = ChiSquared::new(dof as f64).unwrap().sf(x);
                assert!(
                    (sf - alpha).abs() < 1e-12 * alpha.max(1e-3),
                    "dof {dof} alpha {alpha}: sf {sf}"
                );
            }
        }
    }

    #[test]
    fn invalid_inputs_are_errors() {
        assert_eq!(chi2_critical(0, 0.05), Err(StatsError::ZeroDof));
        for alpha in [0.0, 1.0, -0.1, 1.5, f64::NAN, f64::INFINITY] {
            assert!(
                matches!(chi2_critical(10, alpha), Err(StatsError::InvalidAlpha(_))),
                "{alpha}"
            );
        }
        for d2 in [-1.0, f64::NAN, f64::INFINITY] {
            let r = Chi2Test::new(d2, 10, 10, DofConvention::Residual, 0.05);
            assert!(matches!(r, Err(StatsError::InvalidDistance(_))), "{d2}");
        }
        assert_eq!(
            Chi2Test::new(1.0, 10, 0, DofConvention::Residual, 0.05),
            Err(StatsError::NoResidualDof(0))
        );
        assert_eq!(
            Chi2Test::new(1.0, 10, -3, DofConvention::Residual, 0.05),
            Err(StatsError::NoResidualDof(-3))
        );
        assert_eq!(
            Chi2Test::new(1.0, 0, 5, DofConvention::Constraints, 0.05),
            Err(StatsError::ZeroDof)
        );
    }

    #[test]
    fn conventions_pick_their_dof() {
        let r = Chi2Test::new(50.0, 40, 60, DofConvention::Residual, 0.05).unwrap();
        assert_eq!((r.dof, r.dof_constraints, r.dof_residual), (60, 40, 60));
        assert!(r.passed);
        let c = Chi2Test::new(50.0, 40, 60, DofConvention::Constraints, 0.05).unwrap();
        assert_eq!(c.dof, 40);
        // χ²(40) at α = 0.05 is 55.76: 50 passes, 60 fails.
        assert!(c.passed);
        assert!(
            !Chi2Test::new(60.0, 40, 60, DofConvention::Constraints, 0.05)
                .unwrap()
                .passed
        );
        // Non-positive residual dof is fine under the paper's convention.
        let p = Chi2Test::new(5.0, 12, -6, DofConvention::Constraints, 0.05).unwrap();
        assert_eq!((p.dof, p.dof_residual), (12, -6));
    }

    #[test]
    fn boundary_d2_equal_to_critical_passes() {
        let x = chi2_critical(25, 0.05).unwrap();
        assert!(
            Chi2Test::new(x, 25, 25, DofConvention::Residual, 0.05)
                .unwrap()
                .passed
        );
        assert!(
            !Chi2Test::new(x * (1.0 + 1e-12), 25, 25, DofConvention::Residual, 0.05)
                .unwrap()
                .passed
        );
        assert!(
            Chi2Test::new(0.0, 25, 25, DofConvention::Residual, 0.05)
                .unwrap()
                .passed
        );
    }

    #[test]
    fn convention_serializes_lowercase() {
        assert_eq!(
            serde_json::to_string(&DofConvention::Constraints).unwrap(),
            "\"constraints\""
        );
        assert_eq!(
            serde_json::to_string(&DofConvention::Residual).unwrap(),
            "\"residual\""
        );
        assert_eq!(DofConvention::default(), DofConvention::Residual);
    }
}
