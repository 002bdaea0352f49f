//! Mixtures of `K` normal distributions on the real line,
//! `p(y) = Σ_k π_k N(y | μ_k, σ_k)`, fitted to data by
//! expectation–maximisation (EM).
//!
//! * The E-step works with log densities and log-sum-exp, so the posterior
//!   of a component never underflows however far a value lies from it.
//! * The M-step takes each variance around the component's *new* mean, and
//!   never lets it fall below a floor ([`EmOptions::variance_floor`]): with
//!   tied values a component can shrink onto one of them, where the
//!   likelihood grows without bound.
//! * EM finds a local maximum, so it is run from several starts
//!   ([`quantile_start`], [`kmeans_start`], or any start the caller knows)
//!   and the best fit that did not collapse wins ([`best_fit`]).
//! * [`bic`] compares fits with different numbers of components.

use super::squarem;
use serde::Serialize;

/// `ln √(2π)`, the constant of the normal log-density.
const LN_SQRT_2PI: f64 = 0.918_938_533_204_672_8;

/// The smallest variance any component may have, whatever floor is asked
/// for: σ ≥ 1e-6. On the logarithm of a positive quantity that is a
/// relative spread of one part in a million.
pub const MIN_VARIANCE_FLOOR: f64 = 1e-12;

/// A variance within this factor of the floor counts as "at the floor"
/// (the floor times a few units of rounding, as `max(var, floor)` may leave
/// it).
const AT_FLOOR: f64 = 1.0 + 1e-9;

/// Why a mixture could not be made.
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
pub enum MixtureError {
    /// A mixture needs at least one component.
    #[error("a mixture needs at least one component")]
    NoComponents,
    /// A component's weight or σ is not positive and finite, or its mean is
    /// not finite.
    #[error(
        "component {index} is invalid: weight {weight}, mean {mean}, sigma {sigma} \
         (weight and sigma must be positive and finite, the mean finite)"
    )]
    InvalidComponent {
        /// Its position in the list.
        index: usize,
        /// Its weight π.
        weight: f64,
        /// Its mean μ.
        mean: f64,
        /// Its standard deviation σ.
        sigma: f64,
    },
}

/// One component of a normal mixture: its weight π, mean μ and standard
/// deviation σ.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct NormalComponent {
    /// Mixing weight π.
    pub weight: f64,
    /// Mean μ.
    pub mean: f64,
    /// Standard deviation σ.
    pub sigma: f64,
}

impl NormalComponent {
    /// `ln(π N(y | μ, σ))`, the log of the component's weighted density at
    /// `y`.
    pub fn log_weighted_density(&self, y: f64) -> f64 {
        self.weight.ln() + log_normal_pdf(y, self.mean, self.sigma)
    }

    fn is_valid(&self) -> bool {
        let positive = |x: f64| x.is_finite() && x > 0.0;
        positive(self.weight) && positive(self.sigma) && self.mean.is_finite()
    }

    fn is_finite(&self) -> bool {
        self.weight.is_finite() && self.mean.is_finite() && self.sigma.is_finite()
    }

    /// The largest change of π, μ or σ from `other`.
    fn max_abs_change(&self, other: &NormalComponent) -> f64 {
        (self.weight - other.weight)
            .abs()
            .max((self.mean - other.mean).abs())
            .max((self.sigma - other.sigma).abs())
    }
}

/// A mixture of normal distributions, `p(y) = Σ_k π_k N(y | μ_k, σ_k)`.
///
/// Every component has a positive, finite weight and σ and a finite mean.
/// The weights of a fitted mixture sum to 1; a mixture made with
/// [`NormalMixture::new`] has the weights it was given.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct NormalMixture {
    components: Vec<NormalComponent>,
}

impl NormalMixture {
    /// A mixture of these components, in this order. Errors when there is
    /// none or one is invalid (see [`MixtureError`]).
    pub fn new(components: Vec<NormalComponent>) -> Result<Self, MixtureError> {
        if components.is_empty() {
            return Err(MixtureError::NoComponents);
        }
        if let Some((index, c)) = components.iter().enumerate().find(|(_, c)| !c.is_valid()) {
            return Err(MixtureError::InvalidComponent {
                index,
                weight: c.weight,
                mean: c.mean,
                sigma: c.sigma,
            });
        }
        Ok(NormalMixture { components })
    }

