//! A capped update's factor kept from the last one where the poses barely
//! moved ([`super::SolveSettings::keep_factor`]): the panels of the factor that
//! no change of `H` reaches are carried over, and only those on the
//! changed blocks' paths to the root of the elimination tree are formed
//! again, as iSAM2 re-eliminates only the cliques a step touches.
//!
//! A block's rows and columns of `H` change where a new edge reaches it,
//! where it is new, or where an edge joins it to a pose that moved by more
//! than the setting since its block was last formed (an edge's Jacobians
//! depend on both its ends). The factor then is that of a matrix whose
//! other columns are an earlier linearisation's, off by about that move:
//! the step it solves for is an inexact Gauss–Newton step against the
//! exact gradient, which LM's gain ratio judges as any other (a rejected
//! one is solved again, damped, from a whole factorisation).

use super::Optimizer;
use crate::geometry::Pose;
use crate::graph::Graph;
use crate::linear::KeptFactor;

/// What a capped update keeps of the last factorisation for the next
/// ([`Optimizer::take_spare`]): its structure, the graph it was of, and
/// the pose each vertex had when its block's panel was last formed.
pub(super) struct Kept<P> {
    factor: KeptFactor,
    /// Vertex and elimination position of each variable block.
    vertex_of: Vec<usize>,
    positions: Vec<usize>,
    /// The edges then, and their weights (`None`: all 1).
    edges: usize,
    weights: Option<Vec<f64>>,
    /// Each vertex's pose when its block was last counted as changed.
    at: Vec<Option<P>>,
}

/// What an assembly found for the factorisation that follows: the graph
/// it linearised (its poses, number of edges and weights), and, where the
/// factor carried over can be kept, that factor and the changed blocks.
pub(super) struct Plan<P> {
    poses: Vec<P>,
    edges: usize,
    weights: Option<Vec<f64>>,
    keeping: Option<(Kept<P>, Vec<usize>)>,
}

impl<P: Pose<D>, const D: usize> Optimizer<P, D> {
    /// At an assembly of `graph` with `weights`: the plan for keeping the
    /// factor carried over, if the setting is on and the factor is of the
    /// same graph before it grew (the same variable blocks in the same
    /// places, the same weights on its edges).
    ///
    /// Only an optimiser's first assembly plans: a solve that factorises
    /// more than once (EM's rounds, damped trials) keeps nothing, so that
    /// the many assemblies of an update with loop candidates cost no copy.
    pub(super) fn plan_keeping(&mut self, graph: &Graph<P, D>, weights: Option<&[f64]>) {
        self.plan = None;
        let Some(theta) = self.options.keep_factor.filter(|_| !self.factorized) else {
            self.kept = None;
            return;
        };
        let mut plan = Plan {
            poses: graph.poses.clone(),
            edges: graph.edges.len(),
            weights: weights.map(<[f64]>::to_vec),
            keeping: None,
        };
        plan.keeping = self.changed_since(graph, weights, theta);
        self.plan = Some(plan);
    }

    /// The kept factor and the blocks whose rows and columns of `H` changed
    /// since it was formed, if it is of this graph before it grew.
    fn changed_since(
        &mut self,
        graph: &Graph<P, D>,
        weights: Option<&[f64]>,
        theta: f64,
    ) -> Option<(Kept<P>, Vec<usize>)> {
        let kept = self.kept.take()?;
        let old = kept.vertex_of.len();
        let same_weights = match (weights, &kept.weights) {
            (None, None) => true,
            (Some(w), Some(k)) => w.len() >= kept.edges && w[..kept.edges] == k[..],
            _ => false,
        };
        let same_blocks = self.vertex_of.len() >= old
            && self.vertex_of[..old] == kept.vertex_of[..]
            && self.system.positions()[..old] == kept.positions[..];
        if !(same_weights && same_blocks && graph.edges.len() >= kept.edges) {
            return None;
        }
        let block = self.blocks_of(graph.num_vertices());
        let moved: Vec<bool> = (0..graph.num_vertices())
            .map(|v| match kept.at.get(v).copied().flatten() {
                Some(at) => P::error(&at, &graph.poses[v], &P::identity()).amax() > theta,
                None => true,
            })
            .collect();
        let mut changed: Vec<usize> = (0..graph.num_vertices())
            .filter(|&v| moved[v])
            .filter_map(|v| block[v])
            .collect();
        for (k, e) in graph.edges.iter().enumerate() {
            let new = k >= kept.edges;
            for (a, b) in [(e.from, e.to), (e.to, e.from)] {
                if new || moved[a] {
                    changed.extend(block[b]);
                }
            }
        }
        changed.sort_unstable();
        changed.dedup();
        Some((kept, changed))
    }

    /// Factorises `H` at `λ = 0` keeping the carried factor's untouched
    /// panels, if the last assembly planned it; `false` where it cannot
    /// (then the caller factorises the whole of `H`). A pivot that is not
    /// positive in a kept factor is no verdict on `H`: `false` too.
    pub(super) fn factorize_keeping(&mut self) -> bool {
        let Some(plan) = self.plan.as_mut() else {
            return false;
        };
        let Some((kept, changed)) = plan.keeping.take() else {
            return false;
        };
        if !matches!(self.system.refactorize(&kept.factor, &changed), Ok(Some(_))) {
            return false;
        }
        let mut at = kept.at;
        at.resize(plan.poses.len(), None);
        for &b in &changed {
            let v = self.vertex_of[b];
            at[v] = Some(plan.poses[v]);
        }
        self.keep(at);
        true
    }

    /// Records the whole factor just formed at `λ` for the next capped
    /// update (only an undamped one can be kept).
    pub(super) fn kept_after_factorization(&mut self, lambda: f64) {
        self.kept = None;
        let Some(plan) = &self.plan else {
            return;
        };
        if lambda == 0.0 {
            let at = plan.poses.iter().map(|&p| Some(p)).collect();
            self.keep(at);
        }
    }

    /// Keeps the factor the system holds, of the planned assembly, with
    /// the poses `at` of its blocks.
    fn keep(&mut self, at: Vec<Option<P>>) {
        let Some(plan) = &self.plan else {
            return;
        };
        self.kept = self.system.kept_factor().map(|factor| Kept {
            factor,
            vertex_of: self.vertex_of.clone(),
            positions: self.system.positions().to_vec(),
            edges: plan.edges,
            weights: plan.weights.clone(),
            at,
        });
    }
}
