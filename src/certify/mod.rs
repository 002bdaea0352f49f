//! A certificate of global optimality for a returned map (SE-Sync's,
//! Rosen et al., IJRR 2019; Carlone et al., 2015–2016), by one sparse
//! Cholesky factorisation.
//!
//! What is certified: the map is refined on **SE-Sync's isotropic problem**
//! over the edges of the map (trusted edges and accepted loops, at weight
//! 1), each edge weighted by one rotation weight `κ` and one translation
//! weight `τ` from its information matrix ([`problem::isotropic_weights`]);
//! the certificate proves that the refined map is that problem's global
//! optimum, up to `gap_bound` in cost. pgo's own cost weighs each edge by
//! its full information matrix, whose optimum is not a critical point of
//! the isotropic problem, so the certified map is not pgo's map: how far
//! the two are apart is part of the certificate. A map in a wrong basin of
//! pgo's cost refines to a wrong critical point of the isotropic one, and
//! is not certified. The derivation is in `docs/method.md` §10.
//!
//! The steps: [`refine`] (Newton on the isotropic problem from pgo's map),
//! then [`check`] (`S = M − Λ(X)` and a Cholesky factorisation of
//! `S + η·D`); only when that fails, the smallest eigenvalue of `S` and the
//! poses where its vector is largest.

mod check;
pub(crate) mod problem;
mod refine;
#[cfg(test)]
mod tests;

use crate::graph::{self, VertexId};
use crate::report::Report;
use problem::{
    IsotropicEdge, Lift, Map, WeightedEdge, components, isotropic_weights, pose_distance,
};
use serde::Serialize;
use std::time::Instant;

/// The shift `η` of the check, as a fraction of the mean rotation diagonal
/// of the data matrix `M` (per vertex, `Σ κ` over its edges plus the
/// `τ t̃ t̃ᵀ` of those it leaves from). `S + η·D` is factorised in double
/// precision, and at a critical point `S` has exact null directions (the
/// rows of `X`); the shift must lift them above the factorisation's
/// rounding. Measured on intel, cubicle, parking-garage, sphere2500,
/// torus3D, city10000 and manhattan (their maps from `pgo optimize`, the
/// constant changed by hand, with SE-Sync's rotation weights): all certify at every shift down to 10⁻¹²;
/// at 10⁻¹⁴ parking-garage and torus3D fail by rounding (`λ_min` of
/// `−7·10⁻¹³` and `−5·10⁻¹⁰`). 10⁻¹⁰ keeps a factor 100 from there, and
/// is far below what a wrong basin leaves (`λ_min` of the order of `−κ`:
/// about −1.2·10³ on sphere_bignoise left by `--init odometry`).
/// The gap bound `η·d·n` it adds is 10⁻⁷–10⁻⁵ of the cost on those files.
pub const ETA_RELATIVE: f64 = 1e-10;

/// The certificate of a map: whether it is the global optimum of the
/// isotropic problem over its edges (see the module's documentation) and,
/// where it is not, why.
#[derive(Clone, Debug, Serialize)]
pub struct Certificate {
    /// Whether `S + η·D` is positive definite: a proof that the refined map
    /// is the global optimum of the isotropic problem (up to `gap_bound`).
    pub certified: bool,
    /// The shift `η`: every eigenvalue of `Q − Λ` is above `−η` when
    /// certified.
    pub eta: f64,
    /// The isotropic cost `F` of the refined (certified) map.
    pub cost: f64,
    /// The isotropic cost of pgo's map (≥ `cost`).
    pub map_cost: f64,
    /// When certified: `F(X) − F* ≤ gap_bound`, with `F*` the global
    /// optimum (`F(X) − Σ tr Λᵢ + η·d·n`).
    pub gap_bound: Option<f64>,
    /// The largest distance between a pose of the refined map and pgo's
    /// (in the map's units).
    pub max_translation_change: f64,
    /// The largest rotation between a pose of the refined map and pgo's
    /// (radians).
    pub max_rotation_change: f64,
    /// When not certified: the smallest eigenvalue of `Q − Λ` (below
    /// `−η`).
    pub lambda_min: Option<f64>,
    /// When not certified: `[lower, upper]` around `lambda_min` that the
    /// factorisations prove.
    pub lambda_min_bounds: Option<[f64; 2]>,
    /// When not certified: the poses where the eigenvector of `lambda_min`
    /// is largest (up to ten), with their share of its squared norm.
    pub eigenvector_poses: Vec<EigenvectorPose>,
    /// Poses, edges of the map, and connected parts of the map's graph.
    pub poses: usize,
    /// Edges in the map (trusted edges and accepted loops).
    pub edges: usize,
    /// Connected parts (each has its own gauge).
    pub parts: usize,
    /// Refinement steps (Newton's among them) and whether it converged.
    pub refinement_steps: usize,
    /// Of those, Newton steps.
    pub newton_steps: usize,
    /// Whether the refinement's last step was within its tolerance.
    pub refinement_converged: bool,
    /// Where the time went.
    pub time: CertificateTime,
}

