//! Initial guesses for the optimiser.
//!
//! * [`Initialization::File`]: the poses in the file; vertices that no line
//!   defines are reached by composing edges along a spanning tree.
//! * [`Initialization::Odometry`]: every non-gauge pose by composing edges
//!   along a spanning tree from the gauge, breadth-first over odometry edges
//!   first (trusted edges between consecutive ids), then over the others.
//! * [`Initialization::Chordal`]: the chordal relaxation of Carlone et al.
//!   ("Initialization techniques for 3D SLAM", ICRA 2015): rotations from one
//!   linear least-squares problem in the rotation matrices' entries,
//!   projected back onto SO(2)/SO(3), then translations from a second linear
//!   problem with those rotations held fixed. Both use the sparse Cholesky of
//!   [`crate::linear`]. This is what GTSAM's `InitializePose3` does, and it
//!   takes the optimiser to the basin of the global optimum on the standard
//!   datasets where the files' own guesses stop peers in local minima.

use super::SolveError;
use crate::geometry::{NormalBlocks, Pose, Se2, Se3};
use crate::graph::{Graph, IndexedEdge};
use crate::linear::{BlockSystem, LinearError, Parallelism};
use nalgebra::{Matrix2, Matrix3, SMatrix, SVector, UnitQuaternion, Vector2, Vector3};
use serde::Serialize;
use std::collections::VecDeque;

/// How to obtain the initial poses.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum Initialization {
    /// The file's poses (missing ones by spanning tree).
    File,
    /// Composition of odometry along a spanning tree.
    Odometry,
    /// Chordal relaxation of the rotations, then linear translations.
    #[default]
    Chordal,
    /// The poses as they are: the last solution of an incremental update
    /// ([`crate::PoseGraph::update`]), new poses composed along a spanning
    /// tree. Not a command-line choice.
    Previous,
}

/// Pose types that have a chordal initialisation.
pub trait ChordalInit<const D: usize>: Pose<D> {
    /// What repeated chordal solves of one graph share: the linear
    /// problem's structure (elimination order, symbolic factorisation), kept
    /// while the same edges have a positive weight.
    type Reuse: Default + From<Parallelism>;

    /// Replaces every non-gauge pose by the chordal estimate, using the
    /// edges whose weight is positive.
    fn chordal(graph: &mut Graph<Self, D>, weights: Option<&[f64]>) -> Result<(), SolveError> {
        Self::chordal_reusing(graph, weights, &mut Self::Reuse::default())
    }

    /// [`ChordalInit::chordal`] with the structure of an earlier solve of
    /// the same graph, for a sequence of solves whose weights change but
    /// whose set of positive weights does not (an annealing): `reuse` is
    /// rebuilt when that set changed.
    fn chordal_reusing(
        graph: &mut Graph<Self, D>,
        weights: Option<&[f64]>,
        reuse: &mut Self::Reuse,
    ) -> Result<(), SolveError>;
}

/// The [`ChordalInit::Reuse`] of a chordal relaxation with `D` unknowns per
/// free vertex: its linear problem and which edges it holds.
/// Made by `From<Parallelism>` to factorise on the threads of a pool
/// (`Default`: in the calling thread).
#[derive(Default)]
pub struct ChordalReuse<const D: usize> {
    problem: Option<(Vec<bool>, LinearProblem<D>)>,
    /// Each edge's rotation precision ([`rotation_precision`]): the
    /// information does not change between the solves.
    rotation: Vec<f64>,
    parallelism: Parallelism,
}

impl<const D: usize> From<Parallelism> for ChordalReuse<D> {
    fn from(parallelism: Parallelism) -> Self {
        Self {
            parallelism,
            ..Self::default()
        }
    }
}

impl<const D: usize> ChordalReuse<D> {
    /// The linear problem of `graph` over the edges of positive weight,
    /// built again only when that set differs from the last call's, and
    /// each edge's rotation precision (the rotation at `rot` of its error).
    fn problem<P: Pose<D2>, const D2: usize>(
        &mut self,
        graph: &Graph<P, D2>,
        weights: Option<&[f64]>,
        rot: std::ops::Range<usize>,
    ) -> Result<(&mut LinearProblem<D>, &[f64]), SolveError> {
        let held: Vec<bool> = (0..graph.edges.len())
            .map(|k| weight(weights, k) != 0.0)
            .collect();
        if self.problem.as_ref().is_none_or(|(h, _)| *h != held) {
            self.problem = None;
            self.rotation = (graph.edges.iter())
                .map(|e| rotation_precision(&e.information, rot.clone()))
                .collect();
        }
        let problem = match &mut self.problem {
            Some((_, problem)) => problem,
            slot @ None => {
                let problem = LinearProblem::new(graph, weights, self.parallelism.clone())?;
                &mut slot.insert((held, problem)).1
            }
        };
        Ok((problem, &self.rotation))
    }
}

