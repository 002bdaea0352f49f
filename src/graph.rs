//! The pose graph: vertices (poses with external ids), edges (relative-pose
//! measurements with information matrices), which edges are trusted and
//! which are loop-closure candidates, and the gauge.

use crate::geometry::{Pose, Se2, Se3};
use nalgebra::{DMatrix, SMatrix, SymmetricEigen};
use std::collections::HashMap;

/// The id of a vertex as written in the file.
pub type VertexId = u64;

/// A loop-closure candidate: an edge whose correctness is in doubt, with the
/// RANSAC inlier count of its geometric verification when one is known.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LoopCandidate {
    /// Inlier count of the geometric verification, if the front end gave one.
    pub inliers: Option<u64>,
}

/// A relative-pose measurement between two vertices, by their indices: the
/// solver's form of a [`crate::Edge`].
#[derive(Clone, Debug, PartialEq)]
pub struct IndexedEdge<P, const D: usize> {
    /// Index (not id) of the first vertex.
    pub from: usize,
    /// Index (not id) of the second vertex.
    pub to: usize,
    /// The measured pose of `to` in the frame of `from`.
    pub measurement: P,
    /// Information matrix (inverse covariance), in the error's coordinates.
    pub information: SMatrix<f64, D, D>,
    /// `Some` for a loop-closure candidate, `None` for a trusted edge
    /// (odometry, prior, verified loop).
    pub candidate: Option<LoopCandidate>,
}

impl<P: Pose<D>, const D: usize> IndexedEdge<P, D> {
    /// Whether this edge is a loop-closure candidate.
    pub fn is_candidate(&self) -> bool {
        self.candidate.is_some()
    }
}

/// Errors from building a graph.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum GraphError {
    /// Two vertices with the same id.
    #[error("duplicate vertex id {0}")]
    DuplicateVertex(VertexId),
    /// An edge or a FIX names a vertex that does not exist.
    #[error("unknown vertex id {0}")]
    UnknownVertex(VertexId),
    /// An edge from a vertex to itself.
    #[error("edge from vertex {0} to itself")]
    SelfLoop(VertexId),
}

/// A pose graph over poses `P` with `D` degrees of freedom.
#[derive(Clone, Debug, Default)]
pub struct Graph<P, const D: usize> {
    ids: Vec<VertexId>,
    /// The current estimate of every vertex, by index.
    pub poses: Vec<P>,
    index: HashMap<VertexId, usize>,
    /// All edges, in insertion (file) order.
    pub edges: Vec<IndexedEdge<P, D>>,
    fixed: Vec<bool>,
}

/// A planar pose graph.
pub type Graph2 = Graph<Se2, 3>;
/// A spatial pose graph.
pub type Graph3 = Graph<Se3, 6>;

impl<P: Pose<D>, const D: usize> Graph<P, D> {
    /// An empty graph.
    pub fn new() -> Self {
        Self {
            ids: Vec::new(),
            poses: Vec::new(),
            index: HashMap::new(),
            edges: Vec::new(),
            fixed: Vec::new(),
        }
    }

    /// The first edge whose information matrix has a diagonal entry
    /// outside [`INFORMATION_RANGE`]: its vertex ids, the entry's index
    /// and its value.
    pub fn information_out_of_range(&self) -> Option<(VertexId, VertexId, usize, f64)> {
        self.edges.iter().find_map(|e| {
            information_out_of_range(&e.information)
                .map(|(index, value)| (self.id(e.from), self.id(e.to), index, value))
        })
    }

    /// Adds a vertex and returns its index.
    pub fn add_vertex(&mut self, id: VertexId, pose: P) -> Result<usize, GraphError> {
        match self.vertex_or_insert(id, pose) {
            (k, true) => Ok(k),
            (_, false) => Err(GraphError::DuplicateVertex(id)),
        }
    }