impl Certificate {
    /// The certificate as JSON, as in the report of `pgo optimize
    /// --certify --json`. Errors: [`crate::Error::Internal`], which plain
    /// fields like these do not give.
    #[cfg(feature = "json")]
    pub fn to_json(&self) -> Result<String, crate::Error> {
        serde_json::to_string_pretty(self)
            .map_err(|e| crate::Error::Internal(format!("cannot serialise the certificate: {e}")))
    }

    /// One line for humans.
    pub fn summary(&self) -> String {
        let moved = format!(
            "refined map within {:.3e} (translation) and {:.3e} rad of pgo's",
            self.max_translation_change, self.max_rotation_change
        );
        match (self.certified, self.gap_bound, self.lambda_min) {
            (true, Some(gap), _) => format!(
                "certificate: globally optimal (isotropic cost {:.6e}, gap ≤ {gap:.2e}; {moved}), {:.3} s",
                self.cost, self.time.total_s
            ),
            (_, _, Some(lambda)) => {
                let poses: Vec<String> = (self.eigenvector_poses.iter().take(3))
                    .map(|p| format!("{} ({:.0}%)", p.id, 100.0 * p.share))
                    .collect();
                format!(
                    "certificate: NOT certified: λ_min(S) = {lambda:.3e} < −η = {:.3e}, largest at poses {}; {moved}",
                    -self.eta,
                    poses.join(", ")
                )
            }
            _ => format!("certificate: NOT certified (η = {:.3e}); {moved}", self.eta),
        }
    }
}

/// A pose where the eigenvector of `λ_min` is large.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct EigenvectorPose {
    /// The pose's id.
    pub id: VertexId,
    /// Its share of the vector's squared norm (rotation entries).
    pub share: f64,
}

/// Where a certificate's time went, in seconds.
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct CertificateTime {
    /// The refinement on the isotropic problem.
    pub refine_s: f64,
    /// Forming `S` and factorising `S + η·D`.
    pub check_s: f64,
    /// The smallest eigenvalue (only when not certified).
    pub eigen_s: f64,
    /// All of it.
    pub total_s: f64,
}

/// Why a certificate could not be computed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum CertifyError {
    /// More than one pose was held fixed: the certified problem has one
    /// gauge pose per connected part.
    #[error(
        "poses {ids:?} are held fixed: a certificate is of the problem with one fixed pose (the gauge)"
    )]
    SeveralFixed {
        /// The fixed poses' ids.
        ids: Vec<VertexId>,
    },
    /// The map has non-finite numbers.
    #[error("the map has non-finite poses")]
    NonFinite,
    /// The sparse linear algebra failed (memory, threads).
    #[error("certificate: {0}")]
    Linear(String),
}

/// The isotropic problem of a map: its edges with their weights and its
/// gauge, kept with a [`crate::Solution`].
#[derive(Clone, Debug)]
pub(crate) struct Problem<P> {
    edges: Vec<WeightedEdge<P>>,
    /// Vertices held fixed while optimising.
    fixed: Vec<usize>,
}

impl<P: Copy> Problem<P> {
    /// The edges of `graph`'s map — trusted edges and the candidates whose
    /// entry in `report.loops` (in candidate order) is accepted.
    pub fn of_graph<const D: usize>(graph: &graph::Graph<P, D>, report: &Report) -> Self
    where
        P: crate::geometry::Pose<D>,
    {
        let mut accepted = report.loops.iter().map(|l| l.accepted);
        let edges = (graph.edges.iter())
            .filter(|e| !e.is_candidate() || accepted.next().unwrap_or(false))
            .map(|e| {
                let (kappa, tau) = isotropic_weights(&e.information);
                WeightedEdge {
                    from: e.from,
                    to: e.to,
                    measurement: e.measurement,
                    kappa,
                    tau,
                }
            })
            .collect();
        Self {
            edges,
            fixed: graph.gauge(),
        }
    }
}

