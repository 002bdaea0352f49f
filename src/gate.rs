//! Unsupervised learning of the geometric-verification threshold `T_GV`
//! (Lee & Pollefeys, ICRA 2014, §II-A/B and Algorithm 1), and the gate that
//! applies it to loop-closure candidates.
//!
//! # Method
//!
//! 1. Normalise the RANSAC inlier counts by their maximum, `v = count / max`
//!    (Algorithm 1, line 2). A zero count has no logarithm and is "not a loop"
//!    by definition: it is left out of the fit, kept in the counts, and
//!    reported ([`ThresholdFit::zero_counts`]).
//! 2. Fit a two-component log-normal mixture to `v` by EM (Eqs. 3 and 6). A
//!    log-normal in `v` is a normal in `y = ln v`, and the `1/v` factor of the
//!    log-normal density cancels from the responsibilities (Eq. 3) and from
//!    the crossing (Eq. 7), so all the work is done on `y` with Gaussians.
//!    Log-likelihoods reported here are those of `y`, `Σ ln Σ_k π_k N(y|μ_k,σ_k)`
//!    (the likelihood of `v` is that minus `Σ y`).
//! 3. The component with the higher mean models true loops
//!    ([`Component::Loop`], index 1). The threshold is where the weighted
//!    densities cross between the two means (Eq. 7), solved in closed form;
//!    `T_GV = max · exp(y*)` (line 33). **A candidate with `count < T_GV` is
//!    dropped**, one with `count ≥ T_GV` kept.
//!
//! # Changes from the paper
//!
//! * The E-step works with log densities and log-sum-exp, so responsibilities
//!   never underflow however far a count lies from a component.
//! * The M-step variance is taken around the *new* mean, as Eq. 6b says;
//!   Algorithm 1 line 26 accumulates `(ln v_n − μ_k)²` while `μ_k` is still a
//!   partial sum.
//! * Counts are integers, so ties are common and a component can shrink onto
//!   a single tied value, where the likelihood grows without bound. Variances
//!   have a floor ([`VarianceFloor`]), collapsed fits are rejected, and besides
//!   the paper's start two data-driven starts are tried; the fit with the best
//!   likelihood wins (see [`EmStart`]).
//! * The crossing is solved in closed form (a quadratic in `y`) instead of
//!   with Brent's method.
//! * The paper detects a degenerate case (too few or no loops) only after
//!   optimisation, with the χ² test ([`crate::stats`]). Here the counts are
//!   checked first: does a second component exist at all (BIC), are the two
//!   separated (Ashman's D), is the loop component big enough, do the
//!   densities cross? See [`Degeneracy`].
//!
//! # Known limitation
//!
//! The model is continuous and the data are integers. A component that sits
//! on one tied value with at least [`MixtureOptions::min_loop_size`] counts
//! is accepted (saturated inlier counts at the top are a real case), and its
//! width is then the variance floor. With very few distinct values (say,
//! counts 1 to 5 only) the logarithm spreads them unevenly and the checks
//! can accept a split that reflects the discreteness rather than two
//! populations; such counts carry too little information for any threshold.

use serde::Serialize;
use std::fmt;

/// `ln √(2π)`, the constant of the normal log-density.
const LN_SQRT_2PI: f64 = 0.918_938_533_204_672_8;

/// The smallest variance (in `ln v`, squared) any component may have,
/// whatever [`VarianceFloor`] asks for: σ ≥ 1e-6, a relative spread of one
/// count in a million.
pub const MIN_VARIANCE_FLOOR: f64 = 1e-12;

/// A variance within this factor of the floor counts as "at the floor".
const AT_FLOOR: f64 = 1.0 + 1e-9;

/// The paper's start (Algorithm 1 line 4, Fig. 3): μ = [−2, 1], σ = [1, 1].
const PAPER_START_MU: [f64; 2] = [-2.0, 1.0];

/// The two components of the mixture.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Component {
    /// Wrong loop-closure candidates (lower mean), index 0.
    NotLoop,
    /// True loop closures (higher mean), index 1.
    Loop,
}

impl Component {
    /// The index of this component in the arrays of [`LogNormalMixture`].
    pub const fn index(self) -> usize {
        match self {
            Component::NotLoop => 0,
            Component::Loop => 1,
        }
    }
}

/// Where an EM run started.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum EmStart {
    /// The paper's start: μ = [−2, 1], σ = [1, 1], π = [½, ½].
    Paper,
    /// Means at the 25th and 75th percentiles of `ln v`, both σ equal to the
    /// spread of all of `ln v`, π = [½, ½].
    Quartiles,
    /// The best split of the sorted `ln v` into two groups (1-D 2-means),
    /// with each group's mean, spread and share.
    TwoMeans,
}

/// How the variance floor is chosen. Whatever the choice, the floor is at
/// least [`MIN_VARIANCE_FLOOR`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum VarianceFloor {
    /// The quantisation variance of integer counts at the top of the range:
    /// adjacent counts near the maximum are `Δ = ln(max) − ln(max − 1)` apart
    /// in `ln v`, and a value known only to within one such step has variance
    /// `Δ²/12`. That is the finest spread integer counts can resolve
    /// anywhere in the range (Δ is largest at small counts), so a component
    /// pinned at this floor is in effect sitting on a single tied value.
    Quantization,
    /// A fixed floor on the variance of `ln v`.
    Absolute(f64),
}

impl VarianceFloor {
    /// The floor (a variance of `ln v`) for counts whose maximum is `max_count`.
    pub fn value(self, max_count: u64) -> f64 {
        let raw = match self {
            VarianceFloor::Quantization => {
                // Δ = −ln(1 − 1/max), accurate even when max − 1 and max are
                // the same f64.
                let step = -(-1.0 / max_count as f64).ln_1p();
                step * step / 12.0
            }
            VarianceFloor::Absolute(floor) => floor,
        };
        if raw.is_finite() && raw > MIN_VARIANCE_FLOOR {
            raw
        } else {
            MIN_VARIANCE_FLOOR
        }
    }
}

/// Settings of the fit and of the degeneracy checks.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct MixtureOptions {
    /// EM stops when no μ, σ or π changes by more than this (default 1e-9).
    pub tolerance: f64,
    /// EM stops after this many iterations at the latest (default 1000).
    pub max_iterations: usize,
    /// The variance floor (default [`VarianceFloor::Quantization`]).
    pub variance_floor: VarianceFloor,
    /// Fewer non-zero counts than this are degenerate (default 8).
    pub min_counts: usize,
    /// Ashman's D below this is degenerate (default 2.0, the usual bound for
    /// a clean separation of two normals).
    pub min_ashman_d: f64,
    /// A loop-component weight below this is degenerate (default 0.02).
    pub min_loop_weight: f64,
    /// An expected loop-component size `π₁·n` below this is degenerate
    /// (default 3). A component pinned at the variance floor with fewer
    /// counts than this is treated as collapsed.
    pub min_loop_size: f64,
}

