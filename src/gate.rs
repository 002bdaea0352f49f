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
//!    the crossing (Eq. 7), so all the work is done on `y` with a mixture of
//!    two normals ([`crate::stats::mixture`]).
//!    Log-likelihoods reported here are those of `y`, `Σ ln Σ_k π_k N(y|μ_k,σ_k)`
//!    (the likelihood of `v` is that minus `Σ y`).
//! 3. The component with the higher mean models true loops
//!    ([`Component::Loop`], index 1). The threshold is where the weighted
//!    densities cross between the two means (Eq. 7), solved in closed form
//!    ([`crate::stats::separation::crossing`]); `T_GV = max · exp(y*)`
//!    (line 33). **A candidate with `count < T_GV` is
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
//! width is then the variance floor. One with fewer counts that sits on one
//! value or two neighbouring ones (no wider than a count's step at its
//! mean) is a collapse, not a component, and loses to the other starts.
//! With very few distinct values (say, counts 1 to 5 only) the logarithm
//! spreads them unevenly and the checks can accept a split that reflects
//! the discreteness rather than two populations; such counts carry too
//! little information for any threshold.

use crate::stats::mixture::{
    EmFit, EmOptions, MIN_VARIANCE_FLOOR, NormalComponent, NormalMixture, best_fit, bic,
    kmeans_start, quantile_start,
};
use crate::stats::separation::{CLEAN_SEPARATION, ashman_d, crossing};
use serde::Serialize;
use std::fmt;

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

/// How much lower the two-component mixture's BIC must be than one
/// normal's for the counts to show two populations. A difference of BICs
/// approximates twice the logarithm of the Bayes factor between the two
/// models (Schwarz 1978), and evidence below 2 is "not worth more than a
/// bare mention" (Kass & Raftery 1995, "Bayes factors", JASA 90:773–795).
/// A few dozen counts of one population (a young map whose candidates all
/// verified alike) are split by chance that narrowly, and a gate drawn
/// between the halves would drop the true loops of the lower one.
pub const MIN_BIC_GAIN: f64 = 2.0;

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
    /// Two components whose BIC is not lower than one normal's by more
    /// than this are degenerate (default [`MIN_BIC_GAIN`]).
    pub min_bic_gain: f64,
    /// Ashman's D below this is degenerate (default [`CLEAN_SEPARATION`],
    /// the usual bound for a clean separation of two normals).
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
            min_bic_gain: MIN_BIC_GAIN,
            min_ashman_d: CLEAN_SEPARATION,
            min_loop_weight: 0.02,
            min_loop_size: 3.0,
        }
    }
}

