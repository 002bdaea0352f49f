//! Every loop candidate's innovation against the map made without its
//! cluster ([`super::clusters`]): the evidence the loop model weighs.
//!
//! At the least-squares map of the trusted edges and the accepted
//! candidates (normal matrix `H`), take a cluster's candidates: `A` those
//! the map was solved with, `R` the others; `e` their errors, `Σ = Ω⁻¹` their
//! covariances, `M = J·H⁻¹·Jᵀ` ([`BlockSystem::propagate_group_solved`]). To first
//! order (exactly for a linear problem), removing `A` moves the map by
//! `δ = H⁻¹·J_Aᵀ·S⁻¹·e_A` with `S = Σ_A − M_AA`, so against the map
//! without `A`
//!
//! * a member of `A` has the error `ẽ_A = Σ_A·S⁻¹·e_A` with covariance
//!   `Σ_A·S⁻¹·Σ_A` (Baarda's deleted residuals, for a group);
//! * a member of `R` has `ẽ_R = e_R + M_RA·S⁻¹·e_A` with covariance
//!   `Σ_R + M_RR + M_RA·S⁻¹·M_AR`;
//!
//! and its squared innovation is `ν² = ẽᵀ·C⁻¹·ẽ` with its own block of
//! that covariance. A member is also judged against the map with the
//! members in it that agree better with the rest of the map (a smaller
//! `ν²` so far) and without the others, by the same formulas on that
//! group, and keeps the larger `ν²`: a wrong run cannot vouch for its
//! members, and a true loop speaks against an alias beside it. A cluster
//! of one is judged by the plain deleted residual or innovation. When `S`
//! is singular — the cluster is all that ties part of the map — the map
//! without it says nothing about it: `None`.
//!
//! `S` is also singular to rounding when the map without the cluster joins
//! its ends only through a chain far looser than the loops (`S ≈
//! Σ·C⁻¹·Σ` for a chain of covariance `C ≫ Σ`): `Σ_A − M_AA` cancels. Such
//! a cluster is not left unchecked: [`through_wide_chains`] factorises the
//! system without it, and judges its members against the map without it
//! (one Gauss–Newton step away: first order, as the formulas above) as
//! candidates outside it, where nothing cancels.
//!
//! A candidate outside the map whose ends the map joins only through such
//! unchecked clusters is unchecked too ([`beside_unchecked`]): against the
//! part an unchecked cluster placed it would be judged by that placement.
//!
//! [`BlockSystem::propagate_group_solved`]: crate::linear::BlockSystem::propagate_group_solved

use super::Candidate;
use super::model::Evidence;
use crate::geometry::Pose;
use crate::graph::Graph;
use crate::linear::{EdgeJacobian, GroupScratch, Parallelism, SelectedInverse};
use crate::solve::{Optimizer, Session, SolveError};
use faer::Par;
use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::cholesky::llt::factor::{
    LltRegularization, cholesky_in_place, cholesky_in_place_scratch,
};
use faer::linalg::triangular_solve::{
    solve_lower_triangular_in_place, solve_upper_triangular_in_place,
};
use nalgebra::{DMatrix, DVector, SMatrix, SVector};
use std::sync::{Arc, Mutex};

/// The time of the selected inverse in multiply–adds of the sparse group
/// solves, per multiply–add of a numeric factorisation. Takahashi's
/// recurrence is one pass over the factor, but in small blocks, where the
/// solves for a group run panel by panel on all its right-hand sides at
/// once. Timed both ways for the clusters of the new candidates of each
/// update, replaying the aliasing benchmark's files every 100 poses
/// (`examples/replay`): the selected inverse took 0.38 (sphere2500) to 0.62
/// (parking-garage) ns per multiply–add of a factorisation, the solves
/// 0.063–0.068 ns per multiply–add, ratios of 6.0 and 9.1 (9.6 and 15 on
/// manhattan and intel, whose factorisations are smaller); 8 lies between.
pub const SELECTED_INVERSE_COST: f64 = 8.0;

/// The memory one pass of [`Evaluation::largest_moves`] may hold, in
/// bytes, where a fifth of the factor's values is less: each pass reads
/// the factor once and holds two copies of the map's variables per
/// gradient. 32 MB solve a keystone's
/// [`super::doubt::KEYSTONE_CANDIDATES`] in one pass up to about 2·10⁴
/// poses in 2D (manhattan: 5.4 MB), where eight passes of four took
/// twice the instructions (docs/benchmarks.md, "Where the whole aliased
/// replay's time goes"); a pass over 10⁶ poses in 3D (96 MB per
/// gradient) stays within a fifth of such a factor's size.
pub const MOVES_MEMORY: usize = 32 << 20;

/// The fewest gradients solved in one pass, whatever the memory: 4 on
/// 10⁶ poses in 3D hold 384 MB, a fifth of that factor.
pub const MOVES_AT_ONCE: usize = 4;

/// What the innovations of one evaluation found.
#[derive(Clone, Debug, Default)]
pub struct Innovations {
    /// `ν²` of each candidate, `None` where nothing else checks it.
    pub nu2: Vec<Option<f64>>,
    /// Whether each `ν²` is exact; otherwise it is a lower bound (a lone
    /// candidate outside the map, whose endpoints' covariance is bounded
    /// from their marginals: [`Evaluation::refine`] makes it exact).
    pub exact: Vec<bool>,
    /// Each cluster's joint statistic `e_Aᵀ·S⁻¹·e_A` over its members the
    /// map was solved with: by how much `Σ eᵀΩe` of the map would drop
    /// without them (0 when it has none; `None` when `S` is singular).
    pub joint: Vec<Option<f64>>,
    /// Each cluster's share of `joint` that one offset common to its
    /// members in the map explains (`None` with fewer than two of them, or
    /// no joint statistic).
    pub common: Vec<Option<f64>>,
    /// Each cluster's `gᵀ·H⁻¹·g` ([`Evaluation::removing`]) over its
    /// members in the map: the squared size, in the map's own metric, of
    /// the move the map would make without them (`None` with none of them
    /// or `S` singular).
    pub moves: Vec<Option<f64>>,
    /// The largest trace of a pose's block of `H⁻¹`
    /// ([`Evaluation::largest_marginal`]), where the evaluation held the
    /// selected inverse.
    pub spread: Option<f64>,
    /// The candidates the map was solved with, as the evaluation judged
    /// them.
    pub accepted: Vec<bool>,
    /// By how much `Σ eᵀΩe` drops from the map to the exact least-squares
    /// map of its linearisation, where the errors are read: what a
    /// factorisation of the map without a cluster predicts beyond the
    /// cluster's own drop ([`through_wide_chains`]).
    pub remaining: f64,
}

