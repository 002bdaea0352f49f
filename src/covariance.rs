//! Marginal covariances of the map ([`Covariances`], whose documentation
//! says exactly what is computed and in which convention), their numbers
//! for bindings ([`AnyCovariances`]) and the CSV of `pgo optimize
//! --covariances` (`csv`).

mod any;
mod csv;
#[cfg(test)]
mod tests;

pub use any::AnyCovariances;

use crate::error::Error;
use crate::geometry::{NormalBlocks, Pose};
use crate::graph::{Graph, VertexId};
use crate::linear::{BlockSystem, GroupScratch, LinearError, Parallelism, SelectedInverse};
use crate::solve::{EDGES_PER_TASK, LINEARIZE_CHUNK, SolveError};
#[cfg(test)]
use nalgebra::SVector;
use nalgebra::{DMatrix, SMatrix};
use std::sync::{Arc, Mutex, TryLockError};

/// What a pose's covariance is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Place {
    /// A free pose: its variable block of `H`.
    Block(usize),
    /// Held fixed (the gauge): zero.
    Fixed,
    /// Tied to the fixed poses by no chain of edges in the map: unbounded.
    Untied,
}

/// The marginal covariances of a map ([`crate::Solution::covariances`]):
/// how well the edges in the map pin each pose down, in the linearised
/// (Laplace) approximation at the map. Holds the factorisation of the
/// normal matrix `H`, its selected inverse (as large as the factor) and the
/// solved graph; queries take `&self` and may come from several threads.
///
/// # What is computed
///
/// `H = Σ JₖᵀΩₖJₖ` is the normal matrix of the edges *in the map* — every
/// trusted edge and every accepted loop candidate, each at weight 1;
/// rejected and gated-out candidates are left out — at the poses
/// [`crate::PoseGraph::optimize`] or [`crate::PoseGraph::update`] returned,
/// undamped (λ = 0), with the Jacobians of the optimiser
/// ([`crate::geometry`]). The poses held fixed (the gauge: those
/// [`crate::PoseGraph::fix`] or a `FIX` line named, else the first pose)
/// are not variables of `H`. The covariance of the free poses is `H⁻¹`:
///
/// * a pose's `D×D` covariance is its diagonal block of `H⁻¹`, read from the
///   *selected inverse* (every block of `H⁻¹` on the pattern of the
///   Cholesky factor of `H`, by Takahashi's recurrence, at about twice the
///   cost of the factorisation and as much memory);
/// * the joint `2D×2D` covariance of two poses also needs their
///   off-diagonal block: read from the selected inverse when it is on the
///   factor's pattern, else continued from it by the same recurrence or, if
///   that would cost more, by a sparse solve with the factor over the two
///   poses' paths to the root of the elimination tree (`2D` right-hand
///   sides), whichever is cheaper;
/// * the covariance of the relative pose `Xₐ⁻¹X_b` is `M·Σ_ab·Mᵀ` with
///   `M = [−Ad(A⁻¹), I]`, `A = Xₐ⁻¹X_b`: to first order `(Xₐ·Δ(δₐ))⁻¹·X_b·Δ(δ_b)
///   = A·Δ(δ_b − Ad(A⁻¹)·δₐ)`.
///
/// # Conventions
///
/// A covariance is over pgo's tangent space at the pose: a perturbed pose
/// is `X·Δ(δ)`, the perturbation on the *right* (in the pose's own frame),
/// `Δ(δ)` the pose with translation `δ_t` and rotation `Exp(δ_r)`, and `δ`
/// orders translation before rotation: `(x, y, θ)` in 2D, `(x, y, z, rx,
/// ry, rz)` in 3D. Units are the graph's (metres, say) for translation and
/// radians for rotation. To first order this is GTSAM's `Pose2` and
/// `Pose3` convention (also a right perturbation), but GTSAM's `Pose3`
/// orders rotation first: swap the two 3×3 halves. A covariance in the
/// world frame (a left perturbation, `Δ·X`) is `Ad(X)·Σ·Ad(X)ᵀ`.
///
/// The gauge: a fixed pose has zero covariance, and every other covariance
/// is relative to the fixed poses (the uncertainty of pose `k` is that of
/// `k` as seen from the first pose, when that is the one fixed). GTSAM
/// usually fixes the gauge with a prior factor instead; with a prior of
/// covariance `Σ₀` on the same pose its marginals are larger by the
/// propagation of `Σ₀` (`Ad(Xₖ⁻¹X₀)·Σ₀·Ad(Xₖ⁻¹X₀)ᵀ` to first order), and
/// they tend to pgo's as `Σ₀ → 0`. Relative covariances do not depend on
/// the gauge.
///
/// A pose that no chain of edges in the map ties to the fixed ones (joined
/// only by rejected loops: the optimiser held it where it was) has an
/// unbounded covariance: asking for it is [`Error::Unbounded`].
///
/// docs/method.md §11 has the equations and how they were checked.
///
/// ```
/// use pgo::nalgebra::Matrix3;
/// use pgo::{Options, PoseGraph2, Se2};
///
/// // Three poses 1 m apart, each step measured with σ = 0.1 m and 0.01 rad.
/// let mut graph = PoseGraph2::new();
/// for k in 0..3 {
///     graph.add_pose(k, Se2::new(k as f64, 0.0, 0.0))?;
/// }
/// let info = Matrix3::from_diagonal(&[100.0, 100.0, 1e4].into());
/// for k in 1..3 {
///     graph.add_edge(k - 1, k, Se2::new(1.0, 0.0, 0.0), info)?;
/// }
/// let solution = graph.optimize(&Options::default())?;
/// let covariances = solution.covariances()?;
/// // Pose 0 is fixed; the variances of x add up along the chain.
/// assert_eq!(covariances.pose(0)?, Matrix3::zeros());
/// let last = covariances.pose(2)?;
/// assert!((last[(0, 0)] - 0.02).abs() < 1e-12);
/// // Its y also inherits the heading's uncertainty 1 m back: 2·0.01 + 1²·10⁻⁴.
/// assert!((last[(1, 1)] - 0.0201).abs() < 1e-12);
/// // Pose 2 seen from pose 1 has the uncertainty of one step.
/// let step = covariances.relative(1, 2)?;
/// assert!((step - Matrix3::from_diagonal(&[0.01, 0.01, 1e-4].into())).abs().max() < 1e-12);
/// # Ok::<(), pgo::Error>(())
/// ```
pub struct Covariances<P: Pose<D>, const D: usize> {
    graph: Arc<Graph<P, D>>,
    place: Vec<Place>,
    system: BlockSystem<D>,
    inverse: SelectedInverse,
    /// Scratch of the sparse solves of joint covariances.
    scratch: Mutex<GroupScratch>,
}