    /// The maximum-likelihood single normal of `y`: its mean, and its
    /// population variance raised to `floor` (at least
    /// [`MIN_VARIANCE_FLOOR`]). For no data, mean 0 and σ at the floor.
    pub fn moments(y: &[f64], floor: f64) -> Self {
        let (mean, var) = mean_and_variance(y);
        let sigma = var.max(floor.max(MIN_VARIANCE_FLOOR)).sqrt();
        NormalMixture {
            components: vec![NormalComponent {
                weight: 1.0,
                mean,
                sigma,
            }],
        }
    }

    /// The components, in order.
    pub fn components(&self) -> &[NormalComponent] {
        &self.components
    }

    /// The number of components `K` (at least 1).
    pub fn len(&self) -> usize {
        self.components.len()
    }

    /// `ln p(y)`.
    #[cfg(test)]
    pub fn log_density(&self, y: f64) -> f64 {
        self.log_terms(y, &mut vec![0.0; self.len()])
    }

    /// The log-likelihood `Σ_n ln p(y_n)` of the data.
    pub fn log_likelihood(&self, y: &[f64]) -> f64 {
        let mut terms = vec![0.0; self.len()];
        y.iter().map(|&v| self.log_terms(v, &mut terms)).sum()
    }

    /// The posterior probability of each component given `y`,
    /// `π_k N(y | μ_k, σ_k) / p(y)`, in the order of the components; they
    /// sum to 1.
    #[cfg(test)]
    pub fn posteriors(&self, y: f64) -> Vec<f64> {
        let mut terms = vec![0.0; self.len()];
        let log_p = self.log_terms(y, &mut terms);
        terms.iter().map(|t| (t - log_p).exp()).collect()
    }

    /// `ln(π_k N_k(y)) − ln(π_j N_j(y))`: positive where component `k`
    /// explains `y` better than component `j`. NaN when either index is
    /// out of range.
    #[cfg(test)]
    pub fn log_odds(&self, k: usize, j: usize, y: f64) -> f64 {
        match (self.components.get(k), self.components.get(j)) {
            (Some(a), Some(b)) => a.log_weighted_density(y) - b.log_weighted_density(y),
            _ => f64::NAN,
        }
    }

    /// The same mixture with its components in increasing order of mean
    /// (equal means keep their order).
    pub fn sorted_by_mean(mut self) -> Self {
        self.components.sort_by(|a, b| {
            a.mean
                .partial_cmp(&b.mean)
                .unwrap_or(std::cmp::Ordering::Equal)
        });
        self
    }

    /// Whether a fit to `n` values ended in a useless place: a component
    /// with less than one value's worth of weight (`π_k n < 1`), or one
    /// holding fewer than `min_size` values that sits on a single tied
    /// value or two neighbouring ones: pinned at the variance `floor`, or
    /// no wider than `spacing(μ_k)`, the gap between neighbouring values
    /// the data can take near its mean (0 for continuous data; for integer
    /// counts on a log scale, one count's step there). Two neighbouring
    /// counts are as good as tied at the resolution of a count: a component
    /// on them has the density of that step, not of a population.
    pub fn is_collapsed(
        &self,
        n: usize,
        (floor, spacing): (f64, &dyn Fn(f64) -> f64),
        min_size: f64,
    ) -> bool {
        if !self.components.iter().all(NormalComponent::is_finite) {
            return true;
        }
        self.components.iter().any(|c| {
            let size = c.weight * n as f64;
            let pinned = c.sigma * c.sigma <= floor * AT_FLOOR || c.sigma <= spacing(c.mean);
            size < 1.0 || (pinned && size < min_size)
        })
    }

    /// Fills `terms` with `ln(π_k N_k(y))` and returns their log-sum-exp
    /// `ln p(y)`.
    fn log_terms(&self, y: f64, terms: &mut [f64]) -> f64 {
        for (t, c) in terms.iter_mut().zip(&self.components) {
            *t = c.log_weighted_density(y);
        }
        log_sum_exp(terms.iter().copied())
    }