impl Default for MixtureOptions {
    fn default() -> Self {
        MixtureOptions {
            tolerance: 1e-9,
            max_iterations: 1000,
            variance_floor: VarianceFloor::Quantization,
            min_counts: 8,
            min_ashman_d: 2.0,
            min_loop_weight: 0.02,
            min_loop_size: 3.0,
        }
    }
}

/// A two-component log-normal mixture on normalised counts `v ∈ (0, 1]`,
/// i.e. a Gaussian mixture on `y = ln v`. Index 0 is [`Component::NotLoop`],
/// index 1 [`Component::Loop`] (`mu[0] ≤ mu[1]`).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct LogNormalMixture {
    /// Means of `ln v`.
    pub mu: [f64; 2],
    /// Standard deviations of `ln v`.
    pub sigma: [f64; 2],
    /// Mixing weights π, summing to 1.
    pub weight: [f64; 2],
    /// EM iterations run.
    pub iterations: usize,
    /// Whether EM met the tolerance (rather than the iteration limit).
    pub converged: bool,
    /// Log-likelihood of the fitted `ln v`: `Σ_n ln Σ_k π_k N(y_n|μ_k,σ_k)`.
    pub log_likelihood: f64,
    /// The start EM was run from.
    pub start: EmStart,
    /// The variance floor the fit was made under.
    pub variance_floor: f64,
}

impl LogNormalMixture {
    fn params(&self) -> Params {
        Params {
            mu: self.mu,
            sigma: self.sigma,
            weight: self.weight,
        }
    }

    /// The weighted density `π_k · LogNormal(v | μ_k, σ_k)` of one component
    /// at a normalised count `v`, including the `1/v` factor, so that it
    /// overlays a density histogram of the non-zero normalised counts.
    /// Zero for `v ≤ 0` (and NaN).
    pub fn weighted_density(&self, component: Component, v: f64) -> f64 {
        if v.is_nan() || v <= 0.0 {
            return 0.0;
        }
        let y = v.ln();
        (self.params().log_weighted_density(component.index(), y) - y).exp()
    }

    /// The mixture density at a normalised count `v`: the sum of both
    /// [`weighted_density`](Self::weighted_density)s.
    pub fn density(&self, v: f64) -> f64 {
        self.weighted_density(Component::NotLoop, v) + self.weighted_density(Component::Loop, v)
    }

    /// `P(true loop | count)` under the fitted mixture, for a count
    /// normalised by `max_count` (the maximum the mixture was fitted with).
    /// Zero for a zero count; a `max_count` of 0 is taken as 1.
    pub fn posterior_true_loop(&self, count: u64, max_count: u64) -> f64 {
        if count == 0 {
            return 0.0;
        }
        let y = (count as f64).ln() - (max_count.max(1) as f64).ln();
        logistic(self.params().log_odds(y))
    }

    /// Ashman's D = √2·|μ₁ − μ₀| / √(σ₀² + σ₁²); above 2 the components are
    /// cleanly separated.
    pub fn ashman_d(&self) -> f64 {
        let [m0, m1] = self.mu;
        let [s0, s1] = self.sigma;
        std::f64::consts::SQRT_2 * (m1 - m0).abs() / s0.hypot(s1)
    }

    /// The normalised threshold `v_T`: where the weighted densities cross
    /// between the means (Eq. 7), or `None` when they do not.
    pub fn crossing(&self) -> Option<f64> {
        self.params().crossing_log().map(f64::exp)
    }
}

/// The learned threshold.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Threshold {
    /// `T_GV` in inlier counts. A candidate with `count < T_GV` is dropped.
    pub count: f64,
    /// The normalised threshold `v_T = T_GV / max_count`.
    pub normalized: f64,
    /// The largest count, used to normalise.
    pub max_count: u64,
}

impl Threshold {
    fn from_log(y: f64, max_count: u64) -> Threshold {
        let normalized = y.exp();
        Threshold {
            count: normalized * max_count as f64,
            normalized,
            max_count,
        }
    }

    /// Whether a candidate with this count passes: `count ≥ T_GV`.
    pub fn keeps(&self, count: u64) -> bool {
        count as f64 >= self.count
    }
}

/// The numbers behind the degeneracy verdict of a fitted mixture.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Separation {
    /// BIC of a single normal on `ln v` (k = 2 parameters). Lower is better.
    pub bic_one: f64,
    /// BIC of the two-component mixture (k = 5 parameters).
    pub bic_two: f64,
    /// Ashman's D of the two components.
    pub ashman_d: f64,
    /// Weight π₁ of the loop component.
    pub loop_weight: f64,
    /// Expected number of true loops, `π₁ · (number of non-zero counts)`.
    pub loop_expected_size: f64,
    /// Whether the weighted densities cross between the means.
    pub crossing_exists: bool,
}

/// Why the counts cannot give a trustworthy threshold.
///
/// The checks run in the order of the variants and the first that applies is
/// reported: the input first, then whether EM found two components, then
/// model choice (BIC), separation (Ashman's D), loop-component weight and
/// size, and the crossing.
#[derive(Clone, Debug, PartialEq, Serialize)]
#[serde(tag = "reason", rename_all = "snake_case")]
pub enum Degeneracy {
    /// There are no counts at all.
    NoCandidates,
    /// Every count is zero.
    AllZero {
        /// How many counts there are (all zero).
        zero_counts: usize,
    },
    /// Too few non-zero counts to fit two components.
    TooFewCounts {
        /// Non-zero counts available.
        fitted_counts: usize,
        /// [`MixtureOptions::min_counts`].
        min_counts: usize,
    },
    /// All non-zero counts are the same number.
    AllEqual {
        /// The one value.
        count: u64,
        /// How many non-zero counts there are.
        fitted_counts: usize,
    },
    /// Every EM start collapsed: a component lost its weight, shrank onto a
    /// few tied counts, or went non-finite.
    Collapsed {
        /// How many starts were tried.
        starts: usize,
    },
    /// BIC prefers one component to two.
    OneComponent {
        /// BIC of one component.
        bic_one: f64,
        /// BIC of two components.
        bic_two: f64,
    },
    /// The two components overlap too much.
    Overlapping {
        /// Ashman's D of the fit.
        ashman_d: f64,
        /// [`MixtureOptions::min_ashman_d`].
        min_ashman_d: f64,
    },
    /// The loop component carries too little weight.
    LightLoopComponent {
        /// Its weight π₁.
        weight: f64,
        /// [`MixtureOptions::min_loop_weight`].
        min_weight: f64,
    },
    /// The loop component explains too few candidates.
    SmallLoopComponent {
        /// Its expected size `π₁·n`.
        expected_size: f64,
        /// [`MixtureOptions::min_loop_size`].
        min_size: f64,
    },
    /// The weighted densities do not cross between the means.
    NoCrossing {
        /// The two means of `ln v`.
        mu: [f64; 2],
    },
}

