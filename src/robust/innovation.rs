//! EM's second look at the candidates the decided map was solved without
//! (dropped by the gate, rejected by EM): their *innovation* against that
//! map, weighed by their prior against the population the gate dropped
//! ([`Reweighter::accept_by_innovation`]).

use super::{
    CandidateState, MixtureOptions, RESIDUAL_VARIANCE_FLOOR, Reweighter, consistent_component,
};
use serde::Serialize;

impl Reweighter {
    /// EM, once the decisions are done: the candidates the decided map was
    /// solved without — the held-out ones (the gate dropped them) and those
    /// EM's decisions rejected, removed ones included — to be judged by
    /// [`Reweighter::accept_by_innovation`]; `None` when there are no
    /// held-out candidates (their population is the model of a wrong loop)
    /// or they were judged. Asking clears the request.
    pub fn innovation_request(&mut self) -> Option<Vec<usize>> {
        if !std::mem::take(&mut self.innovation_pending) {
            return None;
        }
        let which: Vec<usize> = (0..self.weights.len())
            .filter(|&k| self.held_out[k] || self.weights[k] == 0.0)
            .collect();
        (!which.is_empty()).then_some(which)
    }

    /// EM: judges the candidates `which` (from
    /// [`Reweighter::innovation_request`]) by their squared *innovation*
    /// `ν² = eᵀ(Ω⁻¹ + J·H⁻¹·Jᵀ)⁻¹e` at the decided map, divided by `s²`: the
    /// Mahalanobis distance of the error of an edge the map was solved
    /// without, the map's own uncertainty between the two poses included.
    /// Where the map is loosely tied between them (where the gate dropped
    /// the loops that would have tied it, or along a long loop), `r²` at
    /// the map can be far larger than `ν²`, and the plain residual leaves true
    /// loops out.
    ///
    /// `ν²` alone cannot decide: a wrong loop between poses that only
    /// odometry ties has a small innovation too. So each one left out with a
    /// non-zero prior is accepted when its prior odds (a held-out
    /// candidate's count posterior, a kept one's ½) times the likelihood
    /// ratio of `y = ln(ν²/s²)` are ≥ 1:
    ///
    /// * consistent loops: the consistent component of the residual mixture
    ///   ([`Reweighter::residual_fit`], the one the decision width comes
    ///   from);
    /// * wrong loops: the density of `y` among the held-out candidates
    ///   nothing accepted — the population the gate dropped, mostly wrong —
    ///   each weighted by `1 − p` (what its count says of it being wrong;
    ///   a local wrong loop with a small innovation weighs as much as it is
    ///   likely), the one judged left out: a Gaussian kernel density
    ///   estimate (Silverman's bandwidth `1.06 σ n_eff^(−1/5)`); within the
    ///   population's span mixed with a uniform floor of one
    ///   pseudo-observation over the range the held-out candidates span (a
    ///   wrong loop may land in a gap between the others, so such a gap
    ///   alone does not make a candidate consistent); below its lowest
    ///   points, the larger of the kernel estimate and an exponential tail
    ///   fitted to those points. The tail says how fast the wrong loops thin
    ///   out towards the consistent ones: where they stop abruptly (random
    ///   wrong loops), a candidate well below them is unlike any of them;
    ///   where local wrong loops straggle down, it reaches far. A kernel
    ///   estimate rather than one normal: the population is not one (random
    ///   wrong loops far out, local ones near the consistent loops), and a
    ///   normal fitted to it puts density where none of it lies. Those
    ///   accepted leave the population and the others are judged again,
    ///   until the accepted set repeats (at most [`DROPPED_PASSES`] passes).
    ///
    /// Held-out candidates removed in the weighting phase are judged too
    /// (their plain residual at a map they never shaped was far out, which
    /// is what the innovation looks at again); removal keeps them from the
    /// plain rescue only. Nothing is accepted without a residual fit or with
    /// fewer than 8 held-out candidates left to model the wrong ones.
    /// Returns whether any was accepted (and the map is to be solved again
    /// with them).
    pub fn accept_by_innovation(&mut self, which: &[usize], innovation2: &[f64], s2: f64) -> bool {
        let Some((mu_in, sigma_in)) = self.residual_fit.as_ref().and_then(consistent_component)
        else {
            return false;
        };
        let s2 = if s2 > 0.0 && s2.is_finite() { s2 } else { 1.0 };
        let y: Vec<f64> = innovation2
            .iter()
            .map(|&v| (v / s2).max(f64::MIN_POSITIVE).ln())
            .collect();
        // Judged: those left out with a non-zero prior; the dropped
        // population: the held-out ones left out.
        let judged: Vec<bool> = which
            .iter()
            .map(|&k| self.weights[k] == 0.0 && self.priors[k] > 0.0)
            .collect();
        let dropped: Vec<bool> = which
            .iter()
            .map(|&k| self.held_out[k] && self.weights[k] == 0.0)
            .collect();
        let held_y = which
            .iter()
            .zip(&y)
            .filter(|(k, _)| self.held_out[**k])
            .map(|(_, &y)| y);
        let (lo, hi) = held_y.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), y| {
            (lo.min(y), hi.max(y))
        });
        let mut accepted = vec![false; which.len()];
        let mut ln_odds = vec![f64::NEG_INFINITY; which.len()];
        let mut evaluated = false;
        for _ in 0..DROPPED_PASSES {
            let population: Vec<(usize, f64, f64)> = (0..which.len())
                .filter(|&i| dropped[i] && !accepted[i])
                .map(|i| (i, y[i], 1.0 - self.priors[which[i]]))
                .collect();
            let Some(density) = DroppedDensity::new(population, hi - lo) else {
                break;
            };
            evaluated = true;
            let mut next = vec![false; which.len()];
            for i in (0..which.len()).filter(|&i| judged[i]) {
                let p = self.priors[which[i]];
                let ln_prior_odds = if p >= 1.0 {
                    f64::INFINITY
                } else {
                    (p / (1.0 - p)).ln()
                };
                ln_odds[i] =
                    ln_prior_odds + ln_normal(y[i], mu_in, sigma_in) - density.ln_density(y[i], i);
                next[i] = ln_odds[i] >= 0.0;
            }
            let repeated = next == accepted;
            accepted = next;
            if repeated {
                break;
            }
        }
        if evaluated {
            for (i, &k) in which.iter().enumerate().filter(|(i, _)| judged[*i]) {
                self.judgements[k] = Some(InnovationJudgement {
                    innovation: y[i].exp(),
                    ln_odds: ln_odds[i],
                });
            }
        }
        let mut any = false;
        for (i, &k) in which.iter().enumerate().filter(|(i, _)| accepted[*i]) {
            self.weights[k] = 1.0;
            self.posteriors[k] = 1.0 / (1.0 + (-ln_odds[i]).exp());
            self.states[k] = CandidateState::Active;
            self.innovation_accepted += 1;
            any = true;
        }
        any
    }

    /// EM: candidates accepted by their innovation
    /// ([`Reweighter::accept_by_innovation`]): held-out ones (counted among
    /// [`Reweighter::rescued`] too) and ones EM's decisions had rejected.
    pub fn innovation_accepted(&self) -> usize {
        self.innovation_accepted
    }

    /// EM: each candidate's latest judgement by its innovation
    /// ([`Reweighter::accept_by_innovation`]), `None` for those never
    /// judged (the map was solved with them, or there was no population of
    /// dropped candidates to judge them against).
    pub fn judgements(&self) -> &[Option<InnovationJudgement>] {
        &self.judgements
    }
}