impl MixtureOptions {
    /// The EM settings of these options with the variance floor `floor`.
    fn em(&self, floor: f64) -> EmOptions {
        EmOptions {
            tolerance: self.tolerance,
            max_iterations: self.max_iterations,
            variance_floor: floor,
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
    /// The record of a two-component EM fit (components sorted by mean) from
    /// `start` under the variance floor `floor`; `None` unless the fit has
    /// two components.
    fn from_fit(start: EmStart, fit: EmFit, floor: f64) -> Option<LogNormalMixture> {
        let &[low, high] = fit.mixture.components() else {
            return None;
        };
        Some(LogNormalMixture {
            mu: [low.mean, high.mean],
            sigma: [low.sigma, high.sigma],
            weight: [low.weight, high.weight],
            iterations: fit.iterations,
            converged: fit.converged,
            log_likelihood: fit.log_likelihood,
            start,
            variance_floor: floor,
        })
    }

    /// The two components as normals on `ln v`, [`Component::NotLoop`]
    /// first.
    pub fn components(&self) -> [NormalComponent; 2] {
        [0, 1].map(|k| NormalComponent {
            weight: self.weight[k],
            mean: self.mu[k],
            sigma: self.sigma[k],
        })
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
        (self.components()[component.index()].log_weighted_density(y) - y).exp()
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
        logistic(self.log_odds(y))
    }

    /// `ln(π₁N₁(y)) − ln(π₀N₀(y))` at `y = ln v`: positive where a true loop
    /// is the more probable explanation.
    fn log_odds(&self, y: f64) -> f64 {
        let [not_loop, true_loop] = self.components();
        true_loop.log_weighted_density(y) - not_loop.log_weighted_density(y)
    }

    /// Ashman's D of the two components
    /// ([`crate::stats::separation::ashman_d`]); above 2 they are cleanly
    /// separated.
    pub fn ashman_d(&self) -> f64 {
        let [not_loop, true_loop] = self.components();
        ashman_d(&not_loop, &true_loop)
    }

    /// The normalised threshold `v_T`: where the weighted densities cross
    /// between the means (Eq. 7), or `None` when they do not.
    pub fn crossing(&self) -> Option<f64> {
        self.crossing_log().map(f64::exp)
    }

    /// The crossing in `ln v`.
    fn crossing_log(&self) -> Option<f64> {
        let [not_loop, true_loop] = self.components();
        crossing(&not_loop, &true_loop)
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
    /// BIC does not prefer two components to one by more than
    /// [`MixtureOptions::min_bic_gain`].
    OneComponent {
        /// BIC of one component.
        bic_one: f64,
        /// BIC of two components.
        bic_two: f64,
        /// The gain asked of two components.
        min_gain: f64,
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
            Degeneracy::OneComponent {
                bic_one,
                bic_two,
                min_gain,
            } => write!(
                f,
                "the counts show one component: BIC 1-comp {bic_one:.1} is not above 2-comp {bic_two:.1} by more than {min_gain}"
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
/// ```
/// use pgo::{MixtureOptions, learn_threshold};
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
    let two = fit_two_normals(&y, (floor, &|y| count_step(y, max_count)), options);
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
/// component of the higher mean), EM run from the usual starts. The gate
/// fits `ln(count / max)`; the robust
/// back end fits the logs of the candidates' residuals ([`crate::robust`]).
fn fit_two_normals(
    y: &[f64],
    (floor, spacing): (f64, &dyn Fn(f64) -> f64),
    options: &MixtureOptions,
) -> TwoNormals {
    let floor = floor.max(MIN_VARIANCE_FLOOR);
    let em = options.em(floor);
    let starts = em_starts(y, floor);
    let best = best_fit(y, &starts, &em, (options.min_loop_size, spacing))
        .and_then(|(start, fit)| LogNormalMixture::from_fit(start, fit, floor));
    let Some(mixture) = best else {
        return TwoNormals {
            mixture: None,
            separation: None,
            crossing_log: None,
            degeneracy: Some(Degeneracy::Collapsed {
                starts: starts.len(),
            }),
        };
    };
    let crossing_log = mixture.crossing_log();
    let n = y.len() as f64;
    let one = NormalMixture::moments(y, floor);
    let separation = Separation {
        bic_one: bic(1, n, one.log_likelihood(y)),
        bic_two: bic(2, n, mixture.log_likelihood),
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

/// The step from the count at `y = ln(count / max_count)` to the next one
/// up, in `y`: `ln(1 + 1/count)`. A component of a few counts no wider than
/// this sits on one count or two neighbouring ones
/// ([`NormalMixture::is_collapsed`]): 54 and 55 inliers among 28 counts
/// up to 445 made a "component" of σ 0.009 whose density outweighed the
/// rest, and dropped two true loops.
fn count_step(y: f64, max_count: u64) -> f64 {
    let count = max_count as f64 * y.exp();
    (1.0 / count.max(1.0)).ln_1p()
}

/// The EM starts, in order of preference on ties: the paper's, quartiles
/// (when the quartiles differ), 2-means (when there are two distinct
/// values); see [`EmStart`].
fn em_starts(y: &[f64], floor: f64) -> Vec<(EmStart, NormalMixture)> {
    let sigma = 1.0f64.max(floor.sqrt());
    let paper = PAPER_START_MU.map(|mean| NormalComponent {
        weight: 0.5,
        mean,
        sigma,
    });
    [
        (EmStart::Paper, NormalMixture::new(paper.to_vec()).ok()),
        (EmStart::Quartiles, quantile_start(y, 2, floor)),
        (EmStart::TwoMeans, kmeans_start(y, 2, floor)),
    ]
    .into_iter()
    .filter_map(|(start, mixture)| Some((start, mixture?)))
    .collect()
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
    if s.bic_one - s.bic_two <= options.min_bic_gain {
        Some(Degeneracy::OneComponent {
            bic_one: s.bic_one,
            bic_two: s.bic_two,
            min_gain: options.min_bic_gain,
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
    /// and leave them to the robust back end, which decides them by their
    /// residuals. Counts with few wrong loops among many true ones show one
    /// component, and dropping them all would throw every true loop away.
    /// The degeneracy is reported.
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

    /// The mixture whose posteriors `P(true loop | count)` are the
    /// candidates' count priors downstream: the fit's, when it separates
    /// two populations of counts. A fit degenerate only for want of a
    /// crossing does: one population so much larger than the other that
    /// its weighted density is the higher everywhere between the means
    /// (a few wrong loops among thousands of true ones) has no threshold
    /// to drop by, but its posteriors still tell a count from either.
    /// `None` with the gate off, without a fit, or when the fit is
    /// degenerate for any other reason (one component, overlapping, too
    /// small a loop component).
    pub fn count_model(&self) -> Option<&LogNormalMixture> {
        let separated =
            !self.degenerate || matches!(self.reason, Some(Degeneracy::NoCrossing { .. }));
        self.fit
            .as_ref()
            .and_then(|f| f.mixture.as_ref())
            .filter(|_| separated && self.mode != GateMode::Off)
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
mod tests;
