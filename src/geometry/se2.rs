//! SE(2): planar rigid-body motion.

use super::{EdgeLinearization, NormalBlocks, Pose, wrap_angle};
use nalgebra::{Matrix3, Vector2, Vector3};

/// A planar pose: translation `(x, y)` and heading `θ` (radians, kept in
/// `(-π, π]` by the group operations).
///
/// ```
/// use pgo::geometry::{Pose, Se2};
/// let a = Se2::new(1.0, 0.0, std::f64::consts::FRAC_PI_2);
/// let b = Se2::new(1.0, 0.0, 0.0);
/// let c = a.compose(&b); // one metre forward after turning left
/// assert!((c.x - 1.0).abs() < 1e-12 && (c.y - 1.0).abs() < 1e-12);
/// ```
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Se2 {
    /// x translation.
    pub x: f64,
    /// y translation.
    pub y: f64,
    /// Heading in radians.
    pub theta: f64,
}

impl Se2 {
    /// A pose from its translation and heading. The heading is stored as
    /// given (files may hold unwrapped angles); the group operations wrap.
    pub const fn new(x: f64, y: f64, theta: f64) -> Self {
        Self { x, y, theta }
    }

    /// The translation as a vector.
    pub fn translation(&self) -> Vector2<f64> {
        Vector2::new(self.x, self.y)
    }

    #[inline]
    fn rotate(&self, v: Vector2<f64>) -> Vector2<f64> {
        let (s, c) = self.theta.sin_cos();
        Vector2::new(c * v.x - s * v.y, s * v.x + c * v.y)
    }

    #[inline]
    fn rotate_inv(&self, v: Vector2<f64>) -> Vector2<f64> {
        let (s, c) = self.theta.sin_cos();
        Vector2::new(c * v.x + s * v.y, -s * v.x + c * v.y)
    }

    /// `(sin θ / θ, (1 − cos θ) / θ)`, with Taylor series near zero.
    fn v_coefficients(theta: f64) -> (f64, f64) {
        if theta.abs() < 1e-6 {
            let t2 = theta * theta;
            (1.0 - t2 / 6.0, theta / 2.0 - theta * t2 / 24.0)
        } else {
            (theta.sin() / theta, (1.0 - theta.cos()) / theta)
        }
    }
}

impl Pose<3> for Se2 {
    const NAME: &'static str = "SE2";

    fn identity() -> Self {
        Self::new(0.0, 0.0, 0.0)
    }

    fn compose(&self, other: &Self) -> Self {
        let t = self.translation() + self.rotate(other.translation());
        Self::new(t.x, t.y, wrap_angle(self.theta + other.theta))
    }

    fn inverse(&self) -> Self {
        let t = -self.rotate_inv(self.translation());
        Self::new(t.x, t.y, wrap_angle(-self.theta))
    }

    fn exp(xi: &Vector3<f64>) -> Self {
        let (a, b) = Self::v_coefficients(xi.z);
        // V = [[a, -b], [b, a]]
        Self::new(a * xi.x - b * xi.y, b * xi.x + a * xi.y, wrap_angle(xi.z))
    }

    fn log(&self) -> Vector3<f64> {
        let theta = wrap_angle(self.theta);
        let (a, b) = Self::v_coefficients(theta);
        let det = a * a + b * b;
        // V⁻¹ = [[a, b], [-b, a]] / det
        Vector3::new(
            (a * self.x + b * self.y) / det,
            (-b * self.x + a * self.y) / det,
            theta,
        )
    }

    fn retract(&self, delta: &Vector3<f64>) -> Self {
        self.compose(&Self::new(delta.x, delta.y, delta.z))
    }

    fn is_finite(&self) -> bool {
        self.x.is_finite() && self.y.is_finite() && self.theta.is_finite()
    }

    fn position(&self) -> Vector3<f64> {
        Vector3::new(self.x, self.y, 0.0)
    }

    fn position_shift(delta: &Vector3<f64>) -> f64 {
        delta.x.hypot(delta.y)
    }

    type Prepared = Se2Prepared;

    fn prepare(&self) -> Se2Prepared {
        let (s, c) = self.theta.sin_cos();
        Se2Prepared {
            x: self.x,
            y: self.y,
            theta: self.theta,
            c,
            s,
        }
    }

