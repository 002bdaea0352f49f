//! The log of a squared Mahalanobis error whose scale varies from one
//! error to the next: `y = ln ν²` with `ν² = s_k²·χ²_D`, where the scales
//! `s_k²` of the errors are log-normal around `s²`. So
//! `y = ln s² + ln χ²_D + η` with `η ~ N(0, τ²)`: the density of `ln χ²_D`
//! (its mean `ψ(D/2) + ln 2`, its variance `ψ₁(D/2)`) convolved with a
//! normal. Given the mean and standard deviation `σ` of `y` the density is
//! fixed: `τ² = σ² − ψ₁(D/2)`, and `σ` is never below `√ψ₁(D/2)`
//! ([`ln_chi2_sigma`]), the spread when every error has the same scale.
//!
//! `ln χ²_D` is skewed: its left tail falls as `e^{D·y/2}`, its right
//! tail as `e^{−e^y/2}`. A normal of the same mean and spread has a much
//! thinner left tail and a much thicker right one; fitted to thousands of
//! errors it misses by so much that a second normal placed over the upper
//! half of them pays for its parameters many times over.
//!
//! The density has no closed form. [`LogChi2::ln_density`] interpolates a
//! table of it, computed once per dimension ([`LogChi2::of`]).

use super::mixture::log_normal_pdf;
use statrs::function::erf::erfc;
use statrs::function::gamma::ln_gamma;
use std::sync::OnceLock;

/// The table's step in `y − mean` and in `τ`. Linear interpolation of a
/// smooth `ln f` between steps of 0.05 is off by `0.05²/8·|(ln f)''|`: the
/// curvature is `1/σ²` at the peak and grows in the right tail (as `e^y`
/// for `τ = 0`), but wherever `ln f` is within 20 of its peak the error is
/// below 10⁻² — far below the differences between the candidates a
/// decision tells apart.
const STEP: f64 = 0.05;
/// The table covers `τ` from 0 to this; a wider spread (`σ` above 4, a
/// factor of 50 in scale per standard deviation) is all but normal: the
/// skew of `y` is then `|ψ₂(D/2)|/σ³`, 0.012 for 3-dimensional edges and
/// 0.002 for 6-dimensional ones, and `y` is taken as normal.
const MAX_TAU: f64 = 4.0;
/// The table covers `y − mean` from `−LEFT` to `RIGHT`; beyond, `ln f` is
/// continued along the line through its last two values. The left tail is
/// exponential, so the line is its asymptote; the right tail falls faster,
/// so the line overstates it where no true loop lies (at `RIGHT` their
/// density is below `e^{−18}` for any `τ` in the table).
const LEFT: f64 = 20.0;
const RIGHT: f64 = 25.0;
/// The normal kernel is cut at this many standard deviations (mass beyond:
/// 2·10⁻⁹).
const KERNEL_SIGMAS: f64 = 6.0;
/// Most dimensions with a cached table; larger ones are computed each time.
const MAX_CACHED_DOF: usize = 24;

/// ψ(x) for x > 0: the recurrence ψ(x) = ψ(x + 1) − 1/x up to x ≥ 8, then
/// the asymptotic series (error below 1e-12 there).
pub fn digamma(mut x: f64) -> f64 {
    let mut acc = 0.0;
    while x < 8.0 {
        acc -= 1.0 / x;
        x += 1.0;
    }
    let x2 = 1.0 / (x * x);
    acc + x.ln()
        - 0.5 / x
        - x2 * (1.0 / 12.0
            - x2 * (1.0 / 120.0 - x2 * (1.0 / 252.0 - x2 * (1.0 / 240.0 - x2 / 132.0))))
}

/// ψ₁(x) for x > 0: the recurrence ψ₁(x) = ψ₁(x + 1) + 1/x² up to x ≥ 8,
/// then the asymptotic series (error below 1e-12 there).
pub fn trigamma(mut x: f64) -> f64 {
    let mut acc = 0.0;
    while x < 8.0 {
        acc += 1.0 / (x * x);
        x += 1.0;
    }
    let x2 = 1.0 / (x * x);
    acc + 1.0 / x
        + x2 / 2.0
        + (1.0 / x) * x2 * (1.0 / 6.0 - x2 * (1.0 / 30.0 - x2 * (1.0 / 42.0 - x2 / 30.0)))
}

/// The standard deviation of `ln X` for `X ~ χ²_dof`, `√ψ₁(dof/2)` (ψ₁ the
/// trigamma function): the spread of the log innovations of loops whose
/// noise is exactly Gaussian; no population of loops is tighter.
pub fn ln_chi2_sigma(dof: usize) -> f64 {
    trigamma(dof.max(1) as f64 / 2.0).sqrt()
}

/// The mean of `ln X` for `X ~ χ²_dof`, `ψ(dof/2) + ln 2` (ψ the digamma
/// function): where the log innovations of true loops lie when the file's
/// information is right.
pub fn ln_chi2_mean(dof: usize) -> f64 {
    digamma(dof.max(1) as f64 / 2.0) + std::f64::consts::LN_2
}

