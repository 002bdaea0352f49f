//! SE(3): rigid-body motion in space.

use super::{EdgeLinearization, NormalBlocks, Pose, skew};
use nalgebra::{Matrix3, Matrix6, Quaternion, UnitQuaternion, Vector3, Vector6};

/// A spatial pose: a unit quaternion and a translation.
///
/// ```
/// use pgo::geometry::{Pose, Se3};
/// use nalgebra::Vector6;
/// let xi = Vector6::new(1.0, 2.0, 3.0, 0.1, -0.2, 0.3);
/// let x = Se3::exp(&xi);
/// assert!((x.log() - xi).norm() < 1e-12);
/// ```
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Se3 {
    /// Rotation.
    pub rotation: UnitQuaternion<f64>,
    /// Translation.
    pub translation: Vector3<f64>,
}

/// Quaternions whose squared norm is this close to 1 are taken as unit
/// quaternions unchanged, so that normalising twice gives the same bits.
const UNIT_NORM_TOLERANCE: f64 = 8.0 * f64::EPSILON;

impl Se3 {
    /// A pose from a rotation and a translation.
    pub fn new(rotation: UnitQuaternion<f64>, translation: Vector3<f64>) -> Self {
        Self {
            rotation,
            translation,
        }
    }

    /// A pose from a translation and a quaternion `(qx, qy, qz, qw)` as
    /// stored in g2o files. The quaternion is normalised unless it is
    /// already of unit norm to machine precision (so that reading what was
    /// written gives the same bits), whatever its norm: one whose squared
    /// norm over- or underflows (norm beyond 10^±154) is divided by its
    /// largest component first. Returns `None` for a quaternion that is
    /// zero to floating point (its largest component is 0 or subnormal,
    /// below 2.2·10⁻³⁰⁸, where the ratios of the components have lost
    /// their precision) or a non-finite number.
    pub fn from_translation_quaternion(t: [f64; 3], q: [f64; 4]) -> Option<Self> {
        let quat = Quaternion::new(q[3], q[0], q[1], q[2]);
        if q.iter().chain(&t).any(|v| !v.is_finite()) {
            return None;
        }
        let n2 = quat.norm_squared();
        let quat = if (n2 - 1.0).abs() <= UNIT_NORM_TOLERANCE {
            quat
        } else if n2.is_finite() && n2 > f64::MIN_POSITIVE {
            quat / n2.sqrt()
        } else {
            // Exact scaling by a power of two into range (in two halves:
            // 2¹⁰²³ is the largest f64 power of two, the scale may be one
            // more).
            let largest = q.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            if largest < f64::MIN_POSITIVE {
                return None;
            }
            let e = -(largest.log2().floor() as i32);
            let scaled = quat * 2f64.powi(e / 2) * 2f64.powi(e - e / 2);
            scaled / scaled.norm()
        };
        Some(Self::new(
            UnitQuaternion::new_unchecked(quat),
            Vector3::from(t),
        ))
    }

    /// `(qx, qy, qz, qw)`, the order used in g2o files.
    pub fn quaternion_xyzw(&self) -> [f64; 4] {
        let q = self.rotation.quaternion();
        [q.i, q.j, q.k, q.w]
    }

    /// The rotation matrix.
    pub fn rotation_matrix(&self) -> Matrix3<f64> {
        self.rotation.to_rotation_matrix().into_inner()
    }

    /// The left Jacobian `V(φ)` of SO(3), used by exp/log.
    fn v_matrix(phi: &Vector3<f64>) -> Matrix3<f64> {
        let theta2 = phi.norm_squared();
        let k = skew(phi);
        let (a, b) = if theta2 < 1e-10 {
            (0.5 - theta2 / 24.0, 1.0 / 6.0 - theta2 / 120.0)
        } else {
            let theta = theta2.sqrt();
            (
                (1.0 - theta.cos()) / theta2,
                (theta - theta.sin()) / (theta2 * theta),
            )
        };
        Matrix3::identity() + k * a + k * k * b
    }
}

impl Pose<6> for Se3 {
    const NAME: &'static str = "SE3";

    fn identity() -> Self {
        Self::new(UnitQuaternion::identity(), Vector3::zeros())
    }

    fn compose(&self, other: &Self) -> Self {
        Self::new(
            renormalize(self.rotation * other.rotation),
            self.translation + self.rotation * other.translation,
        )
    }

    fn inverse(&self) -> Self {
        let r = self.rotation.inverse();
        Self::new(r, -(r * self.translation))
    }

