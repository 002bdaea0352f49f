//! The map refined on the isotropic problem: Riemannian Newton steps from
//! pgo's map (Gauss–Newton with Levenberg–Marquardt damping where Newton's
//! model is not convex or does not decrease the cost).
//!
//! Each vertex moves by `ξ = (δ, φ)`: `tᵢ ← tᵢ + δᵢ`, `Rᵢ ← Rᵢ Exp([φᵢ]×)`.
//! `F` is quadratic in `X`, so along this retraction (`Ẋᵢ = [δᵢ Rᵢ[φᵢ]×]`,
//! `Ẍᵢ = [0 Rᵢ[φᵢ]×²]`) its exact second-order model is
//!
//! ```text
//! F(ξ) ≈ F + 2⟨G, Ẋ⟩ + tr(Ẋ M Ẋᵀ) − Σᵢ tr(Rᵢ[φᵢ]× Λᵢ [φᵢ]×ᵀ Rᵢᵀ)
//! ```
//!
//! with `G = X M` and `Λᵢ = sym(Rᵢᵀ Gᵢᴿ)`: the Hessian is the certificate
//! matrix `S = M − Λ` seen through the tangent directions, so Newton's
//! steps converge quadratically to a critical point whose `S` the check
//! then factorises. Without the `Λ` term it is Gauss–Newton's
//! (positive semi-definite: `F` is a sum of squares linear in `X`).

use super::problem::{IsotropicEdge, Map, exp_rotation, generator, rotation_dof};
use crate::linear::{BlockSystem, LinearError, Parallelism};
use nalgebra::{SMatrix, SVector};

/// Most Newton or Gauss–Newton steps. From pgo's map 1–9 suffice
/// on the standard files (quadratic convergence); a map in a wrong basin,
/// where the Hessian is indefinite, takes damped Gauss–Newton steps, whose
/// linear convergence this bounds (sphere_bignoise from `--init odometry`
/// and 30–100 iterations: 40–54 steps to converge; the eigenvalue the check
/// reports after them is within 15 % of that after 50 steps from 1–10
/// iterations).
const MAX_ITERATIONS: usize = 50;

/// After Newton's step fails (its model is not convex, or the step does
/// not decrease the cost: far from a critical point, or in a wrong basin),
/// this many Gauss–Newton steps are taken before it is tried again; each
/// try costs a factorisation.
const NEWTON_RETRY: usize = 3;

/// Converged when the model's decrease `−⟨g, ξ⟩` of the step is below this
/// fraction of the cost: a few hundred times the rounding of a sum of
/// `10⁴–10⁶` terms, where a further step changes `Λ` by far less than the
/// check's shift `η`.
const DECREASE_TOLERANCE: f64 = 1e-13;

/// Levenberg–Marquardt's damping when Gauss–Newton's step does not
/// decrease the cost: from `LM_FIRST`, ×`LM_FACTOR` up to `LM_LAST` (a
/// step of `10⁻⁸` of its undamped length; beyond it the map is stationary
/// to rounding).
const LM_FIRST: f64 = 1e-6;
const LM_FACTOR: f64 = 10.0;
const LM_LAST: f64 = 1e8;

/// What the refinement reached.
#[derive(Clone, Debug)]
pub(crate) struct Refined<const DIM: usize> {
    /// The refined map.
    pub map: Map<DIM>,
    /// Its cost `F`.
    pub cost: f64,
    /// Steps taken.
    pub iterations: usize,
    /// Of those, Newton steps.
    pub newton_steps: usize,
    /// Whether the last step's model decrease was within tolerance.
    pub converged: bool,
}

/// The linear system of the steps: one `DOF` block per free vertex, one
/// slot per edge, and one diagonal-only slot per free vertex (the
/// gradient, and Newton's `Λ` term).
struct Steps<const DOF: usize> {
    sys: BlockSystem<DOF>,
    /// The free vertices, by block.
    free: Vec<usize>,
    /// The gradient by block, as last assembled.
    gradient: Vec<f64>,
}