    fn error_prepared(xi: &Se2Prepared, xj: &Se2Prepared, z: &Se2Prepared) -> Vector3<f64> {
        // A = Xi⁻¹ Xj, E = Z⁻¹ A
        let ta = xi.rotate_inv(xj.x - xi.x, xj.y - xi.y);
        let te = z.rotate_inv(ta.x - z.x, ta.y - z.y);
        Vector3::new(te.x, te.y, wrap_angle(xj.theta - xi.theta - z.theta))
    }

    fn error_and_jacobians_prepared(
        xi: &Se2Prepared,
        xj: &Se2Prepared,
        z: &Se2Prepared,
    ) -> EdgeLinearization<3> {
        let ta = xi.rotate_inv(xj.x - xi.x, xj.y - xi.y);
        let te = z.rotate_inv(ta.x - z.x, ta.y - z.y);
        let error = Vector3::new(te.x, te.y, wrap_angle(xj.theta - xi.theta - z.theta));

        // R_E = R_zᵀ R_iᵀ R_j; e_t = R_zᵀ (R_iᵀ (t_j − t_i) − t_z).
        // ∂e_t/∂ρ_j = R_E, ∂e_t/∂ρ_i = −R_zᵀ, ∂e_t/∂φ_i = R_zᵀ (a_y, −a_x) (a = t_A),
        // ∂e_θ/∂φ_j = 1, ∂e_θ/∂φ_i = −1. The angle of R_E from the prepared
        // sines and cosines: θ_E = θ_j − (θ_i + θ_z).
        let (cz, sz) = (z.c, z.s);
        let (ciz, siz) = (xi.c * cz - xi.s * sz, xi.s * cz + xi.c * sz);
        let (ce, se) = (xj.c * ciz + xj.s * siz, xj.s * ciz - xj.c * siz);
        let p = z.rotate_inv(ta.y, -ta.x);
        let jac_i = Matrix3::new(-cz, -sz, p.x, sz, -cz, p.y, 0.0, 0.0, -1.0);
        let jac_j = Matrix3::new(ce, -se, 0.0, se, ce, 0.0, 0.0, 0.0, 1.0);
        EdgeLinearization {
            error,
            jac_i,
            jac_j,
        }
    }

    /// [`Pose::normal_blocks_prepared`] through the zeros of the Jacobians:
    /// `J_j`'s last row and column are those of the identity, and `J_i`'s
    /// last row is `(0, 0, −1)`, so each product with one takes two rows or
    /// columns (a third of the multiplications of the dense products).
    fn normal_blocks_prepared(
        xi: &Se2Prepared,
        xj: &Se2Prepared,
        z: &Se2Prepared,
        omega: &Matrix3<f64>,
    ) -> NormalBlocks<3> {
        let EdgeLinearization {
            error: e,
            jac_i: ji,
            jac_j: jj,
        } = Self::error_and_jacobians_prepared(xi, xj, z);
        let (o0, o1, o2) = (omega.column(0), omega.column(1), omega.column(2));
        // Ω·J: the columns of Ω combined as J's columns say.
        let oi = Matrix3::from_columns(&[
            o0 * ji[(0, 0)] + o1 * ji[(1, 0)],
            o0 * ji[(0, 1)] + o1 * ji[(1, 1)],
            o0 * ji[(0, 2)] + o1 * ji[(1, 2)] - o2,
        ]);
        let oj = Matrix3::from_columns(&[
            o0 * jj[(0, 0)] + o1 * jj[(1, 0)],
            o0 * jj[(0, 1)] + o1 * jj[(1, 1)],
            o2.into_owned(),
        ]);
        let oe = omega * e;
        // Jᵀ·X: the rows of X combined as J's columns say.
        let ti = |x: &Matrix3<f64>| {
            Matrix3::from_rows(&[
                x.row(0) * ji[(0, 0)] + x.row(1) * ji[(1, 0)],
                x.row(0) * ji[(0, 1)] + x.row(1) * ji[(1, 1)],
                x.row(0) * ji[(0, 2)] + x.row(1) * ji[(1, 2)] - x.row(2),
            ])
        };
        NormalBlocks {
            h_ii: ti(&oi),
            h_ij: ti(&oj),
            h_jj: Matrix3::from_rows(&[
                oj.row(0) * jj[(0, 0)] + oj.row(1) * jj[(1, 0)],
                oj.row(0) * jj[(0, 1)] + oj.row(1) * jj[(1, 1)],
                oj.row(2).into_owned(),
            ]),
            b_i: Vector3::new(
                ji[(0, 0)] * oe.x + ji[(1, 0)] * oe.y,
                ji[(0, 1)] * oe.x + ji[(1, 1)] * oe.y,
                ji[(0, 2)] * oe.x + ji[(1, 2)] * oe.y - oe.z,
            ),
            b_j: Vector3::new(
                jj[(0, 0)] * oe.x + jj[(1, 0)] * oe.y,
                jj[(0, 1)] * oe.x + jj[(1, 1)] * oe.y,
                oe.z,
            ),
            chi2: e.dot(&oe),
        }
    }
}

