//! The optimiser's sparsity pattern: which vertices are variables and which
//! edges are in `H`, built once and rebuilt when the weights change which
//! edges count.

use super::{Optimizer, SolveError};
use crate::geometry::Pose;
use crate::graph::PoseGraph;
use crate::linear::{BlockSystem, Parallelism};

impl<P: Pose<D>, const D: usize> Optimizer<P, D> {
    /// The block system of the edges in the pattern.
    pub(super) fn pattern(
        graph: &PoseGraph<P, D>,
        variable: &[Option<usize>],
        in_pattern: &[bool],
        n_blocks: usize,
        parallelism: &Parallelism,
    ) -> Result<BlockSystem<D>, SolveError> {
        let pairs: Vec<(Option<usize>, Option<usize>)> = graph
            .edges
            .iter()
            .zip(in_pattern)
            .map(|(e, &inside)| {
                if inside {
                    (variable[e.from], variable[e.to])
                } else {
                    (None, None)
                }
            })
            .collect();
        Ok(BlockSystem::new(n_blocks, &pairs, parallelism.clone())?)
    }

    /// Rebuilds the pattern for the edges of non-zero weight when an edge
    /// left out of it now has a weight, or when edges in it have weight 0
    /// (loops a robust method removed) once the optimiser has factorised —
    /// wrong loops that join distant places are the ones that cost the most
    /// fill. A numeric factorisation costs more than building its pattern
    /// (4 to 30 times the time on simulated 2D and 3D graphs of 2·10³ to
    /// 4·10⁴ poses and on manhattanOlson3500 with every non-sequential edge
    /// a candidate: per value of the factor it loads, updates and scales,
    /// where the build handles whole blocks), so each later factorisation
    /// without those edges repays the build. The decision depends on the
    /// weights and the run's history only, never on timings, so that the
    /// elimination order and every bit of the result are the same in every
    /// run. Vertices that the edges of non-zero weight no longer connect to
    /// the gauge (a part of the map joined only by rejected loops) are held
    /// at their poses until an edge joins them again.
    pub(super) fn update_pattern(
        &mut self,
        graph: &PoseGraph<P, D>,
        weights: Option<&[f64]>,
    ) -> Result<(), SolveError> {
        let needed = |k: usize| weights.is_none_or(|w| w[k] != 0.0);
        let missing = (0..self.in_pattern.len()).any(|k| !self.in_pattern[k] && needed(k));
        let unused = (0..self.in_pattern.len()).any(|k| self.in_pattern[k] && !needed(k));
        // Edges gone from the objective may also cut vertices off the gauge,
        // which then have to leave the variables (`vertex_of` is sorted).
        let mut cut_off = None;
        let mut newly_cut_off = || {
            let cut = graph.unconstrained_vertices(weights);
            let any = cut.iter().any(|v| self.vertex_of.binary_search(v).is_ok());
            cut_off = Some(cut);
            any
        };
        if !(missing || unused && (self.factorized || newly_cut_off())) {
            return Ok(());
        }
        let cut_off = cut_off.unwrap_or_else(|| graph.unconstrained_vertices(weights));
        for k in 0..self.in_pattern.len() {
            self.in_pattern[k] = needed(k);
        }
        let variable = Self::variables(graph, &cut_off, &mut self.vertex_of);
        self.step.resize(self.vertex_of.len() * D, 0.0);
        // The old factor goes before the new pattern is built, so that the
        // two never take memory at the same time.
        self.system.release_factor();
        self.system = Self::pattern(
            graph,
            &variable,
            &self.in_pattern,
            self.vertex_of.len(),
            &self.parallelism,
        )?;
        self.max_nnz_factor = self.max_nnz_factor.max(self.system.nnz_factor());
        Ok(())
    }

    /// The variable block of each vertex: every vertex but the gauge and
    /// `cut_off` (those the edges of non-zero weight do not connect to it,
    /// [`PoseGraph::unconstrained_vertices`]). Fills `vertex_of` with the
    /// vertex of each block.
    pub(super) fn variables(
        graph: &PoseGraph<P, D>,
        cut_off: &[usize],
        vertex_of: &mut Vec<usize>,
    ) -> Vec<Option<usize>> {
        let n = graph.num_vertices();
        let mut fixed = vec![false; n];
        for k in graph.gauge().into_iter().chain(cut_off.iter().copied()) {
            fixed[k] = true;
        }
        vertex_of.clear();
        (0..n)
            .map(|k| {
                (!fixed[k]).then(|| {
                    vertex_of.push(k);
                    vertex_of.len() - 1
                })
            })
            .collect()
    }
}