/// Refines `map` on `edges`, the vertices with `pinned` held fixed.
pub(crate) fn refine<const DIM: usize, const DOF: usize>(
    mut map: Map<DIM>,
    edges: &[IsotropicEdge<DIM>],
    pinned: &[bool],
) -> Result<Refined<DIM>, LinearError> {
    debug_assert_eq!(DOF, DIM + rotation_dof(DIM));
    let mut cost = map.cost(edges);
    let mut steps = Steps::<DOF>::new(edges, pinned)?;
    let mut out = Refined {
        map: map.clone(),
        cost,
        iterations: 0,
        newton_steps: 0,
        converged: steps.free.is_empty(),
    };
    if out.converged {
        return Ok(out);
    }
    let mut step = vec![0.0; steps.free.len() * DOF];
    let mut newton_wait = 0;
    while out.iterations < MAX_ITERATIONS {
        let try_newton = newton_wait == 0;
        steps.assemble(&map, edges, try_newton);
        // Newton's step, where its model is convex and it decreases F.
        let mut taken = None;
        if !try_newton {
            newton_wait -= 1;
        } else if steps.sys.factorize(0.0).is_ok() {
            steps.sys.solve(&mut step);
            let trial = steps.retract(&map, &step);
            let c = trial.cost(edges);
            if c < cost {
                taken = Some((trial, c, true));
            } else if steps.decrease(&step) <= DECREASE_TOLERANCE * cost {
                out.converged = true;
                break;
            }
        }
        if taken.is_none() {
            if try_newton {
                newton_wait = NEWTON_RETRY;
                steps.assemble(&map, edges, false);
            }
            taken = steps.damped(&map, edges, cost, &mut step)?;
        }
        let Some((trial, c, newton)) = taken else {
            // No damping decreases F: stationary to rounding.
            out.converged =
                steps.decrease(&step) <= DECREASE_TOLERANCE * cost.max(f64::MIN_POSITIVE);
            break;
        };
        out.iterations += 1;
        out.newton_steps += usize::from(newton);
        let small = steps.decrease(&step) <= DECREASE_TOLERANCE * cost;
        map = trial;
        cost = c;
        if small {
            out.converged = true;
            break;
        }
    }
    out.map = map;
    out.cost = cost;
    Ok(out)
}

impl<const DOF: usize> Steps<DOF> {
    fn new<const DIM: usize>(
        edges: &[IsotropicEdge<DIM>],
        pinned: &[bool],
    ) -> Result<Self, LinearError> {
        let mut block = vec![None; pinned.len()];
        let mut free = Vec::new();
        for (v, &p) in pinned.iter().enumerate() {
            if !p {
                block[v] = Some(free.len());
                free.push(v);
            }
        }
        let pairs: Vec<(Option<usize>, Option<usize>)> = (edges.iter())
            .map(|e| (block[e.i], block[e.j]))
            .chain((0..free.len()).map(|b| (Some(b), None)))
            .collect();
        let sys = BlockSystem::new(free.len(), &pairs, Parallelism::sequential())?;
        Ok(Self {
            sys,
            gradient: vec![0.0; free.len() * DOF],
            free,
        })
    }

    /// Fills `H` (Newton's with `newton`, else Gauss–Newton's) and `g`.
    fn assemble<const DIM: usize>(
        &mut self,
        map: &Map<DIM>,
        edges: &[IsotropicEdge<DIM>],
        newton: bool,
    ) {
        self.sys.clear();
        for (k, e) in edges.iter().enumerate() {
            let (hii, hij, hjj) = hessian_blocks::<DIM, DOF>(e, map);
            let zero = SVector::zeros();
            self.sys.add_edge(k, &hii, &hij, &hjj, &zero, &zero);
        }
        let (gt, gr) = map.gradient(edges);
        let lambdas = map.multipliers(&gr);
        let nr = DOF - DIM;
        for (b, &v) in self.free.iter().enumerate() {
            let mut g = SVector::<f64, DOF>::zeros();
            let mut h = SMatrix::<f64, DOF, DOF>::zeros();
            for a in 0..DIM {
                g[a] = gt[v][a];
            }
            for a in 0..nr {
                let ea = generator::<DIM>(a);
                g[DIM + a] = (map.r[v] * ea).dot(&gr[v]);
                if newton {
                    for c in 0..nr {
                        let ec = generator::<DIM>(c);
                        h[(DIM + a, DIM + c)] = -(ea * lambdas[v] * ec.transpose()).trace();
                    }
                }
            }
            let zero = SMatrix::zeros();
            self.sys
                .add_edge(edges.len() + b, &h, &zero, &zero, &g, &SVector::zeros());
        }
        self.sys.gradient_into(&mut self.gradient);
    }

    /// The model's decrease `−⟨g, ξ⟩` of `step`.
    fn decrease(&self, step: &[f64]) -> f64 {
        -self
            .gradient
            .iter()
            .zip(step)
            .map(|(g, s)| g * s)
            .sum::<f64>()
    }

