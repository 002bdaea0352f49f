//! The true trajectories of the simulated worlds and the search for true
//! loop closures among their poses.

use nalgebra::{Matrix3, Rotation3, UnitQuaternion, Vector3};
use pgo::{Pose, Se2, Se3};
use rand::Rng;
use rustc_hash::FxHashMap;
use serde::{Deserialize, Serialize};
use std::f64::consts::{FRAC_PI_2, PI};

/// the overlap of consecutive poses is not mistaken for a loop.
pub const MIN_LOOP_SEPARATION: usize = 10;

/// Radius (metres) within which two grid poses close a loop: the same cell
/// and its eight neighbours (diagonal `√2 ≈ 1.41`).
pub const GRID_LOOP_RADIUS: f64 = 1.5;

/// Radius, in ring spacings, within which two poses of the sphere or torus
/// close a loop: the pose one ring later at the same longitude qualifies.
pub const RING_LOOP_RADIUS: f64 = 1.2;

/// Probability that the grid walk turns ±90° at a step.
pub const GRID_TURN_PROBABILITY: f64 = 0.25;
/// Fewest poses per ring of the sphere and torus worlds.
const MIN_RING_POSES: usize = 8;
/// The shape of the simulated trajectory.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum World {
    /// SE(2): a Manhattan-style random walk of 1 m steps on a unit grid,
    /// turning ±90° with probability [`GRID_TURN_PROBABILITY`] and kept
    /// inside a square of side ≈ `√poses` metres so that it revisits places.
    Grid2d,
    /// SE(3): a helix of rings of ≈ `√poses` poses around a sphere, climbing
    /// from the south to the north pole (like sphere2500), heading along the
    /// motion with `z` along the outward normal.
    Sphere3d,
    /// SE(3): rings of ≈ `√(1.5·poses)` poses around the major circle of a
    /// torus (aspect ratio 3), advancing once around the tube so that the
    /// last ring meets the first (like torus3D).
    Torus3d,
}

impl World {
    /// Whether the world is planar (SE(2)).
    pub fn is_planar(self) -> bool {
        matches!(self, Self::Grid2d)
    }
}
/// True poses and the radius within which two of them close a loop.
pub(super) struct Trajectory<P> {
    pub(super) poses: Vec<P>,
    pub(super) loop_radius: f64,
}

/// The unit steps of the four grid headings (east, north, west, south).
const GRID_STEPS: [(i64, i64); 4] = [(1, 0), (0, 1), (-1, 0), (0, -1)];
const GRID_HEADINGS: [f64; 4] = [0.0, FRAC_PI_2, PI, -FRAC_PI_2];

/// The Manhattan walk of [`World::Grid2d`], starting at the origin heading
/// east. Each step first turns (at random, or away from the boundary) and
/// then moves one metre, as the M3500 robot does.
pub(super) fn grid_trajectory<R: Rng + ?Sized>(n: usize, rng: &mut R) -> Trajectory<Se2> {
    // A square of side ≈ √n cells holds ≈ one visit per cell on average, so
    // the walk keeps crossing its own path.
    let half = (((n as f64).sqrt() / 2.0).ceil() as i64).max(1);
    let inside = |(x, y): (i64, i64)| x.abs() <= half && y.abs() <= half;
    let step = |(x, y): (i64, i64), d: usize| (x + GRID_STEPS[d].0, y + GRID_STEPS[d].1);

    let mut poses = Vec::with_capacity(n);
    let (mut at, mut dir) = ((0i64, 0i64), 0usize);
    poses.push(Se2::new(0.0, 0.0, 0.0));
    for _ in 1..n {
        let wanted = if rng.random_bool(GRID_TURN_PROBABILITY) {
            if rng.random_bool(0.5) {
                (dir + 1) % 4
            } else {
                (dir + 3) % 4
            }
        } else {
            dir
        };
        dir = if inside(step(at, wanted)) {
            wanted
        } else {
            // Blocked by the boundary: any other non-reversing heading that
            // stays inside. The region is at least 3×3, so one exists; the
            // U-turn is only a guard.
            let open: Vec<usize> = [dir, (dir + 1) % 4, (dir + 3) % 4]
                .into_iter()
                .filter(|&d| d != wanted && inside(step(at, d)))
                .collect();
            match open.len() {
                0 => (dir + 2) % 4,
                len => open[rng.random_range(0..len)],
            }
        };
        at = step(at, dir);
        poses.push(Se2::new(at.0 as f64, at.1 as f64, GRID_HEADINGS[dir]));
    }
    Trajectory {
        poses,
        loop_radius: GRID_LOOP_RADIUS,
    }
}

