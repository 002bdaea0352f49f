//! Gaussian measurement noise drawn in the error coordinates of an edge,
//! and the matching information matrices (see the module documentation of
//! [`crate::simulate`]).

use nalgebra::{Matrix3, Quaternion, SMatrix, SVector, UnitQuaternion, Vector3};
use pgo::{GraphPose, Se2, Se3};
use rand::Rng;
use rand_distr::StandardNormal;
use std::f64::consts::PI;

/// Poses whose edge error can be inverted: given error coordinates `e`, the
/// pose `E` with exactly those coordinates, and the Gaussian noise model in
/// them. Implemented for [`Se2`] and [`Se3`]; the simulator draws all its
/// measurement noise through it, and `corrupt` the noise
/// of aliased candidates.
pub trait ErrorCoordinates<const D: usize>: GraphPose<D> {
    /// The information matrix of the noise drawn by [`Self::sample_error`].
    fn information(translation_sigma: f64, rotation_sigma: f64) -> SMatrix<f64, D, D>;

    /// Draws `e ~ N(0, Ω⁻¹)`, again while `e` falls outside the domain of
    /// [`Self::from_error`].
    fn sample_error<R: Rng + ?Sized>(
        translation_sigma: f64,
        rotation_sigma: f64,
        rng: &mut R,
    ) -> SVector<f64, D>;

    /// The pose `E` whose error coordinates are `e`.
    fn from_error(e: &SVector<f64, D>) -> Self;

    /// Whether `e` is finite and in the domain of [`Self::from_error`] (the
    /// error coordinates of some pose).
    fn in_domain(e: &SVector<f64, D>) -> bool;
}

impl ErrorCoordinates<3> for Se2 {
    fn information(translation_sigma: f64, rotation_sigma: f64) -> Matrix3<f64> {
        let it = 1.0 / (translation_sigma * translation_sigma);
        Matrix3::from_diagonal(&Vector3::new(
            it,
            it,
            1.0 / (rotation_sigma * rotation_sigma),
        ))
    }

    fn sample_error<R: Rng + ?Sized>(
        translation_sigma: f64,
        rotation_sigma: f64,
        rng: &mut R,
    ) -> Vector3<f64> {
        let tx = translation_sigma * rng.sample::<f64, _>(StandardNormal);
        let ty = translation_sigma * rng.sample::<f64, _>(StandardNormal);
        // The error's angle is wrapped to (−π, π]; redraw beyond it.
        loop {
            let theta = rotation_sigma * rng.sample::<f64, _>(StandardNormal);
            if theta.abs() < PI {
                return Vector3::new(tx, ty, theta);
            }
        }
    }

    fn from_error(e: &Vector3<f64>) -> Self {
        Se2::new(e.x, e.y, e.z)
    }

    fn in_domain(e: &Vector3<f64>) -> bool {
        e.x.is_finite() && e.y.is_finite() && e.z.abs() < PI
    }
}

impl ErrorCoordinates<6> for Se3 {
    fn information(translation_sigma: f64, rotation_sigma: f64) -> SMatrix<f64, 6, 6> {
        // q_v ≈ φ/2, so σ(q_v) = σᵣ/2 and its information is 4/σᵣ².
        let it = 1.0 / (translation_sigma * translation_sigma);
        let ir = 4.0 / (rotation_sigma * rotation_sigma);
        SMatrix::<f64, 6, 6>::from_diagonal(&SVector::<f64, 6>::new(it, it, it, ir, ir, ir))
    }

    fn sample_error<R: Rng + ?Sized>(
        translation_sigma: f64,
        rotation_sigma: f64,
        rng: &mut R,
    ) -> SVector<f64, 6> {
        let t: Vector3<f64> =
            Vector3::from_fn(|_, _| translation_sigma * rng.sample::<f64, _>(StandardNormal));
        // A unit quaternion's vector part has norm < 1 (w > 0); redraw beyond it.
        loop {
            let v: Vector3<f64> = Vector3::from_fn(|_, _| {
                0.5 * rotation_sigma * rng.sample::<f64, _>(StandardNormal)
            });
            if v.norm_squared() < 1.0 {
                return SVector::<f64, 6>::new(t.x, t.y, t.z, v.x, v.y, v.z);
            }
        }
    }

    fn from_error(e: &SVector<f64, 6>) -> Self {
        let v = Vector3::new(e[3], e[4], e[5]);
        let w = (1.0 - v.norm_squared()).max(0.0).sqrt();
        let q = UnitQuaternion::new_normalize(Quaternion::new(w, v.x, v.y, v.z));
        Se3::new(q, Vector3::new(e[0], e[1], e[2]))
    }

    fn in_domain(e: &SVector<f64, 6>) -> bool {
        e.iter().all(|x| x.is_finite()) && e.fixed_rows::<3>(3).norm_squared() < 1.0
    }
}

/// The measurement `Z = A·E⁻¹` of a true relative pose `A` whose edge error
/// at the truth is `e`.
pub(super) fn perturb<P: ErrorCoordinates<D>, const D: usize>(truth: &P, e: &SVector<f64, D>) -> P {
    truth.compose(&P::from_error(e).inverse())
}

/// Draws of [`sample_with_information`] before giving up. A draw leaves the
/// domain only when the rotation's standard deviation is of the order of π;
/// if a share `p` of the draws is in the domain, all of them miss with
/// probability `(1 − p)¹⁰⁰⁰`, below 10⁻⁴ for `p ≥ 1 %`. An information that
/// leaves less than that in the domain says the rotation is unknown.
const MAX_NOISE_DRAWS: usize = 1000;

/// Draws `e ~ N(0, Ω⁻¹)` for any positive-definite information `Ω` (as
/// `e = L⁻ᵀz` with `Ω = LLᵀ` and `z ~ N(0, I)`), again while `e` is not in
/// the domain of [`ErrorCoordinates::from_error`]. `None` when `Ω` is not
/// positive definite or [`MAX_NOISE_DRAWS`] draws all miss the domain.
pub(super) fn sample_with_information<P, const D: usize, R>(
    information: &SMatrix<f64, D, D>,
    rng: &mut R,
) -> Option<SVector<f64, D>>
where
    P: ErrorCoordinates<D>,
    R: Rng + ?Sized,
{
    if !information.iter().all(|x| x.is_finite()) {
        return None;
    }
    let l = information.cholesky()?.unpack();
    (0..MAX_NOISE_DRAWS).find_map(|_| {
        let z = SVector::<f64, D>::from_fn(|_, _| rng.sample(StandardNormal));
        l.tr_solve_lower_triangular(&z).filter(P::in_domain)
    })
}