impl fmt::Display for Degeneracy {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Degeneracy::NoCandidates => write!(f, "there are no inlier counts to learn from"),
            Degeneracy::AllZero { zero_counts } => write!(
                f,
                "all {zero_counts} inlier counts are zero: no candidate has geometric support"
            ),
            Degeneracy::TooFewCounts {
                fitted_counts,
                min_counts,
            } => write!(
                f,
                "only {fitted_counts} non-zero inlier counts; at least {min_counts} are needed to fit two components"
            ),
            Degeneracy::AllEqual {
                count,
                fitted_counts,
            } => write!(
                f,
                "all {fitted_counts} non-zero inlier counts equal {count}: nothing tells loops from non-loops"
            ),
            Degeneracy::Collapsed { starts } => write!(
                f,
                "EM found no two-component fit: all {starts} starts collapsed onto a few tied counts or lost a component"
            ),
            Degeneracy::OneComponent { bic_one, bic_two } => write!(
                f,
                "the counts show one component: BIC 1-comp {bic_one:.1} <= 2-comp {bic_two:.1}"
            ),
            Degeneracy::Overlapping {
                ashman_d,
                min_ashman_d,
            } => write!(
                f,
                "the two components overlap: Ashman's D {ashman_d:.2} < {min_ashman_d:.2}"
            ),
            Degeneracy::LightLoopComponent { weight, min_weight } => write!(
                f,
                "too few candidates look like loops: loop-component weight {weight:.4} < {min_weight:.4}"
            ),
            Degeneracy::SmallLoopComponent {
                expected_size,
                min_size,
            } => write!(
                f,
                "too few candidates look like loops: about {expected_size:.1} expected, fewer than {min_size:.1}"
            ),
            Degeneracy::NoCrossing { mu } => write!(
                f,
                "the weighted densities do not cross between the means (ln v = {:.3} and {:.3}): no threshold separates them",
                mu[0], mu[1]
            ),
        }
    }
}

/// The result of learning `T_GV` from a set of inlier counts.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ThresholdFit {
    /// Number of counts given.
    pub total_counts: usize,
    /// Number of zero counts (left out of the fit).
    pub zero_counts: usize,
    /// Number of non-zero counts the mixture was fitted to.
    pub fitted_counts: usize,
    /// The largest count (0 when there is none).
    pub max_count: u64,
    /// The fitted mixture, when EM produced one.
    pub mixture: Option<LogNormalMixture>,
    /// Degeneracy diagnostics, when there is a mixture.
    pub separation: Option<Separation>,
    /// The crossing as a count threshold, when the densities cross between
    /// the means. Present even for some degenerate fits (see
    /// [`DegeneratePolicy::Threshold`]).
    pub threshold: Option<Threshold>,
    /// Why the fit is not trustworthy, or `None` when it is.
    pub degeneracy: Option<Degeneracy>,
}

impl ThresholdFit {
    /// Whether the counts failed a degeneracy check.
    pub fn is_degenerate(&self) -> bool {
        self.degeneracy.is_some()
    }
}

/// Learns the geometric-verification threshold from inlier counts (one per
/// loop-closure candidate): the paper's Algorithm 1 with the changes listed
/// in the [module documentation](self).
///
/// ```ignore
/// use pgo::gate::{learn_threshold, MixtureOptions};
/// // Many weakly supported candidates (8..=32 inliers) and some strong ones
/// // (150..=209 inliers).
/// let mut counts: Vec<u64> = (0..200).map(|i| 8 + (i * 7919) % 25).collect();
/// counts.extend((0..40).map(|i| 150 + (i * 31) % 60));
/// let fit = learn_threshold(&counts, &MixtureOptions::default());
/// assert!(!fit.is_degenerate(), "{:?}", fit.degeneracy);
/// let t = fit.threshold.unwrap();
/// assert!(t.count > 32.0 && t.count < 150.0);
/// assert!(t.keeps(150) && !t.keeps(32));
/// ```
pub fn learn_threshold(counts: &[u64], options: &MixtureOptions) -> ThresholdFit {
    let zero_counts = counts.iter().filter(|&&c| c == 0).count();
    let max_count = counts.iter().copied().max().unwrap_or(0);
    let mut fit = ThresholdFit {
        total_counts: counts.len(),
        zero_counts,
        fitted_counts: counts.len() - zero_counts,
        max_count,
        mixture: None,
        separation: None,
        threshold: None,
        degeneracy: None,
    };
    if let Some(reason) = check_counts(counts, &fit, options) {
        fit.degeneracy = Some(reason);
        return fit;
    }

    let y = log_normalized(counts, max_count);
    let floor = options.variance_floor.value(max_count);
    let two = fit_two_normals(&y, floor, options);
    fit.degeneracy = two.degeneracy;
    fit.threshold = two.crossing_log.map(|y| Threshold::from_log(y, max_count));
    fit.mixture = two.mixture;
    fit.separation = two.separation;
    fit
}

/// Two normals fitted by EM to values `y` (logs of a positive quantity), as
/// [`learn_threshold`] fits them to `ln v`: the same starts, the variance
/// `floor`, and the same degeneracy checks after the fit, with index 1 the
/// component of the higher mean.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TwoNormals {
    /// The fit, unless every EM start collapsed.
    pub mixture: Option<LogNormalMixture>,
    /// The numbers behind the degeneracy verdict, when there is a fit.
    pub separation: Option<Separation>,
    /// Where the weighted densities cross between the means, in `y`.
    pub crossing_log: Option<f64>,
    /// Why the fit is not trustworthy, or `None` when it is. Checks on the
    /// data themselves (how many values) are the caller's.
    pub degeneracy: Option<Degeneracy>,
}

/// Fits [`TwoNormals`] to `y` with the variance floor `floor` (see
/// [`MixtureOptions`] for the checks; "loop component" there means the
/// component of the higher mean). The gate fits `ln(count / max)`; the
/// robust back end fits the logs of the candidates' residuals
/// ([`crate::robust`]).
///
/// ```ignore
/// use pgo::gate::{fit_two_normals, MixtureOptions};
/// // ln of two well-separated groups.
/// let mut y: Vec<f64> = (0..200).map(|i| (i % 20) as f64 * 0.1).collect();
/// y.extend((0..20).map(|i| 10.0 + (i % 5) as f64 * 0.2));
/// let fit = fit_two_normals(&y, 1e-6, &MixtureOptions::default());
/// assert!(fit.degeneracy.is_none());
/// let t = fit.crossing_log.unwrap();
/// assert!(t > 1.9 && t < 10.0);
/// ```
pub fn fit_two_normals(y: &[f64], floor: f64, options: &MixtureOptions) -> TwoNormals {
    let floor = floor.max(MIN_VARIANCE_FLOOR);
    let starts = em_starts(y, floor);
    let Some(mixture) = best_fit(y, &starts, floor, options) else {
        return TwoNormals {
            mixture: None,
            separation: None,
            crossing_log: None,
            degeneracy: Some(Degeneracy::Collapsed {
                starts: starts.len(),
            }),
        };
    };
    let crossing_log = mixture.params().crossing_log();
    let n = y.len() as f64;
    let separation = Separation {
        bic_one: bic(2, n, one_component_log_likelihood(y, floor)),
        bic_two: bic(5, n, mixture.log_likelihood),
        ashman_d: mixture.ashman_d(),
        loop_weight: mixture.weight[1],
        loop_expected_size: mixture.weight[1] * n,
        crossing_exists: crossing_log.is_some(),
    };
    TwoNormals {
        degeneracy: check_separation(&separation, &mixture, options),
        mixture: Some(mixture),
        separation: Some(separation),
        crossing_log,
    }
}