    fn max_abs_change(&self, other: &NormalMixture) -> f64 {
        self.components
            .iter()
            .zip(&other.components)
            .map(|(a, b)| a.max_abs_change(b))
            .fold(0.0, f64::max)
    }
}

/// `ln Σ eᵗ` of `terms`, shifted by the largest so that nothing overflows
/// or underflows; −∞ when there are none or every term is.
pub(crate) fn log_sum_exp(terms: impl Iterator<Item = f64> + Clone) -> f64 {
    let top = terms.clone().fold(f64::NEG_INFINITY, f64::max);
    if top == f64::NEG_INFINITY {
        return top;
    }
    top + terms.map(|t| (t - top).exp()).sum::<f64>().ln()
}

/// Turns log-weights `terms` into the weights' shares in place,
/// `exp(tₖ − top) / sum`, and returns `(top, sum)`, the largest term and
/// `Σ exp(tₖ − top)`, so that `ln Σ eᵗ = top + ln sum`. The largest term
/// needs no exponential (`exp(0) = 1` exactly). When every term is −∞ the
/// shares are 0 and `(−∞, 1)` is returned.
pub(crate) fn normalize_log_terms(terms: &mut [f64]) -> (f64, f64) {
    let top = terms.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    if top == f64::NEG_INFINITY {
        terms.fill(0.0);
        return (top, 1.0);
    }
    let mut sum = 0.0;
    for t in terms.iter_mut() {
        *t = if *t == top { 1.0 } else { (*t - top).exp() };
        sum += *t;
    }
    // One division, not one per term (a division costs several
    // multiplications, and this runs per candidate per EM iteration).
    let inverse = 1.0 / sum;
    for t in terms.iter_mut() {
        *t *= inverse;
    }
    (top, sum)
}

/// `ln Π xᵢ` of factors `xᵢ ≥ 1` (each value's share of a log-sum-exp in
/// an E-step): one logarithm per run of factors whose product stays finite
/// instead of one per factor.
#[derive(Default)]
pub(crate) struct LnProduct {
    logs: f64,
    product: Option<f64>,
}

impl LnProduct {
    /// Multiplies in `x ≥ 1`.
    pub(crate) fn push(&mut self, x: f64) {
        let p = self.product.unwrap_or(1.0) * x;
        if p > 1e250 {
            self.logs += p.ln();
            self.product = None;
        } else {
            self.product = Some(p);
        }
    }

    /// The largest whole power of factors up to `most` that
    /// [`Self::push_power`] multiplies in at once: `most^power ≤ 10⁵⁰`, far
    /// below the product's cap.
    pub(crate) fn largest_power(most: f64) -> f64 {
        let power = (50.0 * std::f64::consts::LN_10 / most.ln().max(f64::EPSILON)).floor();
        power.clamp(1.0, i32::MAX as f64)
    }

    /// Multiplies in `x^times` (`times` a whole number, as a value's
    /// multiplicity is) for `1 ≤ x ≤ most`, in powers of at most `largest`
    /// ([`Self::largest_power`] of `most`).
    pub(crate) fn push_power(&mut self, x: f64, times: f64, largest: f64) {
        let mut left = times;
        while left > 0.0 {
            let n = left.min(largest);
            self.push(x.powi(n as i32));
            left -= n;
        }
    }

    /// `ln` of the product.
    pub(crate) fn ln(&self) -> f64 {
        self.logs + self.product.map_or(0.0, f64::ln)
    }
}

/// The Bayesian information criterion `k ln n − 2 ln L` of a mixture of
/// `components` normals (`k = 3K − 1` free parameters: K means, K σ and
/// K − 1 weights) with log-likelihood `log_likelihood` on `n` values.
/// Lower is better.
pub fn bic(components: usize, n: f64, log_likelihood: f64) -> f64 {
    let parameters = (3 * components).saturating_sub(1) as f64;
    parameters * n.ln() - 2.0 * log_likelihood
}

