//! The optimiser's sparsity pattern: which vertices are variables and which
//! edges are in `H`, built once and rebuilt when the weights change which
//! edges count.

use super::{Optimizer, SolveError};
use crate::geometry::Pose;
use crate::graph::Graph;
use crate::linear::{BlockSystem, Layout, LinearError, Parallelism};
use std::sync::Arc;

/// How much more an earlier elimination order may cost than the
/// fill-reducing order it started as before a pattern is ordered afresh
/// ([`Ordering`]): in factor values per variable block (each factorisation
/// and solve), and in values on a block's path to the root of the
/// elimination tree (each innovation's covariance; appended poses lengthen
/// every path). Ordering (AMD) costs about half a numeric factorisation of
/// a pose graph (an update of city10000 or manhattanOlson3500: ordering
/// 10–12 % of the time, two factorisations 27 %), and 10 % more of either
/// costs at most about 10 % more of the work that follows, so the old order
/// is kept while it is within 10 % on both.
const ORDER_SLACK: f64 = 0.1;

/// An elimination order kept from an earlier solve of a graph that has
/// grown since (incremental updates): each vertex's rank in it, and the
/// cost of the fill-reducing order it started as (factor values per
/// variable block, values per path to the root). A pattern built with it
/// orders the old vertices as before and appends the new ones, unless that
/// costs more than [`ORDER_SLACK`] more.
#[derive(Clone, Debug, Default)]
pub struct Ordering {
    rank: Vec<u32>,
    /// The pattern of the system this order was taken from, for one of
    /// the same graph grown ([`BlockSystem::with_positions`]).
    layout: Arc<Layout>,
    values_per_block: f64,
    path_values: f64,
    /// Whether the paths' cost counts (innovations will be computed).
    paths_matter: bool,
}

impl Ordering {
    /// This order, for solves whose innovations are needed (`true`: the
    /// paths to the root count too) or not.
    pub fn for_innovations(mut self, needed: bool) -> Self {
        self.paths_matter = needed;
        self
    }

    /// The system of the edges `pairs` between the blocks of `vertex_of`
    /// in this order, if there is one and it costs at most [`ORDER_SLACK`]
    /// more than the fresh order it started as.
    fn kept<const D: usize>(
        &self,
        vertex_of: &[usize],
        pairs: &[(Option<usize>, Option<usize>)],
        parallelism: &Parallelism,
    ) -> Result<Option<BlockSystem<D>>, LinearError> {
        if self.rank.is_empty() {
            return Ok(None);
        }
        let n_blocks = vertex_of.len();
        let (position, old) = self.positions(vertex_of);
        // The old structure extends when every one of its blocks is still
        // a variable (they then keep their positions).
        let grown = (old == self.layout.len()).then_some(&*self.layout);
        let kept =
            BlockSystem::with_positions(n_blocks, pairs, parallelism.clone(), position, grown)?;
        let within = |cost: f64, fresh: f64| cost <= (1.0 + ORDER_SLACK) * fresh;
        let fill = within(
            kept.nnz_factor() as f64,
            self.values_per_block * n_blocks as f64,
        );
        let paths = !self.paths_matter || within(kept.mean_path_values(), self.path_values);
        Ok((fill && paths).then_some(kept))
    }

    /// The elimination position of each of `n_blocks` variable blocks
    /// (`vertex_of`: each block's vertex): the old vertices in their old
    /// order, then the rest by vertex; and how many blocks are old.
    fn positions(&self, vertex_of: &[usize]) -> (Vec<usize>, usize) {
        let rank = |b: usize| self.rank.get(vertex_of[b]).copied().unwrap_or(u32::MAX);
        // Every old block still a variable (the usual update): their ranks
        // are their positions, and the new ones follow in block order.
        let old = (0..vertex_of.len())
            .filter(|&b| rank(b) != u32::MAX)
            .count();
        if (0..vertex_of.len()).all(|b| rank(b) == u32::MAX || (rank(b) as usize) < old) {
            let mut next = old;
            let position = (0..vertex_of.len())
                .map(|b| match rank(b) {
                    u32::MAX => {
                        next += 1;
                        next - 1
                    }
                    r => r as usize,
                })
                .collect();
            return (position, old);
        }
        let key = |b: usize| (rank(b), b);
        let mut blocks: Vec<usize> = (0..vertex_of.len()).collect();
        blocks.sort_unstable_by_key(|&b| key(b));
        let mut position = vec![0; blocks.len()];
        for (p, &b) in blocks.iter().enumerate() {
            position[b] = p;
        }
        (position, old)
    }
}

