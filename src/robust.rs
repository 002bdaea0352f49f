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
//!   0) and may come back in a later E-step; at the end of each EM process,
//!   those still off with a weight below [`RobustOptions::remove`] are
//!   removed for good, and EM runs again, until nothing changes. With a
//!   prior inlier probability `p` per candidate (the soft gate), the E-step
//!   multiplies the Cauchy odds `c²/r²` by the prior odds `p/(1 − p)`.
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

use serde::Serialize;

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
    /// Most E-steps (reweighting rounds) in all.
    pub max_rounds: usize,
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
        }
    }
}

/// The default kernel width of each method for edges of dimension `dim`:
///
/// * EM and GNC: `√χ²_dim(0.99)` (3.368 in 2D, 4.100 in 3D), the inlier
///   threshold of GTSAM's `GncOptimizer`: a calibrated inlier has `r²`
///   χ²_dim-distributed, so 99 % of inliers keep a weight ≥ ½;
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
        RobustMethod::Em | RobustMethod::Gnc | RobustMethod::None => quantile(0.01),
        RobustMethod::Huber | RobustMethod::Cauchy => quantile(0.05),
        RobustMethod::Dcs => 1.0,
    }
}

/// The Cauchy (EM) weight `c²/(c² + r²)`.
///
/// ```
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

/// Iteratively reweights candidates from their residuals.
///
/// Use: start with [`Reweighter::new`] (all weights 1, or the priors for the
/// soft gate), solve with [`Reweighter::weights`], call
/// [`Reweighter::update`] with the new residuals, and repeat while it
/// returns `true`.
#[derive(Clone, Debug)]
pub struct Reweighter {
    options: RobustOptions,
    priors: Vec<f64>,
    weights: Vec<f64>,
    states: Vec<CandidateState>,
    rounds: usize,
    mu: Option<f64>,
    /// EM: whether the current EM process has converged and removal ran.
    em_removed_last: usize,
}

impl Reweighter {
    /// A reweighter for `priors.len()` candidates; `priors` are their prior
    /// inlier probabilities (½ when nothing is known; only EM uses them).
    pub fn new(options: RobustOptions, priors: Vec<f64>) -> Self {
        let n = priors.len();
        Self {
            options,
            weights: vec![1.0; n],
            states: vec![CandidateState::Active; n],
            priors,
            rounds: 0,
            mu: None,
            em_removed_last: 0,
        }
    }

    /// The current weight of every candidate.
    pub fn weights(&self) -> &[f64] {
        &self.weights
    }

    /// The EM state of every candidate.
    pub fn states(&self) -> &[CandidateState] {
        &self.states
    }

    /// Reweighting rounds (E-steps) so far.
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

    /// One E-step from the candidates' whitened squared residuals at the
    /// latest solution. Returns whether another solve is needed.
    pub fn update(&mut self, r2: &[f64]) -> bool {
        if !self.is_active() || self.rounds >= self.options.max_rounds {
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
            RobustMethod::Em => return self.em_step(r2, &old),
        }
        max_change(&old, &self.weights) > self.options.tolerance
    }

    fn apply(&mut self, r2: &[f64], f: impl Fn(f64, f64) -> f64) {
        for ((w, &r), &p) in self.weights.iter_mut().zip(r2).zip(&self.priors) {
            *w = f(r, p);
        }
    }

    /// E-step of EM with switching off; at the end of an EM process (weights
    /// settled), removes the lowest for good and starts another process.
    fn em_step(&mut self, r2: &[f64], old: &[f64]) -> bool {
        let o = self.options;
        for k in 0..self.weights.len() {
            if self.states[k] == CandidateState::Removed {
                continue;
            }
            let w = em_weight(r2[k], o.c, self.priors[k]);
            if w < o.switch_off {
                self.states[k] = CandidateState::Off;
                self.weights[k] = 0.0;
            } else {
                self.states[k] = CandidateState::Active;
                self.weights[k] = w;
            }
        }
        if max_change(old, &self.weights) > o.tolerance {
            return true;
        }
        // The EM process converged: remove the lowest for good.
        let mut removed = 0;
        for k in 0..self.weights.len() {
            if self.states[k] == CandidateState::Off
                && em_weight(r2[k], o.c, self.priors[k]) < o.remove
            {
                self.states[k] = CandidateState::Removed;
                removed += 1;
            }
        }
        self.em_removed_last = removed;
        // Removing an edge that already had weight 0 does not change the
        // solution, so the weights are final.
        false
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
                c2 / (2.0 * r2_max - c2)
            }
        };
        self.apply(r2, |r, _| gnc_tls_weight(r, c, mu));
        self.mu = Some(mu * 1.4);
        let binary = self.weights.iter().all(|&w| w == 0.0 || w == 1.0);
        !(binary && max_change(old, &self.weights) <= self.options.tolerance) && mu < 1e9
    }
}

fn max_change(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}

#[cfg(test)]
mod tests {
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
        assert!((default_c(RobustMethod::Em, 3) - 11.344866730144373f64.sqrt()).abs() < 1e-9);
        assert!((default_c(RobustMethod::Gnc, 6) - 16.811893829770927f64.sqrt()).abs() < 1e-9);
        assert_eq!(default_c(RobustMethod::Dcs, 3), 1.0);
    }

    #[test]
    fn em_switches_off_restores_and_removes() {
        let opts = RobustOptions::new(RobustMethod::Em, 3);
        let mut rw = Reweighter::new(opts, vec![0.5; 3]);
        // Candidate 1 looks wrong, candidate 2 borderline.
        assert!(rw.update(&[1.0, 1e5, 30.0]));
        assert_eq!(
            rw.states(),
            &[
                CandidateState::Active,
                CandidateState::Off,
                CandidateState::Active
            ]
        );
        assert_eq!(rw.weights()[1], 0.0);
        // Next round the solution moved: candidate 1 fits now and comes back.
        assert!(rw.update(&[1.0, 2.0, 30.0]));
        assert_eq!(rw.states()[1], CandidateState::Active);
        // It drifts away again, weights settle, the EM process ends and the
        // far-off candidate is removed for good.
        assert!(rw.update(&[1.0, 1e7, 30.0]));
        assert!(!rw.update(&[1.0, 1e7, 30.0]));
        assert_eq!(rw.states()[1], CandidateState::Removed);
        assert_eq!(rw.removed(), 1);
        // A removed candidate never comes back.
        rw.update(&[1.0, 0.0, 30.0]);
        assert_eq!(rw.weights()[1], 0.0);
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