    fn exp(xi: &Vector6<f64>) -> Self {
        let rho = xi.fixed_rows::<3>(0).into_owned();
        let phi = xi.fixed_rows::<3>(3).into_owned();
        Self::new(
            UnitQuaternion::from_scaled_axis(phi),
            Self::v_matrix(&phi) * rho,
        )
    }

    fn log(&self) -> Vector6<f64> {
        let phi = self.rotation.scaled_axis();
        let rho = Self::v_matrix(&phi)
            .try_inverse()
            .map(|vi| vi * self.translation)
            // V(φ) is singular only at |φ| = 2π·k (k ≥ 1), which scaled_axis never returns.
            .unwrap_or(self.translation);
        let mut out = Vector6::zeros();
        out.fixed_rows_mut::<3>(0).copy_from(&rho);
        out.fixed_rows_mut::<3>(3).copy_from(&phi);
        out
    }

    fn retract(&self, delta: &Vector6<f64>) -> Self {
        let rho = Vector3::new(delta[0], delta[1], delta[2]);
        let phi = Vector3::new(delta[3], delta[4], delta[5]);
        Self::new(
            renormalize(self.rotation * UnitQuaternion::from_scaled_axis(phi)),
            self.translation + self.rotation * rho,
        )
    }

    fn is_finite(&self) -> bool {
        self.translation.iter().all(|v| v.is_finite())
            && self.rotation.coords.iter().all(|v| v.is_finite())
    }

    fn position(&self) -> Vector3<f64> {
        self.translation
    }

    fn position_shift(delta: &Vector6<f64>) -> f64 {
        delta.fixed_rows::<3>(0).norm()
    }

    type Prepared = Se3Prepared;

    fn prepare(&self) -> Se3Prepared {
        Se3Prepared {
            rotation: self.rotation,
            matrix: self.rotation_matrix(),
            translation: self.translation,
        }
    }

    fn error_prepared(xi: &Se3Prepared, xj: &Se3Prepared, z: &Se3Prepared) -> Vector6<f64> {
        let t_a = xi.matrix.tr_mul(&(xj.translation - xi.translation));
        let t_e = z.matrix.tr_mul(&(t_a - z.translation));
        let q_e = relative_quaternion(xi, xj, z);
        Vector6::new(t_e.x, t_e.y, t_e.z, q_e.i, q_e.j, q_e.k)
    }

    fn error_and_jacobians_prepared(
        xi: &Se3Prepared,
        xj: &Se3Prepared,
        z: &Se3Prepared,
    ) -> EdgeLinearization<6> {
        let EdgeGeometry {
            rz_t,
            r_a,
            r_e,
            t_a,
            t_e,
            v,
            dq,
        } = EdgeGeometry::new(xi, xj, z);
        let error = Vector6::new(t_e.x, t_e.y, t_e.z, v.x, v.y, v.z);

        let mut jac_i = Matrix6::zeros();
        jac_i.fixed_view_mut::<3, 3>(0, 0).copy_from(&(-rz_t));
        jac_i
            .fixed_view_mut::<3, 3>(0, 3)
            .copy_from(&(rz_t * skew(&t_a)));
        jac_i
            .fixed_view_mut::<3, 3>(3, 3)
            .copy_from(&(-(dq * r_a.transpose())));
        let mut jac_j = Matrix6::zeros();
        jac_j.fixed_view_mut::<3, 3>(0, 0).copy_from(&r_e);
        jac_j.fixed_view_mut::<3, 3>(3, 3).copy_from(&dq);
        EdgeLinearization {
            error,
            jac_i,
            jac_j,
        }
    }

    fn normal_blocks_prepared(
        xi: &Se3Prepared,
        xj: &Se3Prepared,
        z: &Se3Prepared,
        omega: &Matrix6<f64>,
    ) -> NormalBlocks<6> {
        Self::normal_blocks_structured(xi, xj, z, omega)
    }
}

/// The quantities of one edge's error `E = Z⁻¹·Xᵢ⁻¹Xⱼ` that its Jacobians
/// and its normal blocks share (`A = Xᵢ⁻¹Xⱼ`).
struct EdgeGeometry {
    /// `R_zᵀ`.
    rz_t: Matrix3<f64>,
    /// `R_A`.
    r_a: Matrix3<f64>,
    /// `R_E = R_zᵀR_A`.
    r_e: Matrix3<f64>,
    /// `t_A`.
    t_a: Vector3<f64>,
    /// `t_E = R_zᵀ(t_A − t_z)`, the translation error.
    t_e: Vector3<f64>,
    /// The vector part of `q_E` (taken with `w ≥ 0`), the rotation error.
    v: Vector3<f64>,
    /// `d vec(q_E ⊗ (1, φ/2)) / dφ = ½ (w I + [v]×)`.
    dq: Matrix3<f64>,
}

