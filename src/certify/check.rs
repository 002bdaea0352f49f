//! The check: `S = M − Λ(X)` at the refined map, and whether
//! `S + η·D` is positive definite (`D` the identity on the rotation
//! entries, zero on the translation ones) by one sparse Cholesky
//! factorisation. Where it is not, the smallest eigenvalue of `S` on the
//! rotations and its vector, by factorisations at growing shifts and
//! inverse iteration.
//!
//! The translations are free, and `F` does not change when every `tᵢ`
//! moves by the same vector: `M` (and `S`) has that null direction on the
//! translation entries of each connected part. One translation entry per
//! part is pinned by adding `μ` to it (the vertex's own translation weight):
//! for a vector of the relaxation that is zero there this changes nothing,
//! and every feasible point can be moved there at the same cost. The
//! translation block is then positive definite and `S + η·D` is positive
//! definite exactly when SE-Sync's `Q − Λ` (the translations eliminated) has
//! every eigenvalue above `−η`.

use super::problem::{IsotropicEdge, Map, data_blocks};
use crate::linear::{BlockSystem, LinearError, Parallelism};
use nalgebra::{SMatrix, SVector};

/// Shifts tried when the check fails grow by this factor until a
/// factorisation succeeds; the bracket `[−σ_ok, −σ_fail)` of `λ_min` is then
/// narrowed to this ratio before inverse iteration, whose convergence
/// factor `(λ₁ + σ)/(λ₂ + σ)` is then at most `BRACKET − 1` of the gap.
const GROWTH: f64 = 4.0;
const BRACKET: f64 = 1.05;
/// Most shifts tried: `GROWTH^60 ≈ 10³⁶` times `η`.
const MAX_SHIFTS: usize = 60;
/// Inverse iteration stops when the Rayleigh quotient changes by less than
/// this fraction of itself, or after `MAX_INVERSE` steps.
const RAYLEIGH_TOLERANCE: f64 = 1e-10;
const MAX_INVERSE: usize = 200;

/// The certificate matrix's pattern and its pieces at one map.
pub(crate) struct Certificate<const B: usize> {
    sys: BlockSystem<B>,
    /// Per vertex: `−Λ` on the rotation entries and the pin `μ`.
    diag: Vec<SMatrix<f64, B, B>>,
    /// `Σᵢ tr(Λᵢ)`, the dual value.
    pub dual: f64,
}

/// The smallest eigenvalue of `Q − Λ` where the check failed.
#[derive(Clone, Debug)]
pub(crate) struct Eigen {
    /// The Rayleigh quotient of the vector found (≥ `λ_min`).
    pub lambda: f64,
    /// `λ_min` lies in `[lower, upper]` by the factorisations: positive
    /// definite at shift `−lower`, not at `−upper`.
    pub lower: f64,
    pub upper: f64,
    /// The squared norm of each vertex's rotation entries of the vector
    /// (they sum to 1).
    pub share: Vec<f64>,
}

impl<const B: usize> Certificate<B> {
    /// `S` at `map`, whose edges are `edges`, with one pinned vertex per
    /// connected part (`pins`).
    pub fn new<const DIM: usize>(
        map: &Map<DIM>,
        edges: &[IsotropicEdge<DIM>],
        pins: &[usize],
    ) -> Result<Self, LinearError> {
        debug_assert_eq!(B, DIM + 1);
        let n = map.r.len();
        let pairs: Vec<(Option<usize>, Option<usize>)> = (edges.iter())
            .map(|e| (Some(e.i), Some(e.j)))
            .chain((0..n).map(|v| (Some(v), None)))
            .collect();
        let sys = BlockSystem::<B>::new(n, &pairs, Parallelism::sequential())?;
        let (_, gr) = map.gradient(edges);
        let lambdas = map.multipliers(&gr);
        let dual = lambdas.iter().map(|l| l.trace()).fold(0.0, |a, b| a + b);
        let mut diag = vec![SMatrix::<f64, B, B>::zeros(); n];
        for (d, l) in diag.iter_mut().zip(&lambdas) {
            for a in 0..DIM {
                for b in 0..DIM {
                    d[(a + 1, b + 1)] = -l[(a, b)];
                }
            }
        }
        let mut degree = vec![0.0; n];
        for e in edges {
            degree[e.i] += e.tau;
            degree[e.j] += e.tau;
        }
        for &p in pins {
            diag[p][(0, 0)] += if degree[p] > 0.0 { degree[p] } else { 1.0 };
        }
        Ok(Self { sys, diag, dual })
    }

