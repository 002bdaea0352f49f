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
//!   of mutually consistent wrong loops; and perceptual aliasing, candidates
//!   whose measurement is right for a place a few steps away
//!   ([`AliasOffsets`]), scattered or in groups sharing the offset.
//! * **Inlier counts** ([`InlierModel`]) for every loop candidate: log-normal
//!   with a high median for true loops and a low median for wrong ones; a
//!   share of the wrong candidates may draw from the true-loop model
//!   (aliases pass geometric verification).
//!
//! The noisy graph starts from the dead-reckoning guess (the composition of
//! the noisy odometry from the identity); the truth graph holds the true
//! poses and noise-free measurements of every edge that is not wrong.
//!
//! # Noise model
//!
//! For an edge `i → j` with true relative pose `A = Xᵢ⁻¹·Xⱼ`, an error vector
//! `e ~ N(0, Ω⁻¹)` is drawn in the error coordinates of
//! [`Pose::error`](pgo::Pose::error) and turned into the pose `E`
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
//! # Ranges
//!
//! Every numeric option has a range, checked by the options' `validate()`
//! (see [`SimulationOptions`] and [`CorruptionOptions`]), so that every
//! graph written can be read back: [`MIN_NOISE`], [`MAX_LENGTH`],
//! [`MAX_ROTATION_NOISE`], [`MAX_POSES`].
//!
//! # Layout
//!
//! `world` (trajectories and true-loop search), `noise` (error-coordinate
//! noise and information), `counts` (inlier-count models), `wrong`
//! (placement of wrong candidates), `assemble` (the simulated graphs),
//! `corrupt` (the steps of `corrupt`), `labels` (the labels CSV),
//! `options`, `graph` (the working graph the steps edit, which becomes a
//! [`PoseGraph`] when they are done).
//!
//! The crate stands on `pgo`'s public API alone: its graphs are built with
//! [`PoseGraph::add_pose`], [`PoseGraph::add_edge`] and
//! [`PoseGraph::add_loop_candidate`] (and so checked), read back with
//! [`PoseGraph::edges`], and written with [`PoseGraph::write_g2o`].
//!
//! # Determinism
//!
//! The same options give the same graphs, for a given version of `rand`
//! (whose `StdRng` algorithm may change between releases). A zero
//! `true_like_share` draws no random number, and the alias offsets are
//! drawn only by [`OutlierPolicy::Aliased`], so neither changes the graphs
//! of the other policies.

mod assemble;
mod corrupt;
mod counts;
mod graph;
mod labels;
mod noise;
mod options;
mod world;
mod wrong;

/// The library the simulator's graphs are of.
pub use pgo;

pub use counts::InlierModel;
pub use labels::write_labels;
pub use noise::ErrorCoordinates;
pub use options::{
    CorruptionOptions, MAX_LENGTH, MAX_POSES, MAX_ROTATION_NOISE, MIN_NOISE, SimulationOptions,
};
pub use world::{
    GRID_LOOP_RADIUS, GRID_TURN_PROBABILITY, MIN_LOOP_SEPARATION, RING_LOOP_RADIUS, World,
};
pub use wrong::{
    AliasOffsets, AliasPlace, DEFAULT_ALIAS_OFFSET_MAX, DEFAULT_ALIAS_OFFSET_MIN,
    DEFAULT_LOCAL_WINDOW, DEFAULT_OUTLIER_ROTATION, DEFAULT_OUTLIER_TRANSLATION, OutlierPolicy,
};

use assemble::simulate_on;
use graph::Graph;
use pgo::{GraphPose, PoseGraph, Se2, Se3, VertexId};
use rand::{Rng, SeedableRng, rngs::StdRng};
use world::{grid_trajectory, sphere_trajectory, torus_trajectory};

/// Errors from bad options or graphs that cannot hold what was asked.
#[derive(Debug, thiserror::Error)]
pub enum SimulationError {
    /// Fewer than two poses.
    #[error("a simulation needs at least 2 poses, got {0}")]
    TooFewPoses(usize),
    /// A numeric option outside its range `[min, max]`.
    #[error("option {name} = {} is outside its range [{}, {}]", Number(*.value), Number(*.min), Number(*.max))]
    OutOfRange {
        /// The option's name.
        name: &'static str,
        /// Its value.
        value: f64,
        /// The smallest value accepted.
        min: f64,
        /// The largest value accepted.
        max: f64,
    },
    /// A numeric option that breaks a rule other than a range.
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
    /// The information matrix of an existing edge, copied to an aliased
    /// wrong loop, cannot draw its noise: it is not positive definite, or
    /// leaves the rotation so uncertain that the draws fall outside the
    /// error coordinates.
    #[error(
        "the information of edge {edge} cannot draw measurement noise (not positive definite, or its rotation is all but unknown)"
    )]
    UnusableInformation {
        /// Index of the edge whose information was copied.
        edge: usize,
    },
    /// A pose type whose dimension is not that of SE(n).
    #[error("dimension {0} is not that of a rigid-body group SE(n)")]
    UnsupportedDimension(usize),
    /// A vertex of the graph to corrupt has no pose (a file named it
    /// without a vertex line): see [`PoseGraph::compose_missing_poses`].
    #[error("vertex {id} has no pose")]
    MissingPose {
        /// Its id.
        id: VertexId,
    },
    /// The library refused the graph made (an information matrix outside
    /// [`pgo::INFORMATION_RANGE`], a measurement that is no pose).
    #[error(transparent)]
    Graph(#[from] pgo::Error),
}

