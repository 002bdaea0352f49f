//! Log-normal models of the RANSAC inlier counts of loop candidates.

use super::SimulationError;
use super::options::{non_negative, positive};
use rand::Rng;
use rand_distr::StandardNormal;
use serde::{Deserialize, Serialize};

/// Log-normal models of the RANSAC inlier count of loop candidates.
///
/// A count is `round(exp(ln median + σ·N(0, 1)))`. The overlap of the two
/// classes is set by the medians and the σ's: with the defaults (150 vs 25,
/// σ = 0.5 each) the medians are `ln 6 ≈ 1.79` apart in log space, so a
/// threshold at their geometric mean (≈ 61) misclassifies `Φ(−1.79) ≈ 4 %`
/// of each class. Closer medians or larger σ's make gating harder.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct InlierModel {
    /// Median count of true loop closures (default 150).
    pub true_median: f64,
    /// Standard deviation of the natural log of true counts (default 0.5).
    pub true_sigma: f64,
    /// Median count of wrong loop candidates (default 25).
    pub wrong_median: f64,
    /// Standard deviation of the natural log of wrong counts (default 0.5).
    pub wrong_sigma: f64,
}

impl Default for InlierModel {
    fn default() -> Self {
        Self {
            true_median: 150.0,
            true_sigma: 0.5,
            wrong_median: 25.0,
            wrong_sigma: 0.5,
        }
    }
}

impl InlierModel {
    /// Checks that the medians are positive and the σ's non-negative (all
    /// finite).
    pub fn validate(&self) -> Result<(), SimulationError> {
        positive("inliers.true_median", self.true_median)?;
        non_negative("inliers.true_sigma", self.true_sigma)?;
        positive("inliers.wrong_median", self.wrong_median)?;
        non_negative("inliers.wrong_sigma", self.wrong_sigma)
    }

    /// Draws the inlier count of a true loop closure.
    pub fn sample_true<R: Rng + ?Sized>(&self, rng: &mut R) -> u64 {
        log_normal_count(self.true_median, self.true_sigma, rng)
    }

    /// Draws the inlier count of a wrong loop candidate.
    pub fn sample_wrong<R: Rng + ?Sized>(&self, rng: &mut R) -> u64 {
        log_normal_count(self.wrong_median, self.wrong_sigma, rng)
    }
}

/// Draws the count of a wrong candidate: from the true-loop model with
/// probability `true_like_share` (a wrong candidate that passes geometric
/// verification, as aliased places do), from the wrong-loop model
/// otherwise. A share of zero draws nothing more than the wrong count, so
/// that it reproduces the draws of the model alone.
pub(super) fn sample_wrong_candidate<R: Rng + ?Sized>(
    model: &InlierModel,
    true_like_share: f64,
    rng: &mut R,
) -> u64 {
    if true_like_share > 0.0 && rng.random_bool(true_like_share) {
        model.sample_true(rng)
    } else {
        model.sample_wrong(rng)
    }
}

/// The counts of one group of `len` wrong candidates: with `by_group`, the
/// whole group's from the true-loop model with probability
/// `true_like_share` (one draw: verification fooled by a repeated place is
/// fooled along all of it), else each candidate's by
/// [`sample_wrong_candidate`].
pub(super) fn sample_wrong_group<R: Rng + ?Sized>(
    model: &InlierModel,
    (true_like_share, by_group): (f64, bool),
    len: usize,
    rng: &mut R,
) -> Vec<u64> {
    if !by_group {
        return (0..len)
            .map(|_| sample_wrong_candidate(model, true_like_share, rng))
            .collect();
    }
    let like = true_like_share > 0.0 && rng.random_bool(true_like_share);
    (0..len)
        .map(|_| {
            if like {
                model.sample_true(rng)
            } else {
                model.sample_wrong(rng)
            }
        })
        .collect()
}

/// `round(exp(ln median + σ·z))`; the float-to-integer cast saturates, so
/// absurd σ's give `u64::MAX` rather than wrapping.
fn log_normal_count<R: Rng + ?Sized>(median: f64, sigma: f64, rng: &mut R) -> u64 {
    let z: f64 = rng.sample(StandardNormal);
    (median.ln() + sigma * z).exp().round() as u64
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{SeedableRng, rngs::StdRng};

    #[test]
    fn inlier_overlap_is_tunable() {
        let mut rng = StdRng::seed_from_u64(5);
        let same = InlierModel {
            true_median: 40.0,
            true_sigma: 0.0,
            wrong_median: 40.0,
            wrong_sigma: 0.0,
        };
        assert_eq!(
            (same.sample_true(&mut rng), same.sample_wrong(&mut rng)),
            (40, 40)
        );
        let wide = InlierModel {
            true_sigma: 2.0,
            wrong_sigma: 2.0,
            ..Default::default()
        };
        let overlap = (0..2000)
            .filter(|_| wide.sample_true(&mut rng) < wide.sample_wrong(&mut rng))
            .count();
        assert!(overlap > 300, "wide models should overlap, got {overlap}");
    }
}
