//! Robust weights for loop-closure candidates.
//!
//! Every method here turns the whitened squared residual `r² = eᵀΩe` of a
//! loop candidate into a weight `w ∈ [0, 1]` that scales its information in
//! the next weighted least-squares solve (iteratively reweighted least
//! squares). Trusted edges (odometry, priors) are never reweighted: only
//! candidates are given to a [`Reweighter`].
//!
//! * [`RobustMethod::Em`] — Lee, Fraundorfer & Pollefeys, "Robust Pose-Graph
//!   Loop-Closures with Expectation-Maximization" (IROS 2013). Each candidate
//!   has a latent inlier/outlier state; the E-step gives it the posterior
//!   weight, which for their model is the Cauchy weight
//!   `w = c² / (c² + r²)`; the M-step is the weighted solve. Candidates whose
//!   weight falls below [`RobustOptions::switch_off`] are switched off (weight
//!   0) and may come back in a later E-step; when the weights settle, those
//!   still off with a weight below [`RobustOptions::remove`] are removed for
//!   good. Beyond the paper, measured on the outlier benchmark (README,
//!   "Robust loops"): the kernel starts wide (the median residual) and
//!   narrows to `c` as GNC's does, so the first maps are not pulled by the
//!   wrong loops a narrow kernel would keep; the settled weights are then
//!   turned into hard decisions (accept iff `w ≥ ½` at `r²/s²`, `s²` the
//!   variance factor of the decided map, re-decided until the set repeats),
//!   so the map returned is the least-squares map of the accepted loops and
//!   the χ² test tests it; once the decisions at `c` settle, the width of
//!   the decisions is learned from the residuals with the gate's mixture
//!   ([`Reweighter::decision_c`]); and the candidates the
//!   gate dropped are judged once at the final map
//!   ([`Reweighter::hold_out`]), with their counts' posteriors as priors.
//!   When a decided map does not fit the file's information, the noise
//!   scale of the decisions is searched ([`Reweighter::update_fit`]); the
//!   candidates the decided map was solved without are judged once more by
//!   their innovation, against the population the gate dropped
//!   ([`Reweighter::accept_by_innovation`], each judgement in
//!   [`Reweighter::judgements`]). With a prior inlier probability `p` per
//!   candidate, the E-step multiplies the Cauchy odds `c²/r²` by the prior
//!   odds `p/(1 − p)`.
//! * [`RobustMethod::Huber`]: `w = 1` for `r ≤ c`, else `c / r`.
//! * [`RobustMethod::Cauchy`]: `w = c² / (c² + r²)`, plain IRLS (no switching).
//! * [`RobustMethod::Dcs`]: dynamic covariance scaling (Agarwal et al.,
//!   ICRA 2013): `s = min(1, 2Φ / (Φ + r²))`, `w = s²`, with `Φ = c²`.
//! * [`RobustMethod::Gnc`]: graduated non-convexity with the truncated
//!   least-squares surrogate (Yang et al., RA-L 2020), μ schedule as in
//!   GTSAM's `GncOptimizer`: `μ₀ = c² / (2 r²_max − c²)`, `μ ← 1.4 μ`, until
//!   every weight is 0 or 1.
//!
//! `c` is on the whitened-residual-norm scale; its default comes from a χ²
//! quantile of the edge dimension ([`default_c`]), not a magic number: an
//! inlier's `r²` is χ²_D-distributed when the information matrices are
//! calibrated.

use crate::gate::{MixtureOptions, TwoNormals, fit_two_normals};
use serde::Serialize;

mod innovation;
pub use innovation::{DROPPED_PASSES, InnovationJudgement};

/// A robust method for loop candidates.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum RobustMethod {
    /// Plain least squares.
    None,
    /// Expectation-maximisation with switching off and removal (IROS 2013).
    #[default]
    Em,
    /// Huber kernel.
    Huber,
    /// Cauchy kernel.
    Cauchy,
    /// Dynamic covariance scaling.
    Dcs,
    /// Graduated non-convexity, truncated least squares.
    Gnc,
}

impl RobustMethod {
    /// Its name on the command line and in the JSON report.
    pub fn name(self) -> &'static str {
        match self {
            Self::None => "none",
            Self::Em => "em",
            Self::Huber => "huber",
            Self::Cauchy => "cauchy",
            Self::Dcs => "dcs",
            Self::Gnc => "gnc",
        }
    }
}

/// Options of the robust reweighting.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RobustOptions {
    /// The method.
    pub method: RobustMethod,
    /// Kernel width `c` on the whitened-residual-norm scale.
    pub c: f64,
    /// EM: weights below this switch a candidate off.
    pub switch_off: f64,
    /// EM: candidates off with a weight below this at the end of an EM
    /// process are removed for good.
    pub remove: f64,
    /// Stop when no weight changes by more than this.
    pub tolerance: f64,
    /// EM: solve each decided set from a fresh initial guess made with the
    /// accepted loops rather than from the previous map (a wrong loop met
    /// on the way can have left that map in another basin of the cost).
    pub restart: bool,
    /// Most reweighting rounds (E-steps); EM's hard decisions after them
    /// are limited separately ([`MAX_DECISIONS`]).
    pub max_rounds: usize,
    /// EM: learn the width of the hard decisions from the residuals
    /// ([`Reweighter::decision_c`]) instead of deciding at `c`.
    pub learn_width: bool,
    /// EM: search the noise scale when a decided map does not fit the
    /// file's information ([`Reweighter::update_fit`]).
    pub scale_search: bool,
}

impl RobustOptions {
    /// Defaults for edges of dimension `dim` (3 or 6); see [`default_c`].
    pub fn new(method: RobustMethod, dim: usize) -> Self {
        Self {
            method,
            c: default_c(method, dim),
            switch_off: 0.01,
            remove: 1e-4,
            tolerance: 1e-3,
            max_rounds: 100,
            restart: true,
            learn_width: true,
            scale_search: true,
        }
    }
}

/// The default kernel width of each method for edges of dimension `dim`:
///
/// * EM: `√χ²_dim(1 − 10⁻⁶)` (5.54 in 2D, 6.19 in 3D): a calibrated inlier
///   has `r²/s²` χ²_dim-distributed (`s²` the variance factor of the decided
///   map, see the pipeline), so one true loop in a million falls below
///   weight ½, while a wrong loop, typically hundreds of σ away, stays far
///   out. Measured on the outlier benchmark (README, "Robust loops"): with
///   `√χ²_dim(0.99)` EM rejected 3–11 % of the true loops of manhattan and
///   parking-garage, whose loop residuals are heavy-tailed at the clean
///   optimum, and left manhattan's map 1 % of its size away; with this width
///   it keeps ≥ 97.6 % of them at the same precision;
/// * GNC: `√χ²_dim(0.99)` (3.368 / 4.100), the inlier threshold of GTSAM's
///   `GncOptimizer`;
/// * Huber and Cauchy: `√χ²_dim(0.95)` (2.796 / 3.548), the width the peer
///   baselines use;
/// * DCS: `c = 1`, i.e. `Φ = c² = 1`, Agarwal et al.'s default.
pub fn default_c(method: RobustMethod, dim: usize) -> f64 {
    let quantile = |alpha: f64| {
        crate::stats::chi2_critical(dim.max(1) as u64, alpha)
            .map(f64::sqrt)
            .unwrap_or(3.0)
    };
    match method {
        RobustMethod::Em => quantile(EM_ALPHA),
        RobustMethod::Gnc | RobustMethod::None => quantile(0.01),
        RobustMethod::Huber | RobustMethod::Cauchy => quantile(0.05),
        RobustMethod::Dcs => 1.0,
    }
}

/// The Cauchy (EM) weight `c²/(c² + r²)`.
///
/// ```ignore
/// assert_eq!(pgo::robust::cauchy_weight(4.0, 2.0), 0.5);
/// ```
pub fn cauchy_weight(r2: f64, c: f64) -> f64 {
    let c2 = c * c;
    c2 / (c2 + r2)
}