impl Innovations {
    /// The evidence the loop model weighs for candidate `k` of
    /// `candidates`: its count posterior and `ν²`; `None` where nothing
    /// else checks it.
    pub fn evidence(&self, candidates: &[Candidate], k: usize) -> Option<Evidence> {
        self.nu2.get(k).copied().flatten().map(|v| Evidence {
            count_posterior: candidates[k].count_posterior,
            innovation: v,
        })
    }
}

/// The factorisation and selected inverse of one map, for the innovations
/// of its candidates.
pub struct Evaluation<'a, P: Pose<D>, const D: usize> {
    optimizer: &'a mut Optimizer<P, D>,
    graph: &'a Graph<P, D>,
    block: Vec<Option<usize>>,
    /// The step left to the exact least-squares map of the factorised
    /// linearisation ([`Optimizer::remaining_step`]): the errors are read
    /// there.
    step: Vec<f64>,
    /// The selected inverse, unless every cluster is solved for
    /// ([`Evaluation::for_clusters`]).
    inverse: Option<Arc<SelectedInverse>>,
    /// Scratch of the sparse solves, one per thread at work.
    scratch: Mutex<Vec<GroupScratch>>,
    /// Whether a cluster's members are also judged against the map with
    /// those that agree better ([`against_better`]; the `agreement` layer).
    within: bool,
}

impl<'a, P: Pose<D>, const D: usize> Evaluation<'a, P, D> {
    /// Factorises the normal matrix of the map (the graph's poses, the
    /// least-squares map of the edges of non-zero `weights`) and takes its
    /// selected inverse.
    pub fn new(
        optimizer: &'a mut Optimizer<P, D>,
        graph: &'a Graph<P, D>,
        weights: &[f64],
    ) -> Result<Self, SolveError> {
        let mut eval = Self::factored(optimizer, graph, weights)?;
        eval.inverse = Some(eval.optimizer.selected_inverse());
        Ok(eval)
    }

    /// The factorisation of the map, without the selected inverse.
    fn factored(
        optimizer: &'a mut Optimizer<P, D>,
        graph: &'a Graph<P, D>,
        weights: &[f64],
    ) -> Result<Self, SolveError> {
        let block = optimizer.factor_at(graph, weights)?;
        Ok(Self::at(optimizer, graph, block))
    }

    /// The evaluation of the factorisation the optimiser holds, of vertices
    /// in the variable blocks `block`.
    fn at(
        optimizer: &'a mut Optimizer<P, D>,
        graph: &'a Graph<P, D>,
        block: Vec<Option<usize>>,
    ) -> Self {
        let step = optimizer.remaining_step();
        Self {
            optimizer,
            graph,
            block,
            step,
            inverse: None,
            scratch: Mutex::default(),
            within: true,
        }
    }

    /// Judges a cluster's members also against the map with the members
    /// that agree better, or (`false`) against the map without the
    /// cluster only.
    pub fn judging_within_clusters(mut self, within: bool) -> Self {
        self.within = within;
        self
    }

    /// [`Evaluation::new`] for the innovations of `clusters` only (of the
    /// candidates `edges`): without the selected inverse when the sparse
    /// solves of those clusters cost less than it
    /// ([`SELECTED_INVERSE_COST`]), as for the few clusters an update's new
    /// candidates touch.
    pub fn for_clusters(
        optimizer: &'a mut Optimizer<P, D>,
        graph: &'a Graph<P, D>,
        weights: &[f64],
        (edges, clusters): (&[usize], &[Vec<usize>]),
    ) -> Result<Self, SolveError> {
        let eval = Self::factored(optimizer, graph, weights)?;
        Ok(eval.inverse_if_cheaper(edges, clusters))
    }

    /// [`Evaluation::for_clusters`] of the map without a few of the edges
    /// the optimiser last factorised, or with a few taken back (their
    /// `weights` changed), factorised once in the pattern it holds, only
    /// what the change reaches formed again ([`Optimizer::factor_without`]).
    pub fn for_clusters_without(
        optimizer: &'a mut Optimizer<P, D>,
        graph: &'a Graph<P, D>,
        weights: &[f64],
        (edges, clusters): (&[usize], &[Vec<usize>]),
    ) -> Result<Self, SolveError> {
        let block = optimizer.factor_without(graph, weights)?;
        Ok(Self::at(optimizer, graph, block).inverse_if_cheaper(edges, clusters))
    }

    /// This evaluation with the selected inverse where the sparse solves
    /// of `clusters` (of the candidates `edges`) would cost more
    /// ([`SELECTED_INVERSE_COST`]).
    fn inverse_if_cheaper(mut self, edges: &[usize], clusters: &[Vec<usize>]) -> Self {
        let system = self.optimizer.system();
        let mut scratch = GroupScratch::default();
        let solves: usize = (clusters.iter())
            .map(|c| system.group_solve_cost(&self.linearise(edges, c).jacobians, &mut scratch))
            .sum();
        // A factorisation's multiply–adds: half its floating-point operations.
        let inverse_cost = SELECTED_INVERSE_COST * system.factor_stats().1 / 2.0;
        if solves as f64 >= inverse_cost {
            self.inverse = Some(self.optimizer.selected_inverse());
        }
        self
    }