/// Settings of an EM run.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EmOptions {
    /// EM stops when no π, μ or σ changes by more than this.
    pub tolerance: f64,
    /// EM stops after this many iterations at the latest.
    pub max_iterations: usize,
    /// No component's variance falls below this (nor below
    /// [`MIN_VARIANCE_FLOOR`]).
    pub variance_floor: f64,
}

impl EmOptions {
    fn floor(&self) -> f64 {
        self.variance_floor.max(MIN_VARIANCE_FLOOR)
    }
}

/// The result of one EM run.
#[derive(Clone, Debug, PartialEq)]
pub struct EmFit {
    /// The fitted mixture, components in the order of the start.
    pub mixture: NormalMixture,
    /// EM iterations run.
    pub iterations: usize,
    /// Whether EM met the tolerance (rather than the iteration limit).
    pub converged: bool,
    /// Log-likelihood of the data under [`EmFit::mixture`].
    pub log_likelihood: f64,
}

/// EM on `y` from `start` until an iteration changes no parameter by more
/// than the tolerance, or the iteration limit is hit. Each iteration is an
/// E-step (the posteriors of the components) and an M-step (each
/// component's weight, mean, and variance around that new mean, floored).
///
/// The iterations are accelerated by SQUAREM ([`squarem`]): every third
/// starts from a jump along the path of the two before, kept if it is a
/// valid mixture no less likely than the first of them; the fixed points
/// are EM's own, reached in a fraction of the iterations where the
/// components overlap. Where a cycle gains almost nothing, SQUAREM still
/// creeps (a share of the distance per cycle), and EM's test — an
/// iteration that moves no parameter by more than the tolerance — passes
/// while the fixed point is still a hundred tolerances away; there a Newton
/// step on the log-likelihood (its Hessian by differences of the exact
/// gradient) is tried, kept if it is a valid mixture no less likely, and
/// EM's iterations go on from it: the fit still ends with an EM iteration
/// that moves nothing by more than the tolerance, at the fixed point
/// itself. Newton steps count as iterations.
///
/// `None` when an M-step finds a component with no weight or a non-finite
/// parameter. `observe` sees the log-likelihood at the start of every
/// cycle of three EM iterations (`θ`), then that of the final mixture; it
/// never decreases (up to rounding).
pub fn em(
    y: &[f64],
    start: NormalMixture,
    options: &EmOptions,
    mut observe: impl FnMut(f64),
) -> Option<EmFit> {
    // Inlier counts repeat: EM over the distinct values, each weighed by
    // how often it occurs, is EM over `y` at a fraction of the cost.
    let (values, times) = tally(y);
    let mut run = EmRun {
        values: &values,
        times: &times,
        responsibilities: vec![0.0; values.len() * start.len()],
        floor: options.floor(),
        tolerance: options.tolerance,
        iterations: 0,
    };
    let (mut mixture, mut converged) = (start, false);
    let limit = options.max_iterations;
    // Newton steps tried, and the log-likelihood at the start of the last
    // cycle and whether that cycle gained little.
    let (mut newton_tries, mut previous, mut creeping) = (0, None, false);
    // Cycles of two EM iterations, each of which may end the fit, and the
    // iteration from a jump along them; near the optimum, a Newton step
    // first.
    while run.iterations < limit {
        if creeping && newton_tries < MAX_NEWTON_TRIES {
            newton_tries += 1;
            if let Some(next) = run.newton_step(&mixture) {
                mixture = next;
            }
        }
        let (ll0, first, done) = run.step(&mixture)?;
        observe(ll0);
        creeping = previous.is_some_and(|p| ll0 - p < NEWTON_GAIN * ll0.abs().max(1.0));
        previous = Some(ll0);
        if done || run.iterations >= limit {
            (mixture, converged) = (first, done);
            break;
        }
        let (_, second, done) = run.step(&first)?;
        if done || run.iterations >= limit {
            (mixture, converged) = (second, done);
            break;
        }
        (mixture, converged) = run.extrapolated_step(&[mixture, first, second], ll0)?;
        if converged {
            break;
        }
    }
    let log_likelihood = mixture.log_likelihood(y);
    observe(log_likelihood);
    Some(EmFit {
        mixture,
        iterations: run.iterations,
        converged,
        log_likelihood,
    })
}