/// The Huber weight: 1 inside `c`, `c/r` outside.
pub fn huber_weight(r2: f64, c: f64) -> f64 {
    let r = r2.sqrt();
    if r <= c { 1.0 } else { c / r }
}

/// The DCS weight `s²` with `s = min(1, 2Φ/(Φ + r²))`.
pub fn dcs_weight(r2: f64, phi: f64) -> f64 {
    let s = (2.0 * phi / (phi + r2)).min(1.0);
    s * s
}

/// The EM weight with a prior inlier probability `p`: the posterior odds
/// are the Cauchy odds `c²/r²` times the prior odds `p/(1 − p)`.
/// `p = ½` gives the Cauchy weight.
pub fn em_weight(r2: f64, c: f64, prior: f64) -> f64 {
    if prior >= 1.0 {
        return 1.0;
    }
    if prior <= 0.0 {
        return 0.0;
    }
    let prior_odds = prior / (1.0 - prior);
    let c2 = c * c;
    let odds = prior_odds * c2;
    odds / (odds + r2)
}

/// The GNC-TLS weight at control parameter `mu` (GTSAM's formula).
pub fn gnc_tls_weight(r2: f64, c: f64, mu: f64) -> f64 {
    let c2 = c * c;
    let upper = (mu + 1.0) / mu * c2;
    let lower = mu / (mu + 1.0) * c2;
    if r2 >= upper {
        0.0
    } else if r2 <= lower {
        1.0
    } else {
        ((c2 * mu * (mu + 1.0) / r2).sqrt() - mu).clamp(0.0, 1.0)
    }
}

/// The state of one candidate under EM.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum CandidateState {
    /// In the optimisation with its weight.
    Active,
    /// Weight below the switch-off level: out for now, may come back.
    Off,
    /// Removed for good.
    Removed,
}

/// Where EM is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum EmPhase {
    /// E-steps with continuous weights and switching off.
    Weighting,
    /// Hard decisions: the accepted candidates (weight ≥ ½) at full weight,
    /// the others off, re-decided at each solution until the set is stable.
    Deciding {
        /// Decisions taken so far.
        rounds: usize,
    },
    /// Finished.
    Done,
}

/// Iteratively reweights candidates from their residuals.
///
/// Use: start with [`Reweighter::new`] (EM starts every candidate at
/// `min(1, p/(1 − p))`, its prior odds capped at 1: weight 1 without prior
/// knowledge; the other methods at 1), solve with [`Reweighter::weights`]
/// (to convergence when [`Reweighter::full_solve`] says so, a few iterations
/// otherwise), call [`Reweighter::update`] with the new residuals, and
/// repeat while it returns `true`. Report [`Reweighter::final_weights`].
///
/// EM runs in two phases. **Weighting**: E-steps (the posterior weight of
/// each candidate from its residual) alternate with M-steps (the weighted
/// solve); candidates whose weight falls below
/// [`RobustOptions::switch_off`] are switched off (weight 0) and come back
/// when a later E-step gives them more; when the weights settle (no change
/// above [`RobustOptions::tolerance`], or the switched-off and accepted sets
/// unchanged for [`STABLE_ROUNDS`] rounds), the candidates still off with a
/// weight below [`RobustOptions::remove`] are removed for good.
/// **Deciding**: the candidates with weight ≥ ½ are accepted and solved at
/// full weight, the others left out; at that solution every candidate not
/// removed is accepted again iff its posterior weight at `r²/s²` is ≥ ½
/// (`s²` given to [`Reweighter::update_scaled`]), until the accepted set
/// repeats (at most [`MAX_DECISIONS`] times). So the map is the
/// least-squares solution over the trusted edges and the accepted loops, a
/// loop is accepted exactly when it is consistent with that map, and the χ²
/// test of the accepted edges tests the map that is returned. **Rescue**:
/// held-out candidates ([`Reweighter::hold_out`]) are judged once at that
/// map. The final weights are the posteriors at the final map for the
/// accepted candidates, 0 for the others.
#[derive(Clone, Debug)]
pub struct Reweighter {
    options: RobustOptions,
    priors: Vec<f64>,
    weights: Vec<f64>,
    posteriors: Vec<f64>,
    states: Vec<CandidateState>,
    /// EM: candidates held out of the weighting and the decisions (those
    /// the gate dropped), judged once at the final decided map.
    held_out: Vec<bool>,
    rounds: usize,
    mu: Option<f64>,
    phase: EmPhase,
    /// Rounds in a row in which the switched-off and accepted sets stayed
    /// the same.
    stable: usize,
    /// EM: the factor `m ≥ 1` of the annealed kernel width `c²·m` (set by
    /// the first E-step, divided by [`ANNEAL_FACTOR`] every round).
    anneal: Option<f64>,
    /// EM: a restart from a fresh initial guess was asked for.
    restart_pending: bool,
    /// EM: the mixture of the residuals at the map the width was learned
    /// at, and the width (see [`Reweighter::decision_c`]).
    residual_fit: Option<TwoNormals>,
    decision_c: Option<f64>,
    width_learned: bool,
    /// EM: the held-out candidates are waiting to be judged by their
    /// innovation ([`Reweighter::innovation_request`]).
    innovation_pending: bool,
    /// EM: candidates accepted by [`Reweighter::accept_by_innovation`].
    innovation_accepted: usize,
    /// EM: each candidate's latest judgement by its innovation.
    judgements: Vec<Option<InnovationJudgement>>,
    /// EM: the search for the noise scale when a decided map does not fit
    /// the file's ([`Reweighter::update_fit`]).
    scale_search: ScaleSearch,
}

/// EM's search for the noise scale of its decisions
/// ([`Reweighter::update_fit`]).
#[derive(Clone, Debug, Default)]
enum ScaleSearch {
    /// Not needed so far: every decided map fitted the file's information.
    #[default]
    Idle,
    /// Deciding at the trial scale `scale`.
    Trying {
        scale: f64,
        trials: usize,
        /// The variance factor of the map the last trial was taken at.
        last_v: f64,
        /// The decided set before the first trial (weights, states).
        before: (Vec<f64>, Vec<CandidateState>),
    },
    /// Over: a trial scale made a map that fits it, or none did and the
    /// decisions went back to the file's scale.
    Over { trials: usize, found: bool },
}

/// How EM's search for the noise scale ended ([`Reweighter::update_fit`]),
/// for the report.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ScaleSearchOutcome {
    /// Every decided map fitted the file's information: no trial.
    NotNeeded,
    /// A trial scale made a map that fits it; from there on the scale was
    /// measured again.
    Found,
    /// No trial scale made a map that fits it while keeping half the
    /// accepted loops: the decisions went back to the file's scale (an
    /// over-confident file, or too few consistent loops).
    Undone,
    /// Stopped while searching (the iteration or time budget ran out).
    Searching,
}

/// EM: the kernel width's square is divided by this every round until it
/// reaches `c²` (GTSAM's GNC grows μ by the same factor).
pub const ANNEAL_FACTOR: f64 = 1.4;

/// EM: rounds in a row with unchanged switched-off and accepted sets after
/// which the weighting phase ends even if some weight still moves by more
/// than the tolerance.
pub const STABLE_ROUNDS: usize = 3;

/// EM: most hard decisions (solves to convergence) in the deciding phase.
pub const MAX_DECISIONS: usize = 8;

/// EM: the probability that a true loop falls beyond the decision width:
/// `c = √χ²_D(1 − EM_ALPHA)` ([`default_c`]), and the learned width is the
/// same quantile of the learned distribution ([`Reweighter::decision_c`]).
pub const EM_ALPHA: f64 = 1e-6;

/// EM: most hard decisions at the learned width, after those at `c`.
pub const WIDE_DECISIONS: usize = 3;

/// EM: most trial scales ([`Reweighter::update_fit`]), each
/// [`ANNEAL_FACTOR`] below the last: down to `1.4⁻³⁰ ≈ 4·10⁻⁵`, beyond the
/// 20–20 000× under-confidence of square-root information (MANIFEST.md,
/// quirk 1).
pub const MAX_TRIALS: usize = 30;