    /// The innovations of candidates `edges` (edge indices; `accepted[k]`:
    /// the map was solved with it) grouped by `clusters`. A lone candidate
    /// outside the map whose blocks of `H⁻¹` are off the factor's pattern
    /// gets a lower bound of its `ν²` unless `exact` asks for the value
    /// ([`Innovations::exact`]).
    pub fn innovations(
        &mut self,
        edges: &[usize],
        accepted: &[bool],
        clusters: &[Vec<usize>],
        exact: bool,
    ) -> Innovations {
        let mut out = Innovations {
            nu2: vec![None; edges.len()],
            exact: vec![true; edges.len()],
            joint: Vec::with_capacity(clusters.len()),
            common: Vec::with_capacity(clusters.len()),
            moves: Vec::with_capacity(clusters.len()),
            spread: self.largest_marginal(),
            accepted: accepted.to_vec(),
            remaining: self.optimizer.system().predicted_decrease(&self.step),
        };
        // In the map first, then the others.
        let groups: Vec<(Vec<usize>, usize)> = (clusters.iter())
            .map(|cluster| {
                let mut members: Vec<usize> =
                    cluster.iter().copied().filter(|&k| accepted[k]).collect();
                let a = members.len();
                members.extend(cluster.iter().copied().filter(|&k| !accepted[k]));
                (members, a)
            })
            .collect();
        let judged = self.judge_all(edges, &groups, exact);
        for ((members, _), (nu2, (joint, common, moves), exact)) in groups.iter().zip(judged) {
            for (&k, v) in members.iter().zip(nu2) {
                out.nu2[k] = v;
                out.exact[k] = exact;
            }
            out.joint.push(joint);
            out.common.push(common);
            out.moves.push(moves);
        }
        out
    }

    /// How far the errors of a cluster's members, all in the map, share
    /// one offset ([`CommonOffset`]): `members` index the candidates
    /// `edges`. `None` where a covariance is singular or nothing else
    /// checks the cluster (`S` singular).
    pub fn common_offset(&self, edges: &[usize], members: &[usize]) -> Option<CommonOffset> {
        let lin = self.linearise(edges, members);
        let gram = self.gram(&lin.jacobians, &mut GroupScratch::default());
        let sigma = (lin.covariances.iter().copied()).collect::<Option<Vec<_>>>()?;
        let l = cholesky_of_s(&sigma, &gram, D * members.len())?;
        let (y, joint) = whiten(l.as_ref(), &lin.errors);
        let (common, u, b) = common_part::<D>(l.as_ref(), y.as_ref())?;
        // J_Aᵀ·S⁻¹·U·b̂ by variable block, S⁻¹·U·b̂ = L⁻ᵀ·ŷ with ŷ = L⁻¹·U·b̂:
        // H⁻¹ of it is the move the common offset makes the map (module doc).
        let mut fitted = faer::Mat::from_fn(y.nrows(), 1, |r, _| {
            (0..D).map(|c| u[(r, c)] * b[c]).sum::<f64>()
        });
        solve_upper_triangular_in_place(l.transpose(), fitted.as_mut(), Par::Seq);
        Some(CommonOffset {
            joint,
            common,
            members: members.len(),
            gradient: self.gradient(&lin.jacobians, fitted.as_ref()),
        })
    }

    /// `g = J_Aᵀ·S⁻¹·e_A` by variable block for candidates `members`
    /// (indices of `edges`) in the map, `S = Σ_A − J_A·H⁻¹·J_Aᵀ`: `H⁻¹` of
    /// it is how the map would move, to first order, without them (module
    /// doc); and that move's squared size in the map's own metric,
    /// `gᵀ·H⁻¹·g = vᵀ·(J_A·H⁻¹·J_Aᵀ)·v` with `v = S⁻¹·e_A`. `None` where a
    /// covariance is singular or nothing else checks them (`S` singular).
    pub fn removing(&self, edges: &[usize], members: &[usize]) -> Option<(Vec<f64>, f64)> {
        let lin = self.linearise(edges, members);
        let gram = self.gram(&lin.jacobians, &mut GroupScratch::default());
        let sigma = (lin.covariances.iter().copied()).collect::<Option<Vec<_>>>()?;
        let l = cholesky_of_s(&sigma, &gram, D * members.len())?;
        // S⁻¹·e_A = L⁻ᵀ·L⁻¹·e_A.
        let (mut s_inv_e, _) = whiten(l.as_ref(), &lin.errors);
        solve_upper_triangular_in_place(l.transpose(), s_inv_e.as_mut(), Par::Seq);
        let v = DVector::from_fn(s_inv_e.nrows(), |r, _| s_inv_e[(r, 0)]);
        let size = v.dot(&(&gram * &v));
        Some((self.gradient(&lin.jacobians, s_inv_e.as_ref()), size))
    }

    /// The largest trace of a pose's block of `H⁻¹` — at least the largest
    /// variance of the map's marginals in any direction of one pose —
    /// where the evaluation holds the selected inverse. A move
    /// `δ = H⁻¹·g` shifts no pose's position by more than
    /// `√(gᵀ·H⁻¹·g · this)` (Cauchy–Schwarz in the metric of `H`: a
    /// position's shift is as long as the translation part of the pose's
    /// block of `δ`, [`Pose::retract`]).
    pub fn largest_marginal(&self) -> Option<f64> {
        let inverse = self.inverse.as_ref()?;
        Some(self.optimizer.system().largest_marginal(inverse))
    }

    /// `J_Rᵀ·C⁻¹·e_R` by variable block for candidates `members` (indices
    /// of `edges`) outside the map, `C = Σ_R + J_R·H⁻¹·J_Rᵀ` the
    /// covariance of their errors `e_R`: `H⁻¹` of it is how the map would
    /// move, to first order, were they added to it (a Kalman update).
    /// `None` where a covariance is singular.
    pub fn adding(&self, edges: &[usize], members: &[usize]) -> Option<Vec<f64>> {
        let lin = self.linearise(edges, members);
        let mut c = self.gram(&lin.jacobians, &mut GroupScratch::default());
        for (m, sigma) in lin.covariances.iter().enumerate() {
            let mut block = c.view_mut((D * m, D * m), (D, D));
            block += (*sigma)?;
        }
        let e = DVector::from_fn(D * members.len(), |r, _| lin.errors[r / D][r % D]);
        let c_inv_e = c.cholesky()?.solve(&e);
        let v = faer::Mat::from_fn(c_inv_e.len(), 1, |r, _| c_inv_e[r]);
        Some(self.gradient(&lin.jacobians, v.as_ref()))
    }