/// The data and workspace of an [`em`] run.
struct EmRun<'a> {
    values: &'a [f64],
    times: &'a [f64],
    responsibilities: Vec<f64>,
    floor: f64,
    tolerance: f64,
    iterations: usize,
}

impl EmRun<'_> {
    /// The log-likelihood of `mixture` (its E-step).
    fn e_step(&mut self, mixture: &NormalMixture) -> f64 {
        weighted_e_step(self.values, self.times, mixture, &mut self.responsibilities)
    }

    /// The M-step after the last E-step, from `from`: the next mixture and
    /// whether it moved no parameter by more than the tolerance.
    fn m_step(&mut self, from: &NormalMixture) -> Option<(NormalMixture, bool)> {
        self.iterations += 1;
        let k = from.len();
        let next = weighted_m_step(
            self.values,
            self.times,
            &self.responsibilities,
            k,
            self.floor,
        )?;
        let done = from.max_abs_change(&next) < self.tolerance;
        Some((next, done))
    }

    /// One EM iteration from `mixture`: its log-likelihood, the next
    /// mixture, and whether the iteration converged.
    fn step(&mut self, mixture: &NormalMixture) -> Option<(f64, NormalMixture, bool)> {
        let ll = self.e_step(mixture);
        let (next, done) = self.m_step(mixture)?;
        Some((ll, next, done))
    }

    /// The EM iteration from SQUAREM's jump after `θ → θ₁ → θ₂` (`path`,
    /// [`squarem::jumps`]), the first that is a valid mixture at least as
    /// likely as `θ` (log-likelihood `ll0`), else from `θ₂`: the next
    /// mixture, and whether the iteration converged.
    fn extrapolated_step(
        &mut self,
        path: &[NormalMixture; 3],
        ll0: f64,
    ) -> Option<(NormalMixture, bool)> {
        let [t0, t1, t2] = path.each_ref().map(parameters);
        for theta in squarem::jumps(&t0, &t1, &t2) {
            if let Some(jump) = from_parameters(&theta, self.floor)
                && self.e_step(&jump) >= ll0
            {
                return self.m_step(&jump);
            }
        }
        let (_, next, done) = self.step(&path[2])?;
        Some((next, done))
    }
}

/// Newton steps an EM run tries at most. Each costs `2·(3K − 1) + 2`
/// E-steps (12 for the gate's two components); from where one is tried a
/// step or two land on the fixed point, and a step refused (a Hessian not
/// negative definite, a likelihood that falls) is paid for once per try.
/// Over the gate's fits of the aliased manhattan replay every 10 poses
/// (docs/method.md §2), 4 and 8 took 100 E-steps per fit alike (tried
/// at the cycle after the one that gained little: 85 with 4).
const MAX_NEWTON_TRIES: usize = 4;

/// A SQUAREM cycle that raised the log-likelihood by less than this share
/// of it is taken to be near the optimum, where a Newton step is tried.
/// On those fits 10⁻⁶ and 10⁻⁴ took 100 E-steps per fit, 10⁻³ 138 (its
/// steps tried too far out fail; the step tried right after the cycle, at
/// an E-step more per cycle): the quadratic model holds only close in.
const NEWTON_GAIN: f64 = 1e-6;