/// Sets the initial poses of `graph`. `missing` lists the vertices that the
/// file did not define; `weights` (per edge) exclude edges with weight 0
/// (e.g. loop candidates dropped by the gate) from the chordal problem.
pub fn initialize<P: ChordalInit<D>, const D: usize>(
    graph: &mut Graph<P, D>,
    missing: &[usize],
    mode: Initialization,
    weights: Option<&[f64]>,
) -> Result<(), SolveError> {
    let n = graph.num_vertices();
    match mode {
        Initialization::File => {
            let mut known = vec![true; n];
            for &k in missing {
                known[k] = false;
            }
            for g in graph.gauge() {
                known[g] = true;
            }
            spanning_tree(graph, &mut known, weights);
            Ok(())
        }
        Initialization::Odometry => {
            let mut known = vec![false; n];
            for g in graph.gauge() {
                known[g] = true;
            }
            spanning_tree(graph, &mut known, weights);
            Ok(())
        }
        Initialization::Chordal => P::chordal(graph, weights),
        Initialization::Previous => Ok(()),
    }
}

/// Whether an edge is odometry: trusted and between consecutive ids.
fn is_odometry<P: Pose<D>, const D: usize>(graph: &Graph<P, D>, e: &IndexedEdge<P, D>) -> bool {
    e.candidate.is_none() && graph.id(e.from).abs_diff(graph.id(e.to)) == 1
}

/// Gives every unknown vertex reachable from a known one the composition of
/// the edges along a breadth-first spanning tree: first over odometry edges
/// only, then over all edges (with positive weight). Unreachable vertices
/// keep their poses.
pub fn spanning_tree<P: Pose<D>, const D: usize>(
    graph: &mut Graph<P, D>,
    known: &mut [bool],
    weights: Option<&[f64]>,
) {
    let edges: Vec<usize> = (0..graph.edges.len())
        .filter(|&k| weights.is_none_or(|w| w[k] > 0.0))
        .collect();
    grow_tree(graph, known, &edges);
}

/// [`spanning_tree`] over the given `edges` only (indices, increasing): its
/// cost follows their number, not the graph's size, so that poses added to
/// a solved map are placed in time proportional to what was added.
pub fn grow_tree<P: Pose<D>, const D: usize>(
    graph: &mut Graph<P, D>,
    known: &mut [bool],
    edges: &[usize],
) {
    // Each edge at both its ends, by vertex (edges in increasing order at
    // each vertex).
    let mut ends: Vec<(usize, usize)> = (edges.iter())
        .flat_map(|&k| [(graph.edges[k].from, k), (graph.edges[k].to, k)])
        .collect();
    ends.sort_unstable();
    let at = |v: usize| {
        let first = ends.partition_point(|&(u, _)| u < v);
        let last = ends.partition_point(|&(u, _)| u <= v);
        &ends[first..last]
    };
    let mut seeds: Vec<usize> = ends.iter().map(|&(v, _)| v).filter(|&v| known[v]).collect();
    seeds.dedup();
    for odometry_only in [true, false] {
        let mut queue: VecDeque<usize> = seeds.iter().copied().collect();
        while let Some(v) = queue.pop_front() {
            for &(_, k) in at(v) {
                let e = &graph.edges[k];
                let w = if e.from == v { e.to } else { e.from };
                if known[w] || odometry_only && !is_odometry(graph, e) {
                    continue;
                }
                graph.poses[w] = if e.from == v {
                    graph.poses[v].compose(&e.measurement)
                } else {
                    graph.poses[v].compose(&e.measurement.inverse())
                };
                known[w] = true;
                queue.push_back(w);
            }
        }
    }
}

/// Variable block of each vertex (`None` for the gauge) and the count.
fn variables<P: Pose<D>, const D: usize>(graph: &Graph<P, D>) -> (Vec<Option<usize>>, usize) {
    let mut variable = vec![Some(0); graph.num_vertices()];
    for g in graph.gauge() {
        variable[g] = None;
    }
    let mut count = 0;
    for v in variable.iter_mut().flatten() {
        *v = count;
        count += 1;
    }
    (variable, count)
}

/// A linear least-squares problem `Σ ‖Aᵢxᵢ + Aⱼxⱼ + c‖²_W` over the graph's
/// edges, with `D`-dimensional unknowns per free vertex.
struct LinearProblem<const D: usize> {
    system: BlockSystem<D>,
    variable: Vec<Option<usize>>,
    n_free: usize,
}

