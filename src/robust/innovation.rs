//! Every loop candidate's innovation against the map made without its
//! cluster ([`super::clusters`]): the evidence the loop model weighs.
//!
//! At the least-squares map of the trusted edges and the accepted
//! candidates (normal matrix `H`), take a cluster's candidates: `A` those
//! the map was solved with, `R` the others; `e` their errors, `Σ = Ω⁻¹` their
//! covariances, `M = J·H⁻¹·Jᵀ` ([`BlockSystem::propagate_group`]). To first
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
//! that covariance. A cluster of one is judged by the plain deleted
//! residual or innovation. When `S` is singular — the cluster is all that
//! ties part of the map — the map without it says nothing about it: `None`.
//!
//! [`BlockSystem::propagate_group`]: crate::linear::BlockSystem::propagate_group

use crate::geometry::Pose;
use crate::graph::PoseGraph;
use crate::linear::{EdgeJacobian, GroupScratch, Parallelism, SelectedInverse};
use crate::solve::{Optimizer, SolveError};
use nalgebra::{DMatrix, DVector, SMatrix, SVector};
use std::sync::Mutex;

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
}

/// The factorisation and selected inverse of one map, for the innovations
/// of its candidates.
pub struct Evaluation<'a, P: Pose<D>, const D: usize> {
    optimizer: &'a mut Optimizer<P, D>,
    graph: &'a PoseGraph<P, D>,
    block: Vec<Option<usize>>,
    inverse: SelectedInverse,
    /// Scratch of the sparse solves, one per thread at work.
    scratch: Mutex<Vec<GroupScratch>>,
}

impl<'a, P: Pose<D>, const D: usize> Evaluation<'a, P, D> {
    /// Factorises the normal matrix of the map (the graph's poses, the
    /// least-squares map of the edges of non-zero `weights`) and takes its
    /// selected inverse.
    pub fn new(
        optimizer: &'a mut Optimizer<P, D>,
        graph: &'a PoseGraph<P, D>,
        weights: &[f64],
    ) -> Result<Self, SolveError> {
        let block = optimizer.factor_at(graph, weights)?;
        let inverse = optimizer.system().selected_inverse();
        Ok(Self {
            optimizer,
            graph,
            block,
            inverse,
            scratch: Mutex::default(),
        })
    }

    /// The innovations of candidates `edges` (edge indices; `accepted[k]`:
    /// the map was solved with it) grouped by `clusters`.
    pub fn innovations(
        &mut self,
        edges: &[usize],
        accepted: &[bool],
        clusters: &[Vec<usize>],
    ) -> Innovations {
        let mut out = Innovations {
            nu2: vec![None; edges.len()],
            exact: vec![true; edges.len()],
            joint: Vec::with_capacity(clusters.len()),
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
        let judged = self.judge_all(edges, &groups, false);
        for ((members, _), (nu2, joint, exact)) in groups.iter().zip(judged) {
            for (&k, v) in members.iter().zip(nu2) {
                out.nu2[k] = v;
                out.exact[k] = exact;
            }
            out.joint.push(joint);
        }
        out
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
            lin.errors.push(l.error);
            lin.jacobians
                .push([(self.block[e.from], l.jac_i), (self.block[e.to], l.jac_j)]);
            lin.covariances.push(e.information.try_inverse());
        }
        lin
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
        if a == 0 && members.len() == 1 && !exact {
            // Its bound unless its blocks of H⁻¹ are on the pattern.
            let Some(gram) = system.propagate_group_selected(&self.inverse, &lin.jacobians, 0)
            else {
                let bound = system.propagate_bound(&self.inverse, &lin.jacobians[0]);
                let nu2 = lin.covariances[0]
                    .and_then(|c| (c + bound).cholesky())
                    .map(|c| lin.errors[0].dot(&c.solve(&lin.errors[0])));
                return (vec![nu2], Some(0.0), false);
            };
            let (nu2, joint) = judge_cluster(&lin.errors, &lin.covariances, &gram, a);
            return (nu2, joint, true);
        }
        let gram = system.propagate_group_cheaper(&self.inverse, &lin.jacobians, scratch);
        let (nu2, joint) = judge_cluster(&lin.errors, &lin.covariances, &gram, a);
        (nu2, joint, true)
    }
}

/// A cluster's members' `ν²`, its joint statistic, and whether the `ν²`
/// are exact ([`Innovations`]).
type Judged = (Vec<Option<f64>>, Option<f64>, bool);

