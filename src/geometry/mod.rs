//! Rigid-body poses: SE(2) and SE(3), their group operations, exp/log maps,
//! and the relative-pose error of a pose-graph edge with its analytic
//! Jacobians.
//!
//! # Conventions
//!
//! * A pose `X` maps points from its local frame to the world frame.
//! * An edge from `i` to `j` with measurement `Z` predicts `Xᵢ⁻¹·Xⱼ ≈ Z`. Its
//!   error is read off `E = Z⁻¹·(Xᵢ⁻¹·Xⱼ)` exactly as g2o does:
//!   * SE(2): `e = (tₓ, t_y, wrap(θ))` of `E`;
//!   * SE(3): `e = (t, q_v)` where `q_v` is the vector part of the unit
//!     quaternion of `E` taken with `w ≥ 0`.
//!
//!   With this error, the information matrices stored in g2o files mean what
//!   their authors meant and `Σ eᵀΩe` equals g2o's χ².
//! * The optimiser updates a pose on the right: `X ⊞ δ = X·Δ(δ)`, where
//!   `Δ(δ)` is the pose with translation `δ_t` and rotation `Exp(δ_r)`
//!   (SE(2): angle `δ_θ`). The Jacobians returned by
//!   [`Pose::error_and_jacobians`] are derivatives with respect to these
//!   increments at `δ = 0`.

#[cfg(test)]
mod proptests;
mod se2;
mod se3;

pub use se2::{Se2, Se2Prepared};
pub use se3::{Se3, Se3Prepared};

use nalgebra::{Matrix3, SMatrix, SVector, Vector3};

/// A rigid-body pose usable as a pose-graph vertex, with `D` degrees of
/// freedom (3 for [`Se2`], 6 for [`Se3`]).
pub trait Pose<const D: usize>:
    Copy + Clone + std::fmt::Debug + PartialEq + Send + Sync + 'static
{
    /// `"SE2"` or `"SE3"`, for messages.
    const NAME: &'static str;

    /// The identity pose.
    fn identity() -> Self;

    /// Group composition `self · other`.
    fn compose(&self, other: &Self) -> Self;

    /// Group inverse.
    fn inverse(&self) -> Self;

    /// Exponential map from the Lie algebra (translation part first).
    fn exp(xi: &SVector<f64, D>) -> Self;

    /// Logarithm map, the inverse of [`Pose::exp`] (translation part first).
    fn log(&self) -> SVector<f64, D>;

    /// The right update used by the optimiser: `self · Δ(delta)`.
    fn retract(&self, delta: &SVector<f64, D>) -> Self;

    /// Whether every number in the pose is finite.
    fn is_finite(&self) -> bool;

    /// The position of the pose (z = 0 for SE(2)).
    fn position(&self) -> Vector3<f64>;

    /// How far [`Pose::retract`] by `delta` (or by `−delta`) moves the
    /// pose's position, whatever the pose: the length of `delta`'s
    /// translation part, which the pose's rotation turns without
    /// stretching.
    fn position_shift(delta: &SVector<f64, D>) -> f64;

    /// The pose with what every edge at it recomputes otherwise (the sine
    /// and cosine of an angle, a rotation matrix), for evaluating many edges.
    type Prepared: Copy + Clone + std::fmt::Debug + Send + Sync + 'static;

    /// This pose, prepared.
    fn prepare(&self) -> Self::Prepared;

    /// Relative-pose error of the edge `xi → xj` with measurement `z`
    /// (see the module documentation).
    fn error(xi: &Self, xj: &Self, z: &Self) -> SVector<f64, D> {
        Self::error_prepared(&xi.prepare(), &xj.prepare(), &z.prepare())
    }

    /// The error and its Jacobians with respect to the right updates of `xi`
    /// and `xj`.
    fn error_and_jacobians(xi: &Self, xj: &Self, z: &Self) -> EdgeLinearization<D> {
        Self::error_and_jacobians_prepared(&xi.prepare(), &xj.prepare(), &z.prepare())
    }

    /// [`Pose::error`] of prepared poses.
    fn error_prepared(
        xi: &Self::Prepared,
        xj: &Self::Prepared,
        z: &Self::Prepared,
    ) -> SVector<f64, D>;

    /// [`Pose::error_and_jacobians`] of prepared poses.
    fn error_and_jacobians_prepared(
        xi: &Self::Prepared,
        xj: &Self::Prepared,
        z: &Self::Prepared,
    ) -> EdgeLinearization<D>;

    /// The edge's blocks of the normal equations for information `omega`
    /// ([`NormalBlocks`]). The default multiplies out the Jacobians of
    /// [`Pose::error_and_jacobians_prepared`]; a pose type may use the
    /// structure of its Jacobians to do less.
    fn normal_blocks_prepared(
        xi: &Self::Prepared,
        xj: &Self::Prepared,
        z: &Self::Prepared,
        omega: &SMatrix<f64, D, D>,
    ) -> NormalBlocks<D> {
        let lin = Self::error_and_jacobians_prepared(xi, xj, z);
        NormalBlocks::from_jacobians(&lin, omega)
    }
}