/// How a map fits the file's noise model: `Σ eᵀΩe` over the edges it was
/// solved with (at their plain cost) and their redundancy (Σ edge
/// dimensions − free pose parameters).
///
/// ```ignore
/// use pgo::robust::MapFit;
/// let fit = MapFit { chi2: 450.0, dof: 500 };
/// assert_eq!(fit.variance_factor(), 0.9);
/// assert!(fit.fits(1.0)); // χ²₅₀₀(1 − 10⁻⁶) ≈ 673
/// assert!(!fit.fits(0.5));
/// ```
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MapFit {
    /// `Σ eᵀΩe` over the edges the map was solved with.
    pub chi2: f64,
    /// Degrees of freedom (0: no redundancy).
    pub dof: usize,
}

impl MapFit {
    /// The a-posteriori variance factor `χ²/dof` (1 without redundancy).
    pub fn variance_factor(&self) -> f64 {
        if self.dof > 0 && self.chi2 > 0.0 && self.chi2.is_finite() {
            self.chi2 / self.dof as f64
        } else {
            1.0
        }
    }

    /// Whether the map fits noise `s2` times the information's, at EM's
    /// level: `χ² ≤ s2 · χ²_dof(1 − EM_ALPHA)`. Always without redundancy.
    pub fn fits(&self, s2: f64) -> bool {
        self.dof == 0
            || crate::stats::chi2_critical(self.dof as u64, EM_ALPHA)
                .map_or(true, |limit| self.chi2 <= s2 * limit)
    }
}

/// EM: the variance floor of the residual mixture (on `ln(r²/s²)`): a
/// spread of 10⁻³ in the log, far below any real one.
const RESIDUAL_VARIANCE_FLOOR: f64 = 1e-6;

impl Reweighter {
    /// A reweighter for `priors.len()` candidates; `priors` are their prior
    /// inlier probabilities (½ when nothing is known; only EM uses them).
    pub fn new(options: RobustOptions, priors: Vec<f64>) -> Self {
        let n = priors.len();
        let weights = if options.method == RobustMethod::Em {
            priors.iter().map(|&p| em_initial_weight(p)).collect()
        } else {
            vec![1.0; n]
        };
        Self {
            options,
            posteriors: weights.clone(),
            weights,
            states: vec![CandidateState::Active; n],
            held_out: vec![false; n],
            priors,
            rounds: 0,
            mu: None,
            phase: EmPhase::Weighting,
            stable: 0,
            anneal: None,
            restart_pending: false,
            residual_fit: None,
            decision_c: None,
            width_learned: false,
            innovation_pending: false,
            innovation_accepted: 0,
            judgements: vec![None; n],
            scale_search: ScaleSearch::Idle,
        }
    }

    /// EM: holds the candidates marked `true` out of the weighting and the
    /// decisions (weight 0, switched off) and judges them once, at the final
    /// decided map, which none of them shaped: those whose posterior there
    /// is ≥ ½ are accepted and the map is solved once more with them. This
    /// is how the candidates the gate dropped are *rescued*: a true loop
    /// whose count fell below `T_GV` comes back when its residual is that of
    /// an inlier, and a wrong one cannot bend the map until it fits.
    /// Without effect for the other methods (held-out candidates stay at
    /// weight 0).
    pub fn hold_out(&mut self, held_out: &[bool]) {
        for (k, &h) in held_out.iter().enumerate().take(self.weights.len()) {
            self.held_out[k] = h;
            if h {
                self.weights[k] = 0.0;
                self.posteriors[k] = 0.0;
                self.states[k] = CandidateState::Off;
            }
        }
    }

    /// EM: candidates held out of the weighting phase that are accepted
    /// (final weight ≥ ½).
    pub fn rescued(&self) -> usize {
        self.held_out
            .iter()
            .zip(self.final_weights())
            .filter(|(h, w)| **h && *w >= 0.5)
            .count()
    }

    /// The weight of every candidate for the next solve.
    pub fn weights(&self) -> &[f64] {
        &self.weights
    }

    /// The weight to report for every candidate: for EM the posterior at the
    /// final solution for the accepted candidates (at least ½: the map was
    /// solved with them) and 0 for the others (switched off, removed, or
    /// held out and not rescued); for the other methods the weights of the
    /// last solve.
    pub fn final_weights(&self) -> Vec<f64> {
        if self.options.method == RobustMethod::Em && self.phase == EmPhase::Done {
            self.weights
                .iter()
                .zip(&self.posteriors)
                .map(|(&w, &p)| if w > 0.0 { p.max(0.5) } else { 0.0 })
                .collect()
        } else {
            self.weights.clone()
        }
    }

    /// Whether the next solve should run to convergence (EM's deciding
    /// phase) rather than a few iterations.
    pub fn full_solve(&self) -> bool {
        matches!(self.phase, EmPhase::Deciding { .. })
    }

    /// EM: whether the next solve should start from a fresh initial guess
    /// (built with the accepted loops); asking clears the request.
    pub fn take_restart(&mut self) -> bool {
        std::mem::take(&mut self.restart_pending)
    }

    /// The EM state of every candidate.
    pub fn states(&self) -> &[CandidateState] {
        &self.states
    }

    /// Reweighting rounds (E-steps and decisions) so far.
    pub fn rounds(&self) -> usize {
        self.rounds
    }

    /// Candidates removed for good.
    pub fn removed(&self) -> usize {
        self.states
            .iter()
            .filter(|s| **s == CandidateState::Removed)
            .count()
    }

    /// Whether the method reweights at all.
    pub fn is_active(&self) -> bool {
        self.options.method != RobustMethod::None && !self.weights.is_empty()
    }

    /// EM: the posteriors at a map polished after the last decision, from
    /// `r²/s²` as in [`Reweighter::update_scaled`] (the decisions and states
    /// stay).
    pub fn refresh(&mut self, r2: &[f64], s2: f64) {
        if self.options.method == RobustMethod::Em {
            let anneal = self.anneal.take();
            self.posterior(&scaled(r2, s2));
            self.anneal = anneal;
        }
    }

    /// One E-step from the candidates' whitened squared residuals at the
    /// latest solution. Returns whether another solve is needed.
    pub fn update(&mut self, r2: &[f64]) -> bool {
        self.update_scaled(r2, 1.0)
    }

    /// [`Reweighter::update`] with the noise scale `s²` of the latest
    /// solution (its variance factor): EM's hard decisions, the first
    /// included, judge `r²/s²`; its weighting rounds and the other methods
    /// use `r²` as it is.
    pub fn update_scaled(&mut self, r2: &[f64], s2: f64) -> bool {
        self.update_inner(r2, s2, None)
    }

    /// [`Reweighter::update_scaled`] given the latest map's fit
    /// ([`MapFit`]) rather than its scale; EM decides on `r²/s²` with
    /// [`Reweighter::decision_scale`]. The decision width `c` is on the
    /// file's scale, capped at 1 because under-confident information must
    /// not let wrong loops through; but when the wrong loops are many, the
    /// weighting can end, at `c`, in a map they bent, whose accepted set
    /// repeats — published intel with 1000 wrong candidates and no gate:
    /// every one accepted, the map's χ²/dof 102. Such a map does not fit
    /// the file's information, even one trial step ([`ANNEAL_FACTOR`])
    /// above it ([`MapFit::fits`] at 1.4), which real files do at their
    /// optimum (under-confident: χ²/dof from 4.5·10⁻⁵ to 0.69 at the
    /// standard datasets' optima). Then the scale is not known, and EM
    /// searches it: each decision is taken at a trial scale [`ANNEAL_FACTOR`]
    /// below the last (the annealing continued, one step per decided map),
    /// until a decided map fits one step above its trial scale (the
    /// resolution of the trials) and the last step no longer lowered its
    /// variance factor by a step's factor (it no longer took out loops that
    /// strained the map); from there on `s²` is measured again, and the
    /// decision width is learned only then. If a trial would keep fewer than
    /// half the loops accepted before the first, or [`MAX_TRIALS`] pass, the
    /// search is undone (an over-confident file, whose consistent loops
    /// fit no narrower scale) and the decisions go on at the file's scale.
    pub fn update_fit(&mut self, r2: &[f64], fit: MapFit) -> bool {
        let s2 = self.decision_scale(fit);
        self.update_inner(r2, s2, Some(fit))
    }