impl EdgeGeometry {
    #[inline]
    fn new(xi: &Se3Prepared, xj: &Se3Prepared, z: &Se3Prepared) -> Self {
        let ri_t = xi.matrix.transpose();
        let rz_t = z.matrix.transpose();
        let r_a = ri_t * xj.matrix;
        let t_a = ri_t * (xj.translation - xi.translation);
        let q_e = relative_quaternion(xi, xj, z);
        let v = Vector3::new(q_e.i, q_e.j, q_e.k);
        Self {
            rz_t,
            r_a,
            r_e: rz_t * r_a,
            t_a,
            t_e: rz_t * (t_a - z.translation),
            v,
            dq: (Matrix3::identity() * q_e.w + skew(&v)) * 0.5,
        }
    }
}

/// `Ad(A⁻¹)` of `A = Xᵢ⁻¹Xⱼ` as its blocks `[[P, Q], [0, P]]`: the first-order
/// change of `Xᵢ⁻¹Xⱼ` under a right update of `Xᵢ` is that of `Xⱼ` under
/// `−Ad(A⁻¹)·δᵢ`, so `J_i = −J_j·Ad(A⁻¹)` exactly (for the Jacobians of
/// [`Pose::error_and_jacobians`]: `−R_E·P = −R_zᵀ`, `R_E·Q = R_zᵀ[t_A]×`,
/// `−∂q·P = −∂q·R_Aᵀ`).
fn inverse_adjoint(r_a: &Matrix3<f64>, t_a: &Vector3<f64>) -> (Matrix3<f64>, Matrix3<f64>) {
    let p = r_a.transpose();
    (p, -(p * skew(t_a)))
}

impl Se3 {
    /// [`Pose::normal_blocks_prepared`] through the structure of the
    /// Jacobians: `J_j = diag(R_E, ∂q)` is block diagonal and
    /// `J_i = −J_j·Ad(A⁻¹)`, so `H_jj` costs four 3×3 products and
    /// `H_ij = −Ad(A⁻¹)ᵀH_jj`, `H_ii = Ad(A⁻¹)ᵀH_jj·Ad(A⁻¹)`,
    /// `b_i = −Ad(A⁻¹)ᵀb_j` (17 products of 3×3 blocks instead of 8 of 6×6).
    fn normal_blocks_structured(
        xi: &Se3Prepared,
        xj: &Se3Prepared,
        z: &Se3Prepared,
        omega: &Matrix6<f64>,
    ) -> NormalBlocks<6> {
        let EdgeGeometry {
            r_a,
            r_e: e_rot,
            t_a,
            t_e,
            v,
            dq,
            ..
        } = EdgeGeometry::new(xi, xj, z);
        let block = |r: usize, c: usize| omega.fixed_view::<3, 3>(r, c).into_owned();
        let (o_tt, o_tr, o_rt, o_rr) = (block(0, 0), block(0, 3), block(3, 0), block(3, 3));
        // W = Ω·J_j and H_jj = J_jᵀ·W (lower blocks).
        let w11 = o_tt * e_rot;
        let w12 = o_tr * dq;
        let w22 = o_rr * dq;
        let h11 = e_rot.tr_mul(&w11);
        let h12 = e_rot.tr_mul(&w12);
        let h22 = dq.tr_mul(&w22);
        let h21 = h12.transpose();
        // ω = Ω·e, b_j = J_jᵀω, χ² = eᵀω.
        let omega_t = o_tt * t_e + o_tr * v;
        let omega_r = o_rt * t_e + o_rr * v;
        let bj_t = e_rot.tr_mul(&omega_t);
        let bj_r = dq.tr_mul(&omega_r);
        let chi2 = t_e.dot(&omega_t) + v.dot(&omega_r);
        // K = Ad(A⁻¹)ᵀ·H_jj with Ad(A⁻¹)ᵀ = [[Pᵀ, 0], [Qᵀ, Pᵀ]].
        let (p, q) = inverse_adjoint(&r_a, &t_a);
        let k11 = p.tr_mul(&h11);
        let k12 = p.tr_mul(&h12);
        let k21 = q.tr_mul(&h11) + p.tr_mul(&h21);
        let k22 = q.tr_mul(&h12) + p.tr_mul(&h22);
        // H_ii = K·Ad(A⁻¹): lower blocks, the upper one mirrored.
        let i11 = k11 * p;
        let i21 = k21 * p;
        let i22 = k21 * q + k22 * p;
        let mut out = NormalBlocks::<6>::default();
        let put = |m: &mut Matrix6<f64>, r: usize, c: usize, b: &Matrix3<f64>| {
            m.fixed_view_mut::<3, 3>(r, c).copy_from(b);
        };
        put(&mut out.h_jj, 0, 0, &h11);
        put(&mut out.h_jj, 0, 3, &h12);
        put(&mut out.h_jj, 3, 0, &h21);
        put(&mut out.h_jj, 3, 3, &h22);
        put(&mut out.h_ij, 0, 0, &-k11);
        put(&mut out.h_ij, 0, 3, &-k12);
        put(&mut out.h_ij, 3, 0, &-k21);
        put(&mut out.h_ij, 3, 3, &-k22);
        put(&mut out.h_ii, 0, 0, &i11);
        put(&mut out.h_ii, 0, 3, &i21.transpose());
        put(&mut out.h_ii, 3, 0, &i21);
        put(&mut out.h_ii, 3, 3, &i22);
        out.b_j.fixed_rows_mut::<3>(0).copy_from(&bj_t);
        out.b_j.fixed_rows_mut::<3>(3).copy_from(&bj_r);
        out.b_i
            .fixed_rows_mut::<3>(0)
            .copy_from(&-(p.tr_mul(&bj_t)));
        out.b_i
            .fixed_rows_mut::<3>(3)
            .copy_from(&-(q.tr_mul(&bj_t) + p.tr_mul(&bj_r)));
        out.chi2 = chi2;
        out
    }
}