/// The helix of [`World::Sphere3d`]: `m ≈ √n` poses per ring, radius such
/// that an equatorial step is 1 m, colatitude climbing by one ring spacing
/// per ring from half a spacing above the south pole to half a spacing
/// below the north pole.
pub(super) fn sphere_trajectory(n: usize) -> Trajectory<Se3> {
    let m = ring_size(n as f64);
    // One ring spacing of margin at either pole: n/m rings span n/m + 1
    // spacings from pole to pole.
    let spacings = n as f64 / m + 1.0;
    let radius = m / (2.0 * PI);
    let (d_lat, d_lon) = (PI / (spacings * m), 2.0 * PI / m);
    let poses = (0..n)
        .map(|k| {
            let (lat, lon) = (d_lat * (k as f64 + 0.5 * m), d_lon * k as f64);
            let (sa, ca) = lat.sin_cos();
            let (sl, cl) = lon.sin_cos();
            let normal = Vector3::new(sa * cl, sa * sl, -ca);
            let tangent = Vector3::new(ca * cl, ca * sl, sa) * d_lat
                + Vector3::new(-sl, cl, 0.0) * (sa * d_lon);
            surface_pose(normal * radius, normal, tangent)
        })
        .collect();
    let spacing = PI * radius / spacings;
    Trajectory {
        poses: relative_to_first(poses),
        loop_radius: RING_LOOP_RADIUS * spacing,
    }
}

/// The rings of [`World::Torus3d`]: `m ≈ √(1.5 n)` poses around the major
/// circle (radius such that a step along the tube's centre circle is 1 m;
/// steps range from 2/3 m inside to 4/3 m outside), the tube angle
/// advancing once around over the whole trajectory.
pub(super) fn torus_trajectory(n: usize) -> Trajectory<Se3> {
    let m = ring_size(1.5 * n as f64);
    let rings = n as f64 / m;
    let major = m / (2.0 * PI);
    let minor = major / 3.0;
    let (d_u, d_v) = (2.0 * PI / m, 2.0 * PI / n as f64);
    let poses = (0..n)
        .map(|k| {
            let (u, v) = (d_u * k as f64, d_v * k as f64);
            let (su, cu) = u.sin_cos();
            let (sv, cv) = v.sin_cos();
            let normal = Vector3::new(cv * cu, cv * su, sv);
            let center = Vector3::new(cu, su, 0.0) * major;
            let tangent = Vector3::new(-su, cu, 0.0) * (d_u * (major + minor * cv))
                + Vector3::new(-sv * cu, -sv * su, cv) * (d_v * minor);
            surface_pose(center + normal * minor, normal, tangent)
        })
        .collect();
    let spacing = 2.0 * PI * minor / rings;
    Trajectory {
        poses: relative_to_first(poses),
        loop_radius: RING_LOOP_RADIUS * spacing,
    }
}

/// Poses per ring: `√x` rounded, at least [`MIN_RING_POSES`].
pub(super) fn ring_size(x: f64) -> f64 {
    x.sqrt().round().max(MIN_RING_POSES as f64)
}

/// The pose at `position` heading along `tangent` (x) with `z` along the
/// surface `normal` (unit).
fn surface_pose(position: Vector3<f64>, normal: Vector3<f64>, tangent: Vector3<f64>) -> Se3 {
    // The tangent is analytically orthogonal to the normal; project anyway
    // so that the frame is orthonormal to rounding.
    let x = (tangent - normal * tangent.dot(&normal)).normalize();
    let y = normal.cross(&x);
    let frame = Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[x, y, normal]));
    Se3::new(UnitQuaternion::from_rotation_matrix(&frame), position)
}

/// Expresses the trajectory in the frame of its first pose, so that the
/// truth agrees with the dead-reckoning guess, which starts at the identity.
fn relative_to_first<P: Pose<D>, const D: usize>(poses: Vec<P>) -> Vec<P> {
    match poses.first() {
        Some(first) => {
            let origin = first.inverse();
            poses.iter().map(|p| origin.compose(p)).collect()
        }
        None => poses,
    }
}