    /// EM: the noise scale `s²` of the decisions at a map with this fit: a
    /// trial scale while the maps do not fit it (see
    /// [`Reweighter::update_fit`]), else the variance factor, at most 1.
    pub fn decision_scale(&self, fit: MapFit) -> f64 {
        match self.scale_search {
            ScaleSearch::Trying { scale, .. } if !fit.fits(scale * ANNEAL_FACTOR) => scale,
            _ => fit.variance_factor().min(1.0),
        }
    }

    /// EM: how the search for the noise scale ended, and how many trial
    /// scales it took.
    pub fn scale_search(&self) -> (ScaleSearchOutcome, usize) {
        match self.scale_search {
            ScaleSearch::Idle => (ScaleSearchOutcome::NotNeeded, 0),
            ScaleSearch::Trying { trials, .. } => (ScaleSearchOutcome::Searching, trials),
            ScaleSearch::Over {
                trials,
                found: true,
            } => (ScaleSearchOutcome::Found, trials),
            ScaleSearch::Over {
                trials,
                found: false,
            } => (ScaleSearchOutcome::Undone, trials),
        }
    }

    fn update_inner(&mut self, r2: &[f64], s2: f64, fit: Option<MapFit>) -> bool {
        if !self.is_active() {
            return false;
        }
        // EM's deciding phase has its own limit (MAX_DECISIONS).
        if self.rounds >= self.options.max_rounds && self.options.method != RobustMethod::Em {
            return false;
        }
        self.rounds += 1;
        let c = self.options.c;
        let old = self.weights.clone();
        match self.options.method {
            RobustMethod::None => return false,
            RobustMethod::Huber => self.apply(r2, |r2, _| huber_weight(r2, c)),
            RobustMethod::Cauchy => self.apply(r2, |r2, _| cauchy_weight(r2, c)),
            RobustMethod::Dcs => self.apply(r2, |r2, _| dcs_weight(r2, c * c)),
            RobustMethod::Gnc => return self.gnc_step(r2, &old),
            RobustMethod::Em => return self.em_step(r2, s2, fit, &old),
        }
        max_change(&old, &self.weights) > self.options.tolerance
    }

    fn apply(&mut self, r2: &[f64], f: impl Fn(f64, f64) -> f64) {
        for ((w, &r), &p) in self.weights.iter_mut().zip(r2).zip(&self.priors) {
            *w = f(r, p);
        }
    }

    /// The posterior weight of every candidate not removed (0 for removed):
    /// while weighting, at the current (annealed) kernel width; once
    /// deciding, at the decision width ([`Reweighter::decision_c`]), and for
    /// a held-out candidate at least its plain Cauchy weight at `c` (an
    /// inlier at the calibrated width needs no help from its count; beyond
    /// it, its prior odds narrow the learned width).
    fn posterior(&mut self, r2: &[f64]) {
        let deciding = !matches!(self.phase, EmPhase::Weighting);
        let c = if deciding {
            self.decision_c()
        } else {
            self.options.c * self.anneal.unwrap_or(1.0).sqrt()
        };
        for k in 0..self.posteriors.len() {
            self.posteriors[k] = if self.states[k] == CandidateState::Removed {
                0.0
            } else if deciding && self.held_out[k] {
                em_weight(r2[k], c, self.priors[k]).max(cauchy_weight(r2[k], self.options.c))
            } else {
                em_weight(r2[k], c, self.priors[k])
            };
        }
    }

    /// EM: the kernel width of the hard decisions. With
    /// [`RobustOptions::learn_width`], learned from the data: `c` assumes
    /// that a true loop's `r²/s²` is χ²_D-distributed, but real loop
    /// residuals are heavy-tailed (some true loops of parking-garage sit at
    /// `r²/s²` ≈ 10³ at the clean optimum, while wrong ones are at 10⁶–10⁹;
    /// README, "Robust loops"). So two normals are fitted to `ln(r²/s²)` of
    /// the weighed candidates at the map where the decisions at `c` settled
    /// (see `decide`; the gate's EM,
    /// [`crate::gate::fit_two_normals`]); the lower one is the consistent
    /// loops (log-normal `r²/s²`), and the width is the larger of
    ///
    /// * its upper [`EM_ALPHA`]-quantile, `exp(μ₀ + z σ₀)` with
    ///   `z = Φ⁻¹(1 − EM_ALPHA)` — the quantile `c` takes of χ²_D, now of the
    ///   learned distribution; when the fit is degenerate as a split into
    ///   two populations (few wrong loops left), that of the heavier
    ///   component, the bulk of the loops (the other then sweeps up the few
    ///   far ones, or is a thin, broad halo whose mean may lie lower: city10000
    ///   with 10 wrong candidates, σ 4.5 against the bulk's 0.94);
    /// * where the weighted densities cross between the means (the gate's
    ///   rule), when the fit is not degenerate: a loop there is more likely
    ///   consistent than not;
    ///
    /// and never below `c`. `c` when there is no fit (fewer than 8
    /// residuals, every EM start collapsed), and before the first decision.
    pub fn decision_c(&self) -> f64 {
        self.decision_c.unwrap_or(self.options.c)
    }

    /// EM: the mixture of the weighed candidates' `ln(r²/s²)` at the map the
    /// decision width was learned at, when one was fitted.
    pub fn residual_fit(&self) -> Option<&TwoNormals> {
        self.residual_fit.as_ref()
    }

    /// Learns the decision width from `r2` (already divided by `s²`).
    fn learn_decision_width(&mut self, r2: &[f64]) {
        // An exact zero (a candidate nothing else constrains) has no
        // logarithm and says nothing about the spread: left out.
        let y: Vec<f64> = r2
            .iter()
            .zip(&self.held_out)
            .filter(|(r, h)| !**h && **r > 0.0 && r.is_finite())
            .map(|(r, _)| r.ln())
            .collect();
        // The inconsistent component may be small (a good gate leaves few
        // wrong loops); its size and separation only go into the report.
        let options = MixtureOptions {
            min_loop_weight: 0.0,
            ..MixtureOptions::default()
        };
        if y.len() < options.min_counts {
            self.residual_fit = None;
            self.decision_c = None;
            return;
        }
        let fit = fit_two_normals(&y, RESIDUAL_VARIANCE_FLOOR, &options);
        let z = crate::stats::normal_upper_quantile(EM_ALPHA);
        let separated = fit.degeneracy.is_none();
        let crossing = match fit.crossing_log {
            Some(t) if separated => t,
            _ => f64::NEG_INFINITY,
        };
        self.decision_c = consistent_component(&fit).map(|(mu, sigma)| {
            let width2 = (mu + z * sigma).max(crossing).exp();
            width2.sqrt().max(self.options.c)
        });
        self.residual_fit = Some(fit);
    }