/// Degeneracies visible in the counts themselves, before any fitting.
fn check_counts(
    counts: &[u64],
    fit: &ThresholdFit,
    options: &MixtureOptions,
) -> Option<Degeneracy> {
    if counts.is_empty() {
        return Some(Degeneracy::NoCandidates);
    }
    if fit.fitted_counts == 0 {
        return Some(Degeneracy::AllZero {
            zero_counts: fit.zero_counts,
        });
    }
    if fit.fitted_counts < options.min_counts {
        return Some(Degeneracy::TooFewCounts {
            fitted_counts: fit.fitted_counts,
            min_counts: options.min_counts,
        });
    }
    let min_nonzero = counts.iter().copied().filter(|&c| c > 0).min();
    if min_nonzero == Some(fit.max_count) {
        return Some(Degeneracy::AllEqual {
            count: fit.max_count,
            fitted_counts: fit.fitted_counts,
        });
    }
    None
}

/// Degeneracies of a fitted mixture, first failing check in the documented
/// order.
fn check_separation(
    s: &Separation,
    mixture: &LogNormalMixture,
    options: &MixtureOptions,
) -> Option<Degeneracy> {
    if s.bic_one <= s.bic_two {
        Some(Degeneracy::OneComponent {
            bic_one: s.bic_one,
            bic_two: s.bic_two,
        })
    } else if s.ashman_d < options.min_ashman_d {
        Some(Degeneracy::Overlapping {
            ashman_d: s.ashman_d,
            min_ashman_d: options.min_ashman_d,
        })
    } else if s.loop_weight < options.min_loop_weight {
        Some(Degeneracy::LightLoopComponent {
            weight: s.loop_weight,
            min_weight: options.min_loop_weight,
        })
    } else if s.loop_expected_size < options.min_loop_size {
        Some(Degeneracy::SmallLoopComponent {
            expected_size: s.loop_expected_size,
            min_size: options.min_loop_size,
        })
    } else if !s.crossing_exists {
        Some(Degeneracy::NoCrossing { mu: mixture.mu })
    } else {
        None
    }
}

/// `y = ln(count / max)` for every non-zero count, in input order. Computed
/// as a difference of logs of the f64 counts, so nothing overflows; the
/// maximum maps to exactly 0.
fn log_normalized(counts: &[u64], max_count: u64) -> Vec<f64> {
    let ln_max = (max_count as f64).ln();
    counts
        .iter()
        .filter(|&&c| c > 0)
        .map(|&c| (c as f64).ln() - ln_max)
        .collect()
}

/// Bayesian information criterion `k ln n − 2 ln L`.
fn bic(parameters: u32, n: f64, log_likelihood: f64) -> f64 {
    f64::from(parameters) * n.ln() - 2.0 * log_likelihood
}

/// Log-likelihood of `y` under the best single normal (variance floored).
fn one_component_log_likelihood(y: &[f64], floor: f64) -> f64 {
    let (mean, var) = mean_and_variance(y);
    let sigma = var.max(floor).sqrt();
    y.iter().map(|&v| log_normal_pdf(v, mean, sigma)).sum()
}

/// Mean and population variance (0 and 0 for no data).
fn mean_and_variance(y: &[f64]) -> (f64, f64) {
    let n = y.len().max(1) as f64;
    let mean = y.iter().sum::<f64>() / n;
    let var = y.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n;
    (mean, var)
}

/// `ln N(y | μ, σ)`.
fn log_normal_pdf(y: f64, mu: f64, sigma: f64) -> f64 {
    let z = (y - mu) / sigma;
    -0.5 * z * z - sigma.ln() - LN_SQRT_2PI
}

/// `1 / (1 + e^{−g})` without overflow; 0 for NaN (no evidence of a loop).
fn logistic(g: f64) -> f64 {
    if g.is_nan() {
        0.0
    } else if g >= 0.0 {
        1.0 / (1.0 + (-g).exp())
    } else {
        let e = g.exp();
        e / (1.0 + e)
    }
}

/// The parameters EM works on (Gaussians on `y = ln v`).
#[derive(Clone, Copy, Debug, PartialEq)]
struct Params {
    mu: [f64; 2],
    sigma: [f64; 2],
    weight: [f64; 2],
}

impl Params {
    /// `ln(π_k N(y | μ_k, σ_k))`.
    fn log_weighted_density(&self, k: usize, y: f64) -> f64 {
        self.weight[k].ln() + log_normal_pdf(y, self.mu[k], self.sigma[k])
    }

    /// Both log weighted densities at `y` and their log-sum-exp `ln p(y)`.
    fn log_terms(&self, y: f64) -> ([f64; 2], f64) {
        let terms = [
            self.log_weighted_density(0, y),
            self.log_weighted_density(1, y),
        ];
        let top = terms[0].max(terms[1]);
        if top == f64::NEG_INFINITY {
            return (terms, top);
        }
        (
            terms,
            top + ((terms[0] - top).exp() + (terms[1] - top).exp()).ln(),
        )
    }

    /// `ln(π₁N₁(y)) − ln(π₀N₀(y))`: positive where a true loop is the more
    /// probable explanation.
    fn log_odds(&self, y: f64) -> f64 {
        self.log_weighted_density(1, y) - self.log_weighted_density(0, y)
    }

    fn is_finite(&self) -> bool {
        self.mu
            .iter()
            .chain(&self.sigma)
            .chain(&self.weight)
            .all(|x| x.is_finite())
    }