impl<const D: usize> LinearProblem<D> {
    fn new<P: Pose<D2>, const D2: usize>(
        graph: &Graph<P, D2>,
        weights: Option<&[f64]>,
        parallelism: Parallelism,
    ) -> Result<Self, SolveError> {
        let unconstrained = graph.unconstrained_vertices(weights);
        if !unconstrained.is_empty() {
            let gauge = graph.gauge().first().map(|&g| graph.id(g)).unwrap_or(0);
            return Err(SolveError::Unconstrained {
                gauge,
                vertices: unconstrained.iter().map(|&k| graph.id(k)).collect(),
            });
        }
        let (variable, n_free) = variables(graph);
        // Edges of weight 0 are left out of the pattern: a dropped loop
        // candidate would otherwise cost fill for nothing.
        let pairs: Vec<_> = graph
            .edges
            .iter()
            .enumerate()
            .map(|(k, e)| {
                if weight(weights, k) == 0.0 {
                    (None, None)
                } else {
                    (variable[e.from], variable[e.to])
                }
            })
            .collect();
        Ok(Self {
            system: BlockSystem::new(n_free, &pairs, parallelism)?,
            variable,
            n_free,
        })
    }

    /// Adds every edge `k` whose `term(k)` is `Some` (see [`Term`]); the
    /// terms are made, and added, on the system's threads (the same sums
    /// as one after the other: [`BlockSystem::add_edges`]).
    /// `term` gets the edge and each vertex's variable block.
    fn add_all(
        &mut self,
        edges: usize,
        term: impl Fn(usize, &[Option<usize>]) -> Option<Term<D>> + Sync,
    ) {
        // Edges per batch: their blocks take a few MB.
        const BATCH: usize = 1 << 14;
        // Edges per task: a term is some 3×3 products.
        const RUN: usize = 1 << 10;
        let parallelism = self.system.parallelism().clone();
        let mut first = 0;
        while first < edges {
            let batch: Vec<usize> = (first..edges.min(first + BATCH)).collect();
            let blocks = parallelism.map_runs(&batch, RUN, |&k| {
                term(k, &self.variable).map(|t| t.blocks())
            });
            self.system.add_edges(first, &blocks, |b| b.as_ref());
            first += batch.len();
        }
    }

    /// Adds only the right-hand side of edge `k`'s `term` (the matrix is
    /// unchanged).
    fn add_rhs(&mut self, k: usize, term: &Term<D>) {
        let (b_i, b_j) = term.gradient();
        self.system.add_edge_gradient(k, &b_i, &b_j);
    }

    /// Factorises the assembled matrix.
    fn factorize<P: Pose<D2>, const D2: usize>(
        &mut self,
        graph: &Graph<P, D2>,
    ) -> Result<(), SolveError> {
        match self.system.factorize(0.0) {
            Ok(()) => Ok(()),
            Err(LinearError::NotPositiveDefinite { block }) => {
                let vertex = self
                    .variable
                    .iter()
                    .position(|v| *v == Some(block))
                    .map(|k| graph.id(k))
                    .unwrap_or(0);
                Err(SolveError::NotPositiveDefinite { vertex })
            }
            Err(e) => Err(e.into()),
        }
    }

    /// Factorises and solves the assembled problem; the solution by
    /// variable block.
    fn solve<P: Pose<D2>, const D2: usize>(
        &mut self,
        graph: &Graph<P, D2>,
    ) -> Result<Vec<f64>, SolveError> {
        self.factorize(graph)?;
        let mut x = vec![0.0; self.n_free * D];
        self.system.solve(&mut x);
        Ok(x)
    }

    fn value(&self, x: &[f64], vertex: usize) -> Option<SVector<f64, D>> {
        self.variable[vertex].map(|b| SVector::<f64, D>::from_column_slice(&x[b * D..b * D + D]))
    }
}

/// An edge's residual `r = Aᵢxᵢ + Aⱼxⱼ + c` (`c` already holds the
/// contribution of fixed endpoints) and weight `W`: `(Aᵢ, Aⱼ, c, W)`.
struct Term<const D: usize>(
    SMatrix<f64, D, D>,
    SMatrix<f64, D, D>,
    SVector<f64, D>,
    SMatrix<f64, D, D>,
);

impl<const D: usize> Term<D> {
    /// This term of the edge `i → j`, with each end that has no variable
    /// block (`variable`) folded into `c` at its value `x(v)`.
    fn fixing_ends(
        mut self,
        (i, j): (usize, usize),
        variable: &[Option<usize>],
        x: impl Fn(usize) -> SVector<f64, D>,
    ) -> Self {
        let Self(a_i, a_j, c, _) = &mut self;
        if variable[j].is_none() {
            *c += *a_j * x(j);
        }
        if variable[i].is_none() {
            *c += *a_i * x(i);
        }
        self
    }

    /// Its blocks of the normal equations.
    fn blocks(&self) -> NormalBlocks<D> {
        let Self(a_i, a_j, _, w) = self;
        let wa_i = w * a_i;
        let wa_j = w * a_j;
        let (b_i, b_j) = self.gradient();
        NormalBlocks {
            h_ii: a_i.transpose() * wa_i,
            h_ij: a_i.transpose() * wa_j,
            h_jj: a_j.transpose() * wa_j,
            b_i,
            b_j,
            chi2: 0.0,
        }
    }