impl<P: Pose<D>, const D: usize> Optimizer<P, D> {
    /// The block system of the edges in the pattern, in the order of
    /// `self.ordering` if there is one and it is still good (which it then
    /// follows), else in a fill-reducing order.
    pub(super) fn pattern(
        &mut self,
        graph: &Graph<P, D>,
        variable: &[Option<usize>],
    ) -> Result<BlockSystem<D>, SolveError> {
        let pairs: Vec<(Option<usize>, Option<usize>)> = graph
            .edges
            .iter()
            .zip(&self.in_pattern)
            .map(|(e, &inside)| {
                if inside {
                    (variable[e.from], variable[e.to])
                } else {
                    (None, None)
                }
            })
            .collect();
        let n_blocks = self.vertex_of.len();
        let parallelism = self.parallelism.clone();
        let Some(ordering) = &mut self.ordering else {
            return Ok(BlockSystem::new(n_blocks, &pairs, parallelism)?);
        };
        let system = match ordering.kept(&self.vertex_of, &pairs, &parallelism)? {
            Some(kept) => kept,
            None => {
                let fresh = BlockSystem::new(n_blocks, &pairs, parallelism)?;
                ordering.values_per_block = fresh.nnz_factor() as f64 / n_blocks.max(1) as f64;
                ordering.path_values = fresh.mean_path_values();
                fresh
            }
        };
        ordering.rank = vec![u32::MAX; graph.num_vertices()];
        for (&v, &p) in self.vertex_of.iter().zip(system.positions()) {
            ordering.rank[v] = p as u32;
        }
        ordering.layout = Arc::new(system.layout());
        Ok(system)
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
    /// With `keep_unused` (one factorisation of the map with a few edges
    /// left out, [`Optimizer::factor_without`]) edges of zero weight stay
    /// in the pattern unless vertices leave the variables: no later
    /// factorisation would repay the build. Returns whether it built the
    /// pattern anew.
    pub(super) fn update_pattern(
        &mut self,
        graph: &Graph<P, D>,
        weights: Option<&[f64]>,
        keep_unused: bool,
    ) -> Result<bool, SolveError> {
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
        let rebuilt = self.factorized && !keep_unused;
        if !(missing || unused && (rebuilt || newly_cut_off())) {
            return Ok(false);
        }
        let cut_off = cut_off.unwrap_or_else(|| graph.unconstrained_vertices(weights));
        for k in 0..self.in_pattern.len() {
            self.in_pattern[k] = needed(k);
        }
        let variable = Self::variables(graph, &cut_off, &mut self.vertex_of);
        self.step.resize(self.vertex_of.len() * D, 0.0);
        // The old factor goes before the new pattern is built, so that the
        // two never take memory at the same time.
        self.forget_factored();
        self.system.release_factor();
        self.system = self.pattern(graph, &variable)?;
        self.max_nnz_factor = self.max_nnz_factor.max(self.system.nnz_factor());
        Ok(true)
    }

    /// The variable block of each vertex: every vertex but the gauge and
    /// `cut_off` (those the edges of non-zero weight do not connect to it,
    /// [`Graph::unconstrained_vertices`]). Fills `vertex_of` with the
    /// vertex of each block.
    pub(super) fn variables(
        graph: &Graph<P, D>,
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
