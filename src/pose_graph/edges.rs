//! Reading a [`PoseGraph`] back: its edges as they are held, the poses it
//! holds fixed, and poses for the vertices a file named without a vertex
//! line. For tools built on the library (the simulator of `pgo simulate`
//! and `pgo corrupt`, converters, checks) that take a graph apart.

use super::{GraphPose, PoseGraph};
use crate::graph::VertexId;
use crate::solve::init::{Initialization, initialize};
use nalgebra::SMatrix;

/// One edge of a [`PoseGraph`] as the graph holds it (a copy): the pose of
/// `to` in the frame of `from` is `measurement`, with `information` over
/// the error coordinates (symmetric, as [`PoseGraph::add_edge`] keeps it).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Edge<P, const D: usize> {
    /// The id of the vertex the measurement is taken from.
    pub from: VertexId,
    /// The id of the vertex it measures.
    pub to: VertexId,
    /// The pose of `to` in the frame of `from`.
    pub measurement: P,
    /// The inverse covariance of the measurement.
    pub information: SMatrix<f64, D, D>,
    /// Whether it is a loop-closure candidate (added by
    /// [`PoseGraph::add_loop_candidate`], or read with an inlier count)
    /// rather than a trusted edge.
    pub loop_candidate: bool,
    /// The candidate's inlier count, if it has one (`None` for trusted
    /// edges).
    pub inliers: Option<u64>,
}

impl<P: GraphPose<D>, const D: usize> PoseGraph<P, D> {
    /// The edges, loop candidates included, in the order they were added
    /// (read): the `k`-th is the edge whose index
    /// [`PoseGraph::add_edge`] or [`PoseGraph::add_loop_candidate`]
    /// returned `k`.
    ///
    /// ```
    /// use pgo::nalgebra::Matrix3;
    /// use pgo::{PoseGraph2, Se2};
    ///
    /// let mut graph = PoseGraph2::new();
    /// for k in 0..3 {
    ///     graph.add_pose(k, Se2::new(k as f64, 0.0, 0.0))?;
    /// }
    /// graph.add_edge(0, 1, Se2::new(1.0, 0.0, 0.0), Matrix3::identity())?;
    /// graph.add_loop_candidate(0, 2, Se2::new(2.0, 0.0, 0.0), Matrix3::identity(), Some(80))?;
    /// let edges: Vec<_> = graph.edges().collect();
    /// assert_eq!((edges[0].from, edges[0].to, edges[0].loop_candidate), (0, 1, false));
    /// assert_eq!((edges[1].to, edges[1].inliers), (2, Some(80)));
    /// # Ok::<(), pgo::Error>(())
    /// ```
    pub fn edges(&self) -> impl ExactSizeIterator<Item = Edge<P, D>> + '_ {
        self.graph.edges.iter().map(|e| self.view(e))
    }

    /// The edge with this index ([`PoseGraph::edges`]), or `None`.
    pub fn edge(&self, index: usize) -> Option<Edge<P, D>> {
        self.graph.edges.get(index).map(|e| self.view(e))
    }

    fn view(&self, e: &crate::graph::IndexedEdge<P, D>) -> Edge<P, D> {
        Edge {
            from: self.graph.id(e.from),
            to: self.graph.id(e.to),
            measurement: e.measurement,
            information: e.information,
            loop_candidate: e.candidate.is_some(),
            inliers: e.candidate.and_then(|c| c.inliers),
        }
    }

    /// The ids of the poses held fixed by [`PoseGraph::fix`] (or a file's
    /// `FIX` line), in the order they were added; empty when none was, and
    /// the first pose is the one held fixed.
    pub fn fixed(&self) -> Vec<VertexId> {
        let g = &self.graph;
        (0..g.num_vertices())
            .filter(|&k| g.is_fixed(k))
            .map(|k| g.id(k))
            .collect()
    }

    /// Gives every vertex that a file's edges named without a vertex line
    /// (see [`PoseGraph::read_g2o`]) a pose of its own, as `pgo optimize
    /// --init file` starts from: composed along a breadth-first spanning
    /// tree of the edges — odometry (trusted edges between consecutive
    /// ids) first, then any edge — from the poses the file gave and the
    /// fixed ones. A vertex no chain of edges reaches keeps the identity.
    /// Afterwards [`PoseGraph::pose`] answers for every id and
    /// [`PoseGraph::write_g2o`] writes a vertex line for each. Returns how
    /// many vertices got a pose (0 for a graph built call by call).
    ///
    /// ```
    /// # fn main() -> Result<(), Box<dyn std::error::Error>> {
    /// let dir = std::env::temp_dir().join(format!("pgo-doc-compose-{}", std::process::id()));
    /// std::fs::create_dir_all(&dir)?;
    /// let path = dir.join("missing.g2o");
    /// // Vertex 1 has no line of its own.
    /// std::fs::write(&path, "VERTEX_SE2 0 0 0 0\nEDGE_SE2 0 1 2 0 0 1 0 0 1 0 1\n")?;
    /// let mut graph = pgo::PoseGraph2::read_g2o(&path)?;
    /// assert!(graph.pose(1).is_none());
    /// assert_eq!(graph.compose_missing_poses(), 1);
    /// assert_eq!(graph.pose(1).map(|p| p.x), Some(2.0));
    /// # std::fs::remove_dir_all(&dir)?;
    /// # Ok(())
    /// # }
    /// ```
    pub fn compose_missing_poses(&mut self) -> usize {
        if self.missing.is_empty() {
            return 0;
        }
        // Composition along a spanning tree (`Initialization::File`)
        // cannot fail.
        let _ = initialize(&mut self.graph, &self.missing, Initialization::File, None);
        self.state = None;
        std::mem::take(&mut self.missing).len()
    }
}