    /// The index of vertex `id`, adding it with `pose` if it is new; the flag
    /// says whether it was added.
    pub fn vertex_or_insert(&mut self, id: VertexId, pose: P) -> (usize, bool) {
        match self.index.get(&id) {
            Some(&k) => (k, false),
            None => {
                let k = self.ids.len();
                self.ids.push(id);
                self.poses.push(pose);
                self.fixed.push(false);
                self.index.insert(id, k);
                (k, true)
            }
        }
    }

    /// Renumbers the vertices: the vertex at index `order[k]` moves to index
    /// `k`. `order` must be a permutation of `0..num_vertices()`. Returns the
    /// map from old to new index.
    pub fn reorder_vertices(&mut self, order: &[usize]) -> Vec<usize> {
        let n = self.ids.len();
        debug_assert_eq!(order.len(), n);
        let mut new_index = vec![0usize; n];
        for (k, &old) in order.iter().enumerate() {
            new_index[old] = k;
        }
        self.ids = order.iter().map(|&o| self.ids[o]).collect();
        self.poses = order.iter().map(|&o| self.poses[o]).collect();
        self.fixed = order.iter().map(|&o| self.fixed[o]).collect();
        for (k, id) in self.ids.iter().enumerate() {
            self.index.insert(*id, k);
        }
        for e in &mut self.edges {
            e.from = new_index[e.from];
            e.to = new_index[e.to];
        }
        new_index
    }

    /// Adds an edge between two existing vertices (by id) and returns its index.
    pub fn add_edge(
        &mut self,
        from: VertexId,
        to: VertexId,
        measurement: P,
        information: SMatrix<f64, D, D>,
        candidate: Option<LoopCandidate>,
    ) -> Result<usize, GraphError> {
        if from == to {
            return Err(GraphError::SelfLoop(from));
        }
        let f = self.index_of(from).ok_or(GraphError::UnknownVertex(from))?;
        let t = self.index_of(to).ok_or(GraphError::UnknownVertex(to))?;
        self.edges.push(IndexedEdge {
            from: f,
            to: t,
            measurement,
            information,
            candidate,
        });
        Ok(self.edges.len() - 1)
    }

    /// For each vertex pair `(a, b)` in turn, the next edge between them —
    /// from `a` to `b`, else from `b` to `a` — in the order edges were
    /// added, each edge given once. `Err(k)`: pair `k` has no (further)
    /// edge.
    pub fn edges_of_pairs(
        &self,
        pairs: impl IntoIterator<Item = (VertexId, VertexId)>,
    ) -> Result<Vec<usize>, usize> {
        let mut by_pair: HashMap<(VertexId, VertexId), Vec<usize>> = HashMap::new();
        for (k, e) in self.edges.iter().enumerate().rev() {
            (by_pair.entry((self.id(e.from), self.id(e.to))).or_default()).push(k);
        }
        let mut next = |a, b| by_pair.get_mut(&(a, b)).and_then(Vec::pop);
        (pairs.into_iter().enumerate())
            .map(|(k, (a, b))| next(a, b).or_else(|| next(b, a)).ok_or(k))
            .collect()
    }

    /// Number of vertices.
    pub fn num_vertices(&self) -> usize {
        self.ids.len()
    }

    /// The map's size: the diagonal of the bounding box of its positions
    /// (0 for none).
    pub fn extent(&self) -> f64 {
        let mut bounds: Option<(nalgebra::Vector3<f64>, nalgebra::Vector3<f64>)> = None;
        for p in self.poses.iter().map(Pose::position) {
            bounds = Some(match bounds {
                None => (p, p),
                Some((lo, hi)) => (lo.inf(&p), hi.sup(&p)),
            });
        }
        bounds.map_or(0.0, |(lo, hi)| (hi - lo).norm())
    }

    /// The index of the vertex with this id.
    pub fn index_of(&self, id: VertexId) -> Option<usize> {
        self.index.get(&id).copied()
    }

    /// The id of the vertex at this index.
    pub fn id(&self, index: usize) -> VertexId {
        self.ids[index]
    }

