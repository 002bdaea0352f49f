//! The factorisation of the undamped normal matrix at a solution
//! ([`Optimizer::factor_at`]), which the innovations of the loop candidates
//! (`crate::robust`) and the covariances read; and, for the tests, how well
//! each edge agrees with a solution made without it: the innovation of an
//! edge left out ([`Optimizer::innovation_chi2`]) and the deleted residual
//! of an edge in it ([`Optimizer::leave_one_out_chi2`]).

use super::{Optimizer, SolveError};
use crate::geometry::Pose;
use crate::graph::Graph;
use crate::linear::SelectedInverse;
use crate::linear::{KeptFactor, LinearError};
#[cfg(test)]
use nalgebra::SMatrix;
use std::sync::Arc;

impl<P: Pose<D>, const D: usize> Optimizer<P, D> {
    /// Factorises the undamped normal matrix of the edges of non-zero
    /// `weights` at the graph's poses (for the innovations and covariances
    /// read from the system then); returns each vertex's block (`None` for
    /// a vertex held fixed). Where the system still holds the factorisation
    /// of the same poses, weights and gauge (nothing has linearised or
    /// factorised since), it is kept, not made again: the same bits.
    pub(crate) fn factor_at(
        &mut self,
        graph: &Graph<P, D>,
        weights: &[f64],
    ) -> Result<Vec<Option<usize>>, SolveError> {
        self.factor_in_pattern(graph, weights, false)
    }

    /// [`Optimizer::factor_at`] of the map with a few of the edges of the
    /// last factorisation left out or taken back (their weights changed),
    /// once: in the pattern the system holds, the edges of zero weight
    /// left in it (unless vertices leave the variables), and only the
    /// factor's panels on the changed edges' ends' paths to the root of
    /// the elimination tree formed again ([`BlockSystem::refactorize`]:
    /// every other panel is the same to the bit). Single-threaded, as that
    /// refactorisation is; with threads the whole factor is formed.
    ///
    /// [`BlockSystem::refactorize`]: crate::linear::BlockSystem::refactorize
    pub(crate) fn factor_without(
        &mut self,
        graph: &Graph<P, D>,
        weights: &[f64],
    ) -> Result<Vec<Option<usize>>, SolveError> {
        self.factor_in_pattern(graph, weights, true)
    }

    fn factor_in_pattern(
        &mut self,
        graph: &Graph<P, D>,
        weights: &[f64],
        keep: bool,
    ) -> Result<Vec<Option<usize>>, SolveError> {
        if weights.len() != graph.edges.len() {
            return Err(SolveError::WeightCount {
                weights: weights.len(),
                edges: graph.edges.len(),
            });
        }
        self.match_threads()?;
        let gauge = graph.gauge();
        let held = (self.factored_at.as_ref()).is_some_and(|f| f.is_at(graph, weights, &gauge));
        if !held {
            let kept = keep
                .then(|| self.kept_beside(graph, weights, &gauge))
                .flatten();
            let rebuilt = self.update_pattern(graph, Some(weights), keep)?;
            self.factorized = true;
            self.linearize(graph, Some(weights));
            self.kept = None;
            let refactorized = match kept.filter(|_| !rebuilt) {
                Some((factor, changed)) => self.system.refactorize(&factor, &changed),
                None => Ok(None),
            };
            let factorized = refactorized.and_then(|formed| match formed {
                Some(_) => Ok(()),
                None => self.system.factorize(0.0),
            });
            match factorized {
                Ok(()) => {}
                Err(LinearError::NotPositiveDefinite { block }) => {
                    return Err(SolveError::NotPositiveDefinite {
                        vertex: graph.id(self.vertex_of[block]),
                    });
                }
                Err(e) => return Err(e.into()),
            }
            self.factored_at = Some(FactoredAt {
                poses: graph.poses.clone(),
                weights: weights.to_vec(),
                gauge,
                inverse: None,
            });
        }
        Ok(self.blocks_of(graph.num_vertices()))
    }