    /// Its blocks of the right-hand side, `AᵢᵀWc` and `AⱼᵀWc`.
    fn gradient(&self) -> (SVector<f64, D>, SVector<f64, D>) {
        let Self(a_i, a_j, c, w) = self;
        let wc = w * c;
        (a_i.transpose() * wc, a_j.transpose() * wc)
    }
}

/// The weight of edge `k` (0 excludes it).
fn weight(weights: Option<&[f64]>, k: usize) -> f64 {
    weights.map_or(1.0, |w| w[k])
}

/// The marginal information of the trailing `R`×`R` block (the rotation)
/// and the leading `T`×`T` block (the translation, conditioned on the
/// rotation) of an information matrix.
///
/// Scale-invariant: the matrix is inverted divided by the power of two
/// nearest below its largest entry (exact, so in-range matrices give the
/// same bits), since a 3×3 inverse goes through the determinant, the cube
/// of the scale, which over- or underflows for entries beyond 10^±102.
fn rotation_precision<const D: usize>(
    information: &SMatrix<f64, D, D>,
    rot: std::ops::Range<usize>,
) -> f64 {
    let r = rot.len();
    let largest = information.amax();
    if !(largest.is_normal()) {
        return 0.0;
    }
    let exponent = largest.log2().floor() as i32;
    let covariance = (information * 2f64.powi(-exponent)).try_inverse();
    match covariance {
        Some(c) => {
            let block = c.view((rot.start, rot.start), (r, r)).clone_owned();
            let trace = block.trace();
            let precision = r as f64 / trace * 2f64.powi(exponent);
            if trace > 0.0 && precision.is_finite() {
                precision
            } else {
                0.0
            }
        }
        None => 0.0,
    }
}

impl ChordalInit<3> for Se2 {
    type Reuse = ChordalReuse<2>;

    fn chordal_reusing(
        graph: &mut Graph<Self, 3>,
        weights: Option<&[f64]>,
        reuse: &mut ChordalReuse<2>,
    ) -> Result<(), SolveError> {
        let (lp, precision) = reuse.problem(graph, weights, 2..3)?;
        // Rotations: r = (cos θ, sin θ), r_j − M(θ_ij) r_i = 0.
        lp.system.clear();
        lp.add_all(graph.edges.len(), |k, variable| {
            let e = &graph.edges[k];
            let w = weight(weights, k) * precision[k];
            if w == 0.0 {
                return None;
            }
            let (s, c) = e.measurement.theta.sin_cos();
            let m = Matrix2::new(c, -s, s, c);
            Some(
                Term(
                    -m,
                    Matrix2::identity(),
                    Vector2::zeros(),
                    Matrix2::identity() * w,
                )
                .fixing_ends((e.from, e.to), variable, |v| {
                    let (s, c) = graph.poses[v].theta.sin_cos();
                    Vector2::new(c, s)
                }),
            )
        });
        let x = lp.solve(graph)?;
        for v in 0..graph.num_vertices() {
            if let Some(r) = lp.value(&x, v) {
                graph.poses[v].theta = r.y.atan2(r.x);
            }
        }
        // Translations with the rotations fixed: R_iᵀ(t_j − t_i) − t_ij = 0.
        lp.system.clear();
        let poses = &graph.poses;
        lp.add_all(graph.edges.len(), |k, variable| {
            let e = &graph.edges[k];
            let w = weight(weights, k);
            if w == 0.0 {
                return None;
            }
            let omega = e.information.fixed_view::<2, 2>(0, 0).clone_owned() * w;
            let (s, c) = poses[e.from].theta.sin_cos();
            let rt = Matrix2::new(c, s, -s, c);
            Some(
                Term(-rt, rt, -e.measurement.translation(), omega).fixing_ends(
                    (e.from, e.to),
                    variable,
                    |v| poses[v].translation(),
                ),
            )
        });
        let x = lp.solve(graph)?;
        for v in 0..graph.num_vertices() {
            if let Some(t) = lp.value(&x, v) {
                graph.poses[v].x = t.x;
                graph.poses[v].y = t.y;
            }
        }
        Ok(())
    }
}

impl ChordalInit<6> for Se3 {
    type Reuse = ChordalReuse<3>;