    /// All vertex ids, by index.
    pub fn ids(&self) -> &[VertexId] {
        &self.ids
    }

    /// Holds a vertex fixed (part of the gauge).
    pub fn fix(&mut self, id: VertexId) -> Result<(), GraphError> {
        let k = self.index_of(id).ok_or(GraphError::UnknownVertex(id))?;
        self.fixed[k] = true;
        Ok(())
    }

    /// Whether the vertex at this index was fixed explicitly.
    pub fn is_fixed(&self, index: usize) -> bool {
        self.fixed[index]
    }

    /// The vertices held fixed while optimising: those fixed explicitly, or
    /// else the first vertex. Empty only for an empty graph.
    pub fn gauge(&self) -> Vec<usize> {
        let fixed: Vec<usize> = (0..self.ids.len()).filter(|&k| self.fixed[k]).collect();
        if fixed.is_empty() && !self.ids.is_empty() {
            vec![0]
        } else {
            fixed
        }
    }

    /// Number of loop-closure candidates.
    pub fn num_candidates(&self) -> usize {
        self.edges.iter().filter(|e| e.is_candidate()).count()
    }

    /// The error of one edge at the current estimate.
    pub fn edge_error(&self, edge: &IndexedEdge<P, D>) -> nalgebra::SVector<f64, D> {
        P::error(
            &self.poses[edge.from],
            &self.poses[edge.to],
            &edge.measurement,
        )
    }

    /// `eᵀΩe` of one edge at the current estimate.
    pub fn edge_chi2(&self, edge: &IndexedEdge<P, D>) -> f64 {
        let e = self.edge_error(edge);
        e.dot(&(edge.information * e))
    }

    /// `Σ eᵀΩe` over all edges (g2o's χ²).
    pub fn chi2(&self) -> f64 {
        self.chi2_where(|_| true)
    }

    /// `Σ eᵀΩe` over the edges `k` for which `keep(k)`, each pose prepared
    /// once (the same sum, bit for bit, as adding [`Self::edge_chi2`] in
    /// edge order).
    pub fn chi2_where(&self, keep: impl Fn(usize) -> bool) -> f64 {
        // Folded from +0 (`sum` starts from -0, which an edgeless graph
        // would report as "-0").
        self.chi2s(keep).fold(0.0, |a, b| a + b)
    }

    /// Each edge's `eᵀΩe`, each pose prepared once (summed in edge order
    /// from +0, the same bits as [`Self::chi2_where`]).
    pub fn edge_chi2s(&self) -> Vec<f64> {
        self.chi2s(|_| true).collect()
    }

    /// `eᵀΩe` of the edges `k` for which `keep(k)`, in edge order, each pose
    /// prepared once.
    fn chi2s(&self, keep: impl Fn(usize) -> bool) -> impl Iterator<Item = f64> {
        let prepared: Vec<P::Prepared> = self.poses.iter().map(|p| p.prepare()).collect();
        (self.edges.iter().enumerate())
            .filter(move |&(k, _)| keep(k))
            .map(move |(_, e)| {
                let z = e.measurement.prepare();
                let r = P::error_prepared(&prepared[e.from], &prepared[e.to], &z);
                r.dot(&(e.information * r))
            })
    }

    /// The vertices that no chain of edges connects to the gauge, by index,
    /// in increasing order. A non-empty result means the problem has no
    /// unique solution. Edges whose weight (one per edge) is zero do not
    /// count.
    pub fn unconstrained_vertices(&self, weights: Option<&[f64]>) -> Vec<usize> {
        let mut parts = self.parts(|k| weights.is_none_or(|w| w[k] != 0.0));
        let Some(&anchor) = self.gauge().first() else {
            return Vec::new();
        };
        let anchor = parts.find(anchor);
        (0..self.ids.len())
            .filter(|&k| parts.find(k) != anchor)
            .collect()
    }