    fn max_abs_change(&self, other: &Params) -> f64 {
        let a = self.mu.iter().chain(&self.sigma).chain(&self.weight);
        let b = other.mu.iter().chain(&other.sigma).chain(&other.weight);
        a.zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max)
    }

    /// Puts the component with the higher mean (true loops) at index 1.
    fn loop_last(self) -> Params {
        if self.mu[0] <= self.mu[1] {
            return self;
        }
        let swap = |[a, b]: [f64; 2]| [b, a];
        Params {
            mu: swap(self.mu),
            sigma: swap(self.sigma),
            weight: swap(self.weight),
        }
    }

    /// The `y*` in `(μ₀, μ₁)` where the loop component takes over (Eq. 7 in
    /// log form), or `None`.
    ///
    /// With `t = y − μ₀` and `d = μ₁ − μ₀`, the log-odds are the quadratic
    /// `g(t) = a t² + b t + c` with
    /// `a = 1/(2σ₀²) − 1/(2σ₁²)`, `b = d/σ₁²`,
    /// `c = ln(π₁σ₀ / (π₀σ₁)) − d²/(2σ₁²)`.
    /// Shifting to `μ₀` keeps the coefficients small. Between the means `g`
    /// is strictly increasing (`g'` is linear, `g'(0) = d/σ₁² > 0` and
    /// `g'(d) = d/σ₀² > 0`), so there is at most one root there, a crossing
    /// exists exactly when `g(0) < 0 < g(d)`, and counts above it are more
    /// likely loops.
    fn crossing_log(&self) -> Option<f64> {
        let [m0, m1] = self.mu;
        let [s0, s1] = self.sigma;
        let [w0, w1] = self.weight;
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

/// One EM run.
#[derive(Clone, Debug)]
struct EmRun {
    params: Params,
    iterations: usize,
    converged: bool,
    log_likelihood: f64,
}

/// EM from `start` until the largest parameter change is below the
/// tolerance or the iteration limit is hit. `None` when an M-step finds an
/// empty or non-finite component. `observe` sees the log-likelihood before
/// every M-step, then that of the final parameters.
fn run_em(
    y: &[f64],
    start: Params,
    floor: f64,
    options: &MixtureOptions,
    mut observe: impl FnMut(f64),
) -> Option<EmRun> {
    let mut params = start;
    let mut responsibilities = vec![[0.0; 2]; y.len()];
    let mut converged = false;
    let mut iterations = 0;
    while iterations < options.max_iterations {
        iterations += 1;
        observe(e_step(y, &params, &mut responsibilities));
        let next = m_step(y, &responsibilities, floor)?;
        let change = params.max_abs_change(&next);
        params = next;
        if change < options.tolerance {
            converged = true;
            break;
        }
    }
    let log_likelihood = y.iter().map(|&v| params.log_terms(v).1).sum();
    observe(log_likelihood);
    Some(EmRun {
        params,
        iterations,
        converged,
        log_likelihood,
    })
}

/// E-step (Eq. 3) in log space: `T(n,k) = exp(ln π_k N_k(y_n) − ln p(y_n))`.
/// Returns the log-likelihood of the current parameters.
fn e_step(y: &[f64], params: &Params, responsibilities: &mut [[f64; 2]]) -> f64 {
    let mut log_likelihood = 0.0;
    for (&v, r) in y.iter().zip(responsibilities.iter_mut()) {
        let (terms, log_p) = params.log_terms(v);
        *r = [(terms[0] - log_p).exp(), (terms[1] - log_p).exp()];
        log_likelihood += log_p;
    }
    log_likelihood
}

/// M-step (Eq. 6): weighted mean, weighted variance around the *new* mean
/// (floored), and weight. `None` when a component has no mass.
fn m_step(y: &[f64], responsibilities: &[[f64; 2]], floor: f64) -> Option<Params> {
    let n = y.len() as f64;
    let mut params = Params {
        mu: [0.0; 2],
        sigma: [0.0; 2],
        weight: [0.0; 2],
    };
    for k in 0..2 {
        let mass: f64 = responsibilities.iter().map(|r| r[k]).sum();
        if !(mass > 0.0 && mass.is_finite()) {
            return None;
        }
        let weighted = || responsibilities.iter().map(move |r| r[k]).zip(y);
        let mu = weighted().map(|(r, v)| r * v).sum::<f64>() / mass;
        let var = weighted().map(|(r, v)| r * (v - mu).powi(2)).sum::<f64>() / mass;
        params.mu[k] = mu;
        params.sigma[k] = var.max(floor).sqrt();
        params.weight[k] = mass / n;
    }
    params.is_finite().then_some(params)
}

/// Whether a run ended in a useless place: a component with less than one
/// count's worth of weight, or pinned at the variance floor (a single tied
/// value) while holding fewer than `min_loop_size` counts.
fn is_collapsed(params: &Params, n: usize, floor: f64, min_loop_size: f64) -> bool {
    if !params.is_finite() {
        return true;
    }
    (0..2).any(|k| {
        let size = params.weight[k] * n as f64;
        let pinned = params.sigma[k] * params.sigma[k] <= floor * AT_FLOOR;
        size < 1.0 || (pinned && size < min_loop_size)
    })
}

/// The EM starts, in order of preference on ties: the paper's, quartiles
/// (when the quartiles differ), 2-means (when there are two distinct values).
fn em_starts(y: &[f64], floor: f64) -> Vec<(EmStart, Params)> {
    let min_sigma = floor.sqrt();
    let mut starts = vec![(
        EmStart::Paper,
        Params {
            mu: PAPER_START_MU,
            sigma: [1.0f64.max(min_sigma); 2],
            weight: [0.5; 2],
        },
    )];
    let mut sorted = y.to_vec();
    sorted.sort_by(f64::total_cmp);
    let (q25, q75) = (quantile(&sorted, 0.25), quantile(&sorted, 0.75));
    if q25 < q75 {
        let spread = mean_and_variance(y).1.sqrt().max(min_sigma);
        starts.push((
            EmStart::Quartiles,
            Params {
                mu: [q25, q75],
                sigma: [spread; 2],
                weight: [0.5; 2],
            },
        ));
    }
    if let Some(split) = two_means_split(&sorted) {
        let (low, high) = sorted.split_at(split);
        let group = |g: &[f64]| {
            let (mean, var) = mean_and_variance(g);
            (
                mean,
                var.max(floor).sqrt(),
                g.len() as f64 / sorted.len() as f64,
            )
        };
        let ((m0, s0, w0), (m1, s1, w1)) = (group(low), group(high));
        starts.push((
            EmStart::TwoMeans,
            Params {
                mu: [m0, m1],
                sigma: [s0, s1],
                weight: [w0, w1],
            },
        ));
    }
    starts
}

/// Linear-interpolated quantile of sorted data (`p` in [0, 1]).
fn quantile(sorted: &[f64], p: f64) -> f64 {
    let Some(&last) = sorted.last() else {
        return 0.0;
    };
    let pos = p * (sorted.len() - 1) as f64;
    let (i, frac) = (pos.floor() as usize, pos.fract());
    let next = sorted.get(i + 1).copied().unwrap_or(last);
    sorted.get(i).map_or(last, |&lo| lo + frac * (next - lo))
}

/// The split index `s` of sorted data into `[..s]` and `[s..]` that
/// maximises the between-group sum of squares `n_l n_r / n · (m_r − m_l)²`
/// (equivalently minimises the within-group one), only between distinct
/// values. `None` when all values are equal.
fn two_means_split(sorted: &[f64]) -> Option<usize> {
    let n = sorted.len() as f64;
    let total: f64 = sorted.iter().sum();
    let mut left_sum = 0.0;
    let mut best: Option<(usize, f64)> = None;
    for s in 1..sorted.len() {
        left_sum += sorted[s - 1];
        if sorted[s - 1] >= sorted[s] {
            continue;
        }
        let (nl, nr) = (s as f64, n - s as f64);
        let gap = (total - left_sum) / nr - left_sum / nl;
        let between = nl * nr / n * gap * gap;
        if best.is_none_or(|(_, b)| between > b) {
            best = Some((s, between));
        }
    }
    best.map(|(s, _)| s)
}

/// Runs EM from every start and keeps the non-collapsed result with the
/// highest log-likelihood (the earlier start on ties).
fn best_fit(
    y: &[f64],
    starts: &[(EmStart, Params)],
    floor: f64,
    options: &MixtureOptions,
) -> Option<LogNormalMixture> {
    let mut best: Option<LogNormalMixture> = None;
    for &(start, params) in starts {
        let Some(run) = run_em(y, params, floor, options, |_| {}) else {
            continue;
        };
        let params = run.params.loop_last();
        if is_collapsed(&params, y.len(), floor, options.min_loop_size)
            || !run.log_likelihood.is_finite()
        {
            continue;
        }
        if best
            .as_ref()
            .is_none_or(|b| run.log_likelihood > b.log_likelihood)
        {
            best = Some(LogNormalMixture {
                mu: params.mu,
                sigma: params.sigma,
                weight: params.weight,
                iterations: run.iterations,
                converged: run.converged,
                log_likelihood: run.log_likelihood,
                start,
                variance_floor: floor,
            });
        }
    }
    best
}

/// How the gate decides.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum GateMode {
    /// Learn `T_GV` from the counts ([`learn_threshold`]).
    #[default]
    Auto,
    /// No gate: keep every candidate.
    Off,
    /// A fixed threshold: keep a candidate when `count ≥ N`.
    Fixed(u64),
    /// Learn the mixture as [`GateMode::Auto`] does but drop nothing: every
    /// candidate goes on with its posterior `P(true loop | count)` as the
    /// prior of a robust back end ([`LogNormalMixture::posterior_true_loop`]).
    /// Degenerate counts are handled by the policy as for `Auto`.
    Soft,
}

