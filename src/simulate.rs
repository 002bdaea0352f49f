//! Synthetic pose graphs with ground truth, and corruption of existing
//! graphs with wrong loop-closure candidates.
//!
//! # What is simulated
//!
//! * **Worlds** ([`World`]): a Manhattan-style random walk on a unit grid
//!   (like M3500 / city10000), and trajectories on stacked rings around a
//!   sphere (like sphere2500) or a torus (like torus3D).
//! * **Odometry** between consecutive poses: trusted edges whose measurement
//!   is the true relative pose perturbed by Gaussian noise drawn *in the
//!   edge's error coordinates*, with the matching (calibrated) information
//!   matrix, so that `eᵀΩe` at the truth is χ²-distributed with `D` degrees
//!   of freedom.
//! * **True loop closures** between poses that are close in space but at
//!   least [`MIN_LOOP_SEPARATION`] apart in time, with the same noise model.
//! * **Wrong loop candidates** ([`OutlierPolicy`]), as in the Vertigo /
//!   max-mixture outlier sets: random pairs, pairs close in time, or groups
//!   of mutually consistent wrong loops.
//! * **Inlier counts** ([`InlierModel`]) for every loop candidate: log-normal
//!   with a high median for true loops and a low median for wrong ones.
//!
//! The noisy graph starts from the dead-reckoning guess (the composition of
//! the noisy odometry from the identity); the truth graph holds the true
//! poses and noise-free measurements of every edge that is not wrong.
//!
//! # Noise model
//!
//! For an edge `i → j` with true relative pose `A = Xᵢ⁻¹·Xⱼ`, an error vector
//! `e ~ N(0, Ω⁻¹)` is drawn in the error coordinates of
//! [`Pose::error`] and turned into the pose `E`
//! whose error coordinates are `e`; the measurement is `Z = A·E⁻¹`, so that
//! `error(Xᵢ, Xⱼ, Z) = e` exactly. With translation noise `σₜ` (metres) and
//! rotation noise `σᵣ` (radians):
//!
//! * SE(2): `e = (tₓ, t_y, θ)`, `Ω = diag(1/σₜ², 1/σₜ², 1/σᵣ²)`;
//! * SE(3): `e = (t, q_v)` with `q_v ≈ φ/2` the vector part of the unit
//!   quaternion, so a rotation noise `σᵣ` on the rotation vector is
//!   `σᵣ/2` on `q_v`: `Ω = diag(1/σₜ² ·I₃, 4/σᵣ² ·I₃)`.
//!
//! The rare draws outside the domain of the error coordinates (`|θ| ≥ π`,
//! `|q_v| ≥ 1`) are drawn again. Even at [`MAX_ROTATION_NOISE`] this
//! truncation lowers the mean χ² of the SE(3) rotation block by only about
//! 0.6 % (`P(χ²₃ ≥ 16) ≈ 0.1 %` of draws); at the default `σᵣ = 0.01` it
//! never happens.
//!
//! # Which edges are candidates
//!
//! Odometry is always trusted (`candidate: None`) and wrong loops are always
//! candidates. True loops are candidates whenever they could be confused
//! with something — an inlier model is given (then they carry a count) or
//! wrong loops are planted — and trusted otherwise, as in the public
//! datasets. (Trusting them beside planted wrong candidates would let a
//! method reject every candidate and lose nothing.)
//!
//! # Determinism
//!
//! The same options give the same graphs, for a given version of `rand`
//! (whose `StdRng` algorithm may change between releases).

use crate::geometry::{Pose, Se2, Se3};
use crate::graph::{GraphError, LoopCandidate, PoseGraph, VertexId};
use nalgebra::{Matrix3, Quaternion, Rotation3, SMatrix, SVector, UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng, rngs::StdRng};
use rand_distr::StandardNormal;
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::f64::consts::{FRAC_PI_2, PI};
use std::hash::{BuildHasherDefault, Hasher};

/// True loop closures join poses at least this many steps apart, so that
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

/// Largest accepted rotation noise σᵣ (radians); see the module
/// documentation on truncation.
pub const MAX_ROTATION_NOISE: f64 = 0.5;

/// Default half-width (metres) of the uniform translation part of the
/// tangent vector of a wrong measurement.
pub const DEFAULT_OUTLIER_TRANSLATION: f64 = 3.0;

/// Default half-width (radians) of the uniform rotation part of the tangent
/// vector of a wrong measurement.
pub const DEFAULT_OUTLIER_ROTATION: f64 = PI;

/// Default largest index distance of a [`OutlierPolicy::Local`] wrong loop.
pub const DEFAULT_LOCAL_WINDOW: usize = 20;

/// Fewest poses per ring of the sphere and torus worlds.
const MIN_RING_POSES: usize = 8;

/// Draws of a vertex pair before giving up on placing a wrong loop; only
/// graphs with almost no non-consecutive pairs come near it.
const MAX_PAIR_ATTEMPTS: usize = 10_000;

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

/// How wrong loop candidates are placed.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum OutlierPolicy {
    /// A random pair of non-consecutive vertices.
    Random,
    /// A pair at most a few steps apart (but not consecutive).
    Local,
    /// Groups of consecutive pairs `(i+k, j+k)` that all carry the same wrong
    /// relative transform: mutually consistent wrong loops, the hard case.
    Grouped,
}

/// Log-normal models of the RANSAC inlier count of loop candidates.
///
/// A count is `round(exp(ln median + σ·N(0, 1)))`. The overlap of the two
/// classes is set by the medians and the σ's: with the defaults (150 vs 25,
/// σ = 0.5 each) the medians are `ln 6 ≈ 1.79` apart in log space, so a
/// threshold at their geometric mean (≈ 61) misclassifies `Φ(−1.79) ≈ 4 %`
/// of each class. Closer medians or larger σ's make gating harder.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct InlierModel {
    /// Median count of true loop closures (default 150).
    pub true_median: f64,
    /// Standard deviation of the natural log of true counts (default 0.5).
    pub true_sigma: f64,
    /// Median count of wrong loop candidates (default 25).
    pub wrong_median: f64,
    /// Standard deviation of the natural log of wrong counts (default 0.5).
    pub wrong_sigma: f64,
}

impl Default for InlierModel {
    fn default() -> Self {
        Self {
            true_median: 150.0,
            true_sigma: 0.5,
            wrong_median: 25.0,
            wrong_sigma: 0.5,
        }
    }
}

impl InlierModel {
    /// Checks that the medians are positive and the σ's non-negative (all
    /// finite).
    pub fn validate(&self) -> Result<(), SimulationError> {
        positive("inliers.true_median", self.true_median)?;
        non_negative("inliers.true_sigma", self.true_sigma)?;
        positive("inliers.wrong_median", self.wrong_median)?;
        non_negative("inliers.wrong_sigma", self.wrong_sigma)
    }

    /// Draws the inlier count of a true loop closure.
    pub fn sample_true<R: Rng + ?Sized>(&self, rng: &mut R) -> u64 {
        log_normal_count(self.true_median, self.true_sigma, rng)
    }

    /// Draws the inlier count of a wrong loop candidate.
    pub fn sample_wrong<R: Rng + ?Sized>(&self, rng: &mut R) -> u64 {
        log_normal_count(self.wrong_median, self.wrong_sigma, rng)
    }
}

/// `round(exp(ln median + σ·z))`; the float-to-integer cast saturates, so
/// absurd σ's give `u64::MAX` rather than wrapping.
fn log_normal_count<R: Rng + ?Sized>(median: f64, sigma: f64, rng: &mut R) -> u64 {
    let z: f64 = rng.sample(StandardNormal);
    (median.ln() + sigma * z).exp().round() as u64
}

/// Options of [`simulate_planar`], [`simulate_spatial`] and [`simulate`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct SimulationOptions {
    /// The trajectory's shape (default [`World::Grid2d`]).
    pub world: World,
    /// Number of poses, at least 2 (default 1000). Vertex ids are
    /// `0..poses`.
    pub poses: usize,
    /// Standard deviation of the translation noise per axis, metres
    /// (default 0.05).
    pub translation_noise: f64,
    /// Standard deviation of the rotation noise per axis, radians, at most
    /// [`MAX_ROTATION_NOISE`] (default 0.01).
    pub rotation_noise: f64,
    /// Largest number of true loop closures (default 300); fewer are made
    /// when the trajectory has fewer poses with a loop partner.
    pub loops: usize,
    /// Seed of the random generator, [`StdRng::seed_from_u64`] (default 0).
    pub seed: u64,
    /// Number of wrong loop candidates (default 0).
    pub outliers: usize,
    /// How wrong loop candidates are placed (default
    /// [`OutlierPolicy::Random`]).
    pub outlier_policy: OutlierPolicy,
    /// Size of the groups of [`OutlierPolicy::Grouped`], at least 1
    /// (default 10); the last group is smaller when it does not divide
    /// `outliers`.
    pub group_size: usize,
    /// Inlier-count model of the loop candidates (default `None`: no
    /// counts). With a model, true loops are candidates with counts; see
    /// the module documentation for which edges are candidates.
    pub inliers: Option<InlierModel>,
}