/// The certificate of the map `poses` (by vertex index, ids `ids`) over
/// `problem`, in dimension `DIM` (`B = DIM + 1`, `DOF` degrees of freedom
/// per pose).
pub(crate) fn certify<P: Lift<DIM>, const DIM: usize, const B: usize, const DOF: usize>(
    problem: &Problem<P>,
    poses: &[P],
    ids: &[VertexId],
) -> Result<Certificate, CertifyError> {
    let start = Instant::now();
    if problem.fixed.len() > 1 {
        let ids = problem.fixed.iter().map(|&k| ids[k]).collect();
        return Err(CertifyError::SeveralFixed { ids });
    }
    let n = poses.len();
    let edges: Vec<IsotropicEdge<DIM>> = problem.edges.iter().map(IsotropicEdge::lift).collect();
    let given = Map::of(poses);
    let finite = |m: &Map<DIM>| {
        (m.r.iter().all(|r| r.iter().all(|v| v.is_finite())))
            && m.t.iter().all(|t| t.iter().all(|v| v.is_finite()))
    };
    if !finite(&given)
        || !edges
            .iter()
            .all(|e| e.kappa.is_finite() && e.tau.is_finite())
    {
        return Err(CertifyError::NonFinite);
    }
    let pins = gauge_pins(n, &edges, &problem.fixed);
    let mut pinned = vec![false; n];
    for &p in &pins {
        pinned[p] = true;
    }
    let linear = |e: crate::linear::LinearError| CertifyError::Linear(e.to_string());
    let refined = refine::refine::<DIM, DOF>(given.clone(), &edges, &pinned).map_err(linear)?;
    if !finite(&refined.map) {
        return Err(CertifyError::NonFinite);
    }
    let refine_s = start.elapsed().as_secs_f64();
    let checking = Instant::now();
    let mut s = check::Certificate::<B>::new(&refined.map, &edges, &pins).map_err(linear)?;
    let eta = ETA_RELATIVE * check::Certificate::<B>::rotation_scale(&edges, n);
    let certified = s.factorize(&edges, eta);
    let check_s = checking.elapsed().as_secs_f64();
    let mut out = Certificate {
        certified,
        eta,
        cost: refined.cost,
        map_cost: given.cost(&edges),
        gap_bound: certified.then(|| refined.cost - s.dual + eta * (DIM * n) as f64),
        max_translation_change: 0.0,
        max_rotation_change: 0.0,
        lambda_min: None,
        lambda_min_bounds: None,
        eigenvector_poses: Vec::new(),
        poses: n,
        edges: edges.len(),
        parts: components(n, &edges).1,
        refinement_steps: refined.iterations,
        newton_steps: refined.newton_steps,
        refinement_converged: refined.converged,
        time: CertificateTime {
            refine_s,
            check_s,
            ..Default::default()
        },
    };
    for k in 0..n {
        let (dt, dr) = pose_distance(&refined.map, &given, k);
        out.max_translation_change = out.max_translation_change.max(dt);
        out.max_rotation_change = out.max_rotation_change.max(dr);
    }
    if !certified {
        let eigen = Instant::now();
        if let Some(e) = s.smallest(&edges, eta) {
            out.lambda_min = Some(e.lambda);
            out.lambda_min_bounds = Some([e.lower, e.upper]);
            out.eigenvector_poses = largest_shares(&e.share, ids);
        }
        out.time.eigen_s = eigen.elapsed().as_secs_f64();
    }
    out.time.total_s = start.elapsed().as_secs_f64();
    Ok(out)
}

/// Most poses [`Certificate::eigenvector_poses`] lists.
const EIGENVECTOR_POSES: usize = 10;

/// The poses with the largest shares, largest first.
fn largest_shares(share: &[f64], ids: &[VertexId]) -> Vec<EigenvectorPose> {
    let mut order: Vec<usize> = (0..share.len()).collect();
    order.sort_by(|&a, &b| share[b].total_cmp(&share[a]).then(a.cmp(&b)));
    order
        .into_iter()
        .take(EIGENVECTOR_POSES)
        .map(|k| EigenvectorPose {
            id: ids[k],
            share: share[k],
        })
        .collect()
}

/// One vertex per connected part of the map's graph held fixed: the fixed
/// vertex where the part has it, else the part's first vertex.
fn gauge_pins<const DIM: usize>(
    n: usize,
    edges: &[IsotropicEdge<DIM>],
    fixed: &[usize],
) -> Vec<usize> {
    let (part, count) = components(n, edges);
    let mut pin = vec![usize::MAX; count];
    for &f in fixed {
        pin[part[f]] = f;
    }
    for v in 0..n {
        if pin[part[v]] == usize::MAX {
            pin[part[v]] = v;
        }
    }
    pin
}