/// How [`Reweighter::accept_by_innovation`] judged a candidate the map was
/// solved without, in its last pass.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct InnovationJudgement {
    /// Its squared innovation divided by the noise scale, `ν²/s²`.
    pub innovation: f64,
    /// `ln` of its posterior odds of being a consistent loop: its prior
    /// odds times the likelihood ratio of `ln(ν²/s²)`, consistent loops
    /// against the dropped population. Accepted iff ≥ 0.
    pub ln_odds: f64,
}

/// EM: most passes of [`Reweighter::accept_by_innovation`], each judging
/// the candidates left out against the dropped population without those
/// the last pass accepted.
pub const DROPPED_PASSES: usize = 10;

/// `ln` of the normal density `N(y; μ, σ²)`.
fn ln_normal(y: f64, mu: f64, sigma: f64) -> f64 {
    -0.5 * ((y - mu) / sigma).powi(2) - sigma.ln() - 0.5 * (2.0 * std::f64::consts::PI).ln()
}

/// The density of `y = ln(ν²/s²)` among the candidates the gate dropped
/// (mostly wrong loops), for [`Reweighter::accept_by_innovation`] (which
/// says why): a weighted Gaussian kernel density estimate, leave-one-out;
/// within the population's span mixed with a uniform floor of one
/// pseudo-observation over a range, below it an exponential lower tail.
struct DroppedDensity {
    /// `(index into the judged list, y, weight)`, by increasing `y`.
    points: Vec<(usize, f64, f64)>,
    total: f64,
    bandwidth: f64,
    /// The kernel's normalisation `1 / (h √(2π))`.
    scale: f64,
    floor: f64,
    /// How many of the lowest points the lower tail is fitted to.
    tail_len: usize,
}