    /// One EM round: an E-step with switching off in the weighting phase, a
    /// hard decision in the deciding phase.
    fn em_step(&mut self, r2: &[f64], s2: f64, fit: Option<MapFit>, old: &[f64]) -> bool {
        let o = self.options;
        let anneal = match self.anneal {
            // The first E-step: start wide enough that half the candidates
            // keep a weight ≥ ½ (the median residual), never below c².
            None => {
                let weighed: Vec<f64> = r2
                    .iter()
                    .zip(&self.held_out)
                    .filter(|(_, h)| !**h)
                    .map(|(r, _)| *r)
                    .collect();
                (median(&weighed) / (o.c * o.c)).max(1.0)
            }
            Some(m) => (m / ANNEAL_FACTOR).max(1.0),
        };
        self.anneal = Some(anneal);
        if matches!(self.phase, EmPhase::Weighting) {
            self.posterior(r2);
        } else {
            self.posterior(&scaled(r2, s2));
        }
        match self.phase {
            EmPhase::Done => false,
            EmPhase::Weighting => {
                let old_states = self.states.clone();
                for k in 0..self.weights.len() {
                    if self.states[k] == CandidateState::Removed || self.held_out[k] {
                        continue;
                    }
                    let w = self.posteriors[k];
                    if w < o.switch_off {
                        self.states[k] = CandidateState::Off;
                        self.weights[k] = 0.0;
                    } else {
                        self.states[k] = CandidateState::Active;
                        self.weights[k] = w;
                    }
                }
                let same_sets = old_states == self.states
                    && old
                        .iter()
                        .zip(&self.weights)
                        .all(|(a, b)| (*a >= 0.5) == (*b >= 0.5));
                self.stable = if same_sets { self.stable + 1 } else { 0 };
                if self.rounds < o.max_rounds
                    && (anneal > 1.0
                        || max_change(old, &self.weights) > o.tolerance
                            && self.stable < STABLE_ROUNDS)
                {
                    return true;
                }
                // The EM process converged: remove the lowest for good, then
                // decide.
                for k in 0..self.weights.len() {
                    if self.states[k] == CandidateState::Off && self.posteriors[k] < o.remove {
                        self.states[k] = CandidateState::Removed;
                        self.posteriors[k] = 0.0;
                    }
                }
                // Decisions are taken at the decision width.
                self.phase = EmPhase::Deciding { rounds: 0 };
                self.anneal = Some(1.0);
                self.posterior(&scaled(r2, s2));
                self.decide(old, r2, s2, fit)
            }
            EmPhase::Deciding { .. } => self.decide(old, r2, s2, fit),
        }
    }

    /// Accepts the candidates whose posterior is ≥ ½ (weight 1), leaves the
    /// others out (weight 0); returns whether the accepted set changed (and
    /// another solve is needed).
    ///
    /// `r2` are the residuals already divided by `s²`. When the set repeats
    /// at `c` (the map is that of the loops consistent at the calibrated
    /// width, which no wrong loop shaped), the decision width is learned at
    /// that map ([`Reweighter::decision_c`]) and the candidates decided
    /// again at it, once; it is not re-learned at the maps that follow,
    /// where a wrong loop it let in could have widened it further.
    fn decide(&mut self, old: &[f64], r2: &[f64], mut s2: f64, fit: Option<MapFit>) -> bool {
        let EmPhase::Deciding { mut rounds } = self.phase else {
            return false;
        };
        self.accept_by_posterior();
        // The first decision always needs a solve (the last one used
        // continuous weights); later ones only when the set changed.
        let mut changed = rounds == 0 || old != self.weights.as_slice();
        if let Some(scale) = fit.and_then(|fit| self.search_scale(fit, r2)) {
            // A trial scale, or back to the file's: its own decisions.
            s2 = scale;
            changed = true;
            rounds = 0;
        }
        let r2 = &scaled(r2, s2);
        // Learned once: when the set repeats at `c`, or when the decisions
        // at `c` run out (they can shrink the set round after round: each
        // true loop of the heavy tail that is left out lowers s² and so
        // pushes the next ones out).
        let searching = matches!(self.scale_search, ScaleSearch::Trying { .. });
        if (!changed || rounds >= MAX_DECISIONS)
            && !searching
            && !self.width_learned
            && self.options.learn_width
        {
            self.width_learned = true;
            self.learn_decision_width(r2);
            if self.decision_c.is_some() {
                self.posterior(r2);
                self.accept_by_posterior();
                changed = old != self.weights.as_slice();
            }
        }
        let limit = MAX_DECISIONS
            + if self.width_learned {
                WIDE_DECISIONS
            } else {
                0
            };
        if changed && rounds < limit {
            self.phase = EmPhase::Deciding { rounds: rounds + 1 };
            self.restart_pending = self.options.restart;
            return true;
        }
        if changed {
            // Out of decisions: keep the set the map was solved with.
            self.weights.copy_from_slice(old);
        }
        self.phase = EmPhase::Done;
        let rescued = self.rescue();
        self.innovation_pending = self.held_out.iter().any(|&h| h);
        rescued
    }

    /// EM: one step of the search for the noise scale at a decided map
    /// with this fit ([`Reweighter::update_fit`]); `r2` are the raw
    /// residuals. When it takes a trial, or undoes the search, the
    /// candidates are decided again and the scale they were decided at is
    /// returned.
    fn search_scale(&mut self, fit: MapFit, r2: &[f64]) -> Option<f64> {
        if self.width_learned || !self.options.scale_search {
            return None;
        }
        let v = fit.variance_factor();
        let (scale, trials, before) = match std::mem::take(&mut self.scale_search) {
            // Not even one trial step above the file's scale: the tolerance
            // of every fit below (a large graph's χ² test is tight, and a
            // χ²/dof a little above 1 is a heavy tail, not a bent map).
            ScaleSearch::Idle if !fit.fits(ANNEAL_FACTOR) => {
                (1.0, 0, (self.weights.clone(), self.states.clone()))
            }
            ScaleSearch::Trying {
                scale,
                trials,
                last_v,
                before,
            } => {
                if fit.fits(scale * ANNEAL_FACTOR) && v * ANNEAL_FACTOR >= last_v {
                    // Found: the decision just taken, at the measured scale,
                    // stands.
                    self.scale_search = ScaleSearch::Over {
                        trials,
                        found: true,
                    };
                    return None;
                }
                (scale, trials, before)
            }
            other => {
                self.scale_search = other;
                return None;
            }
        };
        let accepted = |w: &[f64]| w.iter().filter(|&&w| w >= 0.5).count();
        let floor = accepted(&before.0).div_ceil(2).max(1);
        let t = scale / ANNEAL_FACTOR;
        self.posterior(&scaled(r2, t));
        self.accept_by_posterior();
        if trials < MAX_TRIALS && accepted(&self.weights) >= floor {
            self.scale_search = ScaleSearch::Trying {
                scale: t,
                trials: trials + 1,
                last_v: v,
                before,
            };
            return Some(t);
        }
        // Undone: back to the set decided before the first trial, at the
        // file's scale.
        (self.weights, self.states) = before;
        let s2 = v.min(1.0);
        self.posterior(&scaled(r2, s2));
        self.scale_search = ScaleSearch::Over {
            trials,
            found: false,
        };
        Some(s2)
    }

    /// Weight 1 for the candidates whose posterior is ≥ ½, 0 for the others;
    /// held-out candidates wait for the rescue, at the final map.
    fn accept_by_posterior(&mut self) {
        for k in 0..self.weights.len() {
            let accept = !self.held_out[k] && self.posteriors[k] >= 0.5;
            self.weights[k] = if accept { 1.0 } else { 0.0 };
            if self.states[k] != CandidateState::Removed {
                self.states[k] = if accept {
                    CandidateState::Active
                } else {
                    CandidateState::Off
                };
            }
        }
    }

    /// Accepts the held-out candidates whose posterior at the decided map
    /// (which none of them shaped) is ≥ ½, once and for all, never one of
    /// zero prior (a zero count); returns whether any was (and the map is to
    /// be solved again with them).
    fn rescue(&mut self) -> bool {
        let mut any = false;
        for k in 0..self.weights.len() {
            if self.held_out[k]
                && self.states[k] != CandidateState::Removed
                && self.priors[k] > 0.0
                && self.posteriors[k] >= 0.5
            {
                self.weights[k] = 1.0;
                self.states[k] = CandidateState::Active;
                any = true;
            }
        }
        any
    }

    /// One GNC step: weights at the current μ, then μ grows.
    fn gnc_step(&mut self, r2: &[f64], old: &[f64]) -> bool {
        let c = self.options.c;
        let c2 = c * c;
        let mu = match self.mu {
            Some(mu) => mu,
            None => {
                let r2_max = r2.iter().copied().fold(0.0f64, f64::max);
                if 2.0 * r2_max <= c2 {
                    // Every residual is already inside the inlier band.
                    self.weights.iter_mut().for_each(|w| *w = 1.0);
                    return false;
                }
                // GTSAM clamps μ₀ at 1e-6 against numerical trouble.
                (c2 / (2.0 * r2_max - c2)).max(1e-6)
            }
        };
        self.apply(r2, |r, _| gnc_tls_weight(r, c, mu));
        self.mu = Some(mu * 1.4);
        let binary = self.weights.iter().all(|&w| w == 0.0 || w == 1.0);
        !(binary && max_change(old, &self.weights) <= self.options.tolerance) && mu < 1e9
    }
}

