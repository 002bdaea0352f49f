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
//! [`chi2_critical`] starts from statrs' `ChiSquared::inverse_cdf`. Two
//! things are added on top: a few guarded Newton steps on the log tail
//! probability, which bring it to machine precision, and a Wilson–Hilferty
//! start for α < ~1e-16, where `1 − α` rounds to 1 and statrs would return
//! +∞.

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
    /// ```
    /// use pgo::{Chi2Test, DofConvention};
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
mod tests;