    /// `map` moved by `step`.
    fn retract<const DIM: usize>(&self, map: &Map<DIM>, step: &[f64]) -> Map<DIM> {
        let mut out = map.clone();
        for (b, &v) in self.free.iter().enumerate() {
            let s = &step[b * DOF..(b + 1) * DOF];
            for a in 0..DIM {
                out.t[v][a] += s[a];
            }
            out.r[v] = map.r[v] * exp_rotation::<DIM>(&s[DIM..]);
        }
        out
    }

    /// Gauss–Newton's step, damped until it decreases the cost; `None`
    /// when no damping does.
    #[allow(clippy::type_complexity)]
    fn damped<const DIM: usize>(
        &mut self,
        map: &Map<DIM>,
        edges: &[IsotropicEdge<DIM>],
        cost: f64,
        step: &mut [f64],
    ) -> Result<Option<(Map<DIM>, f64, bool)>, LinearError> {
        let mut lambda = 0.0;
        while lambda <= LM_LAST {
            match self.sys.factorize(lambda) {
                Ok(()) => {
                    self.sys.solve(step);
                    let trial = self.retract(map, step);
                    let c = trial.cost(edges);
                    if c < cost {
                        return Ok(Some((trial, c, false)));
                    }
                }
                // Gauss–Newton's matrix is positive semi-definite; only a
                // vertex no edge reaches makes it singular.
                Err(e) if lambda >= LM_LAST => return Err(e),
                Err(_) => {}
            }
            lambda = if lambda == 0.0 {
                LM_FIRST
            } else {
                lambda * LM_FACTOR
            };
        }
        Ok(None)
    }
}

/// The Gauss–Newton blocks `(H_ii, H_ij, H_jj)` of one edge in the
/// coordinates `ξ = (δ, φ)`: `Jᵀ W J` of the residuals
/// `√κ (Rⱼ − Rᵢ R̃)` and `√τ (tⱼ − tᵢ − Rᵢ t̃)`, whose derivatives are
/// `∂/∂φⱼₐ = Rⱼ Eₐ`, `∂/∂φᵢₐ = −Rᵢ Eₐ R̃` (rotation) and `∂/∂δⱼ = I`,
/// `∂/∂δᵢ = −I`, `∂/∂φᵢₐ = −Rᵢ Eₐ t̃` (translation).
#[allow(clippy::type_complexity)]
fn hessian_blocks<const DIM: usize, const DOF: usize>(
    e: &IsotropicEdge<DIM>,
    map: &Map<DIM>,
) -> (
    SMatrix<f64, DOF, DOF>,
    SMatrix<f64, DOF, DOF>,
    SMatrix<f64, DOF, DOF>,
) {
    let nr = DOF - DIM;
    let (ri, rj) = (&map.r[e.i], &map.r[e.j]);
    let (k, tau) = (e.kappa, e.tau);
    let mut hii = SMatrix::<f64, DOF, DOF>::zeros();
    let mut hij = SMatrix::<f64, DOF, DOF>::zeros();
    let mut hjj = SMatrix::<f64, DOF, DOF>::zeros();
    for a in 0..DIM {
        hii[(a, a)] = tau;
        hij[(a, a)] = -tau;
        hjj[(a, a)] = tau;
    }
    // Eₐ t̃ and Rᵢ Eₐ t̃, Rᵢ Eₐ R̃.
    let mut et = [SVector::<f64, DIM>::zeros(); 3];
    let mut ret = [SVector::<f64, DIM>::zeros(); 3];
    let mut rer = [SMatrix::<f64, DIM, DIM>::zeros(); 3];
    for a in 0..nr {
        let ea = generator::<DIM>(a);
        et[a] = ea * e.t;
        ret[a] = ri * et[a];
        rer[a] = ri * ea * e.r;
    }
    for a in 0..nr {
        for c in 0..DIM {
            hii[(c, DIM + a)] = tau * ret[a][c];
            hii[(DIM + a, c)] = tau * ret[a][c];
            hij[(DIM + a, c)] = -tau * ret[a][c];
        }
        for b in 0..nr {
            // tr(Eₐᵀ E_b) = 2 δ_ab for these generators.
            let same = if a == b { 2.0 * k } else { 0.0 };
            hii[(DIM + a, DIM + b)] = same + tau * et[a].dot(&et[b]);
            hjj[(DIM + a, DIM + b)] = same;
            hij[(DIM + a, DIM + b)] = -k * rer[a].dot(&(rj * generator::<DIM>(b)));
        }
    }
    (hii, hij, hjj)
}