/// The density of `y` for one dimension: `ln f` on a grid of `y − mean`
/// (every [`STEP`] from `−LEFT`) for each `τ` on a grid (every [`STEP`]
/// from 0).
#[derive(Clone, Debug)]
pub struct LogChi2 {
    /// `ψ₁(D/2)`, the variance of `ln χ²_D`.
    variance: f64,
    /// `rows[i][j]`: `ln f` at `τ = i·STEP`, `y − mean = −LEFT + j·STEP`.
    rows: Vec<Vec<f64>>,
}

impl LogChi2 {
    /// The table for errors of dimension `dof` (cached for up to
    /// [`MAX_CACHED_DOF`] dimensions: the first call per dimension computes
    /// it, in a few milliseconds).
    pub fn of(dof: usize) -> std::borrow::Cow<'static, Self> {
        static TABLES: [OnceLock<LogChi2>; MAX_CACHED_DOF + 1] =
            [const { OnceLock::new() }; MAX_CACHED_DOF + 1];
        let dof = dof.max(1);
        match TABLES.get(dof) {
            Some(cell) => std::borrow::Cow::Borrowed(cell.get_or_init(|| Self::compute(dof))),
            None => std::borrow::Cow::Owned(Self::compute(dof)),
        }
    }

    fn compute(dof: usize) -> Self {
        let a = dof as f64 / 2.0;
        let (psi, ln_gamma_a) = (digamma(a), ln_gamma(a));
        // ln χ²_D − its mean is ln G − ψ(a) with G ~ Gamma(a, 1): its
        // density at u is exp(a·(u + ψ) − e^{u + ψ} − ln Γ(a)).
        let ln_g = |u: f64| a * (u + psi) - (u + psi).exp() - ln_gamma_a;
        let columns = ((LEFT + RIGHT) / STEP).round() as usize + 1;
        let max_shift = (KERNEL_SIGMAS * MAX_TAU / STEP).ceil() as usize;
        // g on the columns extended by the widest kernel on both sides, so
        // that each row is a discrete convolution by whole steps.
        let g: Vec<f64> = (0..columns + 2 * max_shift)
            .map(|j| ln_g(-LEFT + (j as f64 - max_shift as f64) * STEP).exp())
            .collect();
        let rows = (0..=(MAX_TAU / STEP).round() as usize)
            .map(|i| {
                let tau = i as f64 * STEP;
                if i == 0 {
                    return (0..columns)
                        .map(|j| ln_g(-LEFT + j as f64 * STEP))
                        .collect();
                }
                // The normal kernel at whole steps, normalised to mass 1.
                let shift = (KERNEL_SIGMAS * tau / STEP).ceil() as usize;
                let kernel: Vec<f64> = (0..=2 * shift)
                    .map(|k| {
                        let eta = (k as f64 - shift as f64) * STEP;
                        (-0.5 * eta * eta / (tau * tau)).exp()
                    })
                    .collect();
                let mass: f64 = kernel.iter().sum();
                (0..columns)
                    .map(|j| {
                        let centre = j + max_shift;
                        let f: f64 = (kernel.iter().enumerate())
                            .map(|(k, w)| w * g[centre + shift - k])
                            .sum();
                        (f / mass).ln()
                    })
                    .collect()
            })
            .collect();
        Self {
            variance: trigamma(a),
            rows,
        }
    }

    /// The density of mean `mean` and standard deviation `sigma` of `y`
    /// (`sigma` below `√ψ₁(D/2)` is taken as that): its rows and weights
    /// found once, for the many `y` it is then evaluated at.
    pub fn with(&self, mean: f64, sigma: f64) -> Density<'_> {
        let tau = (sigma * sigma - self.variance).max(0.0).sqrt();
        if tau > MAX_TAU {
            return Density::Normal { mean, sigma };
        }
        let at = tau / STEP;
        let i = (at.floor() as usize).min(self.rows.len() - 2);
        Density::Table {
            rows: (&self.rows[i], &self.rows[i + 1]),
            t: at - i as f64,
            mean,
        }
    }

    /// `ln f(y)` of [`LogChi2::with`]`(mean, sigma)`.
    #[cfg(test)]
    pub fn ln_density(&self, y: f64, mean: f64, sigma: f64) -> f64 {
        self.with(mean, sigma).ln(y)
    }
}

/// The density of `y` for one mean and spread ([`LogChi2::with`]).
#[derive(Clone, Copy, Debug)]
pub enum Density<'a> {
    /// Between two rows of the table, `t` of the way to the second.
    Table {
        rows: (&'a [f64], &'a [f64]),
        t: f64,
        mean: f64,
    },
    /// Beyond the table's widest spread: normal.
    Normal { mean: f64, sigma: f64 },
}

impl Density<'_> {
    /// `ln f(y)`; −∞ where the density is below the smallest `f64`.
    pub fn ln(&self, y: f64) -> f64 {
        match *self {
            Density::Normal { mean, sigma } => log_normal_pdf(y, mean, sigma),
            Density::Table { rows, t, mean } => {
                let x = y - mean;
                lerp(row_at(rows.0, x), row_at(rows.1, x), t)
            }
        }
    }
}