    /// The factor the system holds, where it was made at the graph's poses
    /// and `gauge` with other `weights` at some edges, and the variable
    /// blocks of those edges' ends (in the pattern held: a pattern built
    /// anew does not keep the factor).
    fn kept_beside(
        &self,
        graph: &Graph<P, D>,
        weights: &[f64],
        gauge: &[usize],
    ) -> Option<(KeptFactor, Vec<usize>)> {
        let at = self.factored_at.as_ref()?;
        let same =
            at.poses == graph.poses && at.gauge == gauge && at.weights.len() == weights.len();
        if !same {
            return None;
        }
        let factor = self.system.kept_factor()?;
        let mut changed: Vec<usize> = (0..weights.len())
            .filter(|&k| at.weights[k] != weights[k])
            .flat_map(|k| [graph.edges[k].from, graph.edges[k].to])
            .filter_map(|v| self.vertex_of.binary_search(&v).ok())
            .collect();
        changed.sort_unstable();
        changed.dedup();
        Some((factor, changed))
    }

    /// The variable block of each of `n` vertices (`None`: fixed).
    pub(super) fn blocks_of(&self, n: usize) -> Vec<Option<usize>> {
        let mut block = vec![None; n];
        for (b, &v) in self.vertex_of.iter().enumerate() {
            block[v] = Some(b);
        }
        block
    }

    /// The selected inverse of the last [`Self::factor_at`]'s factorisation,
    /// taken once for every evaluation of the same map.
    pub(crate) fn selected_inverse(&mut self) -> Arc<SelectedInverse> {
        if let Some(inverse) = self.factored_at.as_ref().and_then(|f| f.inverse.clone()) {
            return inverse;
        }
        let inverse = Arc::new(self.system.selected_inverse());
        if let Some(f) = self.factored_at.as_mut() {
            f.inverse = Some(Arc::clone(&inverse));
        }
        inverse
    }

    /// Forgets the undamped factorisation [`Self::factor_at`] left (the
    /// system is about to change).
    pub(super) fn forget_factored(&mut self) {
        self.factored_at = None;
    }

    /// `−H⁻¹·g` for `k` gradients `g`, one after the other and each by
    /// variable block (replaced in place), `H` the normal matrix of the
    /// last [`Self::factor_at`]: one pass over the factor for all.
    pub(crate) fn solve_factored(&mut self, g: &mut [f64], k: usize) {
        self.system.solve_many(g, k);
    }

    /// The Gauss–Newton step `δ = −H⁻¹·b` left at the poses of the last
    /// [`Self::factor_at`] (by variable block, `δ[k·D + a]`): what separates
    /// them from the exact least-squares map of their linearisation. A
    /// solve to tolerance leaves it small, but formulas that assume the
    /// exact map (deleted residuals) divide it by the tiny covariance of a
    /// loop that a loose chain alone checks.
    pub(crate) fn remaining_step(&mut self) -> Vec<f64> {
        let mut step = vec![0.0; self.vertex_of.len() * D];
        self.system.solve(&mut step);
        step
    }
}

/// What an undamped factorisation was made at ([`Optimizer::factor_at`]),
/// and its selected inverse once taken: another call at the same finds
/// both in the system as it is.
pub(super) struct FactoredAt<P> {
    poses: Vec<P>,
    weights: Vec<f64>,
    gauge: Vec<usize>,
    inverse: Option<Arc<SelectedInverse>>,
}

impl<P: PartialEq> FactoredAt<P> {
    /// Whether it was made at `graph`'s poses with `weights` and `gauge`.
    fn is_at<const D: usize>(&self, graph: &Graph<P, D>, weights: &[f64], gauge: &[usize]) -> bool
    where
        P: Pose<D>,
    {
        self.poses == graph.poses && self.weights == weights && self.gauge == gauge
    }
}

#[cfg(test)]
impl<P: Pose<D>, const D: usize> Optimizer<P, D> {
    /// The squared *innovation* `ν² = eᵀ(Ω⁻¹ + J·H⁻¹·Jᵀ)⁻¹e` of each of
    /// `edges` at the graph's poses: the Mahalanobis distance of the error of
    /// an edge the solution was made without, with the solution's own
    /// uncertainty (`H` the normal matrix of the edges of non-zero `weights`
    /// at these poses, undamped) added to the edge's. `ν² ≤ eᵀΩe`, and much
    /// less where the solution is loosely tied between the edge's two poses.
    /// An edge at a vertex that is held fixed because no edge of non-zero
    /// weight ties it to the gauge gets its plain `eᵀΩe` (the solution
    /// knows nothing of that vertex to add).
    pub fn innovation_chi2(
        &mut self,
        graph: &Graph<P, D>,
        weights: &[f64],
        edges: &[usize],
    ) -> Result<Vec<f64>, SolveError> {
        let block = self.factor_at(graph, weights)?;
        let gauge = graph.gauge();
        Ok(edges
            .iter()
            .map(|&k| self.left_out_chi2(graph, &block, &gauge, k))
            .collect())
    }