impl Default for SimulationOptions {
    fn default() -> Self {
        Self {
            world: World::Grid2d,
            poses: 1000,
            translation_noise: 0.05,
            rotation_noise: 0.01,
            loops: 300,
            seed: 0,
            outliers: 0,
            outlier_policy: OutlierPolicy::Random,
            group_size: 10,
            inliers: None,
        }
    }
}

impl SimulationOptions {
    /// Checks the options that do not depend on the world: at least two
    /// poses, positive finite noise (rotation noise at most
    /// [`MAX_ROTATION_NOISE`]), a positive group size and a valid inlier
    /// model.
    pub fn validate(&self) -> Result<(), SimulationError> {
        if self.poses < 2 {
            return Err(SimulationError::TooFewPoses(self.poses));
        }
        positive("translation_noise", self.translation_noise)?;
        positive("rotation_noise", self.rotation_noise)?;
        if self.rotation_noise > MAX_ROTATION_NOISE {
            return Err(SimulationError::InvalidOption {
                name: "rotation_noise",
                value: self.rotation_noise,
                requirement: "at most MAX_ROTATION_NOISE (0.5 rad)",
            });
        }
        if self.group_size == 0 {
            return Err(SimulationError::ZeroGroupSize);
        }
        self.inliers.as_ref().map_or(Ok(()), InlierModel::validate)
    }
}

/// Options of [`corrupt`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct CorruptionOptions {
    /// Number of wrong loop candidates to append (default 100).
    pub outliers: usize,
    /// How they are placed (default [`OutlierPolicy::Random`]).
    pub policy: OutlierPolicy,
    /// Size of the groups of [`OutlierPolicy::Grouped`], at least 1
    /// (default 10).
    pub group_size: usize,
    /// Largest index distance of [`OutlierPolicy::Local`] pairs, at least 2
    /// (default [`DEFAULT_LOCAL_WINDOW`]).
    pub local_window: usize,
    /// Half-width (metres) of the uniform translation components of the
    /// tangent vector of a wrong measurement (default
    /// [`DEFAULT_OUTLIER_TRANSLATION`]).
    pub translation_scale: f64,
    /// Half-width (radians) of its uniform rotation components (default
    /// [`DEFAULT_OUTLIER_ROTATION`]).
    pub rotation_scale: f64,
    /// Inlier-count model (default `Some(InlierModel::default())`); `None`
    /// leaves the counts of existing candidates alone and gives wrong
    /// candidates no count.
    pub inliers: Option<InlierModel>,
    /// The last this many existing non-sequential edges (in file order) are
    /// known to be wrong, as in the max-mixture outlier files whose last
    /// 1000 mixture edges are the injected outliers (default 0): they are
    /// labelled wrong and get counts from the wrong-loop model.
    pub known_wrong_last: usize,
}

impl Default for CorruptionOptions {
    fn default() -> Self {
        Self {
            outliers: 100,
            policy: OutlierPolicy::Random,
            group_size: 10,
            local_window: DEFAULT_LOCAL_WINDOW,
            translation_scale: DEFAULT_OUTLIER_TRANSLATION,
            rotation_scale: DEFAULT_OUTLIER_ROTATION,
            inliers: Some(InlierModel::default()),
            known_wrong_last: 0,
        }
    }
}

impl CorruptionOptions {
    /// Checks the group size, the local window, the scales and the inlier
    /// model.
    pub fn validate(&self) -> Result<(), SimulationError> {
        if self.group_size == 0 {
            return Err(SimulationError::ZeroGroupSize);
        }
        if self.local_window < 2 {
            return Err(SimulationError::InvalidOption {
                name: "local_window",
                value: self.local_window as f64,
                requirement: "at least 2",
            });
        }
        non_negative("translation_scale", self.translation_scale)?;
        non_negative("rotation_scale", self.rotation_scale)?;
        self.inliers.as_ref().map_or(Ok(()), InlierModel::validate)
    }
}

/// Errors from bad options or graphs that cannot hold what was asked.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum SimulationError {
    /// Fewer than two poses.
    #[error("a simulation needs at least 2 poses, got {0}")]
    TooFewPoses(usize),
    /// A numeric option out of its range.
    #[error("option {name} = {value} must be {requirement}")]
    InvalidOption {
        /// The option's name.
        name: &'static str,
        /// Its value.
        value: f64,
        /// What it must be.
        requirement: &'static str,
    },
    /// A group size of zero.
    #[error("the outlier group size must be at least 1")]
    ZeroGroupSize,
    /// A planar world asked of the spatial simulator or vice versa.
    #[error("world {world:?} cannot be simulated as {expected}")]
    WrongWorld {
        /// The world asked for.
        world: World,
        /// `"SE(2)"` or `"SE(3)"`.
        expected: &'static str,
    },
    /// The graph has no room for wrong loops of this policy.
    #[error("cannot place {policy:?} wrong loops in a graph of {vertices} vertices")]
    NoRoomForOutliers {
        /// The placement policy.
        policy: OutlierPolicy,
        /// Number of vertices of the graph.
        vertices: usize,
    },
    /// Wrong loops were asked of a graph without edges, whose information
    /// they would copy.
    #[error("the graph has no edge to copy the information of wrong loops from")]
    NoInformationSource,
    /// More known-wrong edges than the graph has non-sequential edges.
    #[error(
        "{asked} edges were said to be wrong, but the graph has only {available} non-sequential edges"
    )]
    TooManyKnownWrong {
        /// `known_wrong_last`.
        asked: usize,
        /// Non-sequential edges in the graph.
        available: usize,
    },
    /// A pose type whose dimension is not that of SE(n).
    #[error("dimension {0} is not that of a rigid-body group SE(n)")]
    UnsupportedDimension(usize),
    /// Building the graph failed.
    #[error(transparent)]
    Graph(#[from] GraphError),
}

fn positive(name: &'static str, value: f64) -> Result<(), SimulationError> {
    if value.is_finite() && value > 0.0 {
        Ok(())
    } else {
        Err(SimulationError::InvalidOption {
            name,
            value,
            requirement: "finite and positive",
        })
    }
}

fn non_negative(name: &'static str, value: f64) -> Result<(), SimulationError> {
    if value.is_finite() && value >= 0.0 {
        Ok(())
    } else {
        Err(SimulationError::InvalidOption {
            name,
            value,
            requirement: "finite and non-negative",
        })
    }
}

/// A simulated pose graph with its ground truth.
#[derive(Clone, Debug)]
pub struct Simulation<P, const D: usize> {
    /// Noisy measurements, starting from the dead-reckoning guess. Edges are
    /// ordered by their later vertex, odometry first, as in the public
    /// datasets.
    pub noisy: PoseGraph<P, D>,
    /// True poses, and every edge of `noisy` that is not wrong (same order,
    /// same information and candidate flag) with its noise-free
    /// measurement, so that its χ² is zero.
    pub truth: PoseGraph<P, D>,
    /// `wrong[k]`: whether edge `k` of `noisy` is a planted wrong loop.
    pub wrong: Vec<bool>,
}

impl<P, const D: usize> Simulation<P, D> {
    /// Number of planted wrong loops.
    pub fn num_wrong(&self) -> usize {
        self.wrong.iter().filter(|&&w| w).count()
    }
}

/// A simulation of either dimension, from [`simulate`].
#[derive(Clone, Debug)]
pub enum AnySimulation {
    /// From [`World::Grid2d`].
    Planar(Simulation<Se2, 3>),
    /// From [`World::Sphere3d`] or [`World::Torus3d`].
    Spatial(Simulation<Se3, 6>),
}

/// Simulates the world of `options` in SE(2) or SE(3) as it requires.
///
/// ```
/// use pgo::simulate::{AnySimulation, SimulationOptions, World, simulate};
/// let options = SimulationOptions { world: World::Torus3d, poses: 300, ..Default::default() };
/// match simulate(&options)? {
///     AnySimulation::Spatial(sim) => assert_eq!(sim.noisy.num_vertices(), 300),
///     AnySimulation::Planar(_) => unreachable!("a torus is spatial"),
/// }
/// # Ok::<(), pgo::simulate::SimulationError>(())
/// ```
pub fn simulate(options: &SimulationOptions) -> Result<AnySimulation, SimulationError> {
    if options.world.is_planar() {
        simulate_planar(options).map(AnySimulation::Planar)
    } else {
        simulate_spatial(options).map(AnySimulation::Spatial)
    }
}