/// The population's density below its `k` lowest points
/// ([`DroppedDensity::lower_tail`]): their weight `mass` (a share of the
/// population), spread below the highest of them, `edge`, as an
/// exponential of scale `scale`.
struct LowerTail {
    edge: f64,
    scale: f64,
    mass: f64,
}

impl LowerTail {
    fn density(&self, y: f64) -> f64 {
        self.mass / self.scale * (-(self.edge - y) / self.scale).exp()
    }
}

impl DroppedDensity {
    /// `None` with fewer than 8 points (too few to model the wrong loops)
    /// or no weight.
    fn new(mut points: Vec<(usize, f64, f64)>, range: f64) -> Option<Self> {
        let total: f64 = points.iter().map(|p| p.2).sum();
        let min_points = MixtureOptions::default().min_counts;
        if points.len() < min_points || total <= 0.0 {
            return None;
        }
        points.sort_by(|a, b| a.1.total_cmp(&b.1));
        let mean = points.iter().map(|p| p.2 * p.1).sum::<f64>() / total;
        let var = points
            .iter()
            .map(|p| p.2 * (p.1 - mean).powi(2))
            .sum::<f64>()
            / total;
        let n_eff = total * total / points.iter().map(|p| p.2 * p.2).sum::<f64>();
        let bandwidth = 1.06 * var.max(RESIDUAL_VARIANCE_FLOOR).sqrt() * n_eff.powf(-0.2);
        let n = points.len() as f64;
        let floor = 1.0 / (n * range.max(bandwidth));
        let tail_len = (n.sqrt().ceil() as usize).max(min_points);
        Some(Self {
            points,
            total,
            bandwidth,
            scale: 1.0 / (bandwidth * (2.0 * std::f64::consts::PI).sqrt()),
            floor,
            tail_len,
        })
    }

    /// `ln` of the density at `y`, the point of judged candidate `i` (if it
    /// is one of the population) left out: below the population's lowest
    /// points the larger of the kernel estimate and their exponential tail
    /// ([`DroppedDensity::lower_tail`]), elsewhere the kernel estimate plus
    /// the floor.
    fn ln_density(&self, y: f64, i: usize) -> f64 {
        let (mut sum, mut total) = (0.0, self.total);
        for &(j, yj, w) in &self.points {
            if j == i {
                total -= w;
            } else {
                sum += w * (-0.5 * ((y - yj) / self.bandwidth).powi(2)).exp();
            }
        }
        let kde = if total > 0.0 {
            self.scale * sum / total
        } else {
            0.0
        };
        let n = self.points.len() as f64;
        let body = (1.0 - 1.0 / n) * kde;
        match self.lower_tail(i, total) {
            Some(tail) if y < tail.edge => body.max(tail.density(y)).ln(),
            _ => (body + self.floor).ln(),
        }
    }