    /// `Jᵀ·v` by variable block for the stacked `jacobians` of some
    /// candidates and a vector `v` of their stacked error dimensions.
    fn gradient(&self, jacobians: &[EdgeJacobian<D>], v: faer::MatRef<'_, f64>) -> Vec<f64> {
        let mut gradient = vec![0.0; self.step.len()];
        for (m, jacobian) in jacobians.iter().enumerate() {
            let v_m = SVector::<f64, D>::from_fn(|a, _| v[(D * m + a, 0)]);
            for (b, j) in jacobian {
                if let Some(b) = b {
                    let g = j.transpose() * v_m;
                    (gradient[b * D..b * D + D].iter_mut().zip(g.iter()))
                        .for_each(|(x, v)| *x += v);
                }
            }
        }
        gradient
    }

    /// The largest distance a pose's position moves, to first order, by
    /// `δ = H⁻¹·g` (`g` by variable block: [`CommonOffset::gradient`] for
    /// the part of the map's move without a cluster,
    /// `H⁻¹·J_Aᵀ·S⁻¹·e_A` of the module doc, that its common offset makes;
    /// [`Self::adding`] for the move candidates outside the map would
    /// make), each pose retracted by its block of `δ`.
    pub fn largest_move(&mut self, g: &[f64]) -> f64 {
        self.largest_moves(&[g.to_vec()])[0]
    }

    /// [`Self::largest_move`] of each of the gradients `gs`, as many to a
    /// pass over the factor as [`Self::moves_per_pass`] allows.
    pub fn largest_moves(&mut self, gs: &[Vec<f64>]) -> Vec<f64> {
        (gs.chunks(self.moves_per_pass()))
            .flat_map(|chunk| self.moves_at_once(chunk))
            .collect()
    }

    /// The gradients one pass of [`Self::largest_moves`] solves: as many
    /// as the larger of [`MOVES_MEMORY`] and a fifth of the factor's values
    /// hold, two copies of the map's variables each, and at least
    /// [`MOVES_AT_ONCE`].
    fn moves_per_pass(&self) -> usize {
        let bytes = std::mem::size_of::<f64>();
        let budget = MOVES_MEMORY.max(self.optimizer.system().nnz_factor() * bytes / 5);
        let per_gradient = 2 * self.step.len().max(1) * bytes;
        (budget / per_gradient).max(MOVES_AT_ONCE)
    }

    /// [`Self::largest_moves`] of `gs` in one pass over the factor.
    fn moves_at_once(&mut self, gs: &[Vec<f64>]) -> Vec<f64> {
        if gs.is_empty() {
            return Vec::new();
        }
        let mut delta: Vec<f64> = gs.concat();
        // The system's solve gives −H⁻¹·g from its factorisation of H.
        self.optimizer.solve_factored(&mut delta, gs.len());
        let n = self.step.len();
        (0..gs.len())
            .map(|c| {
                (delta[c * n..(c + 1) * n].chunks_exact(D))
                    .map(|block| P::position_shift(&SVector::from_column_slice(block)))
                    .fold(0.0, f64::max)
            })
            .collect()
    }

    /// Whether it took the selected inverse ([`Evaluation::for_clusters`]).
    #[cfg(test)]
    pub fn holds_inverse(&self) -> bool {
        self.inverse.is_some()
    }

    /// The threads the solver works on.
    pub fn parallelism(&self) -> &Parallelism {
        self.optimizer.parallelism()
    }

    /// Makes the innovations of candidates `open` exact (lone candidates
    /// outside the map).
    pub fn refine(&mut self, edges: &[usize], open: &[usize], innov: &mut Innovations) {
        let groups: Vec<(Vec<usize>, usize)> = (open.iter())
            .filter(|&&k| !innov.exact[k])
            .map(|&k| (vec![k], 0))
            .collect();
        let judged = self.judge_all(edges, &groups, true);
        for ((members, _), (nu2, _, _)) in groups.iter().zip(judged) {
            innov.nu2[members[0]] = nu2[0];
            innov.exact[members[0]] = true;
        }
    }

    /// [`Self::cluster`] of each `(members, a)` of `groups`, on the
    /// solver's threads. The values are those of one cluster at a time,
    /// whatever the threads.
    fn judge_all(
        &self,
        edges: &[usize],
        groups: &[(Vec<usize>, usize)],
        exact: bool,
    ) -> Vec<Judged> {
        (self.optimizer.parallelism()).map(groups, |(members, a)| {
            let mut scratch = self
                .scratch
                .lock()
                .ok()
                .and_then(|mut s| s.pop())
                .unwrap_or_default();
            let judged = self.cluster(edges, members, *a, exact || members.len() > 1, &mut scratch);
            if let Ok(mut pool) = self.scratch.lock() {
                pool.push(scratch);
            }
            judged
        })
    }

    /// The errors, Jacobians and covariances of candidates `members` at the
    /// map.
    fn linearise(&self, edges: &[usize], members: &[usize]) -> Linearised<D> {
        let graph = self.graph;
        let mut lin = Linearised {
            errors: Vec::with_capacity(members.len()),
            jacobians: Vec::with_capacity(members.len()),
            covariances: Vec::with_capacity(members.len()),
        };
        for &k in members {
            let e = &graph.edges[edges[k]];
            let l =
                P::error_and_jacobians(&graph.poses[e.from], &graph.poses[e.to], &e.measurement);
            // The error at the exact map of the linearisation: e + J·δ.
            let mut error = l.error;
            for (b, jac) in [(self.block[e.from], &l.jac_i), (self.block[e.to], &l.jac_j)] {
                if let Some(b) = b {
                    error +=
                        jac * SVector::<f64, D>::from_column_slice(&self.step[b * D..b * D + D]);
                }
            }
            lin.errors.push(error);
            lin.jacobians
                .push([(self.block[e.from], l.jac_i), (self.block[e.to], l.jac_j)]);
            lin.covariances.push(e.information.try_inverse());
        }
        lin
    }

    /// `J·H⁻¹·Jᵀ` of the stacked `jacobians`: from the selected inverse or
    /// the sparse solves, whichever costs less, when the evaluation holds
    /// it; otherwise by the solves.
    fn gram(&self, jacobians: &[EdgeJacobian<D>], scratch: &mut GroupScratch) -> DMatrix<f64> {
        let system = self.optimizer.system();
        match &self.inverse {
            Some(inverse) => system.propagate_group_cheaper(inverse, jacobians, scratch),
            None => system.propagate_group_solved(jacobians, scratch),
        }
    }