    /// The parts of the graph that the edges `joins` accepts (by index)
    /// make, the gauge's vertices counted as one part: union–find, one
    /// array, where lists of neighbours would allocate one vector per
    /// vertex.
    pub(crate) fn parts(&self, joins: impl Fn(usize) -> bool) -> UnionFind {
        let mut parts = UnionFind::new(self.ids.len());
        let gauge = self.gauge();
        gauge.windows(2).for_each(|w| {
            parts.union(w[0], w[1]);
        });
        for (k, e) in self.edges.iter().enumerate() {
            if joins(k) {
                parts.union(e.from, e.to);
            }
        }
        parts
    }
}

/// A pose graph of either dimension, as read from a file.
#[derive(Clone, Debug)]
pub enum AnyGraph {
    /// SE(2).
    Planar(Graph2),
    /// SE(3).
    Spatial(Graph3),
}

impl AnyGraph {
    /// 2 or 3.
    pub fn dimension(&self) -> usize {
        match self {
            Self::Planar(_) => 2,
            Self::Spatial(_) => 3,
        }
    }

    /// Number of vertices.
    pub fn num_vertices(&self) -> usize {
        match self {
            Self::Planar(g) => g.num_vertices(),
            Self::Spatial(g) => g.num_vertices(),
        }
    }

    /// Number of edges.
    pub fn num_edges(&self) -> usize {
        match self {
            Self::Planar(g) => g.edges.len(),
            Self::Spatial(g) => g.edges.len(),
        }
    }

    /// Number of loop-closure candidates.
    pub fn num_candidates(&self) -> usize {
        match self {
            Self::Planar(g) => g.num_candidates(),
            Self::Spatial(g) => g.num_candidates(),
        }
    }

    /// `Σ eᵀΩe` over all edges.
    pub fn chi2(&self) -> f64 {
        match self {
            Self::Planar(g) => g.chi2(),
            Self::Spatial(g) => g.chi2(),
        }
    }
}

/// The diagonal entries of an information matrix pgo computes with; a
/// matrix with one outside is refused where it enters the job (added, or
/// read for a job, naming the edge), not left to fail later as an
/// undetermined pose or loops rejected for no reason.
///
/// Derivation: a 2D edge's 3×3 covariance is inverted through its
/// determinant, at most the product of the diagonal (Hadamard) and about
/// the cube of the entries' scale. Entries within 10^±100 keep it within
/// 10^±300, inside f64's normal range (2.2·10⁻³⁰⁸ to 1.8·10³⁰⁸), with
/// 10⁸ to spare for the products with lever arms and weights; measured,
/// the job on the bundled samples with their information scaled breaks
/// beyond 10^±103 (2D) and gives the same decisions within. Real
/// sensors' information (1/σ²) lies within 10^±20.
pub const INFORMATION_RANGE: std::ops::RangeInclusive<f64> = 1e-100..=1e100;

/// The first diagonal entry of `m` outside [`INFORMATION_RANGE`]: its
/// index and value.
pub fn information_out_of_range<const D: usize>(m: &SMatrix<f64, D, D>) -> Option<(usize, f64)> {
    (0..D)
        .map(|k| (k, m[(k, k)]))
        .find(|(_, v)| !INFORMATION_RANGE.contains(v))
}

/// Whether a symmetric matrix is positive definite (Cholesky succeeds and
/// every entry is finite).
pub fn is_positive_definite<const D: usize>(m: &SMatrix<f64, D, D>) -> bool {
    m.iter().all(|v| v.is_finite()) && m.cholesky().is_some()
}

/// The smallest eigenvalue of a symmetric matrix (NaN if the bounded
/// eigen-solver fails), for messages about information that is not
/// positive definite.
pub fn min_eigenvalue<const D: usize>(m: &SMatrix<f64, D, D>) -> f64 {
    let d = DMatrix::from_column_slice(D, D, m.as_slice());
    SymmetricEigen::try_new(d, f64::EPSILON, 10_000).map_or(f64::NAN, |e| {
        e.eigenvalues.iter().copied().fold(f64::INFINITY, f64::min)
    })
}