/// Point indices bucketed by cubic cells of side `cell`, so that every point
/// within `cell` of a query lies in the 3×3(×3) cells around it.
pub(super) struct SpatialHash {
    cell: f64,
    pub(super) planar: bool,
    /// Point indices sorted by (cell, index).
    order: Vec<usize>,
    /// Each occupied cell's range in `order`.
    /// (Fx hashing: the loop search makes up to 27 look-ups per pose, and
    /// SipHash's resistance to crafted keys is not needed for coordinates
    /// computed here.)
    ranges: FxHashMap<Cell, (usize, usize)>,
}

/// Integer coordinates of a cell of a [`SpatialHash`].
type Cell = (i64, i64, i64);

impl SpatialHash {
    pub(super) fn new(points: &[Vector3<f64>], cell: f64) -> Self {
        let planar = points.iter().all(|p| p.z == 0.0);
        let mut keyed: Vec<(Cell, usize)> = points
            .iter()
            .enumerate()
            .map(|(k, p)| (Self::key(cell, p), k))
            .collect();
        keyed.sort_unstable();
        let mut ranges = FxHashMap::default();
        let mut start = 0;
        for k in 1..=keyed.len() {
            if k == keyed.len() || keyed[k].0 != keyed[start].0 {
                ranges.insert(keyed[start].0, (start, k));
                start = k;
            }
        }
        let order = keyed.into_iter().map(|(_, k)| k).collect();
        Self {
            cell,
            planar,
            order,
            ranges,
        }
    }

    /// The cell of a point (the saturating cast keeps absurd coordinates
    /// from wrapping).
    fn key(cell: f64, p: &Vector3<f64>) -> Cell {
        (
            (p.x / cell).floor() as i64,
            (p.y / cell).floor() as i64,
            (p.z / cell).floor() as i64,
        )
    }

    /// The indices in the cells around `p`, each cell's in increasing order.
    pub(super) fn near(&self, p: &Vector3<f64>) -> impl Iterator<Item = &[usize]> {
        let (x, y, z) = Self::key(self.cell, p);
        let dz = if self.planar { 0..=0 } else { -1..=1 };
        dz.flat_map(move |dz| {
            (-1..=1).flat_map(move |dy| {
                (-1..=1).map(move |dx| {
                    (
                        x.saturating_add(dx),
                        y.saturating_add(dy),
                        z.saturating_add(dz),
                    )
                })
            })
        })
        .filter_map(|key| self.ranges.get(&key).map(|&(a, b)| &self.order[a..b]))
    }
}

/// Up to `max_loops` true loop closures `(i, j)`, `i + MIN_LOOP_SEPARATION ≤
/// j`, with positions within `radius`: each pose `j` takes one partner drawn
/// uniformly among its eligible earlier poses (as a front end reports its
/// best match), and `max_loops` of these are kept uniformly at random.
/// Sorted by `j`.
pub(super) fn find_loops<R: Rng + ?Sized>(
    positions: &[Vector3<f64>],
    radius: f64,
    max_loops: usize,
    rng: &mut R,
) -> Vec<(usize, usize)> {
    if max_loops == 0 {
        return Vec::new();
    }
    let hash = SpatialHash::new(positions, radius);
    let r2 = radius * radius;
    let mut found = Vec::new();
    for (j, pj) in positions.iter().enumerate().skip(MIN_LOOP_SEPARATION) {
        let (mut partner, mut seen) = (None, 0usize);
        for cell in hash.near(pj) {
            for &i in cell.iter().take_while(|&&i| i + MIN_LOOP_SEPARATION <= j) {
                if (positions[i] - pj).norm_squared() <= r2 {
                    // Reservoir sampling of one partner.
                    seen += 1;
                    if rng.random_range(0..seen) == 0 {
                        partner = Some(i);
                    }
                }
            }
        }
        if let Some(i) = partner {
            found.push((i, j));
        }
    }
    if found.len() > max_loops {
        let mut keep = rand::seq::index::sample(rng, found.len(), max_loops).into_vec();
        keep.sort_unstable();
        found = keep.into_iter().map(|k| found[k]).collect();
    }
    found
}
