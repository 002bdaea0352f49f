//! How far apart two weighted normal components are: Ashman's D, and the
//! point between their means where their weighted densities cross (where
//! the upper component becomes the more probable explanation).

use super::mixture::NormalComponent;

/// Ashman's D of two cleanly separated normals: a mixture of two normals of
/// equal weights is bimodal only beyond it. The gate asks it of its two
/// components, the loop model of each wrong population against the true
/// loops.
pub const CLEAN_SEPARATION: f64 = 2.0;

/// Ashman's D = √2·|μ₁ − μ₀| / √(σ₀² + σ₁²) of two components; above 2
/// they are cleanly separated (a mixture of two normals is bimodal only for
/// D > 2, with equal weights).
pub fn ashman_d(a: &NormalComponent, b: &NormalComponent) -> f64 {
    std::f64::consts::SQRT_2 * (b.mean - a.mean).abs() / a.sigma.hypot(b.sigma)
}

/// The `y*` in `(μ_low, μ_high)` where `π_high N_high(y)` overtakes
/// `π_low N_low(y)`, or `None` when the weighted densities do not cross
/// there (or `μ_low ≥ μ_high`). Solved in closed form.
///
/// With `t = y − μ₀` and `d = μ₁ − μ₀` (0 the lower component, 1 the
/// upper), the log-odds `ln(π₁N₁) − ln(π₀N₀)` are the quadratic
/// `g(t) = a t² + b t + c` with
/// `a = 1/(2σ₀²) − 1/(2σ₁²)`, `b = d/σ₁²`,
/// `c = ln(π₁σ₀ / (π₀σ₁)) − d²/(2σ₁²)`.
/// Shifting to `μ₀` keeps the coefficients small. Between the means `g`
/// is strictly increasing (`g'` is linear, `g'(0) = d/σ₁² > 0` and
/// `g'(d) = d/σ₀² > 0`), so there is at most one root there, a crossing
/// exists exactly when `g(0) < 0 < g(d)`, and values above it are more
/// likely from the upper component.
pub fn crossing(low: &NormalComponent, high: &NormalComponent) -> Option<f64> {
    let (m0, m1) = (low.mean, high.mean);
    let (s0, s1) = (low.sigma, high.sigma);
    let (w0, w1) = (low.weight, high.weight);
    let d = m1 - m0;
    if d.is_nan() || d <= 0.0 {
        return None;
    }
    let (v0, v1) = (s0 * s0, s1 * s1);
    let a = 0.5 / v0 - 0.5 / v1;
    let b = d / v1;
    let c = (w1.ln() - w0.ln()) + (s0.ln() - s1.ln()) - 0.5 * d * d / v1;
    // Over the interval the quadratic term changes g by at most |a|d²,
    // the linear term by bd: when the former is negligible, the equation
    // is linear (equal σ).
    let roots = if a.abs() * d <= 1e-12 * b.abs() {
        linear_root(b, c)
    } else {
        quadratic_roots(a, b, c)
    };
    roots
        .into_iter()
        .flatten()
        .find(|&t| t > 0.0 && t < d)
        .map(|t| m0 + t)
}

/// The root of `b t + c = 0`.
fn linear_root(b: f64, c: f64) -> [Option<f64>; 2] {
    [(b != 0.0).then(|| -c / b), None]
}

/// The real roots of `a t² + b t + c = 0` (`a ≠ 0`) by the stable formula
/// `q = −(b + sign(b)√disc)/2`, roots `q/a` and `c/q`: no cancellation
/// between `−b` and `√disc`.
fn quadratic_roots(a: f64, b: f64, c: f64) -> [Option<f64>; 2] {
    let disc = b * b - 4.0 * a * c;
    if disc.is_nan() || disc < 0.0 {
        return [None, None];
    }
    let q = -0.5 * (b + b.signum() * disc.sqrt());
    if q == 0.0 {
        // b = c = 0: the double root t = 0.
        return [Some(0.0), None];
    }
    [Some(q / a), Some(c / q)]
}

#[cfg(test)]
pub(crate) mod tests;
