//! The isotropic problem the certificate is about (SE-Sync's, Rosen et al.,
//! IJRR 2019, Problem 1): rotations `Rᵢ ∈ SO(d)` and translations
//! `tᵢ ∈ ℝᵈ` minimising
//!
//! ```text
//! F(X) = Σₑ κₑ‖Rⱼ − Rᵢ R̃ₑ‖²_F + τₑ‖tⱼ − tᵢ − Rᵢ t̃ₑ‖²
//! ```
//!
//! over the edges of the map, with one rotation weight `κ` and one
//! translation weight `τ` per edge taken from its information matrix. With
//! `X = [t₁ R₁ … tₙ Rₙ] ∈ ℝ^{d×n(d+1)}` the cost is `tr(X M Xᵀ)` for a
//! sparse symmetric `M` with `(d+1)×(d+1)` blocks ([`data_blocks`]), and
//! its derivative is `2·X M` ([`Map::gradient`]).

use crate::geometry::{Se2, Se3};
use crate::graph::UnionFind;
use nalgebra::{Matrix2, Matrix3, SMatrix, SVector};

/// A pose type whose rotation and translation the certificate reads, with
/// `DIM` its dimension (2 or 3).
pub(crate) trait Lift<const DIM: usize>: Copy {
    /// `(R, t)`.
    fn rotation_translation(&self) -> (SMatrix<f64, DIM, DIM>, SVector<f64, DIM>);
}

impl Lift<2> for Se2 {
    fn rotation_translation(&self) -> (Matrix2<f64>, SVector<f64, 2>) {
        let (s, c) = self.theta.sin_cos();
        (Matrix2::new(c, -s, s, c), self.translation())
    }
}

impl Lift<3> for Se3 {
    fn rotation_translation(&self) -> (Matrix3<f64>, SVector<f64, 3>) {
        (self.rotation_matrix(), self.translation)
    }
}

/// One edge of the map as the certificate keeps it: vertex indices, the
/// measurement and its isotropic weights.
#[derive(Clone, Copy, Debug)]
pub(crate) struct WeightedEdge<P> {
    /// Index of the first vertex.
    pub from: usize,
    /// Index of the second vertex.
    pub to: usize,
    /// The measured pose of `to` in the frame of `from`.
    pub measurement: P,
    /// Rotation weight `κ`.
    pub kappa: f64,
    /// Translation weight `τ`.
    pub tau: f64,
}

/// The isotropic weights `(κ, τ)` of an information matrix over pgo's
/// error `(translation, rotation)`. The translation block is replaced by
/// the isotropic Gaussian closest to it in information divergence,
/// precision `τ = d / tr(I_tt⁻¹)` (SE-Sync's rule). The rotation weight is
/// chosen so that `κ‖Rⱼ − Rᵢ R̃‖²_F` is pgo's rotation cost for isotropic
/// information: `‖Rⱼ − Rᵢ R̃‖²_F = 8 sin²(θ/2)` for a residual rotation
/// by `θ`, in 2D and 3D. pgo's 3D rotation error is the quaternion's
/// vector part, of squared norm `sin²(θ/2)`, so `ω sin²(θ/2) = κ·8
/// sin²(θ/2)` exactly with `ω = 3 / tr(I_RR⁻¹)`: `κ = 3 / (8·tr(I_RR⁻¹))`.
/// pgo's 2D error is the angle, `I_θθ θ² = κ·8 sin²(θ/2)` to second
/// order: `κ = I_θθ / 2`. SE-Sync's g2o reader (`SESync_utils.cpp`) takes
/// `κ = I_θθ` in 2D and `3 / (2·tr(I_RR⁻¹))` in 3D, two and four times
/// these, weighing rotations more than pgo's cost does.
pub(crate) fn isotropic_weights<const D: usize>(info: &SMatrix<f64, D, D>) -> (f64, f64) {
    if D == 3 {
        let tt = Matrix2::new(info[(0, 0)], info[(0, 1)], info[(1, 0)], info[(1, 1)]);
        let tau = 2.0 / inverse_trace(tt.try_inverse().map(|m| m.trace()));
        (info[(2, 2)] / 2.0, tau)
    } else {
        let block = |o: usize| Matrix3::from_fn(|r, c| info[(o + r, o + c)]);
        let tau = 3.0 / inverse_trace(block(0).try_inverse().map(|m| m.trace()));
        let kappa = 3.0 / (8.0 * inverse_trace(block(3).try_inverse().map(|m| m.trace())));
        (kappa, tau)
    }
}

/// The trace of an inverse, infinite when the block is singular (its
/// weight then 0; the graph refuses such information, so this is a guard).
fn inverse_trace(trace: Option<f64>) -> f64 {
    trace
        .filter(|t| t.is_finite() && *t > 0.0)
        .unwrap_or(f64::INFINITY)
}