/// The component of a residual mixture (on `ln(r²/s²)`) that stands for
/// the consistent loops, as `(μ, σ)`: with two populations the lower one;
/// without a clean split the bulk (the heavier component), not a thin,
/// broad halo whose mean happens to lie lower. `None` without a fit.
fn consistent_component(fit: &TwoNormals) -> Option<(f64, f64)> {
    fit.mixture.as_ref().map(|m| {
        let k = if fit.degeneracy.is_none() || m.weight[0] >= m.weight[1] {
            0
        } else {
            1
        };
        (m.mu[k], m.sigma[k])
    })
}

/// EM's starting weight for a candidate of prior inlier probability `p`:
/// its prior odds `p/(1 − p)`, capped at 1 (so 1 without prior knowledge,
/// `p = ½`, as in the paper, which starts from all loops).
pub fn em_initial_weight(prior: f64) -> f64 {
    if prior >= 0.5 {
        1.0
    } else {
        (prior / (1.0 - prior)).max(0.0)
    }
}

/// `r²/s²` (`r²` itself when `s²` is 1 or not a positive number).
fn scaled(r2: &[f64], s2: f64) -> Vec<f64> {
    if s2 > 0.0 && s2.is_finite() && s2 != 1.0 {
        r2.iter().map(|r| r / s2).collect()
    } else {
        r2.to_vec()
    }
}

/// The median of a slice (0 when empty).
fn median(x: &[f64]) -> f64 {
    if x.is_empty() {
        return 0.0;
    }
    let mut v = x.to_vec();
    let mid = v.len() / 2;
    let (_, m, _) = v.select_nth_unstable_by(mid, f64::total_cmp);
    *m
}