/// Candidates linearised at the map: what their innovations are made of.
struct Linearised<const D: usize> {
    errors: Vec<SVector<f64, D>>,
    jacobians: Vec<EdgeJacobian<D>>,
    covariances: Vec<Option<SMatrix<f64, D, D>>>,
}

fn judge_cluster<const D: usize>(
    errors: &[nalgebra::SVector<f64, D>],
    covariances: &[Option<SMatrix<f64, D, D>>],
    gram: &DMatrix<f64>,
    a: usize,
) -> (Vec<Option<f64>>, Option<f64>) {
    let m = errors.len();
    let mut sigma = DMatrix::zeros(D * m, D * m);
    let mut e = DVector::zeros(D * m);
    for (k, (err, cov)) in errors.iter().zip(covariances).enumerate() {
        let Some(cov) = cov else {
            return (vec![None; m], None);
        };
        sigma.view_mut((D * k, D * k), (D, D)).copy_from(cov);
        e.rows_mut(D * k, D).copy_from(err);
    }
    let (na, nr) = (D * a, D * (m - a));
    let s = sigma.view((0, 0), (na, na)) - gram.view((0, 0), (na, na));
    let Some(s_inv) = symmetric_inverse(&s.into_owned()) else {
        return (vec![None; m], None);
    };
    let e_a = e.rows(0, na).into_owned();
    let s_inv_e = &s_inv * &e_a;
    let joint = e_a.dot(&s_inv_e);
    let sigma_a = sigma.view((0, 0), (na, na)).into_owned();
    let e_tilde_a = &sigma_a * &s_inv_e;
    let cov_a = &sigma_a * &s_inv * &sigma_a;
    let m_ra = gram.view((na, 0), (nr, na)).into_owned();
    let e_tilde_r = e.rows(na, nr) + &m_ra * &s_inv_e;
    let cov_r = sigma.view((na, na), (nr, nr))
        + gram.view((na, na), (nr, nr))
        + &m_ra * &s_inv * m_ra.transpose();
    let mut nu2 = Vec::with_capacity(m);
    for k in 0..m {
        let (ek, ck) = if k < a {
            (
                e_tilde_a.rows(D * k, D).into_owned(),
                cov_a.view((D * k, D * k), (D, D)).into_owned(),
            )
        } else {
            let r = k - a;
            (
                e_tilde_r.rows(D * r, D).into_owned(),
                cov_r.view((D * r, D * r), (D, D)).into_owned(),
            )
        };
        nu2.push(ck.cholesky().map(|c| ek.dot(&c.solve(&ek))));
    }
    (nu2, Some(joint).filter(|j| j.is_finite()))
}

/// The inverse of a symmetric matrix that should be positive definite,
/// `None` when it is not (to the precision of its largest entry): an
/// empty matrix inverts to an empty one.
fn symmetric_inverse(s: &DMatrix<f64>) -> Option<DMatrix<f64>> {
    if s.nrows() == 0 {
        return Some(s.clone());
    }
    let scale = s.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let chol = s.clone().cholesky()?;
    let min_pivot = chol
        .l()
        .diagonal()
        .iter()
        .fold(f64::INFINITY, |m, v| m.min(*v));
    (min_pivot * min_pivot > 1e-12 * scale).then(|| chol.inverse())
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
        let (nu2, joint) = judge_cluster(&errors, &cov, &gram, 2);
        // Without z1 and z2 the map is the prior alone: x = 0 with variance
        // 1, so each innovation is z²/(1 + 1).
        for (v, z) in nu2.iter().zip([z1, z2, z3]) {
            assert!((v.unwrap() - z * z / 2.0).abs() < 1e-12, "{v:?} {z}");
        }
        // The drop of Σ eᵀΩe: with them (z1 − x)² + (z2 − x)² + x², without 0.
        let with = (z1 - x).powi(2) + (z2 - x).powi(2) + x * x;
        assert!((joint.unwrap() - with).abs() < 1e-12);
    }

    #[test]
    fn a_cluster_nothing_else_checks_has_no_innovation() {
        // One loop is the only tie: H⁻¹ gives it M = Σ, S = 0.
        let errors = [Vector1::new(0.3)];
        let (nu2, joint) = judge_cluster(
            &errors,
            &[Some(Matrix1::new(2.0))],
            &DMatrix::from_element(1, 1, 2.0),
            1,
        );
        assert_eq!((nu2, joint), (vec![None], None));
    }
}
