//! Assembling a simulation: odometry, true loops and wrong loops on a true
//! trajectory, and the noisy and truth graphs built from them.

use super::counts::sample_wrong_group;
use super::noise::{ErrorCoordinates, perturb};
use super::world::{Trajectory, find_loops};
use super::wrong::{
    DEFAULT_LOCAL_WINDOW, DEFAULT_OUTLIER_ROTATION, DEFAULT_OUTLIER_TRANSLATION, WrongLoopPlan,
    random_measurement, wrong_groups,
};
use super::{Simulated, SimulationError, SimulationOptions};
use crate::graph::{Graph, LoopCandidate};
use nalgebra::{SMatrix, Vector3};
use pgo::Pose;
use pgo::VertexId;
use rand::Rng;

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
pub(super) fn simulate_on<P: ErrorCoordinates<D>, const D: usize, R: Rng + ?Sized>(
    options: &SimulationOptions,
    trajectory: Trajectory<P>,
    rng: &mut R,
) -> Result<Simulated<P, D>, SimulationError> {
    let truth = &trajectory.poses;
    let mut edges: Vec<PlannedEdge<P>> = (1..truth.len())
        .map(|k| noisy_edge(truth, (k - 1, k), options, None, rng))
        .collect();
    let guess = dead_reckoning(&edges);
    let loops = true_loops(options, &trajectory, rng);
    let revisits: Vec<(usize, usize)> = loops.iter().map(|e| (e.from, e.to)).collect();
    edges.extend(loops);
    edges.extend(wrong_loops(options, &trajectory, &revisits, rng)?);

    // Order as the public datasets do: by the later vertex, odometry first.
    edges.sort_by_key(|e| (e.from.max(e.to), !e.odometry));
    let information = P::information(options.translation_noise, options.rotation_noise);
    assemble(truth, &guess, &edges, information)
}

/// The edge `from → to` whose measurement is the true relative pose with
/// noise in error coordinates; odometry when `candidate` is `None` and the
/// vertices are consecutive.
fn noisy_edge<P: ErrorCoordinates<D>, const D: usize, R: Rng + ?Sized>(
    truth: &[P],
    (from, to): (usize, usize),
    options: &SimulationOptions,
    candidate: Option<LoopCandidate>,
    rng: &mut R,
) -> PlannedEdge<P> {
    let exact = truth[from].inverse().compose(&truth[to]);
    let e = P::sample_error(options.translation_noise, options.rotation_noise, rng);
    PlannedEdge {
        from,
        to,
        measurement: perturb(&exact, &e),
        truth: Some(exact),
        candidate,
        odometry: to == from + 1 && candidate.is_none(),
    }
}

/// The true loop closures. They are candidates when there is something to
/// tell them from (wrong loops) or a count to attach; otherwise they are
/// trusted, as in the public datasets.
fn true_loops<P: ErrorCoordinates<D>, const D: usize, R: Rng + ?Sized>(
    options: &SimulationOptions,
    trajectory: &Trajectory<P>,
    rng: &mut R,
) -> Vec<PlannedEdge<P>> {
    let truth = &trajectory.poses;
    let positions: Vec<Vector3<f64>> = truth.iter().map(Pose::position).collect();
    let pairs = find_loops(&positions, trajectory.loop_radius, options.loops, rng);
    let mut edges = Vec::with_capacity(pairs.len());
    for pair in pairs {
        let candidate = match &options.inliers {
            Some(model) => Some(LoopCandidate {
                inliers: Some(model.sample_true(rng)),
            }),
            None if options.outliers > 0 => Some(LoopCandidate { inliers: None }),
            None => None,
        };
        edges.push(noisy_edge(truth, pair, options, candidate, rng));
    }
    edges
}

/// The wrong loops, placed by the policy: one random measurement per group,
/// or for aliased groups, the true relative pose to the aliased vertex with
/// the usual noise per candidate (all the group's noise is drawn before its
/// counts). Counts by the inlier model, if any.
fn wrong_loops<P: ErrorCoordinates<D>, const D: usize, R: Rng + ?Sized>(
    options: &SimulationOptions,
    trajectory: &Trajectory<P>,
    revisits: &[(usize, usize)],
    rng: &mut R,
) -> Result<Vec<PlannedEdge<P>>, SimulationError> {
    let truth = &trajectory.poses;
    let plan = WrongLoopPlan {
        count: options.outliers,
        policy: options.outlier_policy,
        group_size: options.group_size,
        local_window: DEFAULT_LOCAL_WINDOW,
        alias_offsets: options.alias_offsets,
        alias_place: options.alias_place,
        translation_scale: DEFAULT_OUTLIER_TRANSLATION,
        rotation_scale: DEFAULT_OUTLIER_ROTATION,
    };
    // An aliased vertex within the loop radius would close a true loop.
    let radius = trajectory.loop_radius;
    let distinct = |j: usize, t: usize| (truth[j].position() - truth[t].position()).norm() > radius;
    let consecutive = |i: usize, j: usize| i.abs_diff(j) == 1;
    let groups = wrong_groups(&plan, truth.len(), revisits, consecutive, distinct, rng)?;
    let mut edges = Vec::with_capacity(options.outliers);
    for group in groups {
        let measurements: Vec<P> = match &group.alias {
            None => vec![random_measurement::<P, D, R>(&plan, rng)?; group.pairs.len()],
            Some(alias) => (group.pairs.iter().enumerate())
                .map(|(k, &pair)| {
                    let exact = alias.exact(truth, k, pair);
                    let e = P::sample_error(options.translation_noise, options.rotation_noise, rng);
                    perturb(&exact, &e)
                })
                .collect(),
        };
        let shares = (options.true_like_share, options.true_like_by_group);
        let counts = (options.inliers.as_ref())
            .map(|model| sample_wrong_group(model, shares, group.pairs.len(), rng));
        for (k, (&(from, to), measurement)) in group.pairs.iter().zip(measurements).enumerate() {
            let inliers = counts.as_ref().map(|c| c[k]);
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
    Ok(edges)
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
fn assemble<P: ErrorCoordinates<D>, const D: usize>(
    truth_poses: &[P],
    guess: &[P],
    edges: &[PlannedEdge<P>],
    information: SMatrix<f64, D, D>,
) -> Result<Simulated<P, D>, SimulationError> {
    let mut noisy = Graph::new();
    let mut truth = Graph::new();
    for (k, (t, g)) in truth_poses.iter().zip(guess).enumerate() {
        let id = k as VertexId;
        noisy.add_vertex(id, *g);
        truth.add_vertex(id, *t);
    }
    let mut wrong = Vec::with_capacity(edges.len());
    for e in edges {
        let (from, to) = (e.from as VertexId, e.to as VertexId);
        noisy.add_edge(from, to, e.measurement, information, e.candidate);
        if let Some(exact) = e.truth {
            truth.add_edge(from, to, exact, information, e.candidate);
        }
        wrong.push(e.truth.is_none());
    }
    Ok(Simulated {
        noisy,
        truth,
        wrong,
    })
}