/// What [`GateMode::Auto`] does when the counts are degenerate.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum DegeneratePolicy {
    /// Keep every candidate with a positive count (a zero count is no loop)
    /// and leave them to the robust back end, which
    /// decides them by their residuals (the default: EM; measured on the
    /// outlier benchmark, README "Robust loops": with 10 wrong among
    /// hundreds of true loops the counts show one component, and dropping
    /// them all threw every true loop away). The degeneracy is reported.
    #[default]
    KeepAll,
    /// Drop every candidate with a count, so a wrong loop can never get in;
    /// the choice without a robust back end.
    DropAll,
    /// Use the crossing anyway when it exists, else drop every candidate with
    /// a count.
    Threshold,
}

impl DegeneratePolicy {
    /// The name on the command line: `keep-all`, `drop-all` or `threshold`.
    pub fn name(self) -> &'static str {
        match self {
            Self::KeepAll => "keep-all",
            Self::DropAll => "drop-all",
            Self::Threshold => "threshold",
        }
    }
}

/// The gate's verdict on a list of loop-closure candidates.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct GateDecision {
    /// The mode used.
    pub mode: GateMode,
    /// The degenerate policy used.
    pub policy: DegeneratePolicy,
    /// One entry per candidate, in input order: whether it is kept.
    pub kept: Vec<bool>,
    /// The count threshold applied (`count < threshold` dropped); `None`
    /// when none was (mode `Off`, or a degenerate fit whose policy kept or
    /// dropped everything).
    pub threshold: Option<f64>,
    /// The learned fit (mode `Auto` only).
    pub fit: Option<ThresholdFit>,
    /// Whether the fit was degenerate (mode `Auto` only).
    pub degenerate: bool,
    /// Why, when it was.
    pub reason: Option<Degeneracy>,
}

impl GateDecision {
    /// Number of candidates kept.
    pub fn kept_count(&self) -> usize {
        self.kept.iter().filter(|&&k| k).count()
    }

    /// Number of candidates dropped.
    pub fn dropped_count(&self) -> usize {
        self.kept.len() - self.kept_count()
    }
}

/// The rule the gate ends up applying to counted candidates.
enum Rule {
    KeepAll,
    /// Every candidate with a positive count (a zero count is no loop).
    NonZero,
    DropAll,
    /// `count ≥ N`, exact in integers.
    AtLeast(u64),
    /// `count ≥ T_GV`.
    Learned(f64),
}

impl Rule {
    fn keeps(&self, count: u64) -> bool {
        match *self {
            Rule::KeepAll => true,
            Rule::NonZero => count > 0,
            Rule::DropAll => false,
            Rule::AtLeast(n) => count >= n,
            Rule::Learned(t) => count as f64 >= t,
        }
    }

    fn threshold(&self) -> Option<f64> {
        match *self {
            Rule::KeepAll | Rule::NonZero | Rule::DropAll => None,
            Rule::AtLeast(n) => Some(n as f64),
            Rule::Learned(t) => Some(t),
        }
    }
}

/// Applies the geometric-verification gate to loop-closure candidates.
///
/// `counts[i]` is candidate `i`'s inlier count; `None` means the front end
/// gave none, and such a candidate is always kept: the gate has nothing to
/// say about it. For counted candidates:
///
/// * [`GateMode::Off`]: all kept.
/// * [`GateMode::Fixed`]`(N)`: kept when `count ≥ N`.
/// * [`GateMode::Auto`]: `T_GV` is learned from the counts (zeros included,
///   see [`learn_threshold`]); kept when `count ≥ T_GV`. When the counts are
///   degenerate, `policy` decides.
/// * [`GateMode::Soft`]: learned as `Auto`, all kept unless degenerate (then
///   as `Auto`).
///
/// ```ignore
/// use pgo::gate::{gate, DegeneratePolicy, GateMode, MixtureOptions};
/// let mut counts: Vec<Option<u64>> = (0..200).map(|i| Some(8 + (i * 7919) % 25)).collect();
/// counts.extend((0..40).map(|i| Some(150 + (i * 31) % 60)));
/// counts.push(None);
/// let d = gate(&counts, GateMode::Auto, DegeneratePolicy::DropAll, &MixtureOptions::default());
/// assert!(!d.degenerate);
/// assert_eq!(d.kept_count(), 41); // the 40 strong candidates and the uncounted one
///
/// let all_equal = vec![Some(12); 30];
/// let d = gate(&all_equal, GateMode::Auto, DegeneratePolicy::DropAll, &MixtureOptions::default());
/// assert!(d.degenerate && d.kept_count() == 0);
/// println!("{}", d.reason.unwrap()); // all 30 non-zero inlier counts equal 12: ...
/// ```
pub fn gate(
    counts: &[Option<u64>],
    mode: GateMode,
    policy: DegeneratePolicy,
    options: &MixtureOptions,
) -> GateDecision {
    let (rule, fit) = match mode {
        GateMode::Off => (Rule::KeepAll, None),
        GateMode::Fixed(n) => (Rule::AtLeast(n), None),
        GateMode::Auto | GateMode::Soft => {
            let known: Vec<u64> = counts.iter().flatten().copied().collect();
            let fit = learn_threshold(&known, options);
            let rule = match (mode, fit.is_degenerate()) {
                (GateMode::Soft, false) => Rule::KeepAll,
                _ => auto_rule(&fit, policy),
            };
            (rule, Some(fit))
        }
    };
    let kept = counts
        .iter()
        .map(|c| c.is_none_or(|c| rule.keeps(c)))
        .collect();
    let reason = fit.as_ref().and_then(|f| f.degeneracy.clone());
    GateDecision {
        mode,
        policy,
        kept,
        threshold: rule.threshold(),
        fit,
        degenerate: reason.is_some(),
        reason,
    }
}

