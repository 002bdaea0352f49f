//! The simulator's working graph: vertices by index, edges between
//! indices, each edge's candidate flag open to change. Simulation and
//! corruption build and edit it; it becomes a [`PoseGraph`] (the library's
//! checks, its g2o writer) only when it is done.

use crate::SimulationError;
use nalgebra::SMatrix;
use pgo::{GraphPose, Pose, PoseGraph, VertexId};
use rustc_hash::FxHashMap;

/// A loop-closure candidate's mark on an edge: its inlier count, if any.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LoopCandidate {
    /// The RANSAC inlier count of its verification.
    pub inliers: Option<u64>,
}

/// An edge between vertex indices.
#[derive(Clone, Debug, PartialEq)]
pub struct Edge<P, const D: usize> {
    /// Index of the vertex the measurement is taken from.
    pub from: usize,
    /// Index of the vertex it measures.
    pub to: usize,
    /// The pose of `to` in the frame of `from`.
    pub measurement: P,
    /// Its information matrix.
    pub information: SMatrix<f64, D, D>,
    /// `Some` for a loop-closure candidate, `None` for a trusted edge.
    pub candidate: Option<LoopCandidate>,
}

/// Poses by index with their ids, and edges between indices.
#[derive(Clone, Debug)]
pub struct Graph<P, const D: usize> {
    ids: Vec<VertexId>,
    index: FxHashMap<VertexId, usize>,
    /// The pose of every vertex, by index.
    pub poses: Vec<P>,
    /// The edges, in order.
    pub edges: Vec<Edge<P, D>>,
    /// The ids held fixed, kept for the graph made at the end.
    fixed: Vec<VertexId>,
}

impl<P: Pose<D>, const D: usize> Graph<P, D> {
    /// An empty graph.
    pub fn new() -> Self {
        Self {
            ids: Vec::new(),
            index: FxHashMap::default(),
            poses: Vec::new(),
            edges: Vec::new(),
            fixed: Vec::new(),
        }
    }
    /// Adds a vertex (ids are the simulator's own, distinct) and returns
    /// its index.
    pub fn add_vertex(&mut self, id: VertexId, pose: P) -> usize {
        let k = self.ids.len();
        self.ids.push(id);
        self.index.insert(id, k);
        self.poses.push(pose);
        k
    }

    /// Adds an edge between the vertices with these ids (which exist).
    pub fn add_edge(
        &mut self,
        from: VertexId,
        to: VertexId,
        measurement: P,
        information: SMatrix<f64, D, D>,
        candidate: Option<LoopCandidate>,
    ) {
        let (from, to) = (self.index[&from], self.index[&to]);
        self.edges.push(Edge {
            from,
            to,
            measurement,
            information,
            candidate,
        });
    }

    /// Number of vertices.
    #[cfg(test)]
    pub fn num_vertices(&self) -> usize {
        self.ids.len()
    }

    /// Number of loop-closure candidates.
    #[cfg(test)]
    pub fn num_candidates(&self) -> usize {
        self.edges.iter().filter(|e| e.candidate.is_some()).count()
    }

    /// The id of the vertex at this index.
    pub fn id(&self, index: usize) -> VertexId {
        self.ids[index]
    }

    /// The ids, by index.
    pub fn ids(&self) -> &[VertexId] {
        &self.ids
    }
}

impl<P: GraphPose<D>, const D: usize> Graph<P, D> {
    /// The working copy of a library graph, every vertex of which has a
    /// pose ([`PoseGraph::compose_missing_poses`]); else
    /// [`SimulationError::MissingPose`].
    pub fn of(graph: &PoseGraph<P, D>) -> Result<Self, SimulationError> {
        let mut g = Self::new();
        for &id in graph.ids() {
            let pose = graph.pose(id).ok_or(SimulationError::MissingPose { id })?;
            g.add_vertex(id, *pose);
        }
        for e in graph.edges() {
            let candidate = e
                .loop_candidate
                .then_some(LoopCandidate { inliers: e.inliers });
            let (from, to) = (g.index[&e.from], g.index[&e.to]);
            g.edges.push(Edge {
                from,
                to,
                measurement: e.measurement,
                information: e.information,
                candidate,
            });
        }
        g.fixed = graph.fixed();
        Ok(g)
    }

    /// The library's graph of the same poses, edges and fixed poses, built
    /// call by call (and so checked).
    pub fn to_pose_graph(&self) -> Result<PoseGraph<P, D>, pgo::Error> {
        let mut graph = PoseGraph::new();
        for (&id, pose) in self.ids.iter().zip(&self.poses) {
            graph.add_pose(id, *pose)?;
        }
        for e in &self.edges {
            let (from, to) = (self.ids[e.from], self.ids[e.to]);
            match e.candidate {
                None => graph.add_edge(from, to, e.measurement, e.information)?,
                Some(c) => {
                    graph.add_loop_candidate(from, to, e.measurement, e.information, c.inliers)?
                }
            };
        }
        for &id in &self.fixed {
            graph.fix(id)?;
        }
        Ok(graph)
    }
}