/// The number of rotation degrees of freedom in dimension `DIM`.
pub(crate) const fn rotation_dof(dim: usize) -> usize {
    dim * (dim - 1) / 2
}

/// The `a`-th generator `Eₐ` of `so(DIM)`: `[φ]× = Σ φₐ Eₐ` (in 3D
/// `Eₐ = [eₐ]×`; in 2D the one generator `[[0, −1], [1, 0]]`).
pub(crate) fn generator<const DIM: usize>(a: usize) -> SMatrix<f64, DIM, DIM> {
    // (row, col) of the +1 entry; the −1 is at (col, row).
    let (r, c) = if DIM == 2 {
        (1, 0)
    } else {
        [(2, 1), (0, 2), (1, 0)][a]
    };
    let mut e = SMatrix::zeros();
    e[(r, c)] = 1.0;
    e[(c, r)] = -1.0;
    e
}

/// `Exp([φ]×)`, the rotation by the rotation vector `φ` (its first
/// `rotation_dof(DIM)` entries).
pub(crate) fn exp_rotation<const DIM: usize>(phi: &[f64]) -> SMatrix<f64, DIM, DIM> {
    if DIM == 2 {
        let (s, c) = phi[0].sin_cos();
        SMatrix::from_fn(|r, col| match (r, col) {
            (0, 0) | (1, 1) => c,
            (0, 1) => -s,
            _ => s,
        })
    } else {
        let v = nalgebra::Vector3::new(phi[0], phi[1], phi[2]);
        let m = nalgebra::Rotation3::new(v).into_inner();
        SMatrix::from_fn(|r, c| m[(r, c)])
    }
}

/// The angle between two rotations, `2·asin(‖A − B‖_F / √8)` (exact for
/// `d` = 2 and 3, and accurate near zero where `acos` of the trace is not).
pub(crate) fn rotation_distance<const DIM: usize>(
    a: &SMatrix<f64, DIM, DIM>,
    b: &SMatrix<f64, DIM, DIM>,
) -> f64 {
    let half = ((a - b).norm() / 8f64.sqrt()).min(1.0);
    2.0 * half.asin()
}

/// A map in the certificate's coordinates: `Rᵢ`, `tᵢ` per vertex.
#[derive(Clone, Debug)]
pub(crate) struct Map<const DIM: usize> {
    /// Rotations.
    pub r: Vec<SMatrix<f64, DIM, DIM>>,
    /// Translations.
    pub t: Vec<SVector<f64, DIM>>,
}

/// An edge of SE-Sync's isotropic problem, in the certificate's coordinates:
/// its measurement and its rotation and translation weights.
#[derive(Clone, Copy, Debug)]
pub(crate) struct IsotropicEdge<const DIM: usize> {
    /// Index of the first vertex.
    pub i: usize,
    /// Index of the second vertex.
    pub j: usize,
    /// Measured rotation `R̃`.
    pub r: SMatrix<f64, DIM, DIM>,
    /// Measured translation `t̃`.
    pub t: SVector<f64, DIM>,
    /// Rotation weight.
    pub kappa: f64,
    /// Translation weight.
    pub tau: f64,
}

impl<const DIM: usize> IsotropicEdge<DIM> {
    /// The edge of a weighted edge.
    pub fn lift<P: Lift<DIM>>(e: &WeightedEdge<P>) -> Self {
        let (r, t) = e.measurement.rotation_translation();
        Self {
            i: e.from,
            j: e.to,
            r,
            t,
            kappa: e.kappa,
            tau: e.tau,
        }
    }

    /// The residuals `(Rⱼ − Rᵢ R̃, tⱼ − tᵢ − Rᵢ t̃)` at `map`.
    pub fn residuals(&self, map: &Map<DIM>) -> (SMatrix<f64, DIM, DIM>, SVector<f64, DIM>) {
        let (ri, rj) = (&map.r[self.i], &map.r[self.j]);
        (
            rj - ri * self.r,
            map.t[self.j] - map.t[self.i] - ri * self.t,
        )
    }
}

impl<const DIM: usize> Map<DIM> {
    /// The map of `poses`.
    pub fn of<P: Lift<DIM>>(poses: &[P]) -> Self {
        let (r, t) = poses.iter().map(|p| p.rotation_translation()).unzip();
        Self { r, t }
    }

    /// `F(X)`.
    pub fn cost(&self, edges: &[IsotropicEdge<DIM>]) -> f64 {
        edges
            .iter()
            .map(|e| {
                let (rr, rt) = e.residuals(self);
                e.kappa * rr.norm_squared() + e.tau * rt.norm_squared()
            })
            .fold(0.0, |a, b| a + b)
    }