    /// Whether `S + shift·D` is positive definite (its factorisation
    /// succeeds).
    pub fn factorize<const DIM: usize>(
        &mut self,
        edges: &[IsotropicEdge<DIM>],
        shift: f64,
    ) -> bool {
        self.sys.clear();
        for (k, e) in edges.iter().enumerate() {
            let (ii, ij, jj) = data_blocks::<DIM, B>(e);
            let zero = SVector::zeros();
            self.sys.add_edge(k, &ii, &ij, &jj, &zero, &zero);
        }
        let zero = SMatrix::zeros();
        for (v, d) in self.diag.iter().enumerate() {
            let mut d = *d;
            for a in 1..B {
                d[(a, a)] += shift;
            }
            let z = SVector::zeros();
            self.sys.add_edge(edges.len() + v, &d, &zero, &zero, &z, &z);
        }
        self.sys.factorize(0.0).is_ok()
    }

    /// The mean of `M`'s rotation diagonal, the scale of `S`.
    pub fn rotation_scale<const DIM: usize>(edges: &[IsotropicEdge<DIM>], n: usize) -> f64 {
        let total: f64 = edges
            .iter()
            .map(|e| 2.0 * e.kappa * DIM as f64 + e.tau * e.t.norm_squared())
            .sum();
        total / (n.max(1) * DIM) as f64
    }

    /// `S x` (without a shift), `x` and the result by vertex block.
    fn apply<const DIM: usize>(&self, edges: &[IsotropicEdge<DIM>], x: &[f64], y: &mut [f64]) {
        let block = |v: &[f64], k: usize| SVector::<f64, B>::from_column_slice(&v[k * B..][..B]);
        for (k, d) in self.diag.iter().enumerate() {
            let r = d * block(x, k);
            y[k * B..][..B].copy_from_slice(r.as_slice());
        }
        for e in edges {
            let (ii, ij, jj) = data_blocks::<DIM, B>(e);
            let (xi, xj) = (block(x, e.i), block(x, e.j));
            let yi = ii * xi + ij * xj;
            let yj = ij.transpose() * xi + jj * xj;
            for a in 0..B {
                y[e.i * B + a] += yi[a];
                y[e.j * B + a] += yj[a];
            }
        }
    }

    /// The smallest eigenvalue of `Q − Λ` below `−eta` (where the check at
    /// `eta` failed) and its vector.
    pub fn smallest<const DIM: usize>(
        &mut self,
        edges: &[IsotropicEdge<DIM>],
        eta: f64,
    ) -> Option<Eigen> {
        let (mut fail, mut ok) = (eta, eta * GROWTH);
        let mut factorisations = 0;
        loop {
            factorisations += 1;
            if self.factorize(edges, ok) {
                break;
            }
            if factorisations >= MAX_SHIFTS {
                return None;
            }
            fail = ok;
            ok *= GROWTH;
        }
        while ok / fail > BRACKET {
            let mid = (ok * fail).sqrt();
            if self.factorize(edges, mid) {
                ok = mid;
            } else {
                fail = mid;
            }
        }
        // The last factorisation may have been a failure: redo at `ok`.
        if !self.factorize(edges, ok) {
            return None;
        }
        let (lambda, v) = self.inverse_iteration(edges, ok);
        let n = self.diag.len();
        let share: Vec<f64> = (0..n)
            .map(|k| (1..B).map(|a| v[k * B + a].powi(2)).sum::<f64>())
            .collect();
        let total: f64 = share.iter().sum();
        Some(Eigen {
            lambda: lambda.max(-ok),
            lower: -ok,
            upper: -fail,
            share: share.iter().map(|s| s / total).collect(),
        })
    }

    /// Inverse iteration `w ← (S + σD)⁻¹ D w` with the factorisation at
    /// shift `σ`; returns the Rayleigh quotient `wᵀSw / wᵀDw` and `w`.
    fn inverse_iteration<const DIM: usize>(
        &mut self,
        edges: &[IsotropicEdge<DIM>],
        shift: f64,
    ) -> (f64, Vec<f64>) {
        let len = self.diag.len() * B;
        // A fixed start (no randomness: the same report every run), with
        // no special structure: a quasi-random sequence.
        let mut w: Vec<f64> = (0..len)
            .map(|k| ((k as f64 + 1.0) * 0.618_033_988_749_895).fract() - 0.5)
            .collect();
        let mut sw = vec![0.0; len];
        let mut rho = f64::INFINITY;
        let mut steps = 0;
        while steps < MAX_INVERSE {
            steps += 1;
            let mut rhs: Vec<f64> = w
                .iter()
                .enumerate()
                .map(|(k, x)| if k % B == 0 { 0.0 } else { *x })
                .collect();
            self.sys.solve_many(&mut rhs, 1);
            let norm = rhs.iter().map(|x| x * x).sum::<f64>().sqrt();
            w = rhs.iter().map(|x| -x / norm).collect();
            self.apply(edges, &w, &mut sw);
            let num: f64 = w.iter().zip(&sw).map(|(a, b)| a * b).sum();
            let den: f64 = (w.iter().enumerate())
                .filter(|(k, _)| k % B != 0)
                .map(|(_, x)| x * x)
                .sum();
            let next = num / den;
            let settled = (next - rho).abs() <= RAYLEIGH_TOLERANCE * next.abs().max(shift);
            rho = next;
            if settled {
                break;
            }
        }
        (rho, w)
    }
}