/// One edge's contribution to the normal equations `H δ = −b` of
/// `eᵀΩe`: `H_ii = J_iᵀΩJ_i`, `H_ij = J_iᵀΩJ_j`, `H_jj = J_jᵀΩJ_j`,
/// `b_i = J_iᵀΩe`, `b_j = J_jᵀΩe`, and `χ² = eᵀΩe`.
#[derive(Clone, Copy, Debug)]
pub struct NormalBlocks<const D: usize> {
    /// `H_ii`.
    pub h_ii: SMatrix<f64, D, D>,
    /// `H_ij`.
    pub h_ij: SMatrix<f64, D, D>,
    /// `H_jj`.
    pub h_jj: SMatrix<f64, D, D>,
    /// `b_i`.
    pub b_i: SVector<f64, D>,
    /// `b_j`.
    pub b_j: SVector<f64, D>,
    /// `eᵀΩe`.
    pub chi2: f64,
}

impl<const D: usize> Default for NormalBlocks<D> {
    fn default() -> Self {
        Self {
            h_ii: SMatrix::zeros(),
            h_ij: SMatrix::zeros(),
            h_jj: SMatrix::zeros(),
            b_i: SVector::zeros(),
            b_j: SVector::zeros(),
            chi2: 0.0,
        }
    }
}

impl<const D: usize> NormalBlocks<D> {
    /// The blocks multiplied out from the error and its Jacobians.
    pub fn from_jacobians(lin: &EdgeLinearization<D>, omega: &SMatrix<f64, D, D>) -> Self {
        let oi = omega * lin.jac_i;
        let oj = omega * lin.jac_j;
        let oe = omega * lin.error;
        Self {
            h_ii: lin.jac_i.transpose() * oi,
            h_ij: lin.jac_i.transpose() * oj,
            h_jj: lin.jac_j.transpose() * oj,
            b_i: lin.jac_i.transpose() * oe,
            b_j: lin.jac_j.transpose() * oe,
            chi2: lin.error.dot(&oe),
        }
    }

    /// These blocks scaled by a weight.
    pub fn scaled(mut self, w: f64) -> Self {
        if w != 1.0 {
            self.h_ii *= w;
            self.h_ij *= w;
            self.h_jj *= w;
            self.b_i *= w;
            self.b_j *= w;
            self.chi2 *= w;
        }
        self
    }
}

/// The error of one edge and its Jacobians, `∂e/∂δᵢ` and `∂e/∂δⱼ`.
#[derive(Clone, Copy, Debug)]
pub struct EdgeLinearization<const D: usize> {
    /// The error `e`.
    pub error: SVector<f64, D>,
    /// `∂e/∂δᵢ`.
    pub jac_i: SMatrix<f64, D, D>,
    /// `∂e/∂δⱼ`.
    pub jac_j: SMatrix<f64, D, D>,
}