impl EmRun<'_> {
    /// The log-likelihood at `mixture` and its gradient in the reduced
    /// parameters ([`reduced`]), from an E-step at it.
    fn gradient(&mut self, mixture: &NormalMixture) -> (f64, Vec<f64>) {
        let ll = self.e_step(mixture);
        let comps = &mixture.components;
        let k = comps.len();
        let mut g = vec![0.0; 3 * k - 1];
        let rows = self.values.iter().zip(self.times);
        for ((&v, &t), r) in rows.zip(self.responsibilities.chunks_exact(k)) {
            for (j, c) in comps.iter().enumerate() {
                let z = (v - c.mean) / c.sigma;
                g[k - 1 + 2 * j] += t * r[j] * z / c.sigma;
                g[k + 2 * j] += t * r[j] * (z * z - 1.0) / c.sigma;
            }
            for j in 0..k - 1 {
                g[j] += t * (r[j] / comps[j].weight - r[k - 1] / comps[k - 1].weight);
            }
        }
        (ll, g)
    }

    /// A Newton step on the log-likelihood from `mixture`, its Hessian by
    /// central differences of the gradient: the next mixture when it is
    /// valid and no less likely; `None` where a component sits at the
    /// variance floor or the Hessian is not negative definite.
    fn newton_step(&mut self, mixture: &NormalMixture) -> Option<NormalMixture> {
        if (mixture.components.iter()).any(|c| c.sigma * c.sigma <= self.floor * AT_FLOOR) {
            return None;
        }
        let x = reduced(mixture);
        let n = x.len();
        let (ll, g) = self.gradient(mixture);
        let mut h = nalgebra::DMatrix::<f64>::zeros(n, n);
        for i in 0..n {
            let step = 1e-5 * x[i].abs().max(1e-2);
            let mut at = |d: f64| {
                let mut y = x.clone();
                y[i] += d;
                from_reduced(&y, 0.0).map(|m| self.gradient(&m).1)
            };
            let (up, down) = (at(step)?, at(-step)?);
            for r in 0..n {
                h[(r, i)] = (up[r] - down[r]) / (2.0 * step);
            }
        }
        let negative = -(&h + h.transpose()) * 0.5;
        let delta = negative.cholesky()?.solve(&nalgebra::DVector::from_vec(g));
        let y: Vec<f64> = x.iter().zip(delta.iter()).map(|(a, d)| a + d).collect();
        let next = from_reduced(&y, self.floor)?;
        self.iterations += 1;
        (self.e_step(&next) >= ll).then_some(next)
    }
}

/// A mixture's free parameters: the weights but the last (they sum to
/// 1), then μ and σ of each component.
fn reduced(mixture: &NormalMixture) -> Vec<f64> {
    let k = mixture.len();
    let weights = mixture.components[..k - 1].iter().map(|c| c.weight);
    let shapes = mixture.components.iter().flat_map(|c| [c.mean, c.sigma]);
    weights.chain(shapes).collect()
}

/// The mixture of the free parameters `x` ([`reduced`]), if every weight
/// is positive, every σ at least `√floor` and everything finite.
fn from_reduced(x: &[f64], floor: f64) -> Option<NormalMixture> {
    let k = x.len().div_ceil(3);
    let last = 1.0 - x[..k - 1].iter().sum::<f64>();
    let theta: Vec<f64> = (0..k)
        .flat_map(|j| {
            let w = if j + 1 < k { x[j] } else { last };
            [w, x[k - 1 + 2 * j], x[k + 2 * j]]
        })
        .collect();
    from_parameters(&theta, floor.max(f64::MIN_POSITIVE))
}

/// A mixture's parameters in one vector: π, μ, σ of each component.
fn parameters(mixture: &NormalMixture) -> Vec<f64> {
    (mixture.components.iter())
        .flat_map(|c| [c.weight, c.mean, c.sigma])
        .collect()
}

/// The mixture of the parameters `theta` ([`parameters`]), if every weight
/// is positive, every σ at least `√floor` and everything finite.
fn from_parameters(theta: &[f64], floor: f64) -> Option<NormalMixture> {
    let components: Vec<NormalComponent> = theta
        .chunks_exact(3)
        .map(|c| NormalComponent {
            weight: c[0],
            mean: c[1],
            sigma: c[2],
        })
        .collect();
    let valid = |c: &NormalComponent| c.is_valid() && c.sigma * c.sigma >= floor;
    components
        .iter()
        .all(valid)
        .then_some(NormalMixture { components })
}

/// The distinct values of `y`, sorted, and how often each occurs.
fn tally(y: &[f64]) -> (Vec<f64>, Vec<f64>) {
    let mut sorted = y.to_vec();
    sorted.sort_by(f64::total_cmp);
    let (mut values, mut times): (Vec<f64>, Vec<f64>) = (Vec::new(), Vec::new());
    for v in sorted {
        match (values.last(), times.last_mut()) {
            (Some(&last), Some(t)) if last.total_cmp(&v).is_eq() => *t += 1.0,
            _ => {
                values.push(v);
                times.push(1.0);
            }
        }
    }
    (values, times)
}