    /// One cluster's members (the first `a` in the map): their `ν²`, the
    /// joint statistic, and whether they are exact. A lone candidate
    /// outside the map off the factor's pattern gets a lower bound unless
    /// `exact` asks for more.
    fn cluster(
        &self,
        edges: &[usize],
        members: &[usize],
        a: usize,
        exact: bool,
        scratch: &mut GroupScratch,
    ) -> Judged {
        let lin = self.linearise(edges, members);
        let system = self.optimizer.system();
        let gram = match &self.inverse {
            Some(inverse) if a == 0 && members.len() == 1 && !exact => {
                // Its bound unless its blocks of H⁻¹ are on the pattern.
                let Some(gram) = system.propagate_group_selected(inverse, &lin.jacobians, 0) else {
                    let bound = system.propagate_bound(inverse, &lin.jacobians[0]);
                    let nu2 = lin.covariances[0]
                        .and_then(|c| (c + bound).cholesky())
                        .map(|c| lin.errors[0].dot(&c.solve(&lin.errors[0])));
                    return (vec![nu2], (Some(0.0), None, None), false);
                };
                gram
            }
            _ => self.gram(&lin.jacobians, scratch),
        };
        let (nu2, joint, common, moves) =
            judge_cluster(&lin.errors, &lin.covariances, &gram, (a, self.within));
        (nu2, (joint, common, moves), true)
    }
}

/// Gives an innovation to the members of every cluster of `clusters` (of
/// the candidates `edges`; `accepted[k]`: the map in the session was
/// solved with candidate `k`, the edges of non-zero `weights`) that `innov`
/// left without one although edges of the map outside the cluster join
/// both ends of each member (module doc). The system without the cluster
/// is factorised at the map; its Gauss–Newton step `δ` gives the map
/// without the cluster to first order, as the formulas give it every other
/// cluster. The members are judged as candidates outside that map (the
/// evaluation reads their errors at it, `e + J·δ`), and the joint
/// statistic is the drop of `Σ eᵀΩe` to it: the cluster's own terms and
/// the decrease the step predicts for the rest. The session's map does not
/// move (the optimiser's factorisation is then the last cluster's: an
/// evaluation factorises its own). Clusters that nothing else joins keep
/// `None`: their prior decides.
pub fn through_wide_chains<P: Pose<D>, const D: usize>(
    session: &mut Session<'_, P, D>,
    weights: &[f64],
    (edges, accepted, clusters): (&[usize], &[bool], &[Vec<usize>]),
    innov: &mut Innovations,
) -> Result<(), SolveError> {
    let open: Vec<usize> = (0..clusters.len())
        .filter(|&c| unchecked(&clusters[c], accepted, innov))
        .filter(|&c| joined_without(session.graph, weights, edges, &clusters[c]))
        .collect();
    if open.is_empty() {
        return Ok(());
    }
    let outside = vec![false; accepted.len()];
    for c in open {
        let (cluster, members) = (&clusters[c], std::slice::from_ref(&clusters[c]));
        let mut without = weights.to_vec();
        cluster.iter().for_each(|&k| without[edges[k]] = 0.0);
        let own = session
            .graph
            .chi2_where(|i| weights[i] > 0.0 && without[i] == 0.0);
        let (optimizer, graph) = (&mut *session.optimizer, &*session.graph);
        let mut eval =
            Evaluation::for_clusters_without(optimizer, graph, &without, (edges, members))?
                .judging_within_clusters(false);
        let relaxed = eval.optimizer.system().predicted_decrease(&eval.step);
        let judged = eval.innovations(edges, &outside, members, true);
        for &k in cluster {
            innov.nu2[k] = judged.nu2[k];
            innov.exact[k] = true;
        }
        // Both drops are to exact maps: the system without the cluster's
        // from the map, less the map's own to the exact one.
        innov.joint[c] = Some((own + relaxed - innov.remaining).max(0.0));
    }
    Ok(())
}

/// Candidates outside the map whose ends it joins only through unchecked
/// clusters (members in the map, `ν²` `None`: the cluster alone ties part
/// of the map) are unchecked too: their `ν²` set to `None`, their prior
/// deciding. Judged against the part an unchecked cluster placed, they
/// would speak against it with its own placement, however right they are
/// and however wrong it is; in the map with both, each is judged against
/// the other.
pub fn beside_unchecked<P: Pose<D>, const D: usize>(
    graph: &Graph<P, D>,
    weights: &[f64],
    (edges, accepted, clusters): (&[usize], &[bool], &[Vec<usize>]),
    innov: &mut Innovations,
) {
    let mut held_by_prior = vec![false; graph.edges.len()];
    (clusters.iter())
        .filter(|c| unchecked(c, accepted, innov))
        .for_each(|c| c.iter().for_each(|&k| held_by_prior[edges[k]] = true));
    if !held_by_prior.contains(&true) {
        return;
    }
    let mut parts = graph.parts(|i| weights[i] > 0.0 && !held_by_prior[i]);
    for (k, &i) in edges.iter().enumerate() {
        let e = &graph.edges[i];
        if !accepted[k] && parts.find(e.from) != parts.find(e.to) {
            innov.nu2[k] = None;
        }
    }
}

/// Whether the cluster `members` is unchecked in `innov`: some of it in the
/// map (`accepted`), and no member given a `ν²`.
fn unchecked(members: &[usize], accepted: &[bool], innov: &Innovations) -> bool {
    members.iter().any(|&k| accepted[k]) && members.iter().all(|&k| innov.nu2[k].is_none())
}

/// Whether the edges of non-zero `weights` outside `members` (indices into
/// the candidates' `edges`) join both ends of every member, the gauge's
/// vertices counting as joined.
fn joined_without<P: Pose<D>, const D: usize>(
    graph: &Graph<P, D>,
    weights: &[f64],
    edges: &[usize],
    members: &[usize],
) -> bool {
    let cluster: Vec<usize> = members.iter().map(|&k| edges[k]).collect();
    let mut parts = graph.parts(|i| weights[i] > 0.0 && !cluster.contains(&i));
    cluster.iter().all(|&i| {
        let e = &graph.edges[i];
        parts.find(e.from) == parts.find(e.to)
    })
}