    /// The population's lower tail, candidate `i` left out (`total`: the
    /// weight of the others): a peaks-over-threshold model of its `k`
    /// lowest points (`k = max(8, ⌈√n⌉)`), exponential below the highest of
    /// them with their mean weighted distance below it as its scale (at
    /// least the kernel's bandwidth). Where the wrong loops nearest the
    /// consistent ones lie close together, the tail falls off fast and a
    /// candidate well below them is unlike any of them; where they straggle
    /// towards the consistent ones (local wrong loops), it reaches far.
    /// `None` when no point is left or the others weigh nothing.
    fn lower_tail(&self, i: usize, total: f64) -> Option<LowerTail> {
        let lowest: Vec<(f64, f64)> = self
            .points
            .iter()
            .filter(|p| p.0 != i)
            .take(self.tail_len)
            .map(|p| (p.1, p.2))
            .collect();
        let &(edge, _) = lowest.last()?;
        if total <= 0.0 {
            return None;
        }
        let below = &lowest[..lowest.len() - 1];
        let weight: f64 = below.iter().map(|p| p.1).sum();
        let mean_depth = if weight > 0.0 {
            below.iter().map(|p| p.1 * (edge - p.0)).sum::<f64>() / weight
        } else {
            0.0
        };
        Some(LowerTail {
            edge,
            scale: mean_depth.max(self.bandwidth),
            mass: lowest.iter().map(|p| p.1).sum::<f64>() / total,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::robust::tests::{em_options, heavy_tailed_residuals, run_to_the_end};

    #[test]
    fn em_accepts_by_innovation_weighing_the_prior_against_the_dropped_population() {
        // The kept candidates give the residual mixture (consistent loops at
        // ln r² ∈ [−4, 4]); EM rejects the ten at ln r² ∈ [14, 16]. The gate
        // dropped 20: 16 wrong ones (count posterior 0.02, innovations at
        // ln ν² ∈ [6, 10]) and four whose plain residuals are as far out as
        // theirs (e¹²), but:
        //   A: p = 0.2, ln ν² = 1, a consistent innovation → accepted;
        //   B: p = 0.001, ln ν² = 1, consistent too, but its count says
        //      wrong (a local wrong loop the map cannot refute) → not;
        //   C: p = 0.4, ln ν² = 8, among the wrong ones → not;
        //   D: a zero count → never.
        // Of the ten EM rejected (prior ½), the last has a consistent
        // innovation (a long loop the map is loose along) → accepted; the
        // others' innovations are as far out as their residuals → not.
        let mut r2 = heavy_tailed_residuals();
        let mut priors = vec![0.5; r2.len()];
        let mut nu2: Vec<f64> = (50..60)
            .map(|k| if k == 59 { 0.5f64.exp() } else { 14f64.exp() })
            .collect();
        for i in 0..16 {
            r2.push(12f64.exp());
            priors.push(0.02);
            nu2.push((6.0 + 4.0 * i as f64 / 15.0).exp());
        }
        for (p, ln_nu2) in [(0.2, 1.0), (0.001, 1.0), (0.4, 8.0), (0.0, 1.0)] {
            r2.push(12f64.exp());
            priors.push(p);
            nu2.push(f64::exp(ln_nu2));
        }
        let held_out: Vec<bool> = (0..r2.len()).map(|k| k >= 60).collect();
        let mut rw = Reweighter::new(em_options(), priors.clone());
        rw.hold_out(&held_out);
        assert_eq!(rw.innovation_request(), None, "not before the decisions");
        run_to_the_end(&mut rw, &r2);
        assert_eq!(rw.rescued(), 0, "no plain rescue this far out");
        // Every candidate the map was solved without is asked for, once.
        let which = rw.innovation_request().expect("candidates left out");
        assert_eq!(which, (50..80).collect::<Vec<_>>());
        assert_eq!(rw.innovation_request(), None);
        // s² = 2 scales ν² as it scales r².
        let scaled: Vec<f64> = nu2.iter().map(|v| 2.0 * v).collect();
        assert!(rw.accept_by_innovation(&which, &scaled, 2.0));
        // Judged once: nothing more to accept.
        assert!(!rw.accept_by_innovation(&which, &scaled, 2.0));
        // The map is solved once more with the accepted ones; EM is done.
        assert!(!rw.update(&r2));
        let accepted: Vec<usize> = (50..80).filter(|&k| rw.final_weights()[k] >= 0.5).collect();
        assert_eq!(accepted, [59, 76]);
        assert_eq!((rw.rescued(), rw.innovation_accepted()), (1, 2));

        // Too few held-out candidates to fit the dropped population: none.
        let mut rw = Reweighter::new(em_options(), priors[..64].to_vec());
        rw.hold_out(&held_out[..64]);
        run_to_the_end(&mut rw, &r2[..64]);
        let which = rw.innovation_request().expect("candidates left out");
        assert_eq!(which.len(), 14);
        assert!(!rw.accept_by_innovation(&which, &[0.5f64.exp(); 14], 1.0));
        // No residual fit (fewer than 8 kept candidates): none.
        let mut rw = Reweighter::new(em_options(), [vec![0.5; 4], priors[60..].to_vec()].concat());
        let mask: Vec<bool> = (0..24).map(|k| k >= 4).collect();
        rw.hold_out(&mask);
        run_to_the_end(
            &mut rw,
            &[vec![1.0, 2.0, 3.0, 1.5], r2[60..].to_vec()].concat(),
        );
        assert!(rw.residual_fit().is_none());
        let which = rw.innovation_request().expect("candidates left out");
        assert_eq!(which, (4..24).collect::<Vec<_>>());
        assert!(!rw.accept_by_innovation(&which, &nu2[10..], 1.0));
    }

    #[test]
    fn em_models_the_dropped_population_without_the_loops_already_accepted() {
        // The gate dropped 128: 40 true loops the plain rescue takes back
        // (count posterior 0.3, consistent residuals and innovations,
        // ln ν² ∈ [−1, 1]); 80 wrong ones far out (0.02, ln ν² ∈ [12, 16])
        // and 6 that straggle towards the consistent ones (local wrong
        // loops: 0.02, ln ν² ∈ [5, 7.5]); T, a true loop whose residual is
        // far out but whose innovation is not (p = 0.1, ln ν² = 3); and W,
        // as consistent but with a count that says wrong (p = 0.001). One
        // normal fitted to all the dropped ones (the rescued ones included)
        // puts so much density at ln ν² = 3 that T was rejected (the rule
        // before this one); the density of those left out (the wrong ones,
        // T and W) is, at 3, the stragglers' lower tail, and T is accepted,
        // W not. Without the stragglers nothing wrong lies near 3 and W is
        // taken too: its innovation is unlike any wrong loop's.
        let mut r2 = heavy_tailed_residuals();
        let mut priors = vec![0.5; r2.len()];
        let mut nu2: Vec<f64> = vec![14f64.exp(); 10];
        for i in 0..40 {
            r2.push(1.0);
            priors.push(0.3);
            nu2.push((-1.0 + 2.0 * i as f64 / 39.0).exp());
        }
        for i in 0..80 {
            r2.push(12f64.exp());
            priors.push(0.02);
            nu2.push((12.0 + 4.0 * i as f64 / 79.0).exp());
        }
        for i in 0..6 {
            r2.push(12f64.exp());
            priors.push(0.02);
            nu2.push((5.0 + 0.5 * i as f64).exp());
        }
        for p in [0.1, 0.001] {
            r2.push(12f64.exp());
            priors.push(p);
            nu2.push(3f64.exp());
        }
        let (t, w) = (r2.len() - 2, r2.len() - 1);
        let held_out: Vec<bool> = (0..r2.len()).map(|k| k >= 60).collect();
        let judge = |r2: &[f64], priors: &[f64], nu2: &[f64], held_out: &[bool]| {
            let mut rw = Reweighter::new(em_options(), priors.to_vec());
            rw.hold_out(held_out);
            run_to_the_end(&mut rw, r2);
            assert_eq!(rw.rescued(), 40);
            let which = rw.innovation_request().expect("candidates left out");
            assert_eq!(which, (50..r2.len()).collect::<Vec<_>>());
            assert!(rw.accept_by_innovation(&which, nu2, 1.0));
            assert!(!rw.update(r2));
            rw
        };
        let rw = judge(&r2, &priors, &nu2, &held_out);
        let accepted: Vec<usize> = (50..r2.len())
            .filter(|&k| rw.final_weights()[k] >= 0.5)
            .collect();
        let expected: Vec<usize> = (60..100).chain([t]).collect();
        assert_eq!(accepted, expected);
        assert_eq!(rw.innovation_accepted(), 1);

        // The judgements: none for the loops the map was solved with (kept
        // or rescued); ν²/s² and log odds of the decision's sign for the
        // others (the 10 kept ones EM rejected, the wrong ones, T and W).
        let j = rw.judgements();
        let rejected = |j: &[Option<InnovationJudgement>]| {
            j.iter().all(|j| j.is_some_and(|j| j.ln_odds < 0.0))
        };
        assert!(j[..50].iter().chain(&j[60..100]).all(Option::is_none));
        assert!(rejected(&j[50..60]) && rejected(&j[100..t]));
        let (jt, jw) = (j[t].expect("T judged"), j[w].expect("W judged"));
        assert!((jt.innovation - 3f64.exp()).abs() < 1e-9 * jt.innovation);
        assert_eq!(jt.innovation, jw.innovation);
        assert!(jt.ln_odds >= 0.0 && jw.ln_odds < 0.0);

        // Without the stragglers, W is nine units below every wrong loop
        // left, whose lowest lie close together: it is taken too.
        // (`nu2` starts at candidate 50.)
        let keep = |v: &[f64], first: usize| -> Vec<f64> {
            v.iter()
                .enumerate()
                .filter(|(k, _)| !(180..186).contains(&(k + first)))
                .map(|(_, &x)| x)
                .collect()
        };
        let rw = judge(
            &keep(&r2, 0),
            &keep(&priors, 0),
            &keep(&nu2, 50),
            &held_out[6..],
        );
        let w = rw.final_weights();
        assert!(w[t - 6] >= 0.5 && w[w.len() - 1] >= 0.5);
        assert_eq!(rw.innovation_accepted(), 2);
    }

    #[test]
    fn dropped_density_leaves_the_judged_point_out_and_keeps_a_floor() {
        // Eight points of weight 1 at 0, 1 and 2, over a range of 10.
        let density = DroppedDensity::new((0..8).map(|i| (i, (i % 3) as f64, 1.0)).collect(), 10.0)
            .expect("8 points");
        let n = 8.0;
        // By hand: the mean and variance of 0, 1, 2, 0, 1, 2, 0, 1.
        let ys = [0.0, 1.0, 2.0, 0.0, 1.0, 2.0, 0.0, 1.0];
        let m = ys.iter().sum::<f64>() / n;
        let v = ys.iter().map(|y| (y - m) * (y - m)).sum::<f64>() / n;
        let h = 1.06 * v.sqrt() * n.powf(-0.2);
        let k = |d: f64| (-0.5 * (d / h).powi(2)).exp() / (h * (2.0 * std::f64::consts::PI).sqrt());
        // At 5 for point 0 (y = 0), which is left out.
        let kde: f64 = ys[1..].iter().map(|&y| k(5.0 - y)).sum::<f64>() / 7.0;
        let expected = (1.0 - 1.0 / n) * kde + 1.0 / (n * 10.0);
        assert!((density.ln_density(5.0, 0) - expected.ln()).abs() < 1e-12);
        // Far from every point only the floor is left.
        let far = density.ln_density(1e3, 99);
        assert!((far - (1.0 / (n * 10.0)).ln()).abs() < 1e-12);
        // Too few points: no density.
        assert!(DroppedDensity::new((0..7).map(|i| (i, 0.0, 1.0)).collect(), 1.0).is_none());
    }

    #[test]
    fn dropped_density_below_the_population_is_its_exponential_lower_tail() {
        // Twenty points of weight 1 at 10, 10.05, …, 10.95, over a range
        // of 20: the tail is fitted to the lowest k = max(8, ⌈√20⌉) = 8.
        let ys: Vec<f64> = (0..20).map(|i| 10.0 + 0.05 * i as f64).collect();
        let points = ys.iter().enumerate().map(|(i, &y)| (i, y, 1.0)).collect();
        let density = DroppedDensity::new(points, 20.0).expect("20 points");
        let (n, m) = (20.0, ys.iter().sum::<f64>() / 20.0);
        let v = ys.iter().map(|y| (y - m) * (y - m)).sum::<f64>() / n;
        let h = 1.06 * v.sqrt() * n.powf(-0.2);
        // By hand, the judged point `skip` left out: the edge is the 8th
        // lowest of the others, the scale the mean depth of the 7 below it
        // (0.2 either way; the bandwidth is 0.17), the mass 8 of the others.
        let tail = |y: f64, lowest: &[f64], others: f64| {
            let edge = lowest[7];
            let depth = lowest[..7].iter().map(|l| edge - l).sum::<f64>() / 7.0;
            let scale = depth.max(h);
            8.0 / others / scale * (-(edge - y) / scale).exp()
        };
        let at_9 = density.ln_density(9.0, 99);
        assert!((at_9 - tail(9.0, &ys[..8], 20.0).ln()).abs() < 1e-9);
        let lowest_left_out = density.ln_density(9.0, 0);
        assert!((lowest_left_out - tail(9.0, &ys[1..9], 19.0).ln()).abs() < 1e-9);
        // Far below it falls under the floor, which is only for the span.
        let floor = (1.0 / (n * 20.0)).ln();
        assert!(density.ln_density(5.0, 99) < floor - 10.0);
        assert!((density.ln_density(40.0, 99) - floor).abs() < 1e-12);

        // Five stragglers at 6…8 (local wrong loops): the tail reaches
        // down and at 5 the density is far above the tight population's.
        let straggling: Vec<(usize, f64, f64)> = (0..20)
            .map(|i| (i, ys[i], 1.0))
            .chain((0..5).map(|i| (20 + i, 6.0 + 0.5 * i as f64, 1.0)))
            .collect();
        let straggling = DroppedDensity::new(straggling, 20.0).expect("25 points");
        assert!(straggling.ln_density(5.0, 99) > density.ln_density(5.0, 99) + 20.0);
        assert!(straggling.ln_density(5.0, 99) > floor);
    }
}