impl Density<'_> {
    /// `P(Y ≥ y)`: the mass of the density from `y` up.
    pub fn upper_tail(&self, y: f64) -> f64 {
        self.blended().upper_tail(y)
    }

    /// This density with its two rows of the table blended into one, for
    /// evaluating it at many `y`: the same `ln f` up to rounding (linear
    /// interpolation between the rows and between the columns commute), at
    /// one interpolation per `y` instead of three.
    pub fn blended(&self) -> Blended {
        match *self {
            Density::Normal { mean, sigma } => Blended::Normal { mean, sigma },
            Density::Table { rows, t, mean } => Blended::Row {
                row: (rows.0.iter().zip(rows.1))
                    .map(|(&lo, &hi)| lerp(lo, hi, t))
                    .collect(),
                mean,
            },
        }
    }
}

/// A [`Density`] whose rows are blended into one ([`Density::blended`]).
#[derive(Clone, Debug)]
pub enum Blended {
    /// `ln f` on the table's columns at the density's spread.
    Row { row: Vec<f64>, mean: f64 },
    /// Beyond the table's widest spread: normal.
    Normal { mean: f64, sigma: f64 },
}

impl Blended {
    /// `ln f(y)`; −∞ where the density is below the smallest `f64`.
    pub fn ln(&self, y: f64) -> f64 {
        match self {
            Blended::Normal { mean, sigma } => log_normal_pdf(y, *mean, *sigma),
            Blended::Row { row, mean } => row_at(row, y - mean),
        }
    }

    /// `P(Y ≥ y)`: the mass of the density from `y` up, integrated exactly
    /// over the piecewise log-linear `ln f` that [`Blended::ln`] evaluates
    /// (the line beyond the table's last column included), at most 1.
    pub fn upper_tail(&self, y: f64) -> f64 {
        match self {
            Blended::Normal { mean, sigma } => {
                0.5 * erfc((y - mean) / (sigma * std::f64::consts::SQRT_2))
            }
            Blended::Row { row, mean } => row_upper_tail(row, y - mean).min(1.0),
        }
    }
}

/// `∫ₓ^∞ f` of one row's piecewise log-linear `ln f` ([`row_at`]): each
/// step from `x` on exactly, then the line beyond the last column (a tail
/// falling as `e^{b·x}`, `b < 0`, has mass `f/|b|` beyond).
fn row_upper_tail(row: &[f64], x: f64) -> f64 {
    let n = row.len();
    let right = -LEFT + (n - 1) as f64 * STEP;
    let slope = (row[n - 1] - row[n - 2]) / STEP;
    let beyond = |from: f64| {
        let f = row_at(row, from).exp();
        match f {
            0.0 => 0.0,
            _ if slope < 0.0 => f / -slope,
            _ => f64::INFINITY,
        }
    };
    if x >= right {
        return beyond(x);
    }
    // ∫ of e^{ln f} over [a, b] where ln f runs linearly from la to lb.
    let segment = |(a, la): (f64, f64), (b, lb): (f64, f64)| {
        let (fa, fb) = (la.exp(), lb.exp());
        let d = lb - la;
        if fa == 0.0 && fb == 0.0 {
            0.0
        } else if d.abs() < 1e-9 {
            (b - a) * 0.5 * (fa + fb)
        } else {
            (b - a) * (fb - fa) / d
        }
    };
    let first = ((x + LEFT) / STEP).floor().max(0.0) as usize + 1;
    let column = |j: usize| -LEFT + j as f64 * STEP;
    // Below the table the line through its first two columns, as `row_at`.
    let start = x.max(-LEFT);
    let mut mass = if x < -LEFT {
        let slope = (row[1] - row[0]) / STEP;
        if slope > 0.0 {
            (row[0].exp() - row_at(row, x).exp()) / slope
        } else {
            f64::INFINITY
        }
    } else {
        0.0
    };
    mass += segment((start, row_at(row, start)), (column(first), row[first]));
    for j in first..n - 1 {
        mass += segment((column(j), row[j]), (column(j + 1), row[j + 1]));
    }
    mass + beyond(right)
}

/// One row's `ln f` at `x = y − mean`: linear between columns, continued
/// along the line through the two outermost columns beyond the table.
fn row_at(row: &[f64], x: f64) -> f64 {
    let at = (x + LEFT) / STEP;
    // `at as usize` truncates, which for `at ≥ 0` is the floor (and spares
    // the call to `floor` that a baseline x86-64 build makes).
    let j = if at < 0.0 {
        0
    } else {
        (at as usize).min(row.len() - 2)
    };
    lerp(row[j], row[j + 1], at - j as f64)
}

/// `lo + t·(hi − lo)` of two log densities: `lo` at `t = 0`, and −∞ when
/// either is −∞ (a density below the smallest `f64` on one side).
fn lerp(lo: f64, hi: f64, t: f64) -> f64 {
    if t == 0.0 {
        lo
    } else if lo.is_finite() && hi.is_finite() {
        lo + t * (hi - lo)
    } else {
        f64::NEG_INFINITY
    }
}

#[cfg(test)]
mod tests;