/// A cluster's errors, all its members in the map, split into the part
/// one offset shared by every member explains and the rest
/// ([`Evaluation::common_offset`]), with what the move of the map that
/// the offset makes is found from ([`Evaluation::largest_move`]).
#[derive(Clone, Debug)]
pub struct CommonOffset {
    /// `e_Aᵀ·S⁻¹·e_A`: by how much `Σ eᵀΩe` drops without the cluster
    /// (χ² with `D·members` degrees of freedom for true loops).
    pub joint: f64,
    /// The share of `joint` one offset common to every member explains
    /// (χ² with `D` degrees of freedom for true loops, whose errors are
    /// independent; the rest has `D·(members − 1)`).
    pub common: f64,
    /// The members.
    pub members: usize,
    /// `J_Aᵀ·S⁻¹·U·b̂` by variable block (`b̂` the offset, `U` the stacked
    /// identities).
    gradient: Vec<f64>,
}

impl CommonOffset {
    /// `J_Aᵀ·S⁻¹·U·b̂` by variable block: `H⁻¹` of it is the move of the
    /// map the offset makes ([`Evaluation::largest_move`]).
    pub fn gradient(&self) -> &[f64] {
        &self.gradient
    }
}

/// A cluster's members' `ν²`, its joint statistic and common offset's
/// share of it, and whether the `ν²` are exact ([`Innovations`]).
type Judged = (
    Vec<Option<f64>>,
    (Option<f64>, Option<f64>, Option<f64>),
    bool,
);

/// Candidates linearised at the map: what their innovations are made of.
struct Linearised<const D: usize> {
    errors: Vec<SVector<f64, D>>,
    jacobians: Vec<EdgeJacobian<D>>,
    covariances: Vec<Option<SMatrix<f64, D, D>>>,
}

/// `y = L⁻¹·e` and `|y|²` for the stacked `errors` `e` (`S = L·Lᵀ` their
/// covariance): `eᵀ·S⁻¹·e`.
fn whiten<const D: usize>(
    l: faer::MatRef<'_, f64>,
    errors: &[SVector<f64, D>],
) -> (faer::Mat<f64>, f64) {
    let mut y = faer::Mat::from_fn(D * errors.len(), 1, |r, _| errors[r / D][r % D]);
    solve_lower_triangular_in_place(l, y.as_mut(), Par::Seq);
    let norm2 = y.col(0).iter().map(|v| v * v).sum::<f64>();
    (y, norm2)
}

/// The part of `y = L⁻¹·e_A` (`S = L·Lᵀ` the covariance of the stacked
/// errors `e_A` of a cluster's members in the map) that one offset `b`
/// shared by every member explains: with `e_A = U·b + noise`, `U` the
/// stacked `D×D` identities, the projection `ŷ = L⁻¹·U·b̂` of `y` on the
/// columns of `L⁻¹·U`. Returns `|ŷ|²` (at most `|y|²`), `L⁻¹·U` and `b̂`;
/// `None` where those columns are degenerate.
fn common_part<const D: usize>(
    l: faer::MatRef<'_, f64>,
    y: faer::MatRef<'_, f64>,
) -> Option<(f64, faer::Mat<f64>, DVector<f64>)> {
    let n = y.nrows();
    let mut u = faer::Mat::from_fn(n, D, |r, c| if r % D == c { 1.0 } else { 0.0 });
    solve_lower_triangular_in_place(l, u.as_mut(), Par::Seq);
    let utu = DMatrix::from_fn(D, D, |a, b| {
        (0..n).map(|i| u[(i, a)] * u[(i, b)]).sum::<f64>()
    });
    let uty = DVector::from_fn(D, |a, _| (0..n).map(|i| u[(i, a)] * y[(i, 0)]).sum::<f64>());
    let b = utu.cholesky()?.solve(&uty);
    let total = (0..n).map(|i| y[(i, 0)] * y[(i, 0)]).sum::<f64>();
    Some((b.dot(&uty).clamp(0.0, total), u, b))
}

/// A cluster's members' `ν²` (the first `a` in the map), its joint
/// statistic, and with two or more members in the map the share of it one
/// common offset explains ([`common_part`]); with `within`, each member's
/// `ν²` the larger of that and its `ν²` against the map with the members
/// that agree better ([`against_better`]).
fn judge_cluster<const D: usize>(
    errors: &[nalgebra::SVector<f64, D>],
    covariances: &[Option<SMatrix<f64, D, D>>],
    gram: &DMatrix<f64>,
    (a, within): (usize, bool),
) -> (Vec<Option<f64>>, Option<f64>, Option<f64>, Option<f64>) {
    let m = errors.len();
    let Some(sigma) = covariances.iter().copied().collect::<Option<Vec<_>>>() else {
        return (vec![None; m], None, None, None);
    };
    let (na, nr) = (D * a, D * (m - a));
    // S = Σ_A − M_AA = L·Lᵀ; y = L⁻¹·e_A, so e_Aᵀ·S⁻¹·e_A = |y|².
    let Some(l) = cholesky_of_s(&sigma[..a], gram, na) else {
        return (vec![None; m], None, None, None);
    };
    let (y, joint) = whiten(l.as_ref(), &errors[..a]);
    let common = (a >= 2)
        .then(|| common_part::<D>(l.as_ref(), y.as_ref()))
        .flatten()
        .map(|(share, _, _)| share);
    let mut s_inv_e = y.clone();
    solve_upper_triangular_in_place(l.transpose(), s_inv_e.as_mut(), Par::Seq);
    let s_inv_e = DVector::from_fn(na, |r, _| s_inv_e[(r, 0)]);
    // gᵀ·H⁻¹·g = vᵀ·M_AA·v with v = S⁻¹·e_A (Evaluation::removing).
    let moves = (a > 0).then(|| s_inv_e.dot(&(gram.view((0, 0), (na, na)) * &s_inv_e)));
    // The diagonal blocks of S⁻¹ = WᵀW with W = L⁻¹, for the members of A;
    // X = L⁻¹·M_AR, for those of R: M_RA·S⁻¹·M_AR = XᵀX.
    let mut w = faer::Mat::<f64>::identity(na, na);
    solve_lower_triangular_in_place(l.as_ref(), w.as_mut(), Par::Seq);
    let mut x = faer::Mat::from_fn(na, nr, |r, c| gram[(r, na + c)]);
    solve_lower_triangular_in_place(l.as_ref(), x.as_mut(), Par::Seq);
    // Block k of ZᵀZ, from the rows of Z at and after `from`.
    let gram_block = |z: faer::MatRef<'_, f64>, k: usize, from: usize| {
        SMatrix::<f64, D, D>::from_fn(|r, c| {
            (from..na)
                .map(|i| z[(i, D * k + r)] * z[(i, D * k + c)])
                .sum()
        })
    };
    let mut nu2 = Vec::with_capacity(m);
    for k in 0..m {
        let (ek, ck) = if k < a {
            let s_k = sigma[k];
            let e = s_k * s_inv_e.fixed_rows::<D>(D * k);
            // W is lower triangular: its rows above block k are zero there.
            (e, s_k * gram_block(w.as_ref(), k, D * k) * s_k)
        } else {
            let r = k - a;
            let m_ra = gram.view((na + D * r, 0), (D, na));
            let e = errors[k] + m_ra * &s_inv_e;
            let m_rr = gram.fixed_view::<D, D>(na + D * r, na + D * r);
            let propagated = gram_block(x.as_ref(), r, 0);
            (
                SVector::<f64, D>::from_column_slice(e.as_slice()),
                sigma[k] + m_rr + propagated,
            )
        };
        nu2.push(ck.cholesky().map(|c| ek.dot(&c.solve(&ek))));
    }
    let nu2 = if within && m > 1 {
        against_better(errors, &sigma, gram, a, nu2)
    } else {
        nu2
    };
    let joint = Some(joint).filter(|j| j.is_finite());
    let moves = moves.filter(|q| q.is_finite() && joint.is_some());
    (nu2, joint, common.filter(|_| joint.is_some()), moves)
}