fn max_change(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;

    #[test]
    fn weight_functions_follow_their_formulas() {
        let c = 2.0;
        for &r2 in &[0.0, 0.5, 4.0, 9.0, 100.0, 1e6] {
            assert!((cauchy_weight(r2, c) - 4.0 / (4.0 + r2)).abs() < 1e-15);
            let huber = if r2.sqrt() <= c { 1.0 } else { c / r2.sqrt() };
            assert!((huber_weight(r2, c) - huber).abs() < 1e-15);
            let s: f64 = (2.0 * 4.0 / (4.0 + r2)).min(1.0);
            assert!((dcs_weight(r2, 4.0) - s * s).abs() < 1e-15);
            assert!((em_weight(r2, c, 0.5) - cauchy_weight(r2, c)).abs() < 1e-15);
        }
        // The prior shifts the posterior: a likely loop keeps more weight.
        assert!(em_weight(10.0, c, 0.9) > em_weight(10.0, c, 0.5));
        assert!(em_weight(10.0, c, 0.1) < em_weight(10.0, c, 0.5));
        assert_eq!(em_weight(1e9, c, 1.0), 1.0);
        // GNC-TLS: 1 inside the lower band, 0 outside the upper, continuous.
        let mu = 0.5;
        assert_eq!(gnc_tls_weight(0.1, c, mu), 1.0);
        assert_eq!(gnc_tls_weight(100.0, c, mu), 0.0);
        let lower = mu / (mu + 1.0) * 4.0;
        let upper = (mu + 1.0) / mu * 4.0;
        assert!((gnc_tls_weight(lower * 1.000001, c, mu) - 1.0).abs() < 1e-5);
        assert!(gnc_tls_weight(upper * 0.999999, c, mu) < 1e-5);
    }

    #[test]
    fn default_widths_are_chi2_quantiles() {
        assert!((default_c(RobustMethod::Cauchy, 3) - 7.814727903251178f64.sqrt()).abs() < 1e-9);
        assert!((default_c(RobustMethod::Huber, 6) - 12.591587243743977f64.sqrt()).abs() < 1e-9);
        // χ²₃ tail: erfc(√(x/2)) + √(2x/π)·e^(−x/2) = 10⁻⁶ at x = 30.6648497.
        assert!((default_c(RobustMethod::Em, 3) - 30.664849706213598f64.sqrt()).abs() < 1e-7);
        // χ²₆ tail: e^(−x/2)(1 + x/2 + x²/8) = 10⁻⁶ at x = 38.2583364.
        assert!((default_c(RobustMethod::Em, 6) - 38.25833637720968f64.sqrt()).abs() < 1e-7);
        assert!((default_c(RobustMethod::Gnc, 6) - 16.811893829770927f64.sqrt()).abs() < 1e-9);
        assert_eq!(default_c(RobustMethod::Dcs, 3), 1.0);
    }

    /// EM options with `c = 2` (`c² = 4`), whatever the default.
    pub(super) fn em_options() -> RobustOptions {
        RobustOptions {
            c: 2.0,
            ..RobustOptions::new(RobustMethod::Em, 3)
        }
    }

    #[test]
    fn em_switches_off_restores_removes_and_decides() {
        let mut rw = Reweighter::new(em_options(), vec![0.5; 4]);
        assert_eq!(rw.weights(), &[1.0; 4]);
        // Median residual 3 < c²: no annealing. Candidate 1 looks wrong.
        assert!(rw.update(&[1.0, 1e5, 3.0, 0.5]));
        assert_eq!(
            rw.states(),
            &[
                CandidateState::Active,
                CandidateState::Off,
                CandidateState::Active,
                CandidateState::Active
            ]
        );
        assert_eq!(rw.weights()[1], 0.0);
        assert!((rw.weights()[0] - 0.8).abs() < 1e-12);
        assert!(!rw.full_solve());
        // The solution moved: candidate 1 fits now and comes back.
        assert!(rw.update(&[1.0, 2.0, 3.0, 0.5]));
        assert_eq!(rw.states()[1], CandidateState::Active);
        assert!((rw.weights()[1] - 4.0 / 6.0).abs() < 1e-12);
        // It drifts away again; then the weights settle, the candidates still
        // off far out are removed for good, and the hard decisions start:
        // weight ≥ ½ → 1, else 0, solved to convergence.
        assert!(rw.update(&[1.0, 1e7, 3.0, 0.5]));
        assert!(rw.update(&[1.0, 1e7, 3.0, 0.5]));
        assert_eq!(rw.states()[1], CandidateState::Removed);
        assert_eq!(rw.removed(), 1);
        assert!(rw.full_solve());
        assert_eq!(rw.weights(), &[1.0, 0.0, 1.0, 1.0]);
        // At the decided map candidate 2 no longer fits (4/9 < ½): left out.
        assert!(rw.update(&[1.0, 0.0, 5.0, 0.5]));
        assert_eq!(rw.weights(), &[1.0, 0.0, 0.0, 1.0]);
        assert_eq!(rw.states()[2], CandidateState::Off);
        // Without it the map changes and it fits again (4/7.5 ≥ ½): restored.
        // The removed candidate never comes back, whatever its residual.
        assert!(rw.update(&[1.0, 0.0, 3.5, 0.5]));
        assert_eq!(rw.weights(), &[1.0, 0.0, 1.0, 1.0]);
        // The same set twice: done. The reported weights are the posteriors
        // at the final map, ≥ ½ exactly for the candidates solved with.
        assert!(!rw.update(&[1.0, 0.0, 3.5, 0.5]));
        assert!(!rw.full_solve());
        let expected = [0.8, 0.0, 4.0 / 7.5, 4.0 / 4.5];
        for (w, e) in rw.final_weights().iter().zip(expected) {
            assert!((w - e).abs() < 1e-12, "{:?}", rw.final_weights());
        }
        assert!(!rw.update(&[1.0, 0.0, 3.5, 0.5]), "finished for good");
    }

    /// EM at `c = 2` deciding at `c` (no learned width).
    fn em_options_at_c() -> RobustOptions {
        RobustOptions {
            learn_width: false,
            ..em_options()
        }
    }

    #[test]
    fn em_searches_the_noise_scale_when_the_decided_map_does_not_fit() {
        let mut rw = Reweighter::new(em_options_at_c(), vec![0.5; 10]);
        // Eight consistent candidates and two wrong ones that the file's
        // (under-confident) scale lets in: r² ≤ c² = 4.
        let mut r2 = vec![0.1; 10];
        r2[8] = 3.0;
        r2[9] = 3.5;
        // The map they bent does not fit the information: χ²/dof = 10.
        let bent = MapFit {
            chi2: 1000.0,
            dof: 100,
        };
        assert!(!bent.fits(1.0));
        assert!(rw.update_fit(&r2, bent));
        // The weights settle; the first decision, at the file's scale,
        // accepts all ten, and the map does not fit: the next decision is
        // at the trial scale 1/1.4, where the two wrong ones fall out
        // (3/0.714 > 4).
        assert!(rw.update_fit(&r2, bent));
        let mut expected = vec![1.0; 10];
        expected[8] = 0.0;
        expected[9] = 0.0;
        assert_eq!(rw.weights(), expected.as_slice());
        assert_eq!(rw.scale_search(), (ScaleSearchOutcome::Searching, 1));
        assert!((rw.decision_scale(bent) - 1.0 / ANNEAL_FACTOR).abs() < 1e-12);
        // Without them the map fits, and its variance factor fell by far
        // more than a trial step: one more trial, then the map still fits
        // and no longer improves — found; from there on s² is measured
        // (0.1), and the wrong ones, far out now, stay out.
        let fitting = MapFit {
            chi2: 10.0,
            dof: 100,
        };
        r2[8] = 50.0;
        r2[9] = 60.0;
        assert!(rw.update_fit(&r2, fitting));
        assert_eq!(rw.scale_search(), (ScaleSearchOutcome::Searching, 2));
        assert!(!rw.update_fit(&r2, fitting));
        assert_eq!(rw.weights(), expected.as_slice());
        assert_eq!(rw.decision_scale(fitting), 0.1);
        assert_eq!(rw.scale_search(), (ScaleSearchOutcome::Found, 2));
    }

    /// How many candidates are accepted (weight 1).
    fn accepted_count(rw: &Reweighter) -> usize {
        rw.weights().iter().filter(|&&w| w == 1.0).count()
    }

    /// Ten consistent loops whose residuals spread up to `c² = 4`.
    const SPREAD_UP_TO_C2: [f64; 10] = [0.4, 0.8, 1.2, 1.6, 2.0, 2.4, 2.8, 3.2, 3.6, 3.9];

    #[test]
    fn em_undoes_the_scale_search_when_the_trials_only_trim_consistent_loops() {
        // An over-confident file: no narrower scale makes the map fit.
        let r2 = SPREAD_UP_TO_C2;
        let over = MapFit {
            chi2: 300.0,
            dof: 100,
        };
        let mut rw = Reweighter::new(em_options_at_c(), vec![0.5; 10]);
        assert!(rw.update_fit(&r2, over));
        // All ten at the file's scale; the trials keep 7 (r² ≤ 4/1.4), then
        // 5 (≤ 4/1.96), then would keep 3, fewer than half: undone, back to
        // all ten at the file's scale, where the set repeats.
        assert!(rw.update_fit(&r2, over));
        assert_eq!(accepted_count(&rw), 7);
        assert!(rw.update_fit(&r2, over));
        assert_eq!(accepted_count(&rw), 5);
        assert!(rw.update_fit(&r2, over));
        assert_eq!(rw.weights(), &[1.0; 10]);
        assert_eq!(rw.scale_search(), (ScaleSearchOutcome::Undone, 2));
        assert_eq!(rw.decision_scale(over), 1.0);
        assert!(!rw.update_fit(&r2, over));
        assert_eq!(rw.weights(), &[1.0; 10]);
    }

    #[test]
    fn em_does_not_search_when_the_decided_map_fits() {
        let r2 = SPREAD_UP_TO_C2;
        let fitting = MapFit {
            chi2: 90.0,
            dof: 100,
        };
        let mut rw = Reweighter::new(em_options_at_c(), vec![0.5; 10]);
        assert!(rw.update_fit(&r2, fitting));
        // The first decision, at s² = 0.9: 3.6/0.9 = 4 is still in, 3.9/0.9
        // is out; then the set repeats.
        assert!(rw.update_fit(&r2, fitting));
        assert_eq!(accepted_count(&rw), 9);
        assert!(!rw.update_fit(&r2, fitting));
        assert_eq!(rw.scale_search(), (ScaleSearchOutcome::NotNeeded, 0));
    }

    #[test]
    fn em_judges_held_out_candidates_once_at_the_decided_map() {
        let mut rw = Reweighter::new(em_options(), vec![0.5; 3]);
        rw.hold_out(&[false, true, true]);
        assert_eq!(rw.weights(), &[1.0, 0.0, 0.0]);
        // Candidate 1 fits (r² = 1 < c² = 4), candidate 2 does not.
        let r2 = [1.0, 1.0, 100.0];
        let mut solves = 0;
        while rw.update(&r2) {
            solves += 1;
            // Not weighed, not decided: out of every map until the rescue.
            if rw.weights()[1] != 0.0 {
                assert_eq!(rw.weights(), &[1.0, 1.0, 0.0], "rescued: one more solve");
            }
            assert!(solves < 20);
        }
        assert_eq!(rw.final_weights(), vec![0.8, 0.8, 0.0]);
        assert_eq!(rw.rescued(), 1);
        assert_eq!(rw.states()[2], CandidateState::Off);
    }

    #[test]
    fn em_anneals_the_kernel_width_from_the_median_residual() {
        let mut rw = Reweighter::new(em_options(), vec![0.5; 4]);
        let r2 = [100.0, 100.0, 100.0, 1e6];
        // First E-step: c² is widened to the median residual, 100 = 25·c².
        assert!(rw.update(&r2));
        assert!((rw.weights()[0] - 0.5).abs() < 1e-12);
        assert_eq!(rw.states()[3], CandidateState::Off);
        // Then it shrinks by ANNEAL_FACTOR a round: the weights fall although
        // the residuals stay, until the width is c again.
        let mut previous = rw.weights()[0];
        let mut rounds = 1;
        while !rw.full_solve() {
            assert!(rw.update(&r2));
            rounds += 1;
            assert!(rw.weights()[0] <= previous + 1e-15);
            previous = rw.weights()[0];
            assert!(rounds < 30);
        }
        let annealing = (25.0f64.ln() / ANNEAL_FACTOR.ln()).ceil() as usize;
        assert!(rounds > annealing, "{rounds} rounds");
        // Decided at the plain width: 4/104 < ½ for all.
        assert_eq!(rw.weights(), &[0.0; 4]);
    }

    /// 50 consistent loops whose `ln r²` spreads evenly over [−4, 4] (a
    /// heavy tail: r² up to 55 with c² = 4) and 10 wrong ones at r² ≈ 10⁶.
    pub(super) fn heavy_tailed_residuals() -> Vec<f64> {
        let mut r2: Vec<f64> = (0..50)
            .map(|i| (-4.0 + 8.0 * i as f64 / 49.0).exp())
            .collect();
        r2.extend((0..10).map(|k| (14.0 + 0.5 * (k % 5) as f64).exp()));
        r2
    }

    /// Runs EM on residuals that do not move with the weights (every solve
    /// gives the same map) and returns the number of solves.
    pub(super) fn run_to_the_end(rw: &mut Reweighter, r2: &[f64]) -> usize {
        let mut solves = 0;
        while rw.update(r2) {
            solves += 1;
            assert!(solves < 100, "EM does not end");
        }
        solves
    }

    #[test]
    fn em_learns_the_decision_width_where_the_residual_mixture_crosses() {
        let r2 = heavy_tailed_residuals();
        let mut rw = Reweighter::new(em_options(), vec![0.5; r2.len()]);
        run_to_the_end(&mut rw, &r2);
        // Two populations: the width is the larger of the consistent loops'
        // quantile and the crossing, here between the consistent tail (55)
        // and the wrong loops (1.2·10⁶): every consistent loop accepted, no
        // wrong one.
        let c_d = rw.decision_c();
        assert!(c_d * c_d > 55.0 && c_d * c_d < 1.2e6, "c_d = {c_d}");
        let fit = rw.residual_fit().expect("a residual mixture");
        assert!(fit.degeneracy.is_none(), "{:?}", fit.degeneracy);
        let w = rw.final_weights();
        assert!(w[..50].iter().all(|&w| w >= 0.5), "{w:?}");
        assert!(w[50..].iter().all(|&w| w == 0.0), "{w:?}");

        // At c alone the tail beyond c² = 4 (ln r² > 1.39: 17 loops) is
        // rejected with the wrong ones.
        let fixed = RobustOptions {
            learn_width: false,
            ..em_options()
        };
        let mut rw = Reweighter::new(fixed, vec![0.5; r2.len()]);
        run_to_the_end(&mut rw, &r2);
        assert_eq!(rw.decision_c(), 2.0);
        let accepted = rw.final_weights().iter().filter(|&&w| w >= 0.5).count();
        assert_eq!(accepted, 33);
    }

    #[test]
    fn em_decision_width_is_the_consistent_loops_quantile() {
        // 200 consistent loops, ln r² at the normal quantiles of N(0, 1), and
        // two wrong ones: too few for a second population (degenerate), so
        // the width is the 1 − EM_ALPHA quantile of the lower component,
        // r² = exp(0 + 4.75 · 1) ≈ 116, not the crossing.
        let mut r2: Vec<f64> = (0..200)
            .map(|i| {
                let p = (i as f64 + 0.5) / 200.0;
                crate::stats::normal_upper_quantile(1.0 - p).exp()
            })
            .collect();
        r2.extend([14f64.exp(), 15f64.exp()]);
        let mut rw = Reweighter::new(em_options(), vec![0.5; r2.len()]);
        run_to_the_end(&mut rw, &r2);
        let fit = rw.residual_fit().expect("a fit");
        assert!(
            fit.degeneracy.is_some(),
            "two wrong loops are no population"
        );
        let z = crate::stats::normal_upper_quantile(EM_ALPHA);
        let ln_width2 = 2.0 * rw.decision_c().ln();
        assert!(
            (ln_width2 - z).abs() < 0.3,
            "ln c_d² = {ln_width2}, z = {z}"
        );
        let w = rw.final_weights();
        assert!(w[..200].iter().all(|&w| w >= 0.5));
        assert!(w[200..].iter().all(|&w| w == 0.0));
        // Never narrower than c.
        let wide = RobustOptions {
            c: 20.0,
            ..em_options()
        };
        let mut rw = Reweighter::new(wide, vec![0.5; r2.len()]);
        run_to_the_end(&mut rw, &r2);
        assert_eq!(rw.decision_c(), 20.0);
        // Too few residuals to fit: no fit at all, c.
        let mut rw = Reweighter::new(em_options(), vec![0.5; 4]);
        run_to_the_end(&mut rw, &[1.0, 2.0, 1e6, 3.0]);
        assert!(rw.residual_fit().is_none());
        assert_eq!(rw.decision_c(), 2.0);
    }

    #[test]
    fn em_decision_width_follows_the_bulk_not_a_broad_halo() {
        // 300 consistent loops (ln r² at the quantiles of N(0.2, 0.9)) and a
        // thin halo of 8 spread over ln r² ∈ [−9, 7], mean below the bulk's:
        // no clean split; the width is the bulk's quantile, ≈ exp(0.2 + 4.75
        // · 0.9), not the halo's.
        let mut r2: Vec<f64> = (0..300)
            .map(|i| {
                let p = (i as f64 + 0.5) / 300.0;
                (0.2 + 0.9 * crate::stats::normal_upper_quantile(1.0 - p)).exp()
            })
            .collect();
        r2.extend((0..8).map(|k| (-9.0 + 16.0 * k as f64 / 7.0).exp()));
        let mut rw = Reweighter::new(em_options(), vec![0.5; r2.len()]);
        run_to_the_end(&mut rw, &r2);
        let ln_width2 = 2.0 * rw.decision_c().ln();
        let bulk = 0.2 + 0.9 * crate::stats::normal_upper_quantile(EM_ALPHA);
        assert!(ln_width2 < bulk + 1.0, "ln c_d² = {ln_width2}, bulk {bulk}");
    }

    #[test]
    fn em_rescue_beyond_c_needs_the_count_odds() {
        // The kept candidates teach a width c_d; the held-out ones (the gate
        // dropped them; their priors are their counts' posteriors) are
        // accepted within c whatever their count, and beyond it when
        // r² ≤ c_d² · p/(1 − p).
        let mut r2 = heavy_tailed_residuals();
        let mut priors = vec![0.5; r2.len()];
        let mut rw = Reweighter::new(em_options(), priors.clone());
        run_to_the_end(&mut rw, &r2);
        let c_d2 = rw.decision_c().powi(2);
        let held = [
            (3.0, 0.001),      // within c² = 4: accepted
            (0.2 * c_d2, 0.4), // odds 2/3 > 0.2: accepted
            (0.2 * c_d2, 0.1), // odds 1/9 < 0.2: rejected
            (2.0 * c_d2, 0.5), // beyond the width: rejected
            (1.0, 0.0),        // zero count: never
        ];
        for &(r, p) in &held {
            r2.push(r);
            priors.push(p);
        }
        let mut rw = Reweighter::new(em_options(), priors);
        let mut mask = vec![false; 60];
        mask.extend([true; 5]);
        rw.hold_out(&mask);
        run_to_the_end(&mut rw, &r2);
        assert!((rw.decision_c().powi(2) - c_d2).abs() < 1e-9 * c_d2);
        let w = rw.final_weights();
        let accepted: Vec<bool> = w[60..].iter().map(|&w| w >= 0.5).collect();
        assert_eq!(accepted, [true, true, false, false, false]);
        assert_eq!(rw.rescued(), 2);
    }

    #[test]
    fn em_priors_shift_the_start_and_the_decision() {
        assert_eq!(em_initial_weight(0.5), 1.0);
        assert_eq!(em_initial_weight(0.9), 1.0);
        assert!((em_initial_weight(0.2) - 0.25).abs() < 1e-12);
        assert_eq!(em_initial_weight(0.0), 0.0);
        let rw = Reweighter::new(em_options(), vec![0.5, 0.2]);
        assert_eq!(rw.weights()[0], 1.0);
        assert!((rw.weights()[1] - 0.25).abs() < 1e-12);
        // Prior odds ¼: accepted only while r² ≤ c²/4 = 1.
        let mut rw = Reweighter::new(em_options(), vec![0.5, 0.2, 0.2]);
        let r2 = [0.5, 0.9, 1.2];
        while rw.update(&r2) {}
        assert_eq!(
            rw.final_weights()
                .iter()
                .map(|&w| w >= 0.5)
                .collect::<Vec<_>>(),
            vec![true, true, false]
        );
    }

    #[test]
    fn gnc_ends_with_binary_weights() {
        let opts = RobustOptions::new(RobustMethod::Gnc, 3);
        let mut rw = Reweighter::new(opts, vec![0.5; 4]);
        let r2 = [0.5, 2.0, 500.0, 1e4];
        let mut rounds = 0;
        while rw.update(&r2) {
            rounds += 1;
            assert!(rounds < 100);
        }
        assert_eq!(rw.weights(), &[1.0, 1.0, 0.0, 0.0]);
    }

    #[test]
    fn none_never_reweights() {
        let mut rw = Reweighter::new(RobustOptions::new(RobustMethod::None, 3), vec![0.5; 2]);
        assert!(!rw.update(&[1e9, 1e9]));
        assert_eq!(rw.weights(), &[1.0, 1.0]);
    }
}
