//! The robust kernels of pgo's peers, for comparison with the loop model:
//! each turns a candidate's whitened squared residual `r² = eᵀΩe` into a
//! weight by a fixed formula, and iteratively reweighted least squares
//! solves until the weights settle.
//!
//! * Huber: `w = 1` for `r ≤ c`, else `c / r`.
//! * Cauchy: `w = c² / (c² + r²)`.
//! * DCS (Agarwal et al., ICRA 2013): `s = min(1, 2Φ / (Φ + r²))`, `w = s²`,
//!   `Φ = c²`.
//! * GNC with the truncated-least-squares surrogate (Yang et al., RA-L
//!   2020), the μ schedule of GTSAM's `GncOptimizer`: `μ₀ = c² / (2 r²_max −
//!   c²)`, `μ ← 1.4 μ`, until every weight is 0 or 1.

use super::RobustMethod;
use crate::geometry::Pose;
use crate::solve::{Session, SolveError};

/// The Cauchy weight `c²/(c² + r²)`.
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

/// The factor by which GNC's μ grows per round (GTSAM's `GncParams`
/// default).
pub const GNC_MU_STEP: f64 = 1.4;
/// GNC stops when μ passes this: every weight is binary long before.
const GNC_MU_MAX: f64 = 1e9;
/// A weight that moves less than this no longer needs another solve.
const WEIGHT_TOLERANCE: f64 = 1e-3;
/// Iterations of each solve between reweightings (generalised EM: each
/// M-step only has to improve).
const PARTIAL_ITERATIONS: usize = 5;
/// Most reweighting rounds.
const MAX_ROUNDS: usize = 100;

/// When a reweighting is done.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Until {
    /// The weights settle (each moves by at most 10⁻³ in a round), and the
    /// map is solved to the job's tolerance at them: the kernel's answer.
    Settled,
    /// The held set — the candidates of weight ≥ ½ — is the same two
    /// rounds in a row; the map is left where the last round's steps took
    /// it. What a start of EM's decisions needs: they take the held set
    /// and judge every candidate again by its innovation, so the weights'
    /// slow creep inside their side of ½ buys them nothing
    /// (docs/method.md §5).
    HeldSetRepeats,
}

/// Reweights the candidates `edges` with `method`'s kernel of width `c`
/// until the weights settle or the held set repeats (`until`), writing
/// them into `weights` (one per edge); returns the rounds taken and
/// whether the budget cut it short.
pub fn reweight<P: Pose<D>, const D: usize>(
    session: &mut Session<'_, P, D>,
    weights: &mut [f64],
    edges: &[usize],
    (method, c): (RobustMethod, f64),
    until: Until,
) -> Result<(usize, bool), SolveError> {
    let mut mu = None;
    for round in 0..MAX_ROUNDS {
        // The first weights come from the initial guess's residuals (GNC's
        // μ₀ too), as a robust LM weighs its first linearisation: a first
        // solve with every candidate at weight 1 would let the wrong ones
        // bend the map before any is weighed down.
        if round > 0 {
            session.run(weights, PARTIAL_ITERATIONS)?;
        }
        if session.exhausted() {
            return Ok((round, true));
        }
        let graph = &*session.graph;
        let r2: Vec<f64> = edges
            .iter()
            .map(|&k| graph.edge_chi2(&graph.edges[k]))
            .collect();
        let old: Vec<f64> = edges.iter().map(|&k| weights[k]).collect();
        let new: Vec<f64> = match method {
            RobustMethod::Huber => r2.iter().map(|&r| huber_weight(r, c)).collect(),
            RobustMethod::Cauchy => r2.iter().map(|&r| cauchy_weight(r, c)).collect(),
            RobustMethod::Dcs => r2.iter().map(|&r| dcs_weight(r, c * c)).collect(),
            RobustMethod::Gnc => {
                let m = *mu.get_or_insert_with(|| gnc_start(&r2, c));
                mu = Some(m * GNC_MU_STEP);
                r2.iter().map(|&r| gnc_tls_weight(r, c, m)).collect()
            }
            RobustMethod::None | RobustMethod::Em => return Ok((round, false)),
        };
        for (&k, &w) in edges.iter().zip(&new) {
            weights[k] = w;
        }
        if until == Until::HeldSetRepeats {
            let held = |w: &f64| *w >= 0.5;
            if round > 0 && old.iter().map(held).eq(new.iter().map(held)) {
                return Ok((round + 1, false));
            }
            continue;
        }
        let moved = old
            .iter()
            .zip(&new)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        let binary = new.iter().all(|&w| w == 0.0 || w == 1.0);
        let settled = match mu {
            Some(m) => binary && moved <= WEIGHT_TOLERANCE || m > GNC_MU_MAX,
            None => moved <= WEIGHT_TOLERANCE,
        };
        if settled {
            session.converge(weights)?;
            return Ok((round + 1, false));
        }
    }
    session.converge(weights)?;
    Ok((MAX_ROUNDS, false))
}

/// GNC's first μ: `c² / (2 r²_max − c²)`, at least 10⁻⁶ (GTSAM's clamp);
/// when every residual is already inside the inlier band, a μ at which
/// every weight is 1.
fn gnc_start(r2: &[f64], c: f64) -> f64 {
    let c2 = c * c;
    let r2_max = r2.iter().copied().fold(0.0f64, f64::max);
    if 2.0 * r2_max <= c2 {
        GNC_MU_MAX
    } else {
        (c2 / (2.0 * r2_max - c2)).max(1e-6)
    }
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
        }
        // GNC-TLS: 1 inside the lower band, 0 outside the upper, continuous.
        let mu = 0.5;
        assert_eq!(gnc_tls_weight(0.1, c, mu), 1.0);
        assert_eq!(gnc_tls_weight(100.0, c, mu), 0.0);
        let lower = mu / (mu + 1.0) * 4.0;
        let upper = (mu + 1.0) / mu * 4.0;
        assert!((gnc_tls_weight(lower * 1.000001, c, mu) - 1.0).abs() < 1e-5);
        assert!(gnc_tls_weight(upper * 0.999999, c, mu) < 1e-5);
        assert_eq!(gnc_start(&[1.0], c), GNC_MU_MAX);
        assert!((gnc_start(&[10.0], c) - 4.0 / 16.0).abs() < 1e-15);
    }
}
