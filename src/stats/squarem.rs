//! SQUAREM, the squared extrapolation that accelerates EM (Varadhan &
//! Roland, *Scand. J. Statist.* 35, 2008).
//!
//! Where the components of a mixture overlap, EM creeps towards its fixed
//! point along a nearly straight path, each iteration shortening the
//! remaining distance by a constant factor close to 1 (hundreds of
//! iterations on the gate's counts). After two EM iterations
//! `θ → θ₁ → θ₂` of the parameter vector, with `r = θ₁ − θ` and
//! `v = θ₂ − 2θ₁ + θ`, SQUAREM jumps to `θ − 2α r + α² v` with
//! `α = −‖r‖/‖v‖` (its scheme S3), which follows that path much further
//! than `θ₂` (`α = −1`). The caller keeps a jump only if it is a valid
//! parameter vector no less likely than where it started, else halves it
//! towards `θ₂`, and then runs one EM iteration from it; the fixed points
//! are EM's own.

/// Most halvings of a jump before the caller takes the plain EM iterate
/// `θ₂` instead: each costs an E-step, and a jump that still fails after
/// `α + 1` was halved eight times (to 1/256 of its length beyond `θ₂`)
/// would gain little over `θ₂`.
pub const MAX_HALVINGS: usize = 8;

/// The jumps SQUAREM tries after two EM iterations `θ₀ → θ₁ → θ₂`, the
/// longest first, each next one with `α + 1` halved; none when the first is
/// no longer than plain EM's (`α ≥ −1`), or when `θ₁ − θ₀` and the second
/// difference are not finite.
pub fn jumps<'a>(t0: &'a [f64], t1: &[f64], t2: &[f64]) -> impl Iterator<Item = Vec<f64>> + 'a {
    let r: Vec<f64> = t1.iter().zip(t0).map(|(a, b)| a - b).collect();
    let v: Vec<f64> = (t2.iter().zip(t1).zip(t0))
        .map(|((c, b), a)| c - 2.0 * b + a)
        .collect();
    let norm = |x: &[f64]| x.iter().map(|a| a * a).sum::<f64>().sqrt();
    let first = -(norm(&r) / norm(&v));
    let mut alpha = if first.is_finite() { first } else { -1.0 };
    std::iter::from_fn(move || {
        if alpha >= -1.0 {
            return None;
        }
        let a = alpha;
        alpha = (alpha - 1.0) / 2.0;
        Some(
            (t0.iter().zip(&r).zip(&v))
                .map(|((t, r), v)| t - 2.0 * a * r + a * a * v)
                .collect(),
        )
    })
    .take(MAX_HALVINGS + 1)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_linear_iteration_is_jumped_to_its_fixed_point() {
        // θ ← 0.9 θ + b creeps to −10 b, shortening the distance by a tenth
        // per iteration; after two iterations the first jump lands on it.
        let step = |t: &[f64]| vec![0.9 * t[0] + 1.0, 0.9 * t[1] - 2.0];
        let t0 = vec![0.0, 0.0];
        let t1 = step(&t0);
        let t2 = step(&t1);
        let first = jumps(&t0, &t1, &t2).next().unwrap();
        assert!((first[0] - 10.0).abs() < 1e-9 && (first[1] + 20.0).abs() < 1e-9);
        // With two rates the jump is not exact, but still ahead of θ₂.
        let step = |t: &[f64]| vec![0.9 * t[0] + 1.0, 0.5 * t[1] - 2.0];
        let t1 = step(&t0);
        let t2 = step(&t1);
        let first = jumps(&t0, &t1, &t2).next().unwrap();
        let distance = |t: &[f64]| (t[0] - 10.0).hypot(t[1] + 4.0);
        assert!(distance(&first) < distance(&t2), "{first:?} against {t2:?}");
    }

    #[test]
    fn jumps_shorten_towards_the_plain_iterate_and_stop() {
        let all: Vec<Vec<f64>> = jumps(&[8.0], &[4.0], &[2.0]).collect();
        // α = −2 first: exactly the fixed point 0 of halving.
        assert_eq!(all[0], vec![0.0]);
        assert!(all.len() <= MAX_HALVINGS + 1);
        let distance: Vec<f64> = all.iter().map(|t| (t[0] - 2.0).abs()).collect();
        assert!(distance.windows(2).all(|w| w[1] < w[0]), "{distance:?}");
        // No jump longer than plain EM's, and none from a standstill.
        assert_eq!(jumps(&[8.0], &[4.0], &[0.0]).count(), 0);
        assert_eq!(jumps(&[1.0], &[1.0], &[1.0]).count(), 0);
    }
}
