//! Tests of the trajectories and of the spatial hash behind the loop search.

use super::tests::{is_odometry, options};
use super::world::{SpatialHash, ring_size, sphere_trajectory};
use super::*;
use crate::testing::{simulate_planar, simulate_spatial};
use nalgebra::Vector3;
use rand::{Rng, SeedableRng, rngs::StdRng};
use std::f64::consts::{FRAC_PI_2, PI};

#[test]
fn grid_walk_moves_one_metre_on_the_grid_inside_its_square() {
    let n = 2000;
    let sim = simulate_planar(&options(World::Grid2d, n)).unwrap();
    let half = ((n as f64).sqrt() / 2.0).ceil();
    for p in &sim.truth.poses {
        assert!(p.x.abs() <= half && p.y.abs() <= half);
        assert_eq!((p.x.round(), p.y.round()), (p.x, p.y));
    }
    let mut turns = 0;
    for e in sim.truth.edges.iter().filter(|e| is_odometry(e)) {
        let z = e.measurement;
        assert!((z.x.hypot(z.y) - 1.0).abs() < 1e-12);
        let quarter = z.theta / FRAC_PI_2;
        assert!((quarter - quarter.round()).abs() < 1e-12 && quarter.abs() <= 1.0 + 1e-12);
        turns += usize::from(z.theta.abs() > 0.1);
    }
    // Random turns plus turns away from the walls.
    let rate = turns as f64 / (n - 1) as f64;
    assert!(rate > 0.2 && rate < 0.4, "turn rate {rate}");
}

#[test]
fn spatial_poses_head_along_the_motion_with_z_out_of_the_surface() {
    for world in [World::Sphere3d, World::Torus3d] {
        let sim = simulate_spatial(&options(world, 1000)).unwrap();
        for e in sim.truth.edges.iter().filter(|e| is_odometry(e)) {
            let t = e.measurement.translation;
            assert!(t.x > 0.95 * t.norm(), "{world:?}: step {t} is not forward");
            assert!(t.norm() > 0.01 && t.norm() < 1.5);
        }
    }
    // On the sphere (centred on the first pose's -z axis), z is radial.
    let n = 900;
    let t = sphere_trajectory(n);
    let radius = ring_size(n as f64) / (2.0 * PI);
    let centre = Vector3::new(0.0, 0.0, -radius);
    for p in &t.poses {
        let radial = (p.translation - centre) / radius;
        assert!((radial.norm() - 1.0).abs() < 1e-9);
        assert!((p.rotation * Vector3::z() - radial).norm() < 1e-9);
    }
}

#[test]
fn spatial_hash_finds_every_neighbour() {
    let mut rng = StdRng::seed_from_u64(3);
    for planar in [true, false] {
        let points: Vec<Vector3<f64>> = (0..400)
            .map(|_| {
                let z = if planar {
                    0.0
                } else {
                    rng.random_range(-3.0..3.0)
                };
                Vector3::new(rng.random_range(-3.0..3.0), rng.random_range(-3.0..3.0), z)
            })
            .collect();
        let radius = 0.7;
        let hash = SpatialHash::new(&points, radius);
        assert_eq!(hash.planar, planar);
        for p in &points {
            let mut near: Vec<usize> = hash
                .near(p)
                .flatten()
                .copied()
                .filter(|&i| (points[i] - p).norm() <= radius)
                .collect();
            near.sort_unstable();
            let brute: Vec<usize> = (0..points.len())
                .filter(|&i| (points[i] - p).norm() <= radius)
                .collect();
            assert_eq!(near, brute);
        }
    }
}