/// The rule for [`GateMode::Auto`], given the fit and the policy.
fn auto_rule(fit: &ThresholdFit, policy: DegeneratePolicy) -> Rule {
    let learned = fit.threshold.as_ref().map(|t| Rule::Learned(t.count));
    match (fit.is_degenerate(), policy) {
        (false, _) | (true, DegeneratePolicy::Threshold) => learned.unwrap_or(Rule::DropAll),
        (true, DegeneratePolicy::KeepAll) => Rule::NonZero,
        (true, DegeneratePolicy::DropAll) => Rule::DropAll,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use rand::SeedableRng;
    use rand::rngs::StdRng;
    use rand_distr::{Distribution, LogNormal, Normal, Uniform};
    use rayon::prelude::*;
    use statrs::distribution::{Continuous, LogNormal as StatrsLogNormal, Normal as StatrsNormal};

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

    /// The crossing of two weighted normals by scanning the log-odds for a
    /// sign change from − to + and bisecting: no use of the quadratic.
    fn brute_force_crossing(p: &Params) -> Option<f64> {
        let log_odds = |y: f64| {
            let n0 = StatrsNormal::new(p.mu[0], p.sigma[0]).unwrap();
            let n1 = StatrsNormal::new(p.mu[1], p.sigma[1]).unwrap();
            (p.weight[1].ln() + n1.ln_pdf(y)) - (p.weight[0].ln() + n0.ln_pdf(y))
        };
        let steps = 20_000;
        let h = (p.mu[1] - p.mu[0]) / steps as f64;
        let mut crossing = None;
        for i in 0..steps {
            let (mut lo, mut hi) = (p.mu[0] + i as f64 * h, p.mu[0] + (i + 1) as f64 * h);
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
            assert!(crossing.is_none(), "two ascending crossings in {p:?}");
            crossing = Some(0.5 * (lo + hi));
        }
        crossing
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
            let truth = Params {
                mu: [25f64.ln() - ln_max, 250f64.ln() - ln_max],
                sigma: [0.45, 0.25],
                weight: [2000.0 / 2400.0, 400.0 / 2400.0],
            };
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
            let true_crossing = brute_force_crossing(&truth).unwrap();
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
    fn mixture_counts(rng: &mut StdRng, n: usize, truth: &Params) -> Vec<u64> {
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
    fn fit_in_log_counts(fit: &ThresholdFit) -> Option<(Params, f64)> {
        let (m, t) = (fit.mixture.as_ref()?, fit.threshold.as_ref()?);
        let ln_max = (fit.max_count as f64).ln();
        let p = Params {
            mu: m.mu.map(|mu| mu + ln_max),
            sigma: m.sigma,
            weight: m.weight,
        };
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
                let truth = Params {
                    mu: [30f64.ln(), 30f64.ln() + delta],
                    sigma: [0.5, 0.35],
                    weight: [1.0 - w_loop, w_loop],
                };
                // The Bayes-optimal threshold of the true mixture (ln count).
                let bayes = brute_force_crossing(&truth).unwrap();
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
                        let e = |f: fn(&Params) -> [f64; 2]| {
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
        for (start, params) in em_starts(&y, floor) {
            let mut trace = Vec::new();
            let run = run_em(&y, params, floor, &MixtureOptions::default(), |ll| {
                trace.push(ll)
            })
            .unwrap();
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
    fn m_step_variance_is_taken_around_the_new_mean() {
        let mut rng = StdRng::seed_from_u64(11);
        let normal = Normal::new(-1.0, 0.7).unwrap();
        let unit = Uniform::new(0.0, 1.0).unwrap();
        let y: Vec<f64> = (0..60).map(|_| normal.sample(&mut rng)).collect();
        let resp: Vec<[f64; 2]> = (0..60)
            .map(|_| {
                let r: f64 = unit.sample(&mut rng);
                [1.0 - r, r]
            })
            .collect();
        let p = m_step(&y, &resp, MIN_VARIANCE_FLOOR).unwrap();
        for k in 0..2 {
            let w: Vec<f64> = resp.iter().map(|r| r[k]).collect();
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
                (p.sigma[k].powi(2) - var).abs() < 1e-12,
                "k {k}: {} vs {var}",
                p.sigma[k].powi(2)
            );
            let mean = w.iter().zip(&y).map(|(w, y)| w * y).sum::<f64>() / total;
            assert!((p.mu[k] - mean).abs() < 1e-12);
            assert!((p.weight[k] - total / 60.0).abs() < 1e-12);

            // Algorithm 1 lines 25–26 verbatim (μ_k still a partial sum) gives
            // something else entirely: this test tells the two apart.
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
        let resp = [[1.0, 0.0], [1.0, 0.0], [1.0, 0.0], [0.0, 1.0], [0.0, 1.0]];
        let p = m_step(&y, &resp, 1e-4).unwrap();
        assert_eq!(p.sigma[0], 1e-2);
        assert!((p.sigma[1] - 0.05).abs() < 1e-12);
        // An empty component is reported, not divided by zero.
        let empty = [[1.0, 0.0]; 5];
        assert_eq!(m_step(&y, &empty, 1e-4), None);
    }

    #[test]
    fn closed_form_crossing_matches_a_brute_force_scan() {
        let mut rng = StdRng::seed_from_u64(5);
        let u = |rng: &mut StdRng, a: f64, b: f64| Uniform::new(a, b).unwrap().sample(rng);
        let (mut with, mut without) = (0, 0);
        for _ in 0..300 {
            let m0 = u(&mut rng, -4.0, -1.0);
            let w1 = u(&mut rng, 0.02, 0.98);
            let p = Params {
                mu: [m0, m0 + u(&mut rng, 0.2, 4.0)],
                sigma: [u(&mut rng, 0.05, 1.5), u(&mut rng, 0.05, 1.5)],
                weight: [1.0 - w1, w1],
            };
            match (p.crossing_log(), brute_force_crossing(&p)) {
                (Some(a), Some(b)) => {
                    assert!((a - b).abs() < 1e-9, "{p:?}: {a} vs {b}");
                    assert!(p.log_odds(a).abs() < 1e-9);
                    with += 1;
                }
                (None, None) => without += 1,
                (a, b) => panic!("{p:?}: closed form {a:?}, scan {b:?}"),
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
        let w: [f64; 2] = [0.7, 0.3];
        // Equal σ: y* = (μ₀ + μ₁)/2 − σ² ln(π₁/π₀) / (μ₁ − μ₀).
        let expected = 0.5 * (m0 + m1) - s * s * f64::ln(w[1] / w[0]) / (m1 - m0);
        for s1 in [s, s * (1.0 + 1e-15), s * (1.0 - 1e-13)] {
            let p = Params {
                mu: [m0, m1],
                sigma: [s, s1],
                weight: w,
            };
            let y = p.crossing_log().unwrap();
            assert!((y - expected).abs() < 1e-10, "σ₁ = {s1}: {y} vs {expected}");
        }
        // Nearly equal σ: still the quadratic, with a tiny leading coefficient,
        // where the root is prone to cancellation.
        for s1 in [s * (1.0 + 1e-9), s * (1.0 - 1e-8), s * (1.0 + 1e-6)] {
            let p = Params {
                mu: [m0, m1],
                sigma: [s, s1],
                weight: w,
            };
            let (y, scan) = (p.crossing_log().unwrap(), brute_force_crossing(&p).unwrap());
            assert!((y - scan).abs() < 1e-11, "σ₁ = {s1}: {y} vs {scan}");
        }
    }

    #[test]
    fn e_step_survives_counts_far_from_both_components() {
        // ln N underflows below about −745: at 60σ both densities are 0 in
        // linear space, but not in log space.
        let p = Params {
            mu: [-2.0, 1.0],
            sigma: [1.0, 1.0],
            weight: [0.5, 0.5],
        };
        let y = [-60.0, 45.0, -0.5];
        let mut r = [[0.0; 2]; 3];
        let ll = e_step(&y, &p, &mut r);
        assert!(ll.is_finite() && ll < -1000.0, "{ll}");
        assert!(r.iter().flatten().all(|x| x.is_finite()), "{r:?}");
        assert!(r[0][0] > 0.999_999 && r[1][1] > 0.999_999, "{r:?}");
        assert!(r.iter().all(|r| (r[0] + r[1] - 1.0).abs() < 1e-15));

        // Real counts spanning 19 orders of magnitude: the paper's start is at
        // ln v ≈ −2, some counts at ln v ≈ −44.
        let mut rng = StdRng::seed_from_u64(31);
        let mut counts = draw_counts(&mut rng, 200, 20.0, 0.4);
        counts.extend(draw_counts(&mut rng, 50, 1.5e19, 0.05));
        let max = *counts.iter().max().unwrap();
        let y = log_normalized(&counts, max);
        let floor = VarianceFloor::Quantization.value(max);
        let paper = em_starts(&y, floor)[0].1;
        let run = run_em(&y, paper, floor, &MixtureOptions::default(), |_| {}).unwrap();
        assert!(run.params.is_finite() && run.log_likelihood.is_finite());
        let fit = default_fit(&counts);
        assert_eq!(fit.degeneracy, None);
        assert!(fit.threshold.unwrap().count > 1e6);
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
    fn collapsed_and_starts() {
        let p = Params {
            mu: [-2.0, 0.0],
            sigma: [0.5, 0.01],
            weight: [0.99, 0.01],
        };
        // 0.01 · 100 = 1 count at the floor: a collapse onto one value.
        assert!(is_collapsed(&p, 100, 1e-4, 3.0));
        // The same spike holding 10 counts is a component.
        assert!(!is_collapsed(&p, 1000, 1e-4, 3.0));
        // Less than one count's worth of weight, floor or not.
        let q = Params {
            sigma: [0.5, 0.3],
            weight: [0.9995, 0.0005],
            ..p
        };
        assert!(is_collapsed(&q, 1000, 1e-4, 3.0));
        let sorted = [-3.0, -2.9, -2.8, -0.2, -0.1];
        assert_eq!(two_means_split(&sorted), Some(3));
        assert_eq!(two_means_split(&[-1.0, -1.0]), None);
        assert_eq!(quantile(&sorted, 0.5), -2.8);
        assert!((quantile(&sorted, 0.875) - -0.15).abs() < 1e-12);
    }

    #[test]
    fn collapsed_fits_lose_even_with_a_higher_likelihood() {
        // 50 counts around ln v = −2 and one well above them.
        let mut rng = StdRng::seed_from_u64(17);
        let normal = Normal::new(-2.0, 0.3).unwrap();
        let mut y: Vec<f64> = (0..50).map(|_| normal.sample(&mut rng)).collect();
        y.push(-1.0);
        let floor = 1e-6;
        let opts = MixtureOptions::default();
        // A start with a spike on the lone top count stays there: a
        // likelihood the floor alone makes large.
        let spike = Params {
            mu: [-2.0, -1.0],
            sigma: [0.3, 1e-3],
            weight: [50.0 / 51.0, 1.0 / 51.0],
        };
        let broad = Params {
            mu: [-2.2, -1.8],
            sigma: [0.5, 0.5],
            weight: [0.5, 0.5],
        };
        let spike_run = run_em(&y, spike, floor, &opts, |_| {}).unwrap();
        let broad_run = run_em(&y, broad, floor, &opts, |_| {}).unwrap();
        assert!(
            spike_run.log_likelihood > broad_run.log_likelihood,
            "{spike_run:?} {broad_run:?}"
        );
        assert!(is_collapsed(
            &spike_run.params,
            y.len(),
            floor,
            opts.min_loop_size
        ));
        let best = best_fit(
            &y,
            &[(EmStart::Paper, spike), (EmStart::Quartiles, broad)],
            floor,
            &opts,
        )
        .unwrap();
        assert_eq!(best.start, EmStart::Quartiles);
        assert_eq!(best_fit(&y, &[(EmStart::Paper, spike)], floor, &opts), None);
    }

    #[test]
    fn bic_or_ashman_report_their_numbers() {
        let d = Degeneracy::OneComponent {
            bic_one: 123.4,
            bic_two: 130.1,
        };
        assert_eq!(
            d.to_string(),
            "the counts show one component: BIC 1-comp 123.4 <= 2-comp 130.1"
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
        assert!(
            (s.bic_two - (5.0 * n.ln() - 2.0 * m.log_likelihood)).abs() < 1e-8 * s.bic_two.abs()
        );
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
        let at = m.params().log_odds(t.normalized.ln());
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
        let sum =
            m.weighted_density(Component::NotLoop, v) + m.weighted_density(Component::Loop, v);
        assert_eq!(m.density(v), sum);
    }

    #[test]
    fn the_paper_start_is_tried_first_and_components_are_ordered() {
        let fit = default_fit(&two_population_counts(14));
        let m = fit.mixture.unwrap();
        assert!(m.mu[0] < m.mu[1] && m.converged && m.iterations > 1);
        assert!((m.weight[0] + m.weight[1] - 1.0).abs() < 1e-12);
        let swapped = Params {
            mu: [0.0, -1.0],
            sigma: [0.1, 0.2],
            weight: [0.3, 0.7],
        }
        .loop_last();
        assert_eq!(
            swapped,
            Params {
                mu: [-1.0, 0.0],
                sigma: [0.2, 0.1],
                weight: [0.7, 0.3]
            }
        );
        let starts = em_starts(&[-3.0, -2.0, -1.0, 0.0], 1e-6);
        let kinds: Vec<EmStart> = starts.iter().map(|s| s.0).collect();
        assert_eq!(
            kinds,
            vec![EmStart::Paper, EmStart::Quartiles, EmStart::TwoMeans]
        );
        assert_eq!(starts[0].1.mu, [-2.0, 1.0]);
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
}