/// The nearest positive-definite matrix in the spectral sense: eigenvalues
/// below `1e-6 · max|λ|` are raised to it (as `repair_info.py` of the
/// baseline does). Returns `None` when every eigenvalue is zero, or the
/// matrix (or its eigen-decomposition) is not finite.
pub fn nearest_positive_definite<const D: usize>(
    m: &SMatrix<f64, D, D>,
) -> Option<SMatrix<f64, D, D>> {
    if !m.iter().all(|v| v.is_finite()) {
        return None;
    }
    let sym = (m + m.transpose()) * 0.5;
    // Dynamic storage: nalgebra's eigen-solver is not generic over `Const<D>`.
    // Bounded iterations: an unbounded eigen-solver could spin forever on
    // entries so large that its intermediate values overflow.
    let eig = SymmetricEigen::try_new(
        DMatrix::from_column_slice(D, D, sym.as_slice()),
        f64::EPSILON,
        10_000,
    )?;
    if !eig.eigenvalues.iter().all(|v| v.is_finite()) {
        return None;
    }
    let max_abs = eig.eigenvalues.iter().fold(0.0f64, |a, v| a.max(v.abs()));
    if max_abs == 0.0 {
        return None;
    }
    let floor = 1e-6 * max_abs;
    let clamped = eig.eigenvalues.map(|v| v.max(floor));
    let out = &eig.eigenvectors * DMatrix::from_diagonal(&clamped) * eig.eigenvectors.transpose();
    let out = SMatrix::<f64, D, D>::from_column_slice(out.as_slice());
    let out = (out + out.transpose()) * 0.5;
    is_positive_definite(&out).then_some(out)
}

/// Disjoint sets of `0..n` (union–find with path halving), each named by
/// its smallest member: the connected parts of a graph in one array.
#[derive(Clone, Debug)]
pub struct UnionFind {
    parent: Vec<usize>,
}

impl UnionFind {
    /// `n` singletons.
    pub fn new(n: usize) -> Self {
        Self {
            parent: (0..n).collect(),
        }
    }

    /// The smallest member of the set of `k`.
    pub fn find(&mut self, mut k: usize) -> usize {
        let parent = &mut self.parent;
        while parent[k] != k {
            parent[k] = parent[parent[k]];
            k = parent[k];
        }
        k
    }