/// Each member's `ν²` made the larger of `apart` (against the map without
/// the cluster) and its `ν²` against the map with those of the cluster's
/// members in the map that agree better with the rest of it (a smaller
/// `apart`) and without the others. A run of wrong loops cannot vouch for
/// its members (the map without the cluster judges them), and a true loop
/// in the cluster speaks against a wrong one beside it that measures the
/// same stretch otherwise (the map with the true loop judges it).
///
/// In the order of `apart` from the largest, the members the map was
/// solved with that agree worse than member `k`, and `k` itself if it is
/// one, are a prefix `B`: `k` is judged against the map without `B` by the
/// formulas of [`judge_cluster`] on `S_B`, the leading block of `S` in
/// that order, whose Cholesky factor is the leading block of `S`'s.
fn against_better<const D: usize>(
    errors: &[SVector<f64, D>],
    sigma: &[SMatrix<f64, D, D>],
    gram: &DMatrix<f64>,
    a: usize,
    apart: Vec<Option<f64>>,
) -> Vec<Option<f64>> {
    let key = |k: usize| apart[k].unwrap_or(f64::INFINITY);
    let mut order: Vec<usize> = (0..a).collect();
    order.sort_by(|&i, &j| key(j).total_cmp(&key(i)).then(i.cmp(&j)));
    let na = D * a;
    let at = |r: usize| D * order[r / D] + r % D;
    let sigma_b: Vec<_> = order.iter().map(|&k| sigma[k]).collect();
    let gram_b = DMatrix::from_fn(na, na, |r, c| gram[(at(r), at(c))]);
    let Some(l) = cholesky_of_s(&sigma_b, &gram_b, na) else {
        return apart;
    };
    let mut y = faer::Mat::from_fn(na, 1, |r, _| errors[order[r / D]][r % D]);
    solve_lower_triangular_in_place(l.as_ref(), y.as_mut(), Par::Seq);
    (0..errors.len())
        .map(|k| {
            let in_b = k < a;
            let worse = match order.iter().position(|&j| j == k) {
                Some(position) => position,
                None => order.iter().filter(|&&j| key(j) > key(k)).count(),
            };
            let nb = D * (worse + usize::from(in_b));
            if nb == na {
                // Every member in the map is taken out: that is `apart`.
                return apart[k];
            }
            let mut s_inv_e = y.subrows(0, nb).to_owned();
            solve_upper_triangular_in_place(
                l.submatrix(0, 0, nb, nb).transpose(),
                s_inv_e.as_mut(),
                Par::Seq,
            );
            let (e, c) = if in_b {
                // The last block of the prefix: (S_B⁻¹)_kk = L_kk⁻ᵀ·L_kk⁻¹.
                let w = SMatrix::<f64, D, D>::from_fn(|r, c| l[(nb - D + r, nb - D + c)]);
                let w_inv = w.try_inverse().unwrap_or_else(SMatrix::zeros);
                let e = sigma[k] * SVector::<f64, D>::from_fn(|r, _| s_inv_e[(nb - D + r, 0)]);
                (e, sigma[k] * w_inv.transpose() * w_inv * sigma[k])
            } else {
                let m_kb = |r: usize, c: usize| gram[(D * k + r, at(c))];
                let mut x = faer::Mat::from_fn(nb, D, |r, c| m_kb(c, r));
                solve_lower_triangular_in_place(l.submatrix(0, 0, nb, nb), x.as_mut(), Par::Seq);
                let e = errors[k]
                    + SVector::<f64, D>::from_fn(|r, _| {
                        (0..nb).map(|i| m_kb(r, i) * s_inv_e[(i, 0)]).sum()
                    });
                let xtx = SMatrix::<f64, D, D>::from_fn(|r, c| {
                    (0..nb).map(|i| x[(i, r)] * x[(i, c)]).sum()
                });
                let m_kk = gram.fixed_view::<D, D>(D * k, D * k);
                (e, sigma[k] + m_kk + xtx)
            };
            let with_better = c.cholesky().map_or(0.0, |c| e.dot(&c.solve(&e)));
            apart[k].map(|v| v.max(with_better))
        })
        .collect()
}