/// Simulates a planar world ([`World::Grid2d`]).
///
/// ```
/// use pgo::simulate::{InlierModel, OutlierPolicy, SimulationOptions, simulate_planar};
/// let options = SimulationOptions {
///     poses: 500,
///     loops: 100,
///     outliers: 20,
///     outlier_policy: OutlierPolicy::Grouped,
///     inliers: Some(InlierModel::default()),
///     seed: 7,
///     ..Default::default()
/// };
/// let sim = simulate_planar(&options)?;
/// assert_eq!(sim.noisy.num_vertices(), 500);
/// assert_eq!(sim.num_wrong(), 20);
/// assert!(sim.truth.chi2() < 1e-12);
/// # Ok::<(), pgo::simulate::SimulationError>(())
/// ```
pub fn simulate_planar(options: &SimulationOptions) -> Result<Simulation<Se2, 3>, SimulationError> {
    options.validate()?;
    if !options.world.is_planar() {
        return Err(SimulationError::WrongWorld {
            world: options.world,
            expected: "SE(2)",
        });
    }
    let mut rng = StdRng::seed_from_u64(options.seed);
    let trajectory = grid_trajectory(options.poses, &mut rng);
    simulate_on(options, trajectory, &mut rng)
}

/// Simulates a spatial world ([`World::Sphere3d`] or [`World::Torus3d`]).
///
/// ```
/// use pgo::simulate::{SimulationOptions, World, simulate_spatial};
/// let options = SimulationOptions { world: World::Sphere3d, poses: 400, loops: 50, ..Default::default() };
/// let sim = simulate_spatial(&options)?;
/// assert_eq!(sim.noisy.edges.len(), 399 + 50);
/// assert!(sim.wrong.iter().all(|&w| !w));
/// # Ok::<(), pgo::simulate::SimulationError>(())
/// ```
pub fn simulate_spatial(
    options: &SimulationOptions,
) -> Result<Simulation<Se3, 6>, SimulationError> {
    options.validate()?;
    let trajectory = match options.world {
        World::Sphere3d => sphere_trajectory(options.poses),
        World::Torus3d => torus_trajectory(options.poses),
        World::Grid2d => {
            return Err(SimulationError::WrongWorld {
                world: options.world,
                expected: "SE(3)",
            });
        }
    };
    let mut rng = StdRng::seed_from_u64(options.seed);
    simulate_on(options, trajectory, &mut rng)
}

// ---------------------------------------------------------------------------
// Noise in error coordinates
// ---------------------------------------------------------------------------

/// Poses whose edge error can be inverted: given error coordinates `e`, the
/// pose `E` with exactly those coordinates, and the Gaussian noise model in
/// them.
trait ErrorCoordinates<const D: usize>: Pose<D> {
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
}

/// The measurement `Z = A·E⁻¹` of a true relative pose `A` whose edge error
/// at the truth is `e`.
fn perturb<P: ErrorCoordinates<D>, const D: usize>(truth: &P, e: &SVector<f64, D>) -> P {
    truth.compose(&P::from_error(e).inverse())
}

// ---------------------------------------------------------------------------
// Worlds
// ---------------------------------------------------------------------------

/// True poses and the radius within which two of them close a loop.
struct Trajectory<P> {
    poses: Vec<P>,
    loop_radius: f64,
}

/// The unit steps of the four grid headings (east, north, west, south).
const GRID_STEPS: [(i64, i64); 4] = [(1, 0), (0, 1), (-1, 0), (0, -1)];
const GRID_HEADINGS: [f64; 4] = [0.0, FRAC_PI_2, PI, -FRAC_PI_2];