    /// `G = X M = ½ ∂F/∂X`, per vertex: the translation column `Gᵢᵗ` and
    /// the rotation columns `Gᵢᴿ`.
    pub fn gradient(
        &self,
        edges: &[IsotropicEdge<DIM>],
    ) -> (Vec<SVector<f64, DIM>>, Vec<SMatrix<f64, DIM, DIM>>) {
        let n = self.r.len();
        let mut gt = vec![SVector::zeros(); n];
        let mut gr = vec![SMatrix::zeros(); n];
        for e in edges {
            let (rr, rt) = e.residuals(self);
            gr[e.j] += rr * e.kappa;
            gr[e.i] -= rr * e.r.transpose() * e.kappa + rt * e.t.transpose() * e.tau;
            gt[e.j] += rt * e.tau;
            gt[e.i] -= rt * e.tau;
        }
        (gt, gr)
    }

    /// The Lagrange multipliers of `RᵢᵀRᵢ = I` from the first-order
    /// condition `Gᵢᴿ = Rᵢ Λᵢ`: `Λᵢ = sym(Rᵢᵀ Gᵢᴿ)`.
    pub fn multipliers(&self, gr: &[SMatrix<f64, DIM, DIM>]) -> Vec<SMatrix<f64, DIM, DIM>> {
        self.r
            .iter()
            .zip(gr)
            .map(|(r, g)| {
                let l = r.transpose() * g;
                (l + l.transpose()) * 0.5
            })
            .collect()
    }
}

/// The blocks `(M_ii, M_ij, M_jj)` one edge adds to the data matrix `M`,
/// each `B×B` with `B = DIM + 1` (index 0 the translation column, then the
/// rotation columns):
///
/// ```text
/// M_ii = [[τ, τ t̃ᵀ], [τ t̃, τ t̃ t̃ᵀ + κ I]]
/// M_ij = −[[τ, 0], [τ t̃, κ R̃]]
/// M_jj = [[τ, 0], [0, κ I]]
/// ```
///
/// so that `κ‖Rⱼ − Rᵢ R̃‖² + τ‖tⱼ − tᵢ − Rᵢ t̃‖² = tr(xᵢ M_ii xᵢᵀ) +
/// 2 tr(xᵢ M_ij xⱼᵀ) + tr(xⱼ M_jj xⱼᵀ)` with `xᵢ = [tᵢ Rᵢ]`.
#[allow(clippy::type_complexity)]
pub(crate) fn data_blocks<const DIM: usize, const B: usize>(
    e: &IsotropicEdge<DIM>,
) -> (SMatrix<f64, B, B>, SMatrix<f64, B, B>, SMatrix<f64, B, B>) {
    debug_assert_eq!(B, DIM + 1);
    let (k, tau) = (e.kappa, e.tau);
    let mut ii = SMatrix::<f64, B, B>::zeros();
    let mut ij = SMatrix::<f64, B, B>::zeros();
    let mut jj = SMatrix::<f64, B, B>::zeros();
    ii[(0, 0)] = tau;
    ij[(0, 0)] = -tau;
    jj[(0, 0)] = tau;
    for a in 0..DIM {
        ii[(0, a + 1)] = tau * e.t[a];
        ii[(a + 1, 0)] = tau * e.t[a];
        ij[(a + 1, 0)] = -tau * e.t[a];
        jj[(a + 1, a + 1)] = k;
        for b in 0..DIM {
            ii[(a + 1, b + 1)] = tau * e.t[a] * e.t[b] + if a == b { k } else { 0.0 };
            ij[(a + 1, b + 1)] = -k * e.r[(a, b)];
        }
    }
    (ii, ij, jj)
}

/// The connected parts of the graph of `edges` over `n` vertices: the part
/// of each vertex, numbered from 0 in order of first vertex.
pub(crate) fn components<const DIM: usize>(
    n: usize,
    edges: &[IsotropicEdge<DIM>],
) -> (Vec<usize>, usize) {
    let mut parts = UnionFind::new(n);
    for e in edges {
        parts.union(e.i, e.j);
    }
    let mut label = vec![usize::MAX; n];
    let mut part = vec![0; n];
    let mut count = 0;
    for v in 0..n {
        let r = parts.find(v);
        if label[r] == usize::MAX {
            label[r] = count;
            count += 1;
        }
        part[v] = label[r];
    }
    (part, count)
}

/// The distance between two poses: translation and rotation angle.
pub(crate) fn pose_distance<const DIM: usize>(a: &Map<DIM>, b: &Map<DIM>, k: usize) -> (f64, f64) {
    (
        (a.t[k] - b.t[k]).norm(),
        rotation_distance(&a.r[k], &b.r[k]),
    )
}
