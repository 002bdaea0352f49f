//! Tests of the noise in error coordinates and of its information.

use super::noise::{ErrorCoordinates, perturb};
use super::*;
use nalgebra::{Matrix3, Matrix6, SVector, Vector3};
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