    fn chordal_reusing(
        graph: &mut Graph<Self, 6>,
        weights: Option<&[f64]>,
        reuse: &mut ChordalReuse<3>,
    ) -> Result<(), SolveError> {
        let parallelism = reuse.parallelism.clone();
        let (lp, precision) = reuse.problem(graph, weights, 3..6)?;
        let rows = spatial_rotation_rows(graph, weights, lp, precision)?;
        let free: Vec<usize> = (0..graph.num_vertices())
            .filter(|&v| lp.variable[v].is_some())
            .collect();
        let rotations = parallelism.map_runs(&free, 1 << 10, |&v| nearest_rotation(&rows[v]));
        for (&v, q) in free.iter().zip(rotations) {
            graph.poses[v].rotation = q;
        }
        // Translations: R_iᵀ(t_j − t_i) − t_ij = 0.
        lp.system.clear();
        let poses = &graph.poses;
        lp.add_all(graph.edges.len(), |k, variable| {
            let e = &graph.edges[k];
            let w = weight(weights, k);
            if w == 0.0 {
                return None;
            }
            let omega = e.information.fixed_view::<3, 3>(0, 0).clone_owned() * w;
            let rt = poses[e.from].rotation_matrix().transpose();
            Some(
                Term(-rt, rt, -e.measurement.translation, omega).fixing_ends(
                    (e.from, e.to),
                    variable,
                    |v| poses[v].translation,
                ),
            )
        });
        let x = lp.solve(graph)?;
        for v in 0..graph.num_vertices() {
            if let Some(t) = lp.value(&x, v) {
                graph.poses[v].translation = t;
            }
        }
        Ok(())
    }
}

/// The relaxed rotation matrices of a 3D graph (each vertex's; zero for
/// fixed ones), not yet rotations: one row at a time,
/// `row_k(R_j) = row_k(R_i)·R_ij`, i.e. `ρ_j − R_ijᵀ ρ_i = 0` for the row
/// vectors `ρ`. The matrix is the same for the three rows: factorised once,
/// the three right-hand sides solved together.
fn spatial_rotation_rows(
    graph: &Graph<Se3, 6>,
    weights: Option<&[f64]>,
    lp: &mut LinearProblem<3>,
    precision: &[f64],
) -> Result<Vec<Matrix3<f64>>, SolveError> {
    let len = lp.n_free * 3;
    let mut x = vec![0.0; 3 * len];
    let poses = &graph.poses;
    let term = |row: usize, k: usize, variable: &[Option<usize>]| {
        let e = &graph.edges[k];
        // Rotational error in g2o's coordinates is ≈ θ/2, hence the 4.
        let w = weight(weights, k) * precision[k] / 4.0;
        if w == 0.0 {
            return None;
        }
        let m = e.measurement.rotation_matrix().transpose();
        Some(
            Term(
                -m,
                Matrix3::identity(),
                Vector3::zeros(),
                Matrix3::identity() * w,
            )
            .fixing_ends((e.from, e.to), variable, |v| {
                poses[v].rotation_matrix().row(row).transpose()
            }),
        )
    };
    lp.system.clear();
    lp.add_all(graph.edges.len(), |k, variable| term(0, k, variable));
    lp.factorize(graph)?;
    lp.system.gradient_into(&mut x[..len]);
    for row in 1..3 {
        lp.system.clear_gradient();
        for k in 0..graph.edges.len() {
            if let Some(t) = term(row, k, &lp.variable) {
                lp.add_rhs(k, &t);
            }
        }
        lp.system.gradient_into(&mut x[row * len..(row + 1) * len]);
    }
    lp.system.solve_many(&mut x, 3);
    let mut rows = vec![Matrix3::<f64>::zeros(); graph.num_vertices()];
    for (row, x) in x.chunks_exact(len.max(1)).enumerate() {
        for (v, r) in rows.iter_mut().enumerate() {
            if let Some(value) = lp.value(x, v) {
                r.set_row(row, &value.transpose());
            }
        }
    }
    Ok(rows)
}

/// The rotation nearest to `m` in the Frobenius norm (`U·Vᵀ` of its SVD,
/// with the sign fixed so that the determinant is +1); the identity when `m`
/// is not finite or the SVD does not converge.
///
/// `U·Vᵀ` is orthonormal already, so it is converted to a quaternion
/// directly: nalgebra's iterative `from_matrix` never returns for a matrix
/// half a turn away from its identity starting guess (found by fuzzing:
/// two parallel edges whose rotations differ by π).
fn nearest_rotation(m: &Matrix3<f64>) -> UnitQuaternion<f64> {
    if !m.iter().all(|v| v.is_finite()) {
        return UnitQuaternion::identity();
    }
    let r = match polar_newton(m) {
        Some(r) => r,
        None => {
            let Some(svd) = m.try_svd(true, true, f64::EPSILON, 10_000) else {
                return UnitQuaternion::identity();
            };
            let (Some(mut u), Some(v_t)) = (svd.u, svd.v_t) else {
                return UnitQuaternion::identity();
            };
            if (u * v_t).determinant() < 0.0 {
                u.set_column(2, &(-u.column(2)));
            }
            u * v_t
        }
    };
    let q = UnitQuaternion::from_rotation_matrix(&nalgebra::Rotation3::from_matrix_unchecked(r));
    if q.coords.iter().all(|v| v.is_finite()) {
        q
    } else {
        UnitQuaternion::identity()
    }
}