/// Errors compare by their `Debug` form: the library's [`pgo::Error`] is
/// not `PartialEq` (it may hold an I/O error), and its `Debug` form is its
/// message.
impl PartialEq for SimulationError {
    fn eq(&self, other: &Self) -> bool {
        format!("{self:?}") == format!("{other:?}")
    }
}

/// A number in a message: integers in full, others shortest, in scientific
/// notation when very large or small.
struct Number(f64);

impl std::fmt::Display for Number {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let v = self.0;
        if v.fract() == 0.0 && v.abs() < 1e16 {
            write!(f, "{v:.0}")
        } else if v.is_finite() && v != 0.0 && !(1e-4..1e16).contains(&v.abs()) {
            write!(f, "{v:e}")
        } else {
            write!(f, "{v}")
        }
    }
}

/// A simulated pose graph with its ground truth.
#[derive(Clone, Debug)]
pub struct Simulation<P: GraphPose<D>, const D: usize> {
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

impl<P: GraphPose<D>, const D: usize> Simulation<P, D> {
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
/// use pgo_sim::{AnySimulation, SimulationOptions, World, simulate};
/// let options = SimulationOptions { world: World::Torus3d, poses: 300, ..Default::default() };
/// match simulate(&options)? {
///     AnySimulation::Spatial(sim) => assert_eq!(sim.noisy.len(), 300),
///     AnySimulation::Planar(_) => unreachable!("a torus is spatial"),
/// }
/// # Ok::<(), pgo_sim::SimulationError>(())
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
/// use pgo_sim::{InlierModel, OutlierPolicy, SimulationOptions, simulate_planar};
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
/// assert_eq!(sim.noisy.len(), 500);
/// assert_eq!(sim.num_wrong(), 20);
/// // The gate and the robust back end find the planted loops.
/// let solution = sim.noisy.optimize(&pgo::Options::default()).unwrap();
/// let rejected = solution.loops().iter().filter(|d| !d.accepted);
/// assert!(rejected.filter(|d| sim.wrong[d.index]).count() >= 19);
/// # Ok::<(), pgo_sim::SimulationError>(())
/// ```
pub fn simulate_planar(options: &SimulationOptions) -> Result<Simulation<Se2, 3>, SimulationError> {
    simulate_planar_graphs(options)?.finish()
}

/// Simulates a spatial world ([`World::Sphere3d`] or [`World::Torus3d`]).
///
/// ```
/// use pgo_sim::{SimulationOptions, World, simulate_spatial};
/// let options = SimulationOptions { world: World::Sphere3d, poses: 400, loops: 50, ..Default::default() };
/// let sim = simulate_spatial(&options)?;
/// assert_eq!(sim.noisy.num_edges(), 399 + 50);
/// assert!(sim.wrong.iter().all(|&w| !w));
/// # Ok::<(), pgo_sim::SimulationError>(())
/// ```
pub fn simulate_spatial(
    options: &SimulationOptions,
) -> Result<Simulation<Se3, 6>, SimulationError> {
    simulate_spatial_graphs(options)?.finish()
}

/// A simulation in the working graphs, before they become [`PoseGraph`]s.
#[derive(Clone, Debug)]
pub(crate) struct Simulated<P, const D: usize> {
    pub(crate) noisy: Graph<P, D>,
    pub(crate) truth: Graph<P, D>,
    pub(crate) wrong: Vec<bool>,
}

impl<P: GraphPose<D>, const D: usize> Simulated<P, D> {
    /// The library's graphs of the simulation.
    fn finish(self) -> Result<Simulation<P, D>, SimulationError> {
        Ok(Simulation {
            noisy: self.noisy.to_pose_graph()?,
            truth: self.truth.to_pose_graph()?,
            wrong: self.wrong,
        })
    }
}

/// The planar simulation in working graphs.
pub(crate) fn simulate_planar_graphs(
    options: &SimulationOptions,
) -> Result<Simulated<Se2, 3>, SimulationError> {
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

/// The spatial simulation in working graphs.
pub(crate) fn simulate_spatial_graphs(
    options: &SimulationOptions,
) -> Result<Simulated<Se3, 6>, SimulationError> {
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

/// What [`corrupt`] did besides returning the corrupted graph.
#[derive(Clone, Debug)]
pub struct Corruption<P: GraphPose<D>, const D: usize> {
    /// The corrupted graph: the poses, edges (some now loop candidates
    /// with new counts) and fixed poses of the input, then the wrong loop
    /// candidates.
    pub graph: PoseGraph<P, D>,
    /// `wrong[k]`: whether edge `k` of the corrupted graph is a wrong loop
    /// (the appended edges and the known-wrong existing ones).
    pub wrong: Vec<bool>,
    /// Number of existing non-sequential edges marked as true loop
    /// candidates (the known-wrong ones not counted).
    pub marked: usize,
}

/// Corrupts an existing graph for robust and gating benchmarks, returning
/// the corrupted copy (the input is left as it is):
///
/// 1. every existing non-sequential edge (`|idᵢ − idⱼ| ≠ 1`) becomes a loop
///    candidate, with an inlier count drawn from the true-loop model when an
///    inlier model is given (without one, existing counts are kept) — except
///    the last `options.known_wrong_last` of them, which are labelled wrong
///    and drawn as wrong candidates' counts;
/// 2. `options.outliers` wrong loop candidates are appended by the policy,
///    between vertices that are neither consecutive in index nor in id, with
///    the information of a random existing loop edge (of an odometry edge
///    when there is none; one per group) and measurements `P::exp(ξ)` of a
///    random tangent vector `ξ` (see [`CorruptionOptions`]) — or, aliased,
///    the relative pose of the graph's poses from `i` to `j + s` with noise
///    drawn from that information;
/// 3. wrong candidates' counts come from the wrong-loop model, or with
///    probability `options.true_like_share` from the true-loop model.
///
/// Every vertex needs a pose ([`PoseGraph::compose_missing_poses`] gives
/// those a file left out one); else [`SimulationError::MissingPose`].
///
/// ```
/// use pgo::nalgebra::Matrix3;
/// use pgo::{PoseGraph2, Se2};
/// use pgo_sim::{CorruptionOptions, corrupt};
/// use rand::{SeedableRng, rngs::StdRng};
///
/// let mut graph = PoseGraph2::new();
/// for k in 0..50u64 {
///     graph.add_pose(k, Se2::new(k as f64, 0.0, 0.0))?;
/// }
/// for k in 1..50u64 {
///     graph.add_edge(k - 1, k, Se2::new(1.0, 0.0, 0.0), Matrix3::identity())?;
/// }
/// graph.add_edge(0, 40, Se2::new(40.0, 0.0, 0.0), Matrix3::identity() * 2.0)?;
///
/// let options = CorruptionOptions { outliers: 10, ..Default::default() };
/// let corruption = corrupt(&graph, &options, &mut StdRng::seed_from_u64(1))?;
/// assert_eq!(corruption.marked, 1);
/// assert_eq!(corruption.graph.num_edges(), 50 + 10);
/// assert_eq!(corruption.graph.num_loop_candidates(), 1 + 10);
/// assert_eq!(corruption.wrong.iter().filter(|&&w| w).count(), 10);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub fn corrupt<P: ErrorCoordinates<D>, const D: usize>(
    graph: &PoseGraph<P, D>,
    options: &CorruptionOptions,
    rng: &mut impl Rng,
) -> Result<Corruption<P, D>, SimulationError> {
    let mut working = Graph::of(graph)?;
    let (wrong, marked) = corrupt_graph(&mut working, options, rng)?;
    Ok(Corruption {
        graph: working.to_pose_graph()?,
        wrong,
        marked,
    })
}

/// [`corrupt`] on the working graph: which edges are wrong, and how many
/// were marked as true candidates.
pub(crate) fn corrupt_graph<P: ErrorCoordinates<D>, const D: usize>(
    graph: &mut Graph<P, D>,
    options: &CorruptionOptions,
    rng: &mut impl Rng,
) -> Result<(Vec<bool>, usize), SimulationError> {
    options.validate()?;
    let sequential: Vec<bool> = graph
        .edges
        .iter()
        .map(|e| graph.id(e.from).abs_diff(graph.id(e.to)) == 1)
        .collect();

    // Plan everything that can fail before touching the graph.
    let plan = corrupt::plan(options);
    let loops: Vec<usize> = (0..sequential.len()).filter(|&k| !sequential[k]).collect();
    if options.known_wrong_last > loops.len() {
        return Err(SimulationError::TooManyKnownWrong {
            asked: options.known_wrong_last,
            available: loops.len(),
        });
    }
    let revisits: Vec<(usize, usize)> = loops[..loops.len() - options.known_wrong_last]
        .iter()
        .map(|&k| (graph.edges[k].from, graph.edges[k].to))
        .collect();
    let groups = corrupt::place(graph, &plan, &sequential, &revisits, rng)?;
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
    let planned = corrupt::measure(graph, &plan, &groups, &sources, rng)?;

    let marked = corrupt::mark_candidates(graph, options, &sequential, &wrong, rng);
    wrong.resize(wrong.len() + planned.len(), true);
    corrupt::append(graph, planned, &groups, options, rng);
    Ok((wrong, marked))
}

#[cfg(test)]
mod aliasing_tests;
#[cfg(test)]
mod corrupt_tests;
#[cfg(test)]
mod identity_tests;
#[cfg(test)]
mod noise_tests;
#[cfg(test)]
mod options_tests;
#[cfg(test)]
mod testing;
#[cfg(test)]
mod tests;
#[cfg(test)]
mod world_tests;