    /// The squared innovation of each of `edges` against the solution
    /// without it, whether the solution was made without it (weight 0 in
    /// `weights`: [`Optimizer::innovation_chi2`]) or with it (weight 1):
    /// then Baarda's deleted residual `eᵀ(Ω⁻¹ − J·H⁻¹·Jᵀ)⁻¹e`, `H` as there.
    /// `Ω⁻¹ − J·H⁻¹·Jᵀ` is the covariance of the edge's residual at the
    /// optimum, and the number is, to first order (exactly for a linear
    /// problem), the innovation the edge would have against the optimum of
    /// the others — so the two kinds compare like with like. `None` for an
    /// edge of another weight, or one of the solution that the others do
    /// not determine in some direction (a bridge: the whitened redundancy
    /// `I − Ω^½·J·H⁻¹·Jᵀ·Ω^½` has an eigenvalue below `1e-9`).
    pub fn leave_one_out_chi2(
        &mut self,
        graph: &Graph<P, D>,
        weights: &[f64],
        edges: &[usize],
    ) -> Result<Vec<Option<f64>>, SolveError> {
        let block = self.factor_at(graph, weights)?;
        let gauge = graph.gauge();
        // The edges of the solution read H⁻¹ from its selected inverse (one
        // pass over the factor), not from a solve each.
        let inverse = edges
            .iter()
            .any(|&k| weights[k] == 1.0)
            .then(|| self.system.selected_inverse());
        Ok(edges
            .iter()
            .map(|&k| match (weights[k], &inverse) {
                (0.0, _) => Some(self.left_out_chi2(graph, &block, &gauge, k)),
                (1.0, Some(z)) => self.deleted_chi2(graph, &block, z, k),
                _ => None,
            })
            .collect())
    }

    /// [`Optimizer::innovation_chi2`] of edge `k`, at the factor of
    /// [`Optimizer::factor_at`] (`block`) with the graph's `gauge`.
    fn left_out_chi2(
        &mut self,
        graph: &Graph<P, D>,
        block: &[Option<usize>],
        gauge: &[usize],
        k: usize,
    ) -> f64 {
        let e = &graph.edges[k];
        let lin = P::error_and_jacobians(&graph.poses[e.from], &graph.poses[e.to], &e.measurement);
        let plain = lin.error.dot(&(e.information * lin.error));
        let known = |v: usize| block[v].is_some() || gauge.contains(&v);
        if !(known(e.from) && known(e.to)) {
            return plain;
        }
        let spread = self
            .system
            .propagate(block[e.from], &lin.jac_i, block[e.to], &lin.jac_j);
        let innovation = e
            .information
            .try_inverse()
            .map(|sigma| sigma + spread)
            .and_then(|s| s.cholesky());
        match innovation {
            Some(s) => lin.error.dot(&s.solve(&lin.error)).min(plain),
            None => plain,
        }
    }

    /// The deleted residual of edge `k`, one of the solution
    /// ([`Optimizer::leave_one_out_chi2`]), with `H⁻¹` from its selected
    /// `inverse`.
    fn deleted_chi2(
        &self,
        graph: &Graph<P, D>,
        block: &[Option<usize>],
        inverse: &SelectedInverse,
        k: usize,
    ) -> Option<f64> {
        let e = &graph.edges[k];
        let lin = P::error_and_jacobians(&graph.poses[e.from], &graph.poses[e.to], &e.measurement);
        let spread = self.system.propagate_selected(
            inverse,
            block[e.from],
            &lin.jac_i,
            block[e.to],
            &lin.jac_j,
        )?;
        // Whitened: Ω = LLᵀ, ẽ = Lᵀe, R = I − Lᵀ·spread·L.
        let l = e.information.cholesky()?.unpack();
        let whitened = l.transpose() * lin.error;
        let redundancy = SMatrix::<f64, D, D>::identity() - l.transpose() * spread * l;
        // (Dynamic: nalgebra's eigen solver is not generic in D.)
        let eig =
            nalgebra::DMatrix::from_column_slice(D, D, redundancy.as_slice()).symmetric_eigen();
        if eig.eigenvalues.min() < 1e-9 {
            return None;
        }
        let projected = eig.eigenvectors.transpose() * whitened;
        Some(
            projected
                .iter()
                .zip(eig.eigenvalues.iter())
                .map(|(p, lambda)| p * p / lambda)
                .sum(),
        )
    }
}
