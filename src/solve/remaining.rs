//! How far the poses still are from the optimum after a step, estimated
//! from the step's length and how fast the steps shrink.
//!
//! A relative decrease of the objective says how much it still falls, not
//! how far the poses still are: along the map's weakest directions, where
//! the objective is flattest, a step that lowers it by 10⁻¹⁰ of itself can
//! leave the poses as far from the optimum again. After a Gauss–Newton or
//! Levenberg–Marquardt step of length `s` that shrank by `q` from the step
//! before, the rest of a linearly converging sequence is about
//! `s·q/(1 − q)`, and quadratic convergence makes `q` small. A chord step
//! contracts the error least along those directions, by a rate no step
//! before it shows, so its estimate is its own length.

/// The largest translation and rotation components of a step.
type Lengths = [f64; 2];

/// The last step's lengths and the estimate of how far the poses still
/// are from the optimum, `(translation, rotation)`, over one run.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct Remaining {
    last: Option<Lengths>,
    estimate: Lengths,
}

/// The largest share of its length by which a step may shrink and still
/// count as converging: at `q` = 0.9 the rest is estimated at 9 times the
/// step; beyond it the steps are not shrinking, and the estimate stays at
/// that.
const MAX_SHRINK: f64 = 0.9;

impl Remaining {
    /// After a step `step` (`D` numbers per variable block, the
    /// translation first), solved with an earlier factor if
    /// `reused_factor`.
    pub(super) fn after<const D: usize>(&mut self, step: &[f64], reused_factor: bool) {
        let largest = |part: std::ops::Range<usize>| {
            (step.chunks_exact(D))
                .flat_map(|block| &block[part.clone()])
                .fold(0.0f64, |m, v| m.max(v.abs()))
        };
        // SE(2)'s tangent is (x, y, θ), SE(3)'s (ρ, φ): the translation
        // is its first (D + 1) / 2 numbers.
        let translation = D.div_ceil(2);
        let now = [largest(0..translation), largest(translation..D)];
        self.estimate = match (reused_factor, self.last) {
            (false, Some(before)) => std::array::from_fn(|k| {
                let q = match before[k] > 0.0 {
                    true => (now[k] / before[k]).min(MAX_SHRINK),
                    false => MAX_SHRINK,
                };
                now[k] * q / (1.0 - q)
            }),
            _ => now,
        };
        self.last = Some(now);
    }

    /// Whether the poses are estimated within `bound` of the optimum
    /// (`(translation, rotation)`; `None`: always).
    pub(super) fn within(&self, bound: Option<(f64, f64)>) -> bool {
        bound.is_none_or(|(t, r)| self.estimate[0] <= t && self.estimate[1] <= r)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_chord_step_counts_its_length_and_a_fresh_one_its_shrinking() {
        let mut r = Remaining::default();
        // A first step: its own length (x and y translation, θ rotation).
        r.after::<3>(&[1e-2, 0.0, 2e-3, 0.0, -4e-3, 0.0], false);
        assert!(r.within(Some((1e-2, 2e-3))) && !r.within(Some((9e-3, 2e-3))));
        assert!(!r.within(Some((1e-2, 1.9e-3))));
        // A fresh step a hundredth as long: the rest about a hundredth of it.
        r.after::<3>(&[1e-4, 0.0, 2e-5, 0.0, 0.0, 0.0], false);
        assert!(r.within(Some((1.02e-6, 2.1e-7))));
        assert!(!r.within(Some((1e-6, 2.1e-7))));
        // A chord step as long: its own length, however it shrank.
        r.after::<3>(&[1e-6, 0.0, 1e-7, 0.0, 0.0, 0.0], true);
        assert!(r.within(Some((1e-6, 1e-7))) && !r.within(Some((9.9e-7, 1e-7))));
        // A fresh step that did not shrink: nine times its length.
        r.after::<3>(&[2e-6, 0.0, 0.0, 0.0, 0.0, 0.0], false);
        assert!(r.within(Some((1.81e-5, 1.0))) && !r.within(Some((1.79e-5, 1.0))));
        assert!(r.within(None));
        // In 3D the translation is the first three numbers.
        let mut r = Remaining::default();
        r.after::<6>(&[0.0, 0.0, 3e-3, 1e-4, 0.0, 0.0], false);
        assert!(r.within(Some((3e-3, 1e-4))) && !r.within(Some((3e-3, 9e-5))));
    }
}