/// The Manhattan walk of [`World::Grid2d`], starting at the origin heading
/// east. Each step first turns (at random, or away from the boundary) and
/// then moves one metre, as the M3500 robot does.
fn grid_trajectory<R: Rng + ?Sized>(n: usize, rng: &mut R) -> Trajectory<Se2> {
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
fn sphere_trajectory(n: usize) -> Trajectory<Se3> {
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
fn torus_trajectory(n: usize) -> Trajectory<Se3> {
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
fn ring_size(x: f64) -> f64 {
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

// ---------------------------------------------------------------------------
// Loop search
// ---------------------------------------------------------------------------

/// Point indices bucketed by cubic cells of side `cell`, so that every point
/// within `cell` of a query lies in the 3×3(×3) cells around it.
struct SpatialHash {
    cell: f64,
    planar: bool,
    /// Point indices sorted by (cell, index).
    order: Vec<usize>,
    /// Each occupied cell's range in `order`.
    ranges: HashMap<Cell, (usize, usize), BuildHasherDefault<CellHasher>>,
}

/// Integer coordinates of a cell of a [`SpatialHash`].
type Cell = (i64, i64, i64);

/// A multiplicative (Fx-style) hash of cell coordinates: the loop search
/// makes up to 27 look-ups per pose, and SipHash's resistance to crafted
/// keys is not needed for coordinates computed here.
#[derive(Default)]
struct CellHasher(u64);

impl CellHasher {
    const SEED: u64 = 0x51_7c_c1_b7_27_22_0a_95;

    fn add(&mut self, word: u64) {
        self.0 = (self.0.rotate_left(5) ^ word).wrapping_mul(Self::SEED);
    }
}

impl Hasher for CellHasher {
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.add(u64::from(b));
        }
    }

    fn write_i64(&mut self, value: i64) {
        self.add(value as u64);
    }

    fn finish(&self) -> u64 {
        self.0
    }
}

impl SpatialHash {
    fn new(points: &[Vector3<f64>], cell: f64) -> Self {
        let planar = points.iter().all(|p| p.z == 0.0);
        let mut keyed: Vec<(Cell, usize)> = points
            .iter()
            .enumerate()
            .map(|(k, p)| (Self::key(cell, p), k))
            .collect();
        keyed.sort_unstable();
        let mut ranges = HashMap::default();
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
    fn near(&self, p: &Vector3<f64>) -> impl Iterator<Item = &[usize]> {
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
fn find_loops<R: Rng + ?Sized>(
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

// ---------------------------------------------------------------------------
// Wrong loops
// ---------------------------------------------------------------------------

/// What is needed to place wrong loops, shared by simulation and
/// corruption.
#[derive(Clone, Copy)]
struct WrongLoopPlan {
    count: usize,
    policy: OutlierPolicy,
    group_size: usize,
    local_window: usize,
    translation_scale: f64,
    rotation_scale: f64,
}

/// Vertex pairs `(from, to)`, `from < to`, of the wrong loops, in groups
/// sharing one measurement (groups of one unless the policy is
/// [`OutlierPolicy::Grouped`]). `consecutive(i, j)` says whether a pair is
/// already joined by odometry and must be avoided.
fn wrong_pairs<R: Rng + ?Sized>(
    plan: &WrongLoopPlan,
    vertices: usize,
    consecutive: impl Fn(usize, usize) -> bool,
    rng: &mut R,
) -> Result<Vec<Vec<(usize, usize)>>, SimulationError> {
    let no_room = || SimulationError::NoRoomForOutliers {
        policy: plan.policy,
        vertices,
    };
    if plan.count == 0 {
        return Ok(Vec::new());
    }
    let group = match plan.policy {
        OutlierPolicy::Grouped => plan.group_size.max(1),
        OutlierPolicy::Random | OutlierPolicy::Local => 1,
    };
    // The largest group still needs two non-adjacent start vertices.
    if vertices < group.min(plan.count) + 2 {
        return Err(no_room());
    }
    let acceptable = |i: usize, j: usize| i.abs_diff(j) >= 2 && !consecutive(i, j);
    let mut groups = Vec::with_capacity(plan.count.div_ceil(group));
    let mut left = plan.count;
    while left > 0 {
        let len = group.min(left);
        let mut placed = None;
        for _ in 0..MAX_PAIR_ATTEMPTS {
            let (i, j) = match plan.policy {
                OutlierPolicy::Random | OutlierPolicy::Grouped => (
                    rng.random_range(0..=vertices - len),
                    rng.random_range(0..=vertices - len),
                ),
                OutlierPolicy::Local => {
                    let d = rng.random_range(2..=plan.local_window.min(vertices - 1));
                    let i = rng.random_range(0..vertices - d);
                    (i, i + d)
                }
            };
            let (i, j) = (i.min(j), i.max(j));
            if (0..len).all(|k| acceptable(i + k, j + k)) {
                placed = Some((i, j));
                break;
            }
        }
        let (i, j) = placed.ok_or_else(no_room)?;
        groups.push((0..len).map(|k| (i + k, j + k)).collect());
        left -= len;
    }
    Ok(groups)
}

/// A random pose `P::exp(ξ)`, the translation components of `ξ` uniform in
/// `±translation_scale` and the rotation components in `±rotation_scale`.
fn random_measurement<P: Pose<D>, const D: usize, R: Rng + ?Sized>(
    plan: &WrongLoopPlan,
    rng: &mut R,
) -> Result<P, SimulationError> {
    let translation_dims = translation_dims(D)?;
    let xi = SVector::<f64, D>::from_fn(|k, _| {
        let scale = if k < translation_dims {
            plan.translation_scale
        } else {
            plan.rotation_scale
        };
        scale * (2.0 * rng.random::<f64>() - 1.0)
    });
    Ok(P::exp(&xi))
}

/// The number `n` of translation components of SE(n), whose dimension is
/// `n(n+1)/2` (translation first, by the convention of [`Pose::exp`]).
fn translation_dims(dimension: usize) -> Result<usize, SimulationError> {
    (1..=dimension)
        .find(|n| n * (n + 1) / 2 == dimension)
        .ok_or(SimulationError::UnsupportedDimension(dimension))
}

// ---------------------------------------------------------------------------
// Assembling a simulation
// ---------------------------------------------------------------------------

/// An edge before the graphs are built.
struct PlannedEdge<P> {
    from: usize,
    to: usize,
    measurement: P,
    /// The noise-free measurement; `None` for a wrong loop.
    truth: Option<P>,
    candidate: Option<LoopCandidate>,
    odometry: bool,
}

/// Adds odometry, true loops and wrong loops to the trajectory and builds
/// the noisy and truth graphs.
fn simulate_on<P: ErrorCoordinates<D>, const D: usize, R: Rng + ?Sized>(
    options: &SimulationOptions,
    trajectory: Trajectory<P>,
    rng: &mut R,
) -> Result<Simulation<P, D>, SimulationError> {
    let truth = trajectory.poses;
    let (sigma_t, sigma_r) = (options.translation_noise, options.rotation_noise);
    let noisy_edge = |from: usize, to: usize, candidate, odometry, rng: &mut R| {
        let exact = truth[from].inverse().compose(&truth[to]);
        let e = P::sample_error(sigma_t, sigma_r, rng);
        PlannedEdge {
            from,
            to,
            measurement: perturb(&exact, &e),
            truth: Some(exact),
            candidate,
            odometry,
        }
    };

    let mut edges: Vec<PlannedEdge<P>> = (1..truth.len())
        .map(|k| noisy_edge(k - 1, k, None, true, rng))
        .collect();
    let guess = dead_reckoning(&edges);

    // True loops are candidates when there is something to tell them from
    // (wrong loops) or a count to attach; otherwise they are trusted, as in
    // the public datasets.
    let positions: Vec<Vector3<f64>> = truth.iter().map(Pose::position).collect();
    for (i, j) in find_loops(&positions, trajectory.loop_radius, options.loops, rng) {
        let candidate = match &options.inliers {
            Some(model) => Some(LoopCandidate {
                inliers: Some(model.sample_true(rng)),
            }),
            None if options.outliers > 0 => Some(LoopCandidate { inliers: None }),
            None => None,
        };
        edges.push(noisy_edge(i, j, candidate, false, rng));
    }

    let plan = WrongLoopPlan {
        count: options.outliers,
        policy: options.outlier_policy,
        group_size: options.group_size,
        local_window: DEFAULT_LOCAL_WINDOW,
        translation_scale: DEFAULT_OUTLIER_TRANSLATION,
        rotation_scale: DEFAULT_OUTLIER_ROTATION,
    };
    for group in wrong_pairs(&plan, truth.len(), |i, j| i.abs_diff(j) == 1, rng)? {
        let measurement = random_measurement::<P, D, R>(&plan, rng)?;
        for (from, to) in group {
            let inliers = options
                .inliers
                .as_ref()
                .map(|model| model.sample_wrong(rng));
            edges.push(PlannedEdge {
                from,
                to,
                measurement,
                truth: None,
                candidate: Some(LoopCandidate { inliers }),
                odometry: false,
            });
        }
    }

    // Order as the public datasets do: by the later vertex, odometry first.
    edges.sort_by_key(|e| (e.from.max(e.to), !e.odometry));
    assemble(&truth, &guess, &edges, P::information(sigma_t, sigma_r))
}

/// The composition of the odometry measurements from the identity (the
/// odometry edges come first, in order).
fn dead_reckoning<P: Pose<D>, const D: usize>(odometry: &[PlannedEdge<P>]) -> Vec<P> {
    let mut guess = Vec::with_capacity(odometry.len() + 1);
    let mut at = P::identity();
    guess.push(at);
    for edge in odometry {
        at = at.compose(&edge.measurement);
        guess.push(at);
    }
    guess
}

/// Builds the noisy graph (dead-reckoning poses, all edges) and the truth
/// graph (true poses, edges that are not wrong with exact measurements).
fn assemble<P: Pose<D>, const D: usize>(
    truth_poses: &[P],
    guess: &[P],
    edges: &[PlannedEdge<P>],
    information: SMatrix<f64, D, D>,
) -> Result<Simulation<P, D>, SimulationError> {
    let mut noisy = PoseGraph::new();
    let mut truth = PoseGraph::new();
    for (k, (t, g)) in truth_poses.iter().zip(guess).enumerate() {
        let id = k as VertexId;
        noisy.add_vertex(id, *g)?;
        truth.add_vertex(id, *t)?;
    }
    let mut wrong = Vec::with_capacity(edges.len());
    for e in edges {
        let (from, to) = (e.from as VertexId, e.to as VertexId);
        noisy.add_edge(from, to, e.measurement, information, e.candidate)?;
        if let Some(exact) = e.truth {
            truth.add_edge(from, to, exact, information, e.candidate)?;
        }
        wrong.push(e.truth.is_none());
    }
    Ok(Simulation {
        noisy,
        truth,
        wrong,
    })
}

// ---------------------------------------------------------------------------
// Corrupting an existing graph
// ---------------------------------------------------------------------------

/// Writes which edges are wrong as CSV, `edge,from,to,wrong` (edge index in
/// file order, the vertex ids, 1 for wrong and 0 otherwise), the labels of
/// `pgo simulate --labels` and `pgo corrupt --labels`.
///
/// ```
/// use pgo::simulate::{simulate_planar, write_labels, SimulationOptions};
/// let sim = simulate_planar(&SimulationOptions { poses: 50, loops: 5, outliers: 2, ..Default::default() }).unwrap();
/// let mut csv = Vec::new();
/// write_labels(&sim.noisy, &sim.wrong, &mut csv).unwrap();
/// let text = String::from_utf8(csv).unwrap();
/// assert!(text.starts_with("edge,from,to,wrong\n0,"));
/// assert_eq!(text.lines().filter(|l| l.ends_with(",1")).count(), 2);
/// ```
pub fn write_labels<P: Pose<D>, const D: usize>(
    graph: &PoseGraph<P, D>,
    wrong: &[bool],
    w: &mut impl std::io::Write,
) -> std::io::Result<()> {
    writeln!(w, "edge,from,to,wrong")?;
    for (k, (e, wrong)) in graph.edges.iter().zip(wrong).enumerate() {
        writeln!(
            w,
            "{k},{},{},{}",
            graph.id(e.from),
            graph.id(e.to),
            u8::from(*wrong)
        )?;
    }
    Ok(())
}

/// What [`corrupt`] did.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Corruption {
    /// `wrong[k]`: whether edge `k` of the corrupted graph is a wrong loop
    /// (the appended edges and the known-wrong existing ones).
    pub wrong: Vec<bool>,
    /// Number of existing non-sequential edges marked as true loop
    /// candidates (the known-wrong ones not counted).
    pub marked: usize,
}

/// Corrupts an existing graph for robust and gating benchmarks:
///
/// 1. every existing non-sequential edge (`|idᵢ − idⱼ| ≠ 1`) becomes a loop
///    candidate, with an inlier count drawn from the true-loop model when an
///    inlier model is given (without one, existing counts are kept) — except
///    the last `options.known_wrong_last` of them, which are labelled wrong
///    and drawn from the wrong-loop model;
/// 2. `options.outliers` wrong loop candidates are appended by the policy,
///    between vertices that are neither consecutive in index nor in id, with
///    measurements `P::exp(ξ)` of a random tangent vector `ξ` (see
///    [`CorruptionOptions`]), the information of a random existing loop edge
///    (of an odometry edge when there is none; one per group), and counts
///    from the wrong-loop model.
///
/// The graph is left unchanged when an error is returned.
///
/// ```
/// use pgo::geometry::{Pose, Se2};
/// use pgo::graph::PoseGraph;
/// use pgo::simulate::{CorruptionOptions, corrupt};
/// use nalgebra::Matrix3;
/// use rand::{SeedableRng, rngs::StdRng};
///
/// let mut graph = PoseGraph::<Se2, 3>::new();
/// for k in 0..50u64 {
///     graph.add_vertex(k, Se2::new(k as f64, 0.0, 0.0))?;
/// }
/// for k in 1..50u64 {
///     graph.add_edge(k - 1, k, Se2::new(1.0, 0.0, 0.0), Matrix3::identity(), None)?;
/// }
/// graph.add_edge(0, 40, Se2::new(40.0, 0.0, 0.0), Matrix3::identity() * 2.0, None)?;
///
/// let options = CorruptionOptions { outliers: 10, ..Default::default() };
/// let corruption = corrupt(&mut graph, &options, &mut StdRng::seed_from_u64(1))?;
/// assert_eq!(corruption.marked, 1);
/// assert_eq!(graph.edges.len(), 50 + 10);
/// assert_eq!(graph.num_candidates(), 1 + 10);
/// assert_eq!(corruption.wrong.iter().filter(|&&w| w).count(), 10);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub fn corrupt<P: Pose<D>, const D: usize>(
    graph: &mut PoseGraph<P, D>,
    options: &CorruptionOptions,
    rng: &mut impl Rng,
) -> Result<Corruption, SimulationError> {
    options.validate()?;
    let sequential: Vec<bool> = graph
        .edges
        .iter()
        .map(|e| graph.id(e.from).abs_diff(graph.id(e.to)) == 1)
        .collect();

    // Plan everything that can fail before touching the graph.
    let plan = WrongLoopPlan {
        count: options.outliers,
        policy: options.policy,
        group_size: options.group_size,
        local_window: options.local_window,
        translation_scale: options.translation_scale,
        rotation_scale: options.rotation_scale,
    };
    let ids = graph.ids();
    let groups = wrong_pairs(&plan, ids.len(), |i, j| ids[i].abs_diff(ids[j]) == 1, rng)?;
    let loops: Vec<usize> = (0..sequential.len()).filter(|&k| !sequential[k]).collect();
    if options.known_wrong_last > loops.len() {
        return Err(SimulationError::TooManyKnownWrong {
            asked: options.known_wrong_last,
            available: loops.len(),
        });
    }
    let mut wrong = vec![false; graph.edges.len()];
    for &k in &loops[loops.len() - options.known_wrong_last..] {
        wrong[k] = true;
    }
    let sources = if loops.is_empty() {
        (0..sequential.len()).collect()
    } else {
        loops
    };
    if !groups.is_empty() && sources.is_empty() {
        return Err(SimulationError::NoInformationSource);
    }
    let mut wrong_edges = Vec::with_capacity(options.outliers);
    for group in &groups {
        let information = graph.edges[sources[rng.random_range(0..sources.len())]].information;
        let measurement = random_measurement::<P, D, _>(&plan, rng)?;
        for &(from, to) in group {
            wrong_edges.push((from, to, measurement, information));
        }
    }

    let mut marked = 0;
    for ((edge, &seq), &known_wrong) in graph.edges.iter_mut().zip(&sequential).zip(&wrong) {
        if seq {
            continue;
        }
        marked += usize::from(!known_wrong);
        edge.candidate = match (&options.inliers, edge.candidate) {
            (Some(model), _) => Some(LoopCandidate {
                inliers: Some(if known_wrong {
                    model.sample_wrong(rng)
                } else {
                    model.sample_true(rng)
                }),
            }),
            (None, Some(existing)) => Some(existing),
            (None, None) => Some(LoopCandidate { inliers: None }),
        };
    }

    for (from, to, measurement, information) in wrong_edges {
        let inliers = options
            .inliers
            .as_ref()
            .map(|model| model.sample_wrong(rng));
        let (from, to) = (graph.id(from), graph.id(to));
        graph.add_edge(
            from,
            to,
            measurement,
            information,
            Some(LoopCandidate { inliers }),
        )?;
        wrong.push(true);
    }
    Ok(Corruption { wrong, marked })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::graph::Edge;
    use nalgebra::Matrix6;

    const WORLDS: [World; 3] = [World::Grid2d, World::Sphere3d, World::Torus3d];

    fn options(world: World, poses: usize) -> SimulationOptions {
        SimulationOptions {
            world,
            poses,
            ..Default::default()
        }
    }

    /// Runs a check on the simulation of any world.
    fn for_each_world(base: SimulationOptions, check: impl Fn(&AnySimulation, &SimulationOptions)) {
        for world in WORLDS {
            let options = SimulationOptions { world, ..base };
            let sim = simulate(&options).unwrap();
            check(&sim, &options);
        }
    }

    fn loop_radius(options: &SimulationOptions) -> f64 {
        match options.world {
            World::Grid2d => GRID_LOOP_RADIUS,
            World::Sphere3d => sphere_trajectory(options.poses).loop_radius,
            World::Torus3d => torus_trajectory(options.poses).loop_radius,
        }
    }

    fn is_odometry<P, const D: usize>(e: &Edge<P, D>) -> bool {
        e.to == e.from + 1 && e.candidate.is_none()
    }

    /// Mean of `eₖ² Ωₖₖ` per component and of `eᵀΩe` over the edges that are
    /// not wrong, at the true poses.
    fn chi2_at_truth<P: Pose<D>, const D: usize>(sim: &Simulation<P, D>) -> (SVector<f64, D>, f64) {
        let mut at_truth = sim.noisy.clone();
        at_truth.poses.clone_from(&sim.truth.poses);
        let kept: Vec<&Edge<P, D>> = at_truth
            .edges
            .iter()
            .zip(&sim.wrong)
            .filter(|(_, w)| !**w)
            .map(|(e, _)| e)
            .collect();
        let n = kept.len() as f64;
        let mut per_component = SVector::<f64, D>::zeros();
        let mut total = 0.0;
        for e in &kept {
            let err = at_truth.edge_error(e);
            for k in 0..D {
                per_component[k] += err[k] * err[k] * e.information[(k, k)] / n;
            }
            total += at_truth.edge_chi2(e) / n;
        }
        (per_component, total)
    }

    fn same_graphs<P: Pose<D>, const D: usize>(a: &Simulation<P, D>, b: &Simulation<P, D>) -> bool {
        a.noisy.poses == b.noisy.poses
            && a.noisy.edges == b.noisy.edges
            && a.truth.poses == b.truth.poses
            && a.truth.edges == b.truth.edges
            && a.wrong == b.wrong
    }

    #[test]
    fn same_seed_gives_the_same_graphs() {
        let base = SimulationOptions {
            poses: 600,
            outliers: 25,
            outlier_policy: OutlierPolicy::Grouped,
            inliers: Some(InlierModel::default()),
            seed: 42,
            ..Default::default()
        };
        for world in WORLDS {
            let options = SimulationOptions { world, ..base };
            let other_seed = SimulationOptions {
                seed: 43,
                ..options
            };
            match (
                simulate(&options).unwrap(),
                simulate(&options).unwrap(),
                simulate(&other_seed).unwrap(),
            ) {
                (AnySimulation::Planar(a), AnySimulation::Planar(b), AnySimulation::Planar(c)) => {
                    assert!(same_graphs(&a, &b));
                    assert!(!same_graphs(&a, &c));
                }
                (
                    AnySimulation::Spatial(a),
                    AnySimulation::Spatial(b),
                    AnySimulation::Spatial(c),
                ) => {
                    assert!(same_graphs(&a, &b));
                    assert!(!same_graphs(&a, &c));
                }
                _ => panic!("{world:?} changed dimension"),
            }
        }
    }

    #[test]
    fn truth_graph_has_zero_chi2_and_no_wrong_edges() {
        let base = SimulationOptions {
            poses: 800,
            outliers: 30,
            inliers: Some(InlierModel::default()),
            ..Default::default()
        };
        for_each_world(base, |sim, options| {
            let (truth_chi2, truth_edges, noisy_edges, wrong) = match sim {
                AnySimulation::Planar(s) => (
                    s.truth.chi2(),
                    s.truth.edges.len(),
                    s.noisy.edges.len(),
                    s.num_wrong(),
                ),
                AnySimulation::Spatial(s) => (
                    s.truth.chi2(),
                    s.truth.edges.len(),
                    s.noisy.edges.len(),
                    s.num_wrong(),
                ),
            };
            assert!(
                truth_chi2 < 1e-12,
                "{:?}: truth χ² = {truth_chi2:e}",
                options.world
            );
            assert_eq!(wrong, 30);
            assert_eq!(truth_edges + wrong, noisy_edges);
        });
    }

    #[test]
    fn truth_edges_match_the_noisy_edges_that_are_not_wrong() {
        let options = SimulationOptions {
            poses: 400,
            outliers: 15,
            inliers: Some(InlierModel::default()),
            ..Default::default()
        };
        let sim = simulate_planar(&options).unwrap();
        let kept: Vec<_> = sim
            .noisy
            .edges
            .iter()
            .zip(&sim.wrong)
            .filter(|(_, w)| !**w)
            .map(|(e, _)| e)
            .collect();
        assert_eq!(kept.len(), sim.truth.edges.len());
        for (n, t) in kept.iter().zip(&sim.truth.edges) {
            assert_eq!(
                (n.from, n.to, n.information, n.candidate),
                (t.from, t.to, t.information, t.candidate)
            );
        }
        assert_eq!(sim.noisy.ids(), sim.truth.ids());
        assert!(sim.noisy.ids().iter().copied().eq(0..400));
        assert!(sim.noisy.unconstrained_vertices(None).is_empty());
    }

    #[test]
    fn noise_is_calibrated_to_the_information() {
        let base = SimulationOptions {
            poses: 3000,
            loops: 2000,
            translation_noise: 0.1,
            rotation_noise: 0.05,
            ..Default::default()
        };
        for_each_world(base, |sim, options| {
            let (per_component, total, dim) = match sim {
                AnySimulation::Planar(s) => {
                    let (c, t) = chi2_at_truth(s);
                    (c.iter().copied().collect::<Vec<_>>(), t, 3.0)
                }
                AnySimulation::Spatial(s) => {
                    let (c, t) = chi2_at_truth(s);
                    (c.iter().copied().collect::<Vec<_>>(), t, 6.0)
                }
            };
            assert!(
                (total - dim).abs() < 0.05 * dim,
                "{:?}: mean χ² {total} vs {dim}",
                options.world
            );
            for (k, c) in per_component.iter().enumerate() {
                assert!(
                    (c - 1.0).abs() < 0.1,
                    "{:?}: component {k} has normalised variance {c}",
                    options.world
                );
            }
        });
    }

    fn check_dead_reckoning<P: Pose<D>, const D: usize>(sim: &Simulation<P, D>) {
        assert_eq!(sim.noisy.poses[0], P::identity());
        let odometry: Vec<_> = sim.noisy.edges.iter().filter(|e| is_odometry(e)).collect();
        assert_eq!(odometry.len(), sim.noisy.num_vertices() - 1);
        for (k, e) in odometry.iter().enumerate() {
            assert_eq!((e.from, e.to), (k, k + 1));
            let composed = sim.noisy.poses[k].compose(&e.measurement);
            assert!(P::error(&composed, &sim.noisy.poses[k + 1], &P::identity()).norm() < 1e-9);
        }
    }

    #[test]
    fn odometry_composes_to_the_dead_reckoning_guess() {
        for_each_world(options(World::Grid2d, 500), |sim, _| match sim {
            AnySimulation::Planar(s) => check_dead_reckoning(s),
            AnySimulation::Spatial(s) => check_dead_reckoning(s),
        });
    }

    fn check_loops<P: Pose<D>, const D: usize>(
        sim: &Simulation<P, D>,
        options: &SimulationOptions,
    ) {
        let radius = loop_radius(options);
        let loops: Vec<_> = sim.truth.edges.iter().filter(|e| !is_odometry(e)).collect();
        assert_eq!(loops.len(), options.loops, "{:?}", options.world);
        for e in loops {
            assert!(e.to >= e.from + MIN_LOOP_SEPARATION);
            let d = (sim.truth.poses[e.from].position() - sim.truth.poses[e.to].position()).norm();
            assert!(
                d <= radius,
                "{:?}: loop {}–{} is {d} m long",
                options.world,
                e.from,
                e.to
            );
            // No outliers and no inlier model: loops are trusted.
            assert!(e.candidate.is_none());
        }
        // Edges come in the order of their later vertex, odometry first.
        let keys: Vec<_> = sim
            .noisy
            .edges
            .iter()
            .map(|e| (e.to, !is_odometry(e)))
            .collect();
        assert!(keys.windows(2).all(|w| w[0] <= w[1]));
    }

    #[test]
    fn loops_are_close_in_space_and_far_in_time() {
        let base = SimulationOptions {
            poses: 1500,
            loops: 400,
            ..Default::default()
        };
        for_each_world(base, |sim, options| match sim {
            AnySimulation::Planar(s) => check_loops(s, options),
            AnySimulation::Spatial(s) => check_loops(s, options),
        });
    }

    #[test]
    fn loops_are_capped_by_what_the_trajectory_offers() {
        // Ten poses cannot close a loop MIN_LOOP_SEPARATION steps apart.
        let sim = simulate_planar(&SimulationOptions {
            poses: 10,
            loops: 5,
            ..Default::default()
        })
        .unwrap();
        assert_eq!(sim.noisy.edges.len(), 9);
        let sim = simulate_spatial(&SimulationOptions {
            world: World::Sphere3d,
            poses: 200,
            loops: 100_000,
            ..Default::default()
        })
        .unwrap();
        let loops = sim.noisy.edges.len() - 199;
        assert!(loops > 100 && loops <= 200 - MIN_LOOP_SEPARATION);
    }

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
    fn true_loops_are_candidates_when_wrong_ones_are_planted() {
        let sim = simulate_planar(&SimulationOptions {
            poses: 500,
            loops: 50,
            outliers: 10,
            ..Default::default()
        })
        .unwrap();
        let loops = sim.noisy.edges.iter().filter(|e| e.to > e.from + 1).count();
        assert_eq!(sim.noisy.num_candidates(), loops);
        assert!(
            sim.noisy
                .edges
                .iter()
                .all(|e| e.candidate.is_none_or(|c| c.inliers.is_none()))
        );
    }

    fn wrong_edges<P: Pose<D>, const D: usize>(sim: &Simulation<P, D>) -> Vec<&Edge<P, D>> {
        sim.noisy
            .edges
            .iter()
            .zip(&sim.wrong)
            .filter(|(_, w)| **w)
            .map(|(e, _)| e)
            .collect()
    }

    #[test]
    fn random_and_local_outliers_are_placed_by_policy() {
        for (policy, max_gap) in [
            (OutlierPolicy::Random, usize::MAX),
            (OutlierPolicy::Local, DEFAULT_LOCAL_WINDOW),
        ] {
            let options = SimulationOptions {
                poses: 700,
                outliers: 57,
                outlier_policy: policy,
                ..Default::default()
            };
            let sim = simulate_planar(&options).unwrap();
            let wrong = wrong_edges(&sim);
            assert_eq!(wrong.len(), 57);
            for e in wrong {
                assert!(
                    e.from < e.to && e.to - e.from >= 2 && e.to - e.from <= max_gap,
                    "{policy:?}: {}–{}",
                    e.from,
                    e.to
                );
                assert_eq!(e.candidate, Some(LoopCandidate { inliers: None }));
                assert_eq!(
                    e.information,
                    Se2::information(options.translation_noise, options.rotation_noise)
                );
            }
        }
    }

    fn check_grouped<P: Pose<D>, const D: usize>(
        sim: &Simulation<P, D>,
        count: usize,
        group: usize,
    ) {
        let mut wrong = wrong_edges(sim);
        assert_eq!(wrong.len(), count);
        wrong.sort_by_key(|e| (e.from, e.to));
        // Members of a group share their measurement and are (i+k, j+k).
        let mut groups: Vec<Vec<&Edge<P, D>>> = Vec::new();
        for e in wrong {
            match groups
                .iter_mut()
                .find(|g| g[0].measurement == e.measurement)
            {
                Some(g) => g.push(e),
                None => groups.push(vec![e]),
            }
        }
        let mut sizes: Vec<usize> = groups.iter().map(Vec::len).collect();
        sizes.sort_unstable();
        let mut expected = vec![group; count / group];
        if count % group > 0 {
            expected.insert(0, count % group);
        }
        assert_eq!(sizes, expected);
        for g in &groups {
            for (k, e) in g.iter().enumerate() {
                assert_eq!((e.from, e.to), (g[0].from + k, g[0].to + k));
                assert!(e.to - e.from >= 2);
            }
        }
    }

    #[test]
    fn grouped_outliers_share_one_wrong_transform() {
        let base = SimulationOptions {
            poses: 600,
            outliers: 25,
            outlier_policy: OutlierPolicy::Grouped,
            group_size: 10,
            ..Default::default()
        };
        for_each_world(base, |sim, _| match sim {
            AnySimulation::Planar(s) => check_grouped(s, 25, 10),
            AnySimulation::Spatial(s) => check_grouped(s, 25, 10),
        });
    }

    #[test]
    fn inlier_counts_of_true_and_wrong_candidates_separate() {
        let model = InlierModel::default();
        let options = SimulationOptions {
            poses: 2000,
            loops: 800,
            outliers: 400,
            inliers: Some(model),
            ..Default::default()
        };
        let sim = simulate_planar(&options).unwrap();
        let (mut true_counts, mut wrong_counts) = (Vec::new(), Vec::new());
        for (e, &w) in sim.noisy.edges.iter().zip(&sim.wrong) {
            match (e.candidate, w) {
                (None, false) => assert!(is_odometry(e)),
                (None, true) => panic!("a wrong loop is trusted"),
                (Some(LoopCandidate { inliers: None }), _) => panic!("a candidate without a count"),
                (Some(LoopCandidate { inliers: Some(n) }), false) => true_counts.push(n as f64),
                (Some(LoopCandidate { inliers: Some(n) }), true) => wrong_counts.push(n as f64),
            }
        }
        assert_eq!((true_counts.len(), wrong_counts.len()), (800, 400));
        let median = |v: &mut Vec<f64>| {
            v.sort_by(f64::total_cmp);
            v[v.len() / 2]
        };
        let (mt, mw) = (median(&mut true_counts), median(&mut wrong_counts));
        assert!(
            (mt / model.true_median - 1.0).abs() < 0.1,
            "true median {mt}"
        );
        assert!(
            (mw / model.wrong_median - 1.0).abs() < 0.1,
            "wrong median {mw}"
        );
        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
        assert!(mean(&true_counts) > 3.0 * mean(&wrong_counts));
        // σ of the log count.
        let log_sd = |v: &[f64]| {
            let logs: Vec<f64> = v.iter().map(|x| x.max(1.0).ln()).collect();
            let m = mean(&logs);
            (logs.iter().map(|l| (l - m).powi(2)).sum::<f64>() / logs.len() as f64).sqrt()
        };
        assert!((log_sd(&true_counts) - 0.5).abs() < 0.05);
        assert!((log_sd(&wrong_counts) - 0.5).abs() < 0.05);
    }

    #[test]
    fn inlier_overlap_is_tunable() {
        let mut rng = StdRng::seed_from_u64(5);
        let same = InlierModel {
            true_median: 40.0,
            true_sigma: 0.0,
            wrong_median: 40.0,
            wrong_sigma: 0.0,
        };
        assert_eq!(
            (same.sample_true(&mut rng), same.sample_wrong(&mut rng)),
            (40, 40)
        );
        let wide = InlierModel {
            true_sigma: 2.0,
            wrong_sigma: 2.0,
            ..Default::default()
        };
        let overlap = (0..2000)
            .filter(|_| wide.sample_true(&mut rng) < wide.sample_wrong(&mut rng))
            .count();
        assert!(overlap > 300, "wide models should overlap, got {overlap}");
    }

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

    fn line_graph(n: u64, information: Matrix3<f64>) -> PoseGraph<Se2, 3> {
        let mut g = PoseGraph::new();
        for k in 0..n {
            g.add_vertex(k, Se2::new(k as f64, 0.0, 0.0)).unwrap();
        }
        for k in 1..n {
            g.add_edge(k - 1, k, Se2::new(1.0, 0.0, 0.0), information, None)
                .unwrap();
        }
        g
    }

    /// An 800-pose simulated graph with 120 loops to corrupt.
    fn corruptible_graph() -> Simulation<Se2, 3> {
        simulate_planar(&SimulationOptions {
            poses: 800,
            loops: 120,
            ..Default::default()
        })
        .unwrap()
    }

    #[test]
    fn corrupt_marks_existing_loops_and_appends_exactly_the_wrong_ones() {
        let sim = corruptible_graph();
        let mut graph = sim.noisy.clone();
        let before = graph.edges.clone();
        let options = CorruptionOptions {
            outliers: 37,
            policy: OutlierPolicy::Grouped,
            group_size: 10,
            ..Default::default()
        };
        let corruption = corrupt(&mut graph, &options, &mut StdRng::seed_from_u64(4)).unwrap();

        assert_eq!(corruption.marked, 120);
        assert_eq!(graph.edges.len(), before.len() + 37);
        assert_eq!(corruption.wrong.len(), graph.edges.len());
        assert!(corruption.wrong[..before.len()].iter().all(|&w| !w));
        assert!(corruption.wrong[before.len()..].iter().all(|&w| w));
        for (old, new) in before.iter().zip(&graph.edges) {
            assert_eq!(
                (old.from, old.to, old.measurement, old.information),
                (new.from, new.to, new.measurement, new.information)
            );
            if is_odometry(old) {
                assert!(new.candidate.is_none());
            } else {
                assert!(matches!(
                    new.candidate,
                    Some(LoopCandidate { inliers: Some(_) })
                ));
            }
        }
        let loop_information = before[before.len() - 1].information;
        for e in &graph.edges[before.len()..] {
            assert!(e.to - e.from >= 2);
            assert_eq!(e.information, loop_information);
            assert!(matches!(
                e.candidate,
                Some(LoopCandidate { inliers: Some(_) })
            ));
        }
        let as_sim = Simulation {
            noisy: graph,
            truth: sim.truth,
            wrong: corruption.wrong,
        };
        check_grouped(&as_sim, 37, 10);
    }

    #[test]
    fn corrupt_works_on_spatial_graphs_with_local_outliers() {
        let sim = simulate_spatial(&SimulationOptions {
            world: World::Torus3d,
            poses: 500,
            loops: 80,
            ..Default::default()
        })
        .unwrap();
        let mut graph = sim.noisy;
        let options = CorruptionOptions {
            outliers: 40,
            policy: OutlierPolicy::Local,
            local_window: 5,
            inliers: None,
            ..Default::default()
        };
        let corruption = corrupt(&mut graph, &options, &mut StdRng::seed_from_u64(8)).unwrap();
        assert_eq!(corruption.marked, 80);
        assert_eq!(graph.num_candidates(), 120);
        let wrong: Vec<_> = graph
            .edges
            .iter()
            .zip(&corruption.wrong)
            .filter(|(_, w)| **w)
            .map(|(e, _)| e)
            .collect();
        assert_eq!(wrong.len(), 40);
        for e in wrong {
            assert!((2..=5).contains(&(e.to - e.from)));
            assert_eq!(e.candidate, Some(LoopCandidate { inliers: None }));
            assert!(e.measurement.is_finite());
        }
    }

    #[test]
    fn corrupt_keeps_existing_counts_without_a_model() {
        let mut graph = line_graph(30, Matrix3::identity());
        graph
            .add_edge(
                0,
                20,
                Se2::new(20.0, 0.0, 0.0),
                Matrix3::identity(),
                Some(LoopCandidate { inliers: Some(77) }),
            )
            .unwrap();
        let options = CorruptionOptions {
            outliers: 0,
            inliers: None,
            ..Default::default()
        };
        let corruption = corrupt(&mut graph, &options, &mut StdRng::seed_from_u64(1)).unwrap();
        assert_eq!(corruption.marked, 1);
        assert_eq!(
            graph.edges[29].candidate,
            Some(LoopCandidate { inliers: Some(77) })
        );
    }

    #[test]
    fn corrupt_copies_odometry_information_when_there_are_no_loops() {
        let information = Matrix3::from_diagonal(&Vector3::new(5.0, 6.0, 7.0));
        let mut graph = line_graph(40, information);
        let options = CorruptionOptions {
            outliers: 12,
            ..Default::default()
        };
        let corruption = corrupt(&mut graph, &options, &mut StdRng::seed_from_u64(2)).unwrap();
        assert_eq!(corruption.marked, 0);
        assert_eq!(graph.num_candidates(), 12);
        assert!(
            graph.edges[39..]
                .iter()
                .all(|e| e.information == information)
        );
    }

    #[test]
    fn corrupt_avoids_pairs_consecutive_in_id() {
        // Ids 0, 10, 11, 20, 21, …: index neighbours are not id neighbours
        // and some index-distance-2 pairs are id neighbours.
        let mut graph = PoseGraph::<Se2, 3>::new();
        let ids: Vec<u64> = (0..60u64).map(|k| k / 2 * 10 + k % 2).collect();
        for &id in &ids {
            graph.add_vertex(id, Se2::identity()).unwrap();
        }
        for w in ids.windows(2) {
            graph
                .add_edge(w[0], w[1], Se2::identity(), Matrix3::identity(), None)
                .unwrap();
        }
        let options = CorruptionOptions {
            outliers: 200,
            policy: OutlierPolicy::Local,
            local_window: 3,
            ..Default::default()
        };
        let corruption = corrupt(&mut graph, &options, &mut StdRng::seed_from_u64(6)).unwrap();
        // Edges whose ids differ by 10 or 9 are non-sequential loops already.
        assert!(corruption.marked > 0);
        for e in graph
            .edges
            .iter()
            .zip(&corruption.wrong)
            .filter(|(_, w)| **w)
            .map(|(e, _)| e)
        {
            assert_ne!(graph.id(e.from).abs_diff(graph.id(e.to)), 1);
        }
    }

    #[test]
    fn corrupt_labels_the_last_loops_known_wrong_with_wrong_counts() {
        let sim = corruptible_graph();
        let mut graph = sim.noisy.clone();
        let n = graph.edges.len();
        let loops: Vec<usize> = (0..n).filter(|&k| !is_odometry(&graph.edges[k])).collect();
        // Counts far apart, so that the model each was drawn from shows.
        let model = InlierModel {
            true_median: 1000.0,
            true_sigma: 0.0,
            wrong_median: 10.0,
            wrong_sigma: 0.0,
        };
        let options = CorruptionOptions {
            outliers: 0,
            known_wrong_last: 20,
            inliers: Some(model),
            ..Default::default()
        };
        let corruption = corrupt(&mut graph, &options, &mut StdRng::seed_from_u64(2)).unwrap();
        assert_eq!(corruption.marked, loops.len() - 20);
        assert_eq!(graph.edges.len(), n);
        for (k, e) in graph.edges.iter().enumerate() {
            let known_wrong = loops[loops.len() - 20..].contains(&k);
            assert_eq!(corruption.wrong[k], known_wrong, "edge {k}");
            let expected = if is_odometry(e) {
                None
            } else if known_wrong {
                Some(10)
            } else {
                Some(1000)
            };
            assert_eq!(e.candidate.and_then(|c| c.inliers), expected, "edge {k}");
        }

        let too_many = CorruptionOptions {
            known_wrong_last: loops.len() + 1,
            ..options
        };
        let mut untouched = sim.noisy.clone();
        assert_eq!(
            corrupt(&mut untouched, &too_many, &mut StdRng::seed_from_u64(2)),
            Err(SimulationError::TooManyKnownWrong {
                asked: loops.len() + 1,
                available: loops.len()
            })
        );
        assert_eq!(untouched.edges, sim.noisy.edges);
    }

    #[test]
    fn corrupt_fails_without_changing_the_graph() {
        let mut tiny = line_graph(2, Matrix3::identity());
        let before = tiny.edges.clone();
        let err = corrupt(
            &mut tiny,
            &CorruptionOptions::default(),
            &mut StdRng::seed_from_u64(1),
        );
        assert_eq!(
            err,
            Err(SimulationError::NoRoomForOutliers {
                policy: OutlierPolicy::Random,
                vertices: 2
            })
        );
        assert_eq!(tiny.edges, before);

        let mut edgeless = PoseGraph::<Se2, 3>::new();
        for k in 0..5 {
            edgeless.add_vertex(k, Se2::identity()).unwrap();
        }
        let err = corrupt(
            &mut edgeless,
            &CorruptionOptions::default(),
            &mut StdRng::seed_from_u64(1),
        );
        assert_eq!(err, Err(SimulationError::NoInformationSource));
        assert!(edgeless.edges.is_empty());

        let grouped = CorruptionOptions {
            policy: OutlierPolicy::Grouped,
            group_size: 10,
            ..Default::default()
        };
        let mut short = line_graph(11, Matrix3::identity());
        assert!(matches!(
            corrupt(&mut short, &grouped, &mut StdRng::seed_from_u64(1)),
            Err(SimulationError::NoRoomForOutliers { .. })
        ));
        assert_eq!(short.edges.len(), 10);

        for bad in [
            CorruptionOptions {
                group_size: 0,
                ..Default::default()
            },
            CorruptionOptions {
                local_window: 1,
                ..Default::default()
            },
            CorruptionOptions {
                translation_scale: f64::NAN,
                ..Default::default()
            },
            CorruptionOptions {
                rotation_scale: -1.0,
                ..Default::default()
            },
            CorruptionOptions {
                inliers: Some(InlierModel {
                    wrong_median: 0.0,
                    ..Default::default()
                }),
                ..Default::default()
            },
        ] {
            let mut g = line_graph(30, Matrix3::identity());
            assert!(
                corrupt(&mut g, &bad, &mut StdRng::seed_from_u64(1)).is_err(),
                "{bad:?}"
            );
            assert_eq!(g.edges.len(), 29);
        }
    }

    #[test]
    fn bad_options_are_errors() {
        for poses in [0, 1] {
            for world in WORLDS {
                assert_eq!(
                    simulate(&options(world, poses)).err(),
                    Some(SimulationError::TooFewPoses(poses))
                );
            }
        }
        let invalid = |o: SimulationOptions| simulate(&o).err();
        let base = options(World::Grid2d, 100);
        for bad in [
            SimulationOptions {
                translation_noise: 0.0,
                ..base
            },
            SimulationOptions {
                translation_noise: f64::INFINITY,
                ..base
            },
            SimulationOptions {
                rotation_noise: -0.1,
                ..base
            },
            SimulationOptions {
                rotation_noise: f64::NAN,
                ..base
            },
            SimulationOptions {
                rotation_noise: 0.6,
                ..base
            },
            SimulationOptions {
                inliers: Some(InlierModel {
                    true_sigma: -1.0,
                    ..Default::default()
                }),
                ..base
            },
        ] {
            assert!(
                matches!(invalid(bad), Some(SimulationError::InvalidOption { .. })),
                "{bad:?}"
            );
        }
        assert_eq!(
            invalid(SimulationOptions {
                group_size: 0,
                ..base
            }),
            Some(SimulationError::ZeroGroupSize)
        );
        assert!(matches!(
            simulate_planar(&options(World::Torus3d, 100)),
            Err(SimulationError::WrongWorld { .. })
        ));
        assert!(matches!(
            simulate_spatial(&options(World::Grid2d, 100)),
            Err(SimulationError::WrongWorld { .. })
        ));
        // Two poses leave no room for a non-consecutive wrong loop.
        assert_eq!(
            invalid(SimulationOptions {
                poses: 2,
                outliers: 1,
                ..base
            }),
            Some(SimulationError::NoRoomForOutliers {
                policy: OutlierPolicy::Random,
                vertices: 2
            })
        );
        let grouped = SimulationOptions {
            poses: 11,
            outliers: 10,
            outlier_policy: OutlierPolicy::Grouped,
            ..base
        };
        assert!(matches!(
            invalid(grouped),
            Some(SimulationError::NoRoomForOutliers { .. })
        ));
        // …but three poses do, and two poses simulate fine without outliers.
        assert!(
            simulate(&SimulationOptions {
                poses: 3,
                outliers: 4,
                ..base
            })
            .is_ok()
        );
        assert!(simulate(&SimulationOptions { poses: 2, ..base }).is_ok());
        assert!(
            simulate(&SimulationOptions {
                poses: 12,
                outliers: 10,
                outlier_policy: OutlierPolicy::Grouped,
                ..base
            })
            .is_ok()
        );
    }

    #[test]
    fn translation_dims_are_those_of_se_n() {
        assert_eq!(translation_dims(3), Ok(2));
        assert_eq!(translation_dims(6), Ok(3));
        assert_eq!(
            translation_dims(4),
            Err(SimulationError::UnsupportedDimension(4))
        );
    }

    /// `cargo test --release --lib simulate::tests::million -- --ignored --nocapture`
    #[test]
    #[ignore = "a million poses: run in release mode"]
    fn million_poses_are_fast() {
        for world in WORLDS {
            let start = std::time::Instant::now();
            let options = SimulationOptions {
                world,
                poses: 1_000_000,
                loops: 300_000,
                outliers: 10_000,
                inliers: Some(InlierModel::default()),
                ..Default::default()
            };
            let edges = match simulate(&options).unwrap() {
                AnySimulation::Planar(s) => s.noisy.edges.len(),
                AnySimulation::Spatial(s) => s.noisy.edges.len(),
            };
            println!("{world:?}: {edges} edges in {:.2?}", start.elapsed());
            assert_eq!(edges, 999_999 + 300_000 + 10_000);
        }
    }
}