impl<P: Pose<D>, const D: usize> std::fmt::Debug for Covariances<P, D> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Covariances")
            .field("poses", &self.place.len())
            .field("free", &self.system.num_blocks())
            .field("factor_values", &self.system.nnz_factor())
            .finish()
    }
}

/// Whether each edge of `graph` is in the map: trusted edges are, loop
/// candidates as `accepted` says, one flag per candidate in edge order.
/// `None` if the flags are not one per candidate.
pub(crate) fn edges_in_map<P: Pose<D>, const D: usize>(
    graph: &Graph<P, D>,
    accepted: impl IntoIterator<Item = bool>,
) -> Option<Vec<bool>> {
    let mut accepted = accepted.into_iter();
    let in_map = (graph.edges.iter())
        .map(|e| {
            if e.is_candidate() {
                accepted.next()
            } else {
                Some(true)
            }
        })
        .collect::<Option<Vec<bool>>>()?;
    accepted.next().is_none().then_some(in_map)
}

impl<P: Pose<D>, const D: usize> Covariances<P, D> {
    /// Factorises the normal matrix of the edges of `graph` that `in_map`
    /// marks (one flag per edge) at its poses, undamped, on `threads`
    /// threads (0 or 1: the calling thread; as
    /// [`crate::solve::SolveSettings::threads`]), and computes its
    /// selected inverse. Errors: [`SolveError::NotPositiveDefinite`] (the
    /// edges at a pose do not determine it, to rounding),
    /// [`SolveError::Linear`] (threads, memory).
    pub(crate) fn new(
        graph: Arc<Graph<P, D>>,
        in_map: &[bool],
        threads: usize,
    ) -> Result<Self, SolveError> {
        if in_map.len() != graph.edges.len() {
            return Err(SolveError::WeightCount {
                weights: in_map.len(),
                edges: graph.edges.len(),
            });
        }
        let weights: Vec<f64> = in_map.iter().map(|&m| f64::from(u8::from(m))).collect();
        let mut place = vec![Place::Fixed; graph.num_vertices()];
        for v in graph.unconstrained_vertices(Some(&weights)) {
            place[v] = Place::Untied;
        }
        let gauge = graph.gauge();
        let mut vertex_of = Vec::new();
        for (v, p) in place.iter_mut().enumerate() {
            if *p == Place::Fixed && !gauge.contains(&v) {
                *p = Place::Block(vertex_of.len());
                vertex_of.push(v);
            }
        }
        let block = |v: usize| match place[v] {
            Place::Block(b) => Some(b),
            _ => None,
        };
        let pairs: Vec<_> = (graph.edges.iter().zip(in_map))
            .map(|(e, &m)| {
                if m {
                    (block(e.from), block(e.to))
                } else {
                    (None, None)
                }
            })
            .collect();
        let parallelism = Parallelism::new(threads)?;
        let mut system = BlockSystem::new(vertex_of.len(), &pairs, parallelism.clone())?;
        assemble(&graph, in_map, &mut system, &parallelism);
        system.factorize(0.0).map_err(|e| match e {
            LinearError::NotPositiveDefinite { block } => SolveError::NotPositiveDefinite {
                vertex: graph.id(vertex_of[block]),
            },
            other => other.into(),
        })?;
        let inverse = system.selected_inverse();
        Ok(Self {
            graph,
            place,
            system,
            inverse,
            scratch: Mutex::new(GroupScratch::default()),
        })
    }