/// The lower Cholesky factor of `S = Σ_A − M_AA` (`na × na`; `sigma`: the
/// members' covariances, `M_AA` the top-left block of `gram`), `None` when
/// `S` is not positive definite to the precision of its largest entry
/// (its smallest pivot squared at most 10⁻¹² of it); empty for `na = 0`.
fn cholesky_of_s<const D: usize>(
    sigma: &[SMatrix<f64, D, D>],
    gram: &DMatrix<f64>,
    na: usize,
) -> Option<faer::Mat<f64>> {
    let mut l = faer::Mat::from_fn(na, na, |r, c| {
        let within = r / D == c / D;
        let s = if within {
            sigma[r / D][(r % D, c % D)]
        } else {
            0.0
        };
        s - gram[(r, c)]
    });
    if na == 0 {
        return Some(l);
    }
    let scale = (0..na)
        .flat_map(|c| (0..na).map(move |r| (r, c)))
        .fold(0.0f64, |m, (r, c)| m.max(l[(r, c)].abs()));
    let mut mem = MemBuffer::new(cholesky_in_place_scratch::<f64>(
        na,
        Par::Seq,
        Default::default(),
    ));
    cholesky_in_place(
        l.as_mut(),
        LltRegularization::default(),
        Par::Seq,
        MemStack::new(&mut mem),
        Default::default(),
    )
    .ok()?;
    for c in 0..na {
        for r in 0..c {
            l[(r, c)] = 0.0;
        }
    }
    let min_pivot = (0..na).fold(f64::INFINITY, |m, k| m.min(l[(k, k)]));
    (min_pivot * min_pivot > 1e-12 * scale).then_some(l)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Matrix1, Vector1};

    /// Scalar loops on a line with H known: a map x with two "loops" each
    /// measuring x (Σ = 1) and a prior x ~ N(0, 1): H = 3. The errors at the
    /// map are those of a linear fit of measurements z₁, z₂ and the prior 0.
    #[test]
    fn cluster_formulas_match_refitting_without_the_cluster() {
        let (z1, z2, z3) = (1.0, 2.5, 7.0);
        // Map of the prior and z1, z2 (z3 left out): x = (z1 + z2) / 3.
        let x = (z1 + z2) / 3.0;
        let errors = [
            Vector1::new(x - z1),
            Vector1::new(x - z2),
            Vector1::new(x - z3),
        ];
        let cov = [Some(Matrix1::new(1.0)); 3];
        let hinv = 1.0 / 3.0;
        let gram = DMatrix::from_element(3, 3, hinv);
        // Cluster {z1, z2} in the map, z3 out.
        let (nu2, joint, _, _) = judge_cluster(&errors, &cov, &gram, (2, true));
        // Without z1 and z2 the map is the prior alone: x = 0 with variance
        // 1, so each innovation is z²/(1 + 1). z1 and z2 agree with it
        // better than z3 does, so z3 is also judged against the map with
        // them: x with variance 1/3, (z3 − x)²/(1 + 1/3), the larger.
        let against_map = (z3 - x).powi(2) / (1.0 + hinv);
        for (v, want) in nu2.iter().zip([z1 * z1 / 2.0, z2 * z2 / 2.0, against_map]) {
            assert!((v.unwrap() - want).abs() < 1e-12, "{v:?} {want}");
        }
        // The drop of Σ eᵀΩe: with them (z1 − x)² + (z2 − x)² + x², without 0.
        let with = (z1 - x).powi(2) + (z2 - x).powi(2) + x * x;
        assert!((joint.unwrap() - with).abs() < 1e-12);
    }

    /// A true loop and a wrong one measuring the same pose (z = 0 and 5,
    /// Σ = 1), both in the map, over a prior that knows little (variance
    /// 100): without the cluster neither is checked much (0 and 25/101),
    /// but the wrong one is judged against the map with the true one,
    /// which agrees better with the rest: x = 0 with variance 100/101.
    #[test]
    fn a_true_loop_speaks_against_a_wrong_one_of_its_cluster() {
        let (z_true, z_wrong, prior) = (0.0, 5.0, 100.0);
        let h = 1.0 / prior + 2.0;
        let x = (z_true + z_wrong) / h;
        let errors = [Vector1::new(x - z_true), Vector1::new(x - z_wrong)];
        let gram = DMatrix::from_element(2, 2, 1.0 / h);
        let (nu2, _, _, _) =
            judge_cluster(&errors, &[Some(Matrix1::new(1.0)); 2], &gram, (2, true));
        let with_true = 1.0 / (1.0 / prior + 1.0);
        let want = [0.0, z_wrong.powi(2) / (1.0 + with_true)];
        for (v, want) in nu2.iter().zip(want) {
            assert!((v.unwrap() - want).abs() < 1e-9, "{v:?} {want}");
        }
        assert!(want[1] > 12.0 && z_wrong.powi(2) / (1.0 + prior) < 0.25);
    }

    #[test]
    fn a_cluster_nothing_else_checks_has_no_innovation() {
        // One loop is the only tie: H⁻¹ gives it M = Σ, S = 0.
        let errors = [Vector1::new(0.3)];
        let (nu2, joint, _, _) = judge_cluster(
            &errors,
            &[Some(Matrix1::new(2.0))],
            &DMatrix::from_element(1, 1, 2.0),
            (1, true),
        );
        assert_eq!((nu2, joint), (vec![None], None));
    }

    #[test]
    fn a_common_offset_explains_what_the_members_share_and_nothing_else() {
        // S = I: two 3-D members with the same error share all of it;
        // opposite errors share none; otherwise the mean's share, 2·|mean|².
        let l = faer::Mat::<f64>::identity(6, 6);
        let share = |e: [f64; 6]| {
            let y = faer::Mat::from_fn(6, 1, |r, _| e[r]);
            common_part::<3>(l.as_ref(), y.as_ref()).unwrap().0
        };
        assert!((share([1.0, 2.0, 3.0, 1.0, 2.0, 3.0]) - 28.0).abs() < 1e-12);
        assert!(share([1.0, 0.0, 0.0, -1.0, 0.0, 0.0]).abs() < 1e-12);
        assert!((share([2.0, 0.0, 0.0, 0.0, 0.0, 0.0]) - 2.0).abs() < 1e-12);
    }
}