/// E-step on `y`, each value once.
#[cfg(test)]
fn e_step(y: &[f64], mixture: &NormalMixture, responsibilities: &mut [f64]) -> f64 {
    weighted_e_step(y, &vec![1.0; y.len()], mixture, responsibilities)
}

/// E-step: `r(n,k) = exp(ln π_k N_k(y_n) − ln p(y_n))` into
/// `responsibilities` (`K` per value, value-major). Returns the
/// log-likelihood of `mixture`, value `n` counted `times[n]` times.
fn weighted_e_step(
    y: &[f64],
    times: &[f64],
    mixture: &NormalMixture,
    responsibilities: &mut [f64],
) -> f64 {
    // Per component, once: ln π − ln σ − ln √(2π), 1/σ and μ.
    let constants: Vec<(f64, f64, f64)> = (mixture.components.iter())
        .map(|c| {
            (
                c.weight.ln() - c.sigma.ln() - LN_SQRT_2PI,
                1.0 / c.sigma,
                c.mean,
            )
        })
        .collect();
    // `Σ t·top`, and `Π sumᵗ` (each `sum` in [1, K]) with one logarithm
    // per run of factors instead of one per value.
    let (mut tops, mut sums) = (0.0, LnProduct::default());
    let largest = LnProduct::largest_power(mixture.len() as f64);
    for ((&v, &t), r) in y
        .iter()
        .zip(times)
        .zip(responsibilities.chunks_exact_mut(mixture.len()))
    {
        for (x, &(c, inv_sigma, mean)) in r.iter_mut().zip(&constants) {
            let z = (v - mean) * inv_sigma;
            *x = c - 0.5 * z * z;
        }
        let (top, sum) = normalize_log_terms(r);
        tops += t * top;
        sums.push_power(sum, t, largest);
    }
    tops + sums.ln()
}

/// M-step on `y`, each value once.
#[cfg(test)]
fn m_step(y: &[f64], responsibilities: &[f64], k: usize, floor: f64) -> Option<NormalMixture> {
    weighted_m_step(y, &vec![1.0; y.len()], responsibilities, k, floor)
}

/// M-step: each component's weighted mean, weighted variance around that
/// *new* mean (raised to `floor`), and weight, value `n` counted
/// `times[n]` times. `None` when a component has no mass or a parameter is
/// not finite.
fn weighted_m_step(
    y: &[f64],
    times: &[f64],
    responsibilities: &[f64],
    k: usize,
    floor: f64,
) -> Option<NormalMixture> {
    let n: f64 = times.iter().sum();
    let rows = || responsibilities.chunks_exact(k).zip(times);
    let mut components = Vec::with_capacity(k);
    for j in 0..k {
        let mass: f64 = rows().map(|(r, t)| t * r[j]).sum();
        if !(mass > 0.0 && mass.is_finite()) {
            return None;
        }
        let weighted = || rows().map(move |(r, t)| t * r[j]).zip(y);
        let mean = weighted().map(|(r, v)| r * v).sum::<f64>() / mass;
        let var = weighted().map(|(r, v)| r * (v - mean).powi(2)).sum::<f64>() / mass;
        components.push(NormalComponent {
            weight: mass / n,
            mean,
            sigma: var.max(floor).sqrt(),
        });
    }
    components
        .iter()
        .all(NormalComponent::is_finite)
        .then_some(NormalMixture { components })
}

/// A start for `k` components: means at the quantiles `(j + ½)/k` of `y`
/// (the quartiles for `k = 2`), every σ the spread of all of `y` (at least
/// `√floor`), equal weights. `None` when those quantiles are not strictly
/// increasing (too many tied values) or `k = 0`.
pub fn quantile_start(y: &[f64], k: usize, floor: f64) -> Option<NormalMixture> {
    if k == 0 {
        return None;
    }
    let mut sorted = y.to_vec();
    sorted.sort_by(f64::total_cmp);
    let means: Vec<f64> = (0..k)
        .map(|j| quantile(&sorted, (j as f64 + 0.5) / k as f64))
        .collect();
    if means.windows(2).any(|w| w[0] >= w[1]) {
        return None;
    }
    let min_sigma = floor.max(MIN_VARIANCE_FLOOR).sqrt();
    let sigma = mean_and_variance(y).1.sqrt().max(min_sigma);
    let weight = 1.0 / k as f64;
    let components = means.into_iter().map(|mean| NormalComponent {
        weight,
        mean,
        sigma,
    });
    NormalMixture::new(components.collect()).ok()
}