    /// The `D×D` covariance of the pose with this id (zero for a fixed
    /// pose). Errors: [`Error::UnknownVertex`], [`Error::Unbounded`].
    pub fn pose(&self, id: VertexId) -> Result<SMatrix<f64, D, D>, Error> {
        match self.place_of(id)? {
            Place::Block(b) => self.diagonal(b),
            Place::Fixed => Ok(SMatrix::zeros()),
            Place::Untied => Err(Error::Unbounded { id }),
        }
    }

    /// Every pose's covariance with its id, in the graph's order (that of
    /// [`crate::Solution::poses`]); an item is [`Error::Unbounded`] for a
    /// pose the map does not tie to the fixed ones.
    pub fn iter(
        &self,
    ) -> impl ExactSizeIterator<Item = (VertexId, Result<SMatrix<f64, D, D>, Error>)> + '_ {
        self.place.iter().enumerate().map(|(v, &p)| {
            let id = self.graph.id(v);
            let covariance = match p {
                Place::Block(b) => self.diagonal(b),
                Place::Fixed => Ok(SMatrix::zeros()),
                Place::Untied => Err(Error::Unbounded { id }),
            };
            (id, covariance)
        })
    }

    /// The joint `2D×2D` covariance of poses `a` and `b`: `[[Σ_aa, Σ_ab],
    /// [Σ_ba, Σ_bb]]` (rows and columns of a fixed pose are zero). Errors
    /// as [`Covariances::pose`].
    pub fn joint(&self, a: VertexId, b: VertexId) -> Result<DMatrix<f64>, Error> {
        let identity = SMatrix::<f64, D, D>::identity();
        let (pa, pb) = (self.free_block(a)?, self.free_block(b)?);
        let rows = [
            [(pa, identity), (None, identity)],
            [(pb, identity), (None, identity)],
        ];
        Ok(self.gram(&rows))
    }

    /// The `D×D` covariance of the pose of `b` relative to `a`, `Xₐ⁻¹X_b`,
    /// in the tangent space of that relative pose (perturbed on the right,
    /// as every pose here): the uncertainty of `b` as seen from `a`, which
    /// does not depend on the gauge. Errors as [`Covariances::pose`].
    pub fn relative(&self, a: VertexId, b: VertexId) -> Result<SMatrix<f64, D, D>, Error> {
        let (pa, pb) = (self.free_block(a)?, self.free_block(b)?);
        let (xa, xb) = (self.pose_at(a)?, self.pose_at(b)?);
        let row = [(pa, -inverse_adjoint(xa, xb)), (pb, SMatrix::identity())];
        let gram = self.gram(&[row]);
        Ok(SMatrix::from_fn(|r, c| gram[(r, c)]))
    }

    /// The ids of the poses, in the graph's order.
    pub fn ids(&self) -> &[VertexId] {
        self.graph.ids()
    }

    /// Number of poses (fixed ones included).
    pub fn len(&self) -> usize {
        self.place.len()
    }

    /// Whether there are no poses.
    pub fn is_empty(&self) -> bool {
        self.place.is_empty()
    }

    /// The values of the Cholesky factor of `H` (the selected inverse
    /// holds as many): the memory the covariances take, 8 bytes each,
    /// twice.
    pub fn factor_values(&self) -> usize {
        self.system.nnz_factor()
    }

    /// Where the pose with this id is.
    fn place_of(&self, id: VertexId) -> Result<Place, Error> {
        let v = (self.graph.index_of(id)).ok_or(Error::UnknownVertex { id })?;
        Ok(self.place[v])
    }

    /// The variable block of pose `id`, `None` for a fixed pose.
    fn free_block(&self, id: VertexId) -> Result<Option<usize>, Error> {
        match self.place_of(id)? {
            Place::Block(b) => Ok(Some(b)),
            Place::Fixed => Ok(None),
            Place::Untied => Err(Error::Unbounded { id }),
        }
    }

    /// The optimised pose with this id (known to exist).
    fn pose_at(&self, id: VertexId) -> Result<&P, Error> {
        let v = (self.graph.index_of(id)).ok_or(Error::UnknownVertex { id })?;
        Ok(&self.graph.poses[v])
    }

    /// Block `b`'s diagonal block of `H⁻¹`, from the selected inverse
    /// (where every diagonal block is).
    fn diagonal(&self, b: usize) -> Result<SMatrix<f64, D, D>, Error> {
        let identity = SMatrix::<f64, D, D>::identity();
        let block = (self.system)
            .propagate_selected(&self.inverse, Some(b), &identity, None, &identity)
            .ok_or_else(|| Error::Internal("a diagonal block off the factor's pattern".into()))?;
        Ok((block + block.transpose()) * 0.5)
    }

    /// `A·H⁻¹·Aᵀ` for the rows `A` (each `D` rows, nonzero on two blocks
    /// at most), by the cheaper of the selected inverse's recurrence and
    /// the sparse solve.
    fn gram(&self, rows: &[crate::linear::EdgeJacobian<D>]) -> DMatrix<f64> {
        // The kept scratch, or (another thread is using it) one of this
        // call's own: queries from several threads do not wait.
        let mut own = GroupScratch::default();
        let mut kept = match self.scratch.try_lock() {
            Ok(guard) => Some(guard),
            Err(TryLockError::Poisoned(poisoned)) => Some(poisoned.into_inner()),
            Err(TryLockError::WouldBlock) => None,
        };
        let scratch = kept.as_deref_mut().unwrap_or(&mut own);
        (self.system).propagate_group_cheaper(&self.inverse, rows, scratch)
    }
}

