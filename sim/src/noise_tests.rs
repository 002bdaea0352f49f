//! Tests of the noise in error coordinates and of its information.

use super::noise::{ErrorCoordinates, perturb, sample_with_information};
use super::*;
use nalgebra::{Matrix3, Matrix6, SVector, Vector3};
use pgo::{Pose, Se2, Se3};
use rand::{Rng, SeedableRng, rngs::StdRng};

#[test]
fn error_coordinate_noise_is_reproduced_exactly() {
    let mut rng = StdRng::seed_from_u64(9);
    for _ in 0..200 {
        let xi = Se2::new(
            rng.random_range(-9.0..9.0),
            rng.random_range(-9.0..9.0),
            rng.random_range(-3.0..3.0),
        );
        let xj = Se2::new(
            rng.random_range(-9.0..9.0),
            rng.random_range(-9.0..9.0),
            rng.random_range(-3.0..3.0),
        );
        let e = Se2::sample_error(0.5, MAX_ROTATION_NOISE * 4.0, &mut rng);
        let z = perturb(&xi.inverse().compose(&xj), &e);
        assert!((Se2::error(&xi, &xj, &z) - e).norm() < 1e-12);
    }
    let random_se3 = |rng: &mut StdRng| {
        let xi = SVector::<f64, 6>::from_fn(|_, _| rng.random_range(-3.0..3.0));
        Se3::exp(&xi)
    };
    for _ in 0..200 {
        let (xi, xj) = (random_se3(&mut rng), random_se3(&mut rng));
        // Large rotation noise puts some draws near |q_v| = 1.
        let e = Se3::sample_error(0.5, 1.5, &mut rng);
        assert!(e.fixed_rows::<3>(3).norm() < 1.0);
        let z = perturb(&xi.inverse().compose(&xj), &e);
        assert!((Se3::error(&xi, &xj, &z) - e).norm() < 1e-12);
    }
}

#[test]
fn information_is_the_inverse_covariance_in_error_coordinates() {
    let i2 = Se2::information(0.1, 0.02);
    assert!((i2 - Matrix3::from_diagonal(&Vector3::new(100.0, 100.0, 2500.0))).norm() < 1e-9);
    let i3 = Se3::information(0.5, 0.1);
    let expected =
        Matrix6::from_diagonal(&SVector::<f64, 6>::new(4.0, 4.0, 4.0, 400.0, 400.0, 400.0));
    assert!((i3 - expected).norm() < 1e-9);
    // A small rotation φ has error coordinates ≈ φ/2.
    let phi = SVector::<f64, 6>::new(0.0, 0.0, 0.0, 1e-3, -2e-3, 5e-4);
    let e = Se3::error(&Se3::identity(), &Se3::exp(&phi), &Se3::identity());
    assert!((e.fixed_rows::<3>(3) - phi.fixed_rows::<3>(3) / 2.0).norm() < 1e-9);
}

#[test]
fn noise_drawn_from_any_information_has_its_covariance() {
    let mut rng = StdRng::seed_from_u64(4);
    let a = Matrix3::new(2.0, 0.5, 0.1, 0.0, 1.0, 0.3, 0.0, 0.0, 0.2);
    // Correlated, and tight enough (σ(θ) ≈ 0.1) that no draw is redrawn.
    let omega = a * a.transpose() * 5000.0;
    let n = 20_000;
    let mut covariance = Matrix3::zeros();
    for _ in 0..n {
        let e = sample_with_information::<Se2, 3, _>(&omega, &mut rng).unwrap();
        assert!(Se2::in_domain(&e));
        covariance += e * e.transpose() / n as f64;
    }
    // Whitened by Ω = LLᵀ, the sampled covariance Lᵀ·Σ·L is that of
    // N(0, I): each entry within ≈ √(2/20 000) = 0.01 of I's.
    let l = omega.cholesky().unwrap().unpack();
    let off = (l.transpose() * covariance * l - Matrix3::identity()).norm();
    assert!(off < 0.05, "LᵀΣL − I has norm {off}");
    assert!(sample_with_information::<Se2, 3, _>(&Matrix3::zeros(), &mut rng).is_none());
    let nan = Matrix3::identity() * f64::NAN;
    assert!(sample_with_information::<Se2, 3, _>(&nan, &mut rng).is_none());
    // A rotation of σ = 10⁷ rad: almost no draw has |θ| < π.
    let unknown = Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, 1e-14));
    assert!(sample_with_information::<Se2, 3, _>(&unknown, &mut rng).is_none());
    // SE(3): the vector part of the rotation stays inside the unit ball.
    let i6 = Matrix6::identity() * 4.0;
    for _ in 0..100 {
        let e = sample_with_information::<Se3, 6, _>(&i6, &mut rng).unwrap();
        assert!(e.fixed_rows::<3>(3).norm() < 1.0);
    }
}