/// An [`Se3`] with its rotation matrix.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Se3Prepared {
    rotation: UnitQuaternion<f64>,
    matrix: Matrix3<f64>,
    translation: Vector3<f64>,
}

/// The quaternion of `E = Z⁻¹·Xᵢ⁻¹·Xⱼ` with `w ≥ 0`.
#[inline]
fn relative_quaternion(xi: &Se3Prepared, xj: &Se3Prepared, z: &Se3Prepared) -> Quaternion<f64> {
    positive_w(
        z.rotation.inverse().quaternion()
            * xi.rotation.inverse().quaternion()
            * xj.rotation.quaternion(),
    )
}

/// The same rotation with `w ≥ 0`.
#[inline]
fn positive_w(q: Quaternion<f64>) -> Quaternion<f64> {
    if q.w < 0.0 { -q } else { q }
}

/// Removes the drift of repeated quaternion products.
#[inline]
fn renormalize(q: UnitQuaternion<f64>) -> UnitQuaternion<f64> {
    UnitQuaternion::new_normalize(q.into_inner())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::testing::{check_jacobians, check_normal_blocks_on_random_edges};
    use rand::{Rng, SeedableRng, rngs::StdRng};
    use std::f64::consts::PI;

    fn random_rotation(rng: &mut StdRng, max_angle: f64) -> UnitQuaternion<f64> {
        let axis = Vector3::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
        );
        let axis = if axis.norm() < 1e-3 {
            Vector3::x()
        } else {
            axis.normalize()
        };
        UnitQuaternion::from_scaled_axis(axis * rng.random_range(-max_angle..max_angle))
    }

    fn random_pose(rng: &mut StdRng, scale: f64) -> Se3 {
        let t = Vector3::new(
            rng.random_range(-scale..scale),
            rng.random_range(-scale..scale),
            rng.random_range(-scale..scale),
        );
        Se3::new(random_rotation(rng, PI), t)
    }

    fn close(a: &Se3, b: &Se3, tol: f64) -> bool {
        (a.translation - b.translation).norm() < tol && a.rotation.angle_to(&b.rotation) < tol
    }

    #[test]
    fn compose_inverse_is_identity() {
        let mut rng = StdRng::seed_from_u64(11);
        for _ in 0..100 {
            let a = random_pose(&mut rng, 10.0);
            assert!(close(&a.compose(&a.inverse()), &Se3::identity(), 1e-12));
        }
    }

    #[test]
    fn compose_is_associative() {
        let mut rng = StdRng::seed_from_u64(12);
        for _ in 0..100 {
            let (a, b, c) = (
                random_pose(&mut rng, 5.0),
                random_pose(&mut rng, 5.0),
                random_pose(&mut rng, 5.0),
            );
            assert!(close(
                &a.compose(&b).compose(&c),
                &a.compose(&b.compose(&c)),
                1e-12
            ));
        }
    }

    #[test]
    fn exp_log_round_trip() {
        let mut rng = StdRng::seed_from_u64(13);
        for _ in 0..100 {
            let a = random_pose(&mut rng, 10.0);
            assert!(close(&Se3::exp(&a.log()), &a, 1e-10));
        }
        let tiny = Vector6::new(1e-3, 2e-3, -1e-3, 1e-9, -2e-9, 3e-9);
        assert!((Se3::exp(&tiny).log() - tiny).norm() < 1e-15);
    }

    #[test]
    fn jacobians_match_finite_differences_on_random_poses() {
        let mut rng = StdRng::seed_from_u64(14);
        for _ in 0..200 {
            let xi = random_pose(&mut rng, 20.0);
            let xj = random_pose(&mut rng, 20.0);
            let z = random_pose(&mut rng, 5.0);
            check_jacobians(&xi, &xj, &z, 2e-6);
        }
    }

    #[test]
    fn jacobians_match_near_identity_and_near_pi() {
        let mut rng = StdRng::seed_from_u64(15);
        // Residual rotation E near identity, and near (but not at) π, on both
        // sides of the w = 0 flip.
        for &angle in &[0.0, 1e-8, 1e-4, PI - 1e-2, -(PI - 1e-2)] {
            let xi = random_pose(&mut rng, 3.0);
            let z = random_pose(&mut rng, 2.0);
            let e = Se3::new(
                UnitQuaternion::from_scaled_axis(Vector3::new(0.3, -0.5, 0.8).normalize() * angle),
                Vector3::new(0.01, 0.02, -0.01),
            );
            let xj = xi.compose(&z).compose(&e);
            check_jacobians(&xi, &xj, &z, 2e-6);
        }
    }

    #[test]
    fn error_matches_g2o_definition() {
        let mut rng = StdRng::seed_from_u64(16);
        for _ in 0..50 {
            let xi = random_pose(&mut rng, 10.0);
            let xj = random_pose(&mut rng, 10.0);
            let z = random_pose(&mut rng, 3.0);
            let e = z.inverse().compose(&xi.inverse().compose(&xj));
            let q = positive_w(*e.rotation.quaternion());
            let expected = Vector6::new(
                e.translation.x,
                e.translation.y,
                e.translation.z,
                q.i,
                q.j,
                q.k,
            );
            assert!((Se3::error(&xi, &xj, &z) - expected).norm() < 1e-10);
            assert!((Se3::error_and_jacobians(&xi, &xj, &z).error - expected).norm() < 1e-10);
        }
    }

    #[test]
    fn structured_normal_blocks_equal_the_multiplied_out_ones() {
        check_normal_blocks_on_random_edges(random_pose);
    }

    #[test]
    fn quaternion_normalisation_is_idempotent() {
        let a = Se3::from_translation_quaternion([1.0, 2.0, 3.0], [0.1, 0.2, 0.3, 0.9]).unwrap();
        let b = Se3::from_translation_quaternion([1.0, 2.0, 3.0], a.quaternion_xyzw()).unwrap();
        assert_eq!(a, b);
        assert!(Se3::from_translation_quaternion([0.0; 3], [0.0; 4]).is_none());
        // Norms whose square over- or underflows are normalised all the same.
        for scale in [1e200, 1e300, f64::MAX, 1e-200, f64::MIN_POSITIVE] {
            let q = Se3::from_translation_quaternion([0.0; 3], [0.0, 0.0, scale, scale])
                .unwrap()
                .quaternion_xyzw();
            let half = std::f64::consts::FRAC_1_SQRT_2;
            assert!(
                (q[2] - half).abs() < 1e-15 && (q[3] - half).abs() < 1e-15,
                "{scale}: {q:?}"
            );
        }
        // Subnormal components: zero to floating point.
        let subnormal = [0.0, 0.0, 5e-324, 1e-320];
        assert!(Se3::from_translation_quaternion([0.0; 3], subnormal).is_none());
        assert!(
            Se3::from_translation_quaternion([0.0; 3], [f64::INFINITY, 0.0, 0.0, 1.0]).is_none()
        );
        assert!(Se3::from_translation_quaternion([0.0; 3], [f64::NAN, 0.0, 0.0, 1.0]).is_none());
    }
}