/// `Ad(A⁻¹)` of `A = Xₐ⁻¹X_b` in the tangent convention of the module: the
/// change of `A` under a right perturbation `δₐ` of `Xₐ` is that under
/// `−Ad(A⁻¹)·δₐ` of `X_b`. Read off the Jacobians of an edge `a → b` whose
/// measurement is `A` itself (zero error), where `J_a = −J_b·Ad(A⁻¹)` and
/// `J_b` is invertible (the identity in 2D, `diag(I, ½I)` in 3D).
fn inverse_adjoint<P: Pose<D>, const D: usize>(xa: &P, xb: &P) -> SMatrix<f64, D, D> {
    let a = xa.inverse().compose(xb);
    let lin = P::error_and_jacobians(xa, xb, &a);
    // J_b is a rotation (or half a rotation, and ½·w ≥ ½·cos(π/4) with an
    // error of rounding size): never singular here.
    let jb_inv = lin.jac_j.try_inverse().unwrap_or_else(SMatrix::identity);
    -(jb_inv * lin.jac_i)
}

/// Assembles `H` of the edges in the map at the graph's poses into
/// `system`, a batch of edges at a time, each batch linearised on the
/// threads of `parallelism`.
fn assemble<P: Pose<D>, const D: usize>(
    graph: &Graph<P, D>,
    in_map: &[bool],
    system: &mut BlockSystem<D>,
    parallelism: &Parallelism,
) {
    system.clear();
    let prepared: Vec<P::Prepared> = graph.poses.iter().map(Pose::prepare).collect();
    let edges: Vec<usize> = (0..graph.edges.len()).collect();
    for (c, chunk) in edges.chunks(LINEARIZE_CHUNK).enumerate() {
        let terms: Vec<Option<NormalBlocks<D>>> =
            parallelism.map_runs(chunk, EDGES_PER_TASK, |&k| {
                let e = &graph.edges[k];
                in_map[k].then(|| {
                    let z = e.measurement.prepare();
                    let (xi, xj) = (&prepared[e.from], &prepared[e.to]);
                    P::normal_blocks_prepared(xi, xj, &z, &e.information)
                })
            });
        system.add_edges(c * LINEARIZE_CHUNK, &terms, Option::as_ref);
    }
}