/// A start for `k` components from a split of the sorted `y` into `k`
/// groups of consecutive values (1-D k-means by bisection: the whole is
/// split in two where the between-group sum of squares is largest, then
/// the group whose best split gains most, until there are `k`; for `k = 2`
/// this is the optimal 2-means split). Each component takes its group's
/// mean, spread (variance at least `floor`) and share. `None` when `y` has
/// fewer than `k` distinct values or `k = 0`.
pub fn kmeans_start(y: &[f64], k: usize, floor: f64) -> Option<NormalMixture> {
    if k == 0 {
        return None;
    }
    let mut sorted = y.to_vec();
    sorted.sort_by(f64::total_cmp);
    // Group g is sorted[bounds[g]..bounds[g + 1]].
    let mut bounds = vec![0, sorted.len()];
    while bounds.len() <= k {
        let mut best: Option<(usize, f64)> = None;
        for w in bounds.windows(2) {
            if let Some((split, gain)) = two_means_split(&sorted[w[0]..w[1]]) {
                if best.is_none_or(|(_, g)| gain > g) {
                    best = Some((w[0] + split, gain));
                }
            }
        }
        let (at, _) = best?;
        bounds.insert(bounds.partition_point(|&b| b < at), at);
    }
    let floor = floor.max(MIN_VARIANCE_FLOOR);
    let components = bounds.windows(2).map(|w| {
        let group = &sorted[w[0]..w[1]];
        let (mean, var) = mean_and_variance(group);
        NormalComponent {
            weight: group.len() as f64 / sorted.len() as f64,
            mean,
            sigma: var.max(floor).sqrt(),
        }
    });
    NormalMixture::new(components.collect()).ok()
}

/// Runs EM from every start and keeps the result with the highest
/// log-likelihood (the earlier start on ties) among those that did not
/// collapse ([`NormalMixture::is_collapsed`] with `min_size` and the
/// data's `spacing`) and have a finite log-likelihood. The winner's
/// components are sorted by mean; its start's label comes with it. `None`
/// when every start failed or collapsed.
pub fn best_fit<S: Copy>(
    y: &[f64],
    starts: &[(S, NormalMixture)],
    options: &EmOptions,
    (min_size, spacing): (f64, &dyn Fn(f64) -> f64),
) -> Option<(S, EmFit)> {
    let mut best: Option<(S, EmFit)> = None;
    for (label, start) in starts {
        let Some(mut fit) = em(y, start.clone(), options, |_| {}) else {
            continue;
        };
        fit.mixture = fit.mixture.sorted_by_mean();
        if fit
            .mixture
            .is_collapsed(y.len(), (options.floor(), spacing), min_size)
            || !fit.log_likelihood.is_finite()
        {
            continue;
        }
        if best
            .as_ref()
            .is_none_or(|(_, b)| fit.log_likelihood > b.log_likelihood)
        {
            best = Some((*label, fit));
        }
    }
    best
}

/// Linear-interpolated quantile of sorted data (`p` in [0, 1]); 0 for no
/// data.
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
/// values, with that sum. `None` when all values are equal.
fn two_means_split(sorted: &[f64]) -> Option<(usize, f64)> {
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
    best
}

/// Mean and population variance (0 and 0 for no data).
fn mean_and_variance(y: &[f64]) -> (f64, f64) {
    let n = y.len().max(1) as f64;
    let mean = y.iter().sum::<f64>() / n;
    let var = y.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n;
    (mean, var)
}

/// `ln N(y | μ, σ)`.
pub(crate) fn log_normal_pdf(y: f64, mu: f64, sigma: f64) -> f64 {
    let z = (y - mu) / sigma;
    -0.5 * z * z - sigma.ln() - LN_SQRT_2PI
}

#[cfg(test)]
mod tests;