/// The skew-symmetric matrix `[v]×` with `[v]× w = v × w`.
#[inline]
pub fn skew(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

/// Wraps an angle to `(-π, π]`.
///
/// ```
/// use pgo::geometry::wrap_angle;
/// use std::f64::consts::PI;
/// assert!((wrap_angle(3.0 * PI / 2.0) + PI / 2.0).abs() < 1e-12);
/// assert_eq!(wrap_angle(PI), PI);
/// ```
#[inline]
pub fn wrap_angle(theta: f64) -> f64 {
    use std::f64::consts::PI;
    if theta > -PI && theta <= PI {
        return theta;
    }
    let w = theta.rem_euclid(2.0 * PI);
    if w > PI { w - 2.0 * PI } else { w }
}

#[cfg(test)]
pub(crate) mod testing {
    //! Central finite differences of the edge error, and the structured
    //! normal blocks against the multiplied-out ones, shared by the SE(2)
    //! and SE(3) tests.
    use super::*;
    use rand::{Rng, SeedableRng, rngs::StdRng};

    /// Numerical Jacobians of `Pose::error` with respect to right updates of
    /// `xi` and `xj` (central differences, step `h`).
    pub fn numerical_jacobians<P: Pose<D>, const D: usize>(
        xi: &P,
        xj: &P,
        z: &P,
        h: f64,
    ) -> (SMatrix<f64, D, D>, SMatrix<f64, D, D>) {
        let mut ji = SMatrix::<f64, D, D>::zeros();
        let mut jj = SMatrix::<f64, D, D>::zeros();
        for k in 0..D {
            let mut d = SVector::<f64, D>::zeros();
            d[k] = h;
            let ep = P::error(&xi.retract(&d), xj, z);
            let em = P::error(&xi.retract(&(-d)), xj, z);
            ji.set_column(k, &(wrapped_difference(&ep, &em) / (2.0 * h)));
            let ep = P::error(xi, &xj.retract(&d), z);
            let em = P::error(xi, &xj.retract(&(-d)), z);
            jj.set_column(k, &(wrapped_difference(&ep, &em) / (2.0 * h)));
        }
        (ji, jj)
    }

    /// `a − b`, each component taken modulo 2π into (−π, π]: an angle of the
    /// error that wraps at ±π between the two evaluations (an error near π)
    /// jumps by 2π, which is no derivative. Other components never differ
    /// by more than π over a step of 1e-6.
    fn wrapped_difference<const D: usize>(
        a: &SVector<f64, D>,
        b: &SVector<f64, D>,
    ) -> SVector<f64, D> {
        (a - b).map(wrap_angle)
    }

    /// Asserts that the analytic Jacobians match central differences.
    pub fn check_jacobians<P: Pose<D>, const D: usize>(xi: &P, xj: &P, z: &P, tol: f64) {
        let lin = P::error_and_jacobians(xi, xj, z);
        let e = P::error(xi, xj, z);
        assert!(
            (lin.error - e).norm() < 1e-12,
            "error mismatch: {} vs {}",
            lin.error,
            e
        );
        let (ni, nj) = numerical_jacobians(xi, xj, z, 1e-6);
        let di = (lin.jac_i - ni).abs().max();
        let dj = (lin.jac_j - nj).abs().max();
        assert!(
            di < tol && dj < tol,
            "Jacobian mismatch (|ΔJi| = {di:e}, |ΔJj| = {dj:e})\nanalytic Ji {}\nnumeric Ji {}\nanalytic Jj {}\nnumeric Jj {}",
            lin.jac_i,
            ni,
            lin.jac_j,
            nj
        );
    }

    /// [`check_normal_blocks`] on 200 random edges: poses from
    /// `random_pose(rng, scale)` (scale 20, the measurement 5) and a random
    /// positive definite information matrix.
    pub fn check_normal_blocks_on_random_edges<P: Pose<D>, const D: usize>(
        random_pose: fn(&mut StdRng, f64) -> P,
    ) {
        let mut rng = StdRng::seed_from_u64(17);
        for _ in 0..200 {
            let xi = random_pose(&mut rng, 20.0);
            let xj = random_pose(&mut rng, 20.0);
            let z = random_pose(&mut rng, 5.0);
            let m = SMatrix::<f64, D, D>::from_fn(|_, _| rng.random_range(-1.0..1.0));
            let omega = m * m.transpose() + SMatrix::<f64, D, D>::identity();
            check_normal_blocks(&xi, &xj, &z, &omega);
        }
    }

    /// Asserts that a pose type's normal blocks (its structured
    /// [`Pose::normal_blocks_prepared`]) equal those multiplied out from its
    /// Jacobians, to 1e-12 relative, on an edge with information `omega`.
    fn check_normal_blocks<P: Pose<D>, const D: usize>(
        xi: &P,
        xj: &P,
        z: &P,
        omega: &SMatrix<f64, D, D>,
    ) {
        let (pi, pj, pz) = (xi.prepare(), xj.prepare(), z.prepare());
        let fast = P::normal_blocks_prepared(&pi, &pj, &pz, omega);
        let lin = P::error_and_jacobians_prepared(&pi, &pj, &pz);
        let slow = NormalBlocks::from_jacobians(&lin, omega);
        let scale = slow.h_ii.norm() + slow.h_jj.norm();
        for (a, b) in [
            (fast.h_ii, slow.h_ii),
            (fast.h_ij, slow.h_ij),
            (fast.h_jj, slow.h_jj),
        ] {
            assert!((a - b).norm() < 1e-12 * scale, "{a} vs {b}");
        }
        let bscale = slow.b_i.norm() + slow.b_j.norm() + 1.0;
        assert!((fast.b_i - slow.b_i).norm() < 1e-12 * bscale);
        assert!((fast.b_j - slow.b_j).norm() < 1e-12 * bscale);
        assert!((fast.chi2 - slow.chi2).abs() < 1e-12 * slow.chi2.max(1.0));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    #[test]
    fn wrap_angle_maps_into_half_open_interval() {
        for k in -5..=5 {
            let t = 0.3 + 2.0 * PI * k as f64;
            assert!((wrap_angle(t) - 0.3).abs() < 1e-12);
        }
        assert_eq!(wrap_angle(-PI), PI);
        assert!((wrap_angle(4.786) - (4.786 - 2.0 * PI)).abs() < 1e-12);
    }

    #[test]
    fn skew_is_cross_product() {
        let a = Vector3::new(0.3, -1.2, 2.0);
        let b = Vector3::new(-0.7, 0.4, 1.1);
        assert!((skew(&a) * b - a.cross(&b)).norm() < 1e-15);
    }
}

/// The dimension (2 or 3) of poses with `D` degrees of freedom.
pub(crate) const fn dimension<const D: usize>() -> usize {
    if D == 3 { 2 } else { 3 }
}