/// The orthogonal polar factor of `m` — its nearest rotation when
/// `det m > 0` — by the scaled Newton iteration `X ← ½(γX + γ⁻¹X⁻ᵀ)`,
/// `γ = (‖X⁻¹‖/‖X‖)^½` (Higham, *Functions of Matrices*, §8.6), which
/// converges quadratically; a few times cheaper than an SVD, and what a
/// chordal relaxation asks of every pose at every step. `None` when `m` is
/// far from invertible or has `det m ≤ 0` (the SVD decides those), or the
/// iteration does not settle.
fn polar_newton(m: &Matrix3<f64>) -> Option<Matrix3<f64>> {
    // Reciprocal condition below which the SVD decides: the polar factor
    // of a nearly singular matrix is ill-determined anyway.
    const MIN_DETERMINANT: f64 = 1e-8;
    let norm = m.norm();
    let det = m.determinant();
    if det.is_nan() || det <= MIN_DETERMINANT * norm * norm * norm {
        return None;
    }
    let mut x = *m;
    for _ in 0..30 {
        let inv_t = x.try_inverse()?.transpose();
        let gamma = (inv_t.norm() / x.norm()).sqrt();
        let next = (x * gamma + inv_t / gamma) * 0.5;
        let change = (next - x).norm();
        x = next;
        // ‖X‖ = √3 at the fixed point; a change at rounding level means
        // the next iterate would differ only in rounding.
        if change <= 1e-14 {
            return Some(x);
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rotation_precision_is_scale_invariant() {
        // Through a 3×3 determinant, scales beyond 10^±103 used to give 0:
        // no rotation term, "the edges at vertex … do not determine its
        // pose".
        let info = Matrix3::new(400.0, 12.0, 3.0, 12.0, 300.0, -5.0, 3.0, -5.0, 1e4);
        let unit = rotation_precision(&info, 2..3);
        assert!(unit > 0.0);
        for scale in [1e-300, 1e-150, 1e-110, 1e110, 1e150, 1e300] {
            let scaled = rotation_precision(&(info * scale), 2..3);
            assert!(
                (scaled / (unit * scale) - 1.0).abs() < 1e-12,
                "{scale}: {scaled} vs {}",
                unit * scale
            );
        }
        // In range, the same bits as without the scaling.
        let direct = 1.0 / info.try_inverse().unwrap()[(2, 2)];
        assert_eq!(unit, direct);
        assert_eq!(rotation_precision(&Matrix3::zeros(), 2..3), 0.0);
    }

    #[test]
    fn nearest_rotation_of_half_turns_and_degenerate_matrices_returns() {
        // Found by the optimize fuzz target: this used to loop forever.
        let half_turn = Matrix3::new(-1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 1.0);
        let q = nearest_rotation(&half_turn);
        assert!((q.to_rotation_matrix().into_inner() - half_turn).norm() < 1e-12);
        // The chordal average of two rotations half a turn apart (rank 1).
        let average = (half_turn + Matrix3::identity()) * 0.5;
        let q = nearest_rotation(&average);
        assert!((q.to_rotation_matrix().into_inner().determinant() - 1.0).abs() < 1e-12);
        let mut nan = Matrix3::identity();
        nan[(1, 2)] = f64::NAN;
        assert_eq!(nearest_rotation(&nan), UnitQuaternion::identity());
        let zero = nearest_rotation(&Matrix3::zeros());
        assert!(zero.coords.iter().all(|v| v.is_finite()));
    }
    use crate::solve::{SolveSettings, optimize};
    use nalgebra::{Matrix3, Matrix6, Vector6};
    use rand::{Rng, SeedableRng, rngs::StdRng};

    #[test]
    fn polar_newton_gives_the_svd_nearest_rotation() {
        let mut rng = StdRng::seed_from_u64(7);
        for k in 0..500 {
            // Rotations perturbed a little (a chordal estimate) and a lot.
            let spread = if k % 2 == 0 { 0.05 } else { 0.8 };
            let r = Se3::exp(&Vector6::from_fn(|_, _| rng.random_range(-3.0..3.0)));
            let m =
                r.rotation_matrix() + Matrix3::from_fn(|_, _| rng.random_range(-spread..spread));
            let Some(polar) = polar_newton(&m) else {
                assert!(m.determinant() <= 1e-8 * m.norm().powi(3), "{m}");
                continue;
            };
            let svd = m.svd(true, true);
            let (u, v_t) = (svd.u.unwrap(), svd.v_t.unwrap());
            assert!((u * v_t).determinant() > 0.0);
            assert!((polar - u * v_t).norm() < 1e-12, "{m}");
        }
        // A reflection, singular and rank-1 matrices go to the SVD.
        assert!(polar_newton(&Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, -1.0))).is_none());
        assert!(polar_newton(&Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, 0.0))).is_none());
    }

    fn grid_truth() -> Vec<Se2> {
        // A 5×5 serpentine walk.
        let mut poses = Vec::new();
        for r in 0..5 {
            for c in 0..5 {
                let (x, th) = if r % 2 == 0 {
                    (c as f64, 0.0)
                } else {
                    (4.0 - c as f64, std::f64::consts::PI)
                };
                poses.push(Se2::new(x, r as f64, th));
            }
        }
        poses
    }

    fn planar_graph(truth: &[Se2], noise: f64, seed: u64) -> Graph<Se2, 3> {
        let mut rng = StdRng::seed_from_u64(seed);
        let mut g = Graph::new();
        for (k, _) in truth.iter().enumerate() {
            g.add_vertex(
                k as u64,
                Se2::new(
                    rng.random_range(-5.0..5.0),
                    rng.random_range(-5.0..5.0),
                    rng.random_range(-3.0..3.0),
                ),
            )
            .unwrap();
        }
        g.poses[0] = truth[0];
        let mut add = |g: &mut Graph<Se2, 3>, i: usize, j: usize| {
            let z = truth[i].inverse().compose(&truth[j]);
            let z = Se2::new(
                z.x + noise * rng.random_range(-1.0..1.0),
                z.y + noise * rng.random_range(-1.0..1.0),
                z.theta + noise * rng.random_range(-1.0..1.0),
            );
            g.add_edge(i as u64, j as u64, z, Matrix3::identity(), None)
                .unwrap();
        };
        for k in 1..truth.len() {
            add(&mut g, k - 1, k);
        }
        for k in 0..truth.len() {
            for m in k + 2..truth.len() {
                if (truth[k].translation() - truth[m].translation()).norm() < 1.01 {
                    add(&mut g, k, m);
                }
            }
        }
        g
    }

    #[test]
    fn chordal_recovers_noise_free_planar_poses_exactly() {
        let truth = grid_truth();
        let mut g = planar_graph(&truth, 0.0, 1);
        initialize(&mut g, &[], Initialization::Chordal, None).unwrap();
        for (p, t) in g.poses.iter().zip(&truth) {
            assert!((p.translation() - t.translation()).norm() < 1e-9);
            assert!(crate::geometry::wrap_angle(p.theta - t.theta).abs() < 1e-9);
        }
    }

    #[test]
    fn chordal_then_lm_matches_lm_from_the_truth_on_noisy_planar_graph() {
        let truth = grid_truth();
        let mut g = planar_graph(&truth, 0.05, 2);
        let mut reference = g.clone();
        reference.poses = truth.clone();
        let best = optimize(&mut reference, &SolveSettings::default())
            .unwrap()
            .final_objective;
        initialize(&mut g, &[], Initialization::Chordal, None).unwrap();
        let s = optimize(&mut g, &SolveSettings::default()).unwrap();
        assert!(
            (s.final_objective - best).abs() < 1e-9 * best,
            "{} vs {best}",
            s.final_objective
        );
    }

    #[test]
    fn chordal_with_a_reused_structure_equals_a_fresh_solve() {
        let truth = grid_truth();
        let g = planar_graph(&truth, 0.05, 4);
        let loops: Vec<usize> = (0..g.edges.len())
            .filter(|&k| g.id(g.edges[k].to) - g.id(g.edges[k].from) > 1)
            .collect();
        let mut reuse = ChordalReuse::default();
        // Weights that change (first two), then a set of positive weights
        // that changes too (last): each must give the fresh solve's poses.
        let mut steps = Vec::new();
        for (scale, dropped) in [(1.0, None), (0.3, None), (0.3, Some(loops[0]))] {
            let mut w = vec![1.0; g.edges.len()];
            for (i, &k) in loops.iter().enumerate() {
                w[k] = scale / (1.0 + i as f64);
            }
            if let Some(k) = dropped {
                w[k] = 0.0;
            }
            steps.push(w);
        }
        for w in &steps {
            let (mut fresh, mut reused) = (g.clone(), g.clone());
            Se2::chordal(&mut fresh, Some(w)).unwrap();
            Se2::chordal_reusing(&mut reused, Some(w), &mut reuse).unwrap();
            assert_eq!(fresh.poses, reused.poses);
        }
        // The poses differ between the steps: the weights reached the solve.
        let (mut a, mut b) = (g.clone(), g.clone());
        Se2::chordal(&mut a, Some(&steps[0])).unwrap();
        Se2::chordal(&mut b, Some(&steps[1])).unwrap();
        assert_ne!(a.poses, b.poses);
    }

    #[test]
    fn chordal_on_threads_equals_one_thread_bit_for_bit() {
        // More edges than one batch of `add_all`, and weights that change:
        // the terms made and added on two threads, and the nearest
        // rotations, must give the sequential solve's poses exactly.
        let mut rng = StdRng::seed_from_u64(9);
        let n = 9000u64;
        let mut g = Graph::<Se3, 6>::new();
        let noisy = |rng: &mut StdRng, scale: f64| {
            Se3::exp(&Vector6::from_fn(|_, _| rng.random_range(-scale..scale)))
        };
        for k in 0..n {
            g.add_vertex(k, Se3::identity()).unwrap();
        }
        let step = Se3::exp(&Vector6::new(1.0, 0.0, 0.0, 0.0, 0.0, 0.01));
        for k in 1..n {
            let m = step.compose(&noisy(&mut rng, 0.01));
            g.add_edge(k - 1, k, m, Matrix6::identity(), None).unwrap();
        }
        for k in 0..n - 100 {
            let to = k + 50 + k % 50;
            let m = noisy(&mut rng, 0.5);
            g.add_edge(k, to, m, Matrix6::identity() * 0.5, None)
                .unwrap();
        }
        assert!(g.edges.len() > 1 << 14);
        let weights: Vec<f64> = (0..g.edges.len())
            .map(|k| 1.0 / (1.0 + (k % 7) as f64))
            .collect();
        let mut one = ChordalReuse::default();
        let mut two = ChordalReuse::from(Parallelism::new(2).unwrap());
        let (mut a, mut b) = (g.clone(), g.clone());
        for _ in 0..2 {
            Se3::chordal_reusing(&mut a, Some(&weights), &mut one).unwrap();
            Se3::chordal_reusing(&mut b, Some(&weights), &mut two).unwrap();
            assert!(a.poses == b.poses);
        }
        assert!(a.poses.iter().any(|p| p.translation.norm() > 1.0));
    }

    #[test]
    fn chordal_recovers_noise_free_spatial_poses() {
        let mut rng = StdRng::seed_from_u64(5);
        let mut truth = vec![Se3::identity()];
        for k in 1..30 {
            let step = Se3::exp(&Vector6::new(1.0, 0.2, 0.1, 0.3, -0.2, 0.4));
            truth.push(truth[k - 1].compose(&step));
        }
        let mut g = Graph::<Se3, 6>::new();
        for k in 0..30u64 {
            let p = Se3::exp(&Vector6::from_fn(|_, _| rng.random_range(-2.0..2.0)));
            g.add_vertex(k, if k == 0 { truth[0] } else { p }).unwrap();
        }
        for k in 1..30 {
            g.add_edge(
                k as u64 - 1,
                k as u64,
                truth[k - 1].inverse().compose(&truth[k]),
                Matrix6::identity(),
                None,
            )
            .unwrap();
        }
        g.add_edge(
            3,
            25,
            truth[3].inverse().compose(&truth[25]),
            Matrix6::identity(),
            None,
        )
        .unwrap();
        initialize(&mut g, &[], Initialization::Chordal, None).unwrap();
        for (p, t) in g.poses.iter().zip(&truth) {
            assert!((p.translation - t.translation).norm() < 1e-8);
            assert!(p.rotation.angle_to(&t.rotation) < 1e-8);
        }
    }

    #[test]
    fn spanning_tree_prefers_odometry_and_fills_only_missing_vertices() {
        let truth = grid_truth();
        let mut g = planar_graph(&truth, 0.0, 3);
        // Corrupt one loop closure: the spanning tree must not use it for
        // vertices that odometry reaches.
        let k = g
            .edges
            .iter()
            .position(|e| g.id(e.to) - g.id(e.from) > 1)
            .unwrap();
        g.edges[k].measurement = Se2::new(9.0, 9.0, 1.0);
        let before = g.poses.clone();
        let missing: Vec<usize> = (5..25).collect();
        initialize(&mut g, &missing, Initialization::File, None).unwrap();
        assert_eq!(g.poses[..5], before[..5]);
        let mut o = planar_graph(&truth, 0.0, 3);
        o.edges[k].measurement = Se2::new(9.0, 9.0, 1.0);
        initialize(&mut o, &[], Initialization::Odometry, None).unwrap();
        for (p, t) in o.poses.iter().zip(&truth) {
            assert!((p.translation() - t.translation()).norm() < 1e-9);
        }
    }

    #[test]
    fn grow_tree_places_only_what_the_given_edges_reach() {
        let truth = grid_truth();
        let mut g = planar_graph(&truth, 0.0, 5);
        let before = g.poses.clone();
        let mut known: Vec<bool> = (0..g.num_vertices()).map(|v| v < 20).collect();
        g.poses[..20].clone_from_slice(&truth[..20]);
        // The edges that reach vertices 20–22, and none beyond.
        let edges: Vec<usize> = (0..g.edges.len())
            .filter(|&k| g.edges[k].to <= 22 && g.edges[k].to >= 20)
            .collect();
        grow_tree(&mut g, &mut known, &edges);
        for v in 20..=22 {
            assert!(known[v]);
            assert!((g.poses[v].translation() - truth[v].translation()).norm() < 1e-9);
        }
        assert!(!known[23] && !known[24]);
        assert_eq!(g.poses[23..], before[23..]);
    }

    #[test]
    fn disconnected_graphs_are_reported_by_chordal() {
        let truth = grid_truth();
        let mut g = planar_graph(&truth, 0.0, 4);
        g.add_vertex(100, Se2::identity()).unwrap();
        assert!(matches!(
            initialize(&mut g, &[], Initialization::Chordal, None),
            Err(SolveError::Unconstrained { .. })
        ));
    }
}