/// An [`Se2`] with the cosine and sine of its heading.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Se2Prepared {
    x: f64,
    y: f64,
    theta: f64,
    c: f64,
    s: f64,
}

impl Se2Prepared {
    /// `R(θ)ᵀ·(vx, vy)`.
    #[inline]
    fn rotate_inv(&self, vx: f64, vy: f64) -> Vector2<f64> {
        Vector2::new(self.c * vx + self.s * vy, -self.s * vx + self.c * vy)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::testing::{check_jacobians, check_normal_blocks_on_random_edges};
    use rand::{Rng, SeedableRng, rngs::StdRng};
    use std::f64::consts::PI;

    fn random_pose(rng: &mut StdRng, scale: f64) -> Se2 {
        Se2::new(
            rng.random_range(-scale..scale),
            rng.random_range(-scale..scale),
            rng.random_range(-PI..PI),
        )
    }

    #[test]
    fn compose_inverse_is_identity() {
        let mut rng = StdRng::seed_from_u64(1);
        for _ in 0..100 {
            let a = random_pose(&mut rng, 10.0);
            let e = a.compose(&a.inverse());
            assert!(e.log().norm() < 1e-12);
        }
    }

    #[test]
    fn exp_log_round_trip() {
        let mut rng = StdRng::seed_from_u64(2);
        for _ in 0..100 {
            let a = random_pose(&mut rng, 10.0);
            let b = Se2::exp(&a.log());
            assert!((a.x - b.x).abs() < 1e-10 && (a.y - b.y).abs() < 1e-10);
            assert!(wrap_angle(a.theta - b.theta).abs() < 1e-12);
        }
        let tiny = Vector3::new(1e-3, -2e-3, 1e-9);
        assert!((Se2::exp(&tiny).log() - tiny).norm() < 1e-15);
    }

    #[test]
    fn structured_normal_blocks_equal_the_multiplied_out_ones() {
        check_normal_blocks_on_random_edges(random_pose);
    }

    #[test]
    fn jacobians_match_finite_differences_on_random_poses() {
        let mut rng = StdRng::seed_from_u64(3);
        for _ in 0..200 {
            let xi = random_pose(&mut rng, 20.0);
            let xj = random_pose(&mut rng, 20.0);
            let z = random_pose(&mut rng, 5.0);
            check_jacobians(&xi, &xj, &z, 1e-6);
        }
    }

    #[test]
    fn jacobians_match_near_identity_and_near_pi() {
        let mut rng = StdRng::seed_from_u64(4);
        for &theta in &[0.0, 1e-9, -1e-7, PI - 1e-3, -PI + 1e-3] {
            let xi = random_pose(&mut rng, 3.0);
            // A relative rotation close to `theta` so that E's angle is near it.
            let z = Se2::new(0.2, -0.1, 0.3);
            let xj = xi.compose(&z).compose(&Se2::new(1e-4, 2e-4, theta));
            check_jacobians(&xi, &xj, &z, 1e-6);
        }
    }

    #[test]
    fn error_matches_g2o_definition() {
        // E = Z⁻¹ Xi⁻¹ Xj computed by composition must equal error().
        let mut rng = StdRng::seed_from_u64(5);
        for _ in 0..50 {
            let xi = random_pose(&mut rng, 10.0);
            let xj = random_pose(&mut rng, 10.0);
            let z = random_pose(&mut rng, 3.0);
            let e = z.inverse().compose(&xi.inverse().compose(&xj));
            let err = Se2::error(&xi, &xj, &z);
            assert!((err - Vector3::new(e.x, e.y, e.theta)).norm() < 1e-10);
        }
    }

    #[test]
    #[allow(clippy::approx_constant)] // 6.2831 is what the ring dataset stores
    fn unwrapped_angles_give_wrapped_errors() {
        let xi = Se2::new(0.0, 0.0, 6.2831);
        let xj = Se2::new(1.0, 0.0, 0.0);
        let z = Se2::new(1.0, 0.0, 4.786 - 2.0 * PI);
        let e = Se2::error(&xi, &xj, &z);
        assert!(e.z.abs() <= PI);
    }
}