    /// Joins the sets of `a` and `b`; whether they were apart.
    pub fn union(&mut self, a: usize, b: usize) -> bool {
        let (ra, rb) = (self.find(a), self.find(b));
        if ra != rb {
            self.parent[ra.max(rb)] = ra.min(rb);
        }
        ra != rb
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Matrix3;

    fn line_graph(n: u64) -> Graph2 {
        let mut g = Graph2::new();
        for k in 0..n {
            g.add_vertex(k, Se2::new(k as f64, 0.0, 0.0)).unwrap();
        }
        for k in 1..n {
            g.add_edge(k - 1, k, Se2::new(1.0, 0.0, 0.0), Matrix3::identity(), None)
                .unwrap();
        }
        g
    }

    #[test]
    fn the_extent_is_the_bounding_box_diagonal() {
        let mut g = Graph2::new();
        assert_eq!(g.extent(), 0.0);
        for (k, (x, y)) in [(0.0, 0.0), (3.0, -1.0), (1.0, 3.0)]
            .into_iter()
            .enumerate()
        {
            g.add_vertex(k as u64, Se2::new(x, y, 0.5)).unwrap();
        }
        assert!((g.extent() - 5.0).abs() < 1e-12);
    }

    #[test]
    fn rejects_duplicates_self_loops_and_unknown_ids() {
        let mut g = line_graph(3);
        assert_eq!(
            g.add_vertex(1, Se2::identity()),
            Err(GraphError::DuplicateVertex(1))
        );
        let i = Matrix3::identity();
        assert_eq!(
            g.add_edge(2, 2, Se2::identity(), i, None),
            Err(GraphError::SelfLoop(2))
        );
        assert_eq!(
            g.add_edge(2, 9, Se2::identity(), i, None),
            Err(GraphError::UnknownVertex(9))
        );
        assert_eq!(g.fix(7), Err(GraphError::UnknownVertex(7)));
    }

    #[test]
    fn gauge_is_first_vertex_unless_fixed() {
        let mut g = line_graph(4);
        assert_eq!(g.gauge(), vec![0]);
        g.fix(2).unwrap();
        assert_eq!(g.gauge(), vec![2]);
    }

    #[test]
    fn finds_vertices_disconnected_from_the_gauge() {
        let mut g = line_graph(3);
        g.add_vertex(10, Se2::identity()).unwrap();
        g.add_vertex(11, Se2::identity()).unwrap();
        g.add_edge(10, 11, Se2::identity(), Matrix3::identity(), None)
            .unwrap();
        g.add_vertex(12, Se2::identity()).unwrap();
        let ids: Vec<_> = g
            .unconstrained_vertices(None)
            .iter()
            .map(|&k| g.id(k))
            .collect();
        assert_eq!(ids, vec![10, 11, 12]);
    }

    #[test]
    fn zero_weights_cut_and_every_fixed_vertex_anchors_its_part() {
        // 0-1-2-3 in a line, 4-5 joined to it by edge 5 (5 → 2) and to
        // nothing else; 6 alone, fixed.
        let mut g = line_graph(4);
        let i = Matrix3::identity();
        for k in 4..7 {
            g.add_vertex(k, Se2::identity()).unwrap();
        }
        g.add_edge(4, 5, Se2::identity(), i, None).unwrap();
        g.add_edge(5, 2, Se2::identity(), i, None).unwrap();
        let mut w = vec![1.0; g.edges.len()];
        assert_eq!(g.unconstrained_vertices(Some(&w)), vec![6]);
        w[1] = 0.0; // 1-2 cut: 2, 3, 4 and 5 hang from nothing
        assert_eq!(g.unconstrained_vertices(Some(&w)), vec![2, 3, 4, 5, 6]);
        g.fix(6).unwrap(); // the gauge is the fixed vertices only
        assert_eq!(g.unconstrained_vertices(Some(&w)), vec![0, 1, 2, 3, 4, 5]);
        g.fix(4).unwrap();
        assert_eq!(g.unconstrained_vertices(Some(&w)), vec![0, 1]);
        assert!(g.unconstrained_vertices(None).is_empty());
    }

    #[test]
    fn reorder_keeps_edges_attached_to_their_ids() {
        let mut g = line_graph(4);
        let before: Vec<(u64, u64)> = g.edges.iter().map(|e| (g.id(e.from), g.id(e.to))).collect();
        let map = g.reorder_vertices(&[3, 1, 0, 2]);
        assert_eq!(map, vec![2, 1, 3, 0]);
        assert_eq!(g.ids(), &[3, 1, 0, 2]);
        assert_eq!(g.poses[0].x, 3.0);
        assert_eq!(g.index_of(2), Some(3));
        let after: Vec<(u64, u64)> = g.edges.iter().map(|e| (g.id(e.from), g.id(e.to))).collect();
        assert_eq!(before, after);
    }

    #[test]
    fn chi2_counts_every_edge() {
        let mut g = line_graph(3);
        g.poses[2] = Se2::new(3.0, 0.0, 0.0);
        assert!((g.chi2() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn projects_indefinite_information_to_positive_definite() {
        let m = Matrix3::new(10.0, 0.0, 84022.0, 0.0, 10.0, 0.0, 84022.0, 0.0, 10.0);
        assert!(!is_positive_definite(&m));
        let p = nearest_positive_definite(&m).unwrap();
        assert!(is_positive_definite(&p));
        // The positive eigen-direction is kept.
        assert!((p[(0, 2)] - 42016.0).abs() < 1.0);
        assert!(nearest_positive_definite(&Matrix3::zeros()).is_none());
    }
}
