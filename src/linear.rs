//! The sparse linear algebra of one Gauss–Newton step: the block sparsity
//! pattern of the normal equations `H δ = −b`, values written straight into
//! that pattern, and faer's supernodal sparse Cholesky.
//!
//! Everything that depends only on the graph's structure is done once in
//! [`BlockSystem::new`]:
//!
//! * a fill-reducing ordering, computed with AMD on the graph of *blocks*
//!   (one node per free vertex), which is `D²` times smaller than the scalar
//!   matrix and keeps each vertex's `D` columns together (they become part
//!   of the same supernode);
//! * the lower-triangular CSC pattern of `H` in that order, and for every
//!   edge and vertex the positions of its blocks in the value array, so that
//!   assembly writes each Jacobian product in place (no triplets, no sort);
//! * the symbolic Cholesky factorisation and all workspace.
//!
//! Each iteration then only refills values, adds the damping, runs the
//! numeric factorisation and two triangular solves, with no allocation.

use faer::dyn_stack::{MemBuffer, MemStack, StackReq};
use faer::linalg::cholesky::llt::factor::{LltError, LltRegularization};
use faer::sparse::linalg::cholesky::{
    CholeskySymbolicParams, LltRef, SymbolicCholesky, SymmetricOrdering,
    factorize_symbolic_cholesky,
};
use faer::sparse::linalg::{SupernodalThreshold, amd};
use faer::sparse::{SparseColMatRef, SymbolicSparseColMatRef};
use faer::{Conj, MatMut, Par, Side};
use nalgebra::{SMatrix, SVector};

/// Errors of the linear solver.
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
pub enum LinearError {
    /// The (damped) normal matrix is not positive definite; `block` is the
    /// first variable block where the factorisation broke down.
    #[error("normal equations are not positive definite (at variable block {block})")]
    NotPositiveDefinite {
        /// The variable block (free vertex) where the factorisation failed.
        block: usize,
    },
    /// The factorisation could not allocate its memory, or failed otherwise.
    #[error("sparse Cholesky failed: {0}")]
    Factorization(String),
}

/// Where one edge's off-diagonal block lives in the value array.
#[derive(Clone, Copy, Debug)]
struct OffDiagonal<const D: usize> {
    /// Value index of the block's first entry in each of its `D` columns.
    cols: [usize; D],
    /// Whether the stored block is `H_ij` (`false`: rows are `j`'s, columns
    /// `i`'s, i.e. the stored block is `H_ji = H_ijᵀ`).
    i_is_row: bool,
}

/// The variable blocks an edge touches and where its off-diagonal block is.
#[derive(Clone, Copy, Debug)]
struct EdgeSlot<const D: usize> {
    i: Option<usize>,
    j: Option<usize>,
    off: Option<OffDiagonal<D>>,
}

/// The normal equations of a pose graph with `D`-dimensional blocks, and
/// their factorisation.
///
/// ```
/// use nalgebra::{Matrix1, Vector1};
/// use pgo::linear::BlockSystem;
/// // Two scalar variables tied by one edge, plus a prior on the first:
/// // H = [[2, −1], [−1, 1]], b = [0, −1], so δ = −H⁻¹b = [1, 2].
/// let mut sys = BlockSystem::<1>::new(2, &[(Some(0), Some(1)), (Some(0), None)], 0).unwrap();
/// sys.clear();
/// let one = Matrix1::new(1.0);
/// sys.add_edge(0, &one, &Matrix1::new(-1.0), &one, &Vector1::new(0.0), &Vector1::new(-1.0));
/// sys.add_edge(1, &one, &Matrix1::zeros(), &Matrix1::zeros(), &Vector1::new(0.0), &Vector1::zeros());
/// sys.factorize(0.0).unwrap();
/// let mut step = vec![0.0; 2];
/// sys.solve(&mut step);
/// assert!((step[0] - 1.0).abs() < 1e-12 && (step[1] - 2.0).abs() < 1e-12);
/// ```
pub struct BlockSystem<const D: usize> {
    n_blocks: usize,
    /// Elimination position of each variable block.
    position: Vec<usize>,
    col_ptr: Vec<usize>,
    row_idx: Vec<usize>,
    /// Value index of the diagonal entry of each column, by variable block.
    diagonal: Vec<[usize; D]>,
    edges: Vec<EdgeSlot<D>>,
    /// Lower triangle of `H` (plus damping after [`Self::factorize`]).
    values: Vec<f64>,
    /// The undamped diagonal of `H`, by scalar column in elimination order.
    undamped_diagonal: Vec<f64>,
    /// `b = Σ Jᵀ Ω e`, in elimination order.
    gradient: Vec<f64>,
    /// The right-hand side and solution of the triangular solves.
    rhs: Vec<f64>,
    lambda: f64,
    symbolic: SymbolicCholesky<usize>,
    factor: Vec<f64>,
    scratch: MemBuffer,
    threads: usize,
}

impl<const D: usize> BlockSystem<D> {
    /// Builds the pattern for `n_blocks` variable blocks and the given edges,
    /// each as the variable blocks `(i, j)` it joins (`None` for a fixed
    /// vertex). `threads` > 1 lets faer factorise in parallel; 0 means all
    /// available cores.
    pub fn new(
        n_blocks: usize,
        edges: &[(Option<usize>, Option<usize>)],
        threads: usize,
    ) -> Result<Self, LinearError> {
        let position = fill_reducing_order(n_blocks, edges)?;
        Self::with_positions(n_blocks, edges, threads, position)
    }

    /// Like [`Self::new`] with a given elimination position of each block.
    pub fn with_positions(
        n_blocks: usize,
        edges: &[(Option<usize>, Option<usize>)],
        threads: usize,
        position: Vec<usize>,
    ) -> Result<Self, LinearError> {
        // Neighbours of each block that come later in the elimination order,
        // by elimination position.
        let mut later: Vec<Vec<usize>> = vec![Vec::new(); n_blocks];
        for &(i, j) in edges {
            if let (Some(i), Some(j)) = (i, j) {
                if i != j {
                    let (pi, pj) = (position[i], position[j]);
                    later[pi.min(pj)].push(pi.max(pj));
                }
            }
        }
        for l in &mut later {
            l.sort_unstable();
            l.dedup();
        }

        // Scalar CSC of the lower triangle: column p·D + a holds rows
        // p·D + a … p·D + D − 1 of the diagonal block, then D rows for each
        // later neighbour in order.
        let n = n_blocks * D;
        let mut col_ptr = Vec::with_capacity(n + 1);
        let nnz: usize = later
            .iter()
            .map(|l| D * (D + 1) / 2 + l.len() * D * D)
            .sum();
        let mut row_idx = Vec::with_capacity(nnz);
        col_ptr.push(0);
        for (p, l) in later.iter().enumerate() {
            for a in 0..D {
                row_idx.extend((a..D).map(|b| p * D + b));
                for &q in l {
                    row_idx.extend((0..D).map(|b| q * D + b));
                }
                col_ptr.push(row_idx.len());
            }
        }

        let diagonal: Vec<[usize; D]> = (0..n_blocks)
            .map(|b| std::array::from_fn(|a| col_ptr[position[b] * D + a]))
            .collect();
        let edges = edges
            .iter()
            .map(|&(i, j)| {
                let off = match (i, j) {
                    (Some(i), Some(j)) if i != j => {
                        let (pi, pj) = (position[i], position[j]);
                        let (col, row) = (pi.min(pj), pi.max(pj));
                        // Cannot fail: `row` was recorded as a later neighbour of `col`.
                        let rank = later[col].binary_search(&row).unwrap_or(0);
                        let cols =
                            std::array::from_fn(|a| col_ptr[col * D + a] + (D - a) + rank * D);
                        Some(OffDiagonal {
                            cols,
                            i_is_row: pi > pj,
                        })
                    }
                    _ => None,
                };
                EdgeSlot { i, j, off }
            })
            .collect();

        // faer's symbolic analysis without reordering reads the *upper*
        // triangle whatever `side` says, so hand it the transposed pattern.
        let (upper_ptr, upper_idx) = transpose_pattern(n, &col_ptr, &row_idx);
        let pattern = SymbolicSparseColMatRef::new_checked(n, n, &upper_ptr, None, &upper_idx);
        let params = CholeskySymbolicParams {
            supernodal_flop_ratio_threshold: SupernodalThreshold::FORCE_SUPERNODAL,
            ..Default::default()
        };
        let symbolic =
            factorize_symbolic_cholesky(pattern, Side::Upper, SymmetricOrdering::Identity, params)
                .map_err(|e| LinearError::Factorization(format!("{e:?}")))?;
        let par = parallelism(threads);
        let req = StackReq::any_of(&[
            symbolic.factorize_numeric_llt_scratch::<f64>(par, Default::default()),
            symbolic.solve_in_place_scratch::<f64>(1, par),
        ]);
        let scratch = MemBuffer::try_new(req)
            .map_err(|_| LinearError::Factorization("out of memory".into()))?;
        let factor = vec![0.0; symbolic.len_val()];
        Ok(Self {
            n_blocks,
            position,
            values: vec![0.0; row_idx.len()],
            col_ptr,
            row_idx,
            diagonal,
            edges,
            undamped_diagonal: vec![0.0; n],
            gradient: vec![0.0; n],
            rhs: vec![0.0; n],
            lambda: 0.0,
            symbolic,
            factor,
            scratch,
            threads,
        })
    }

    /// Number of variable blocks.
    pub fn num_blocks(&self) -> usize {
        self.n_blocks
    }

    /// Non-zeros stored for the lower triangle of `H`.
    pub fn nnz_hessian(&self) -> usize {
        self.row_idx.len()
    }

    /// Non-zeros of the Cholesky factor.
    pub fn nnz_factor(&self) -> usize {
        self.factor.len()
    }

    /// Supernodes of the factor and the floating-point operations of one
    /// numeric factorisation, `Σ_k c_k²` over the non-zero counts `c_k` of
    /// the factor's columns (a multiply–add counts as two).
    pub fn factor_stats(&self) -> (usize, f64) {
        use faer::sparse::linalg::cholesky::SymbolicCholeskyRaw;
        match self.symbolic.raw() {
            SymbolicCholeskyRaw::Supernodal(s) => {
                let (begin, end) = (s.supernode_begin(), s.supernode_end());
                let val = s.col_ptr_for_val();
                let mut flops = 0.0;
                for k in 0..s.n_supernodes() {
                    let c = end[k] - begin[k];
                    let r = (val[k + 1] - val[k]) / c.max(1);
                    for j in 0..c {
                        let cnt = (r - j) as f64;
                        flops += cnt * cnt;
                    }
                }
                (s.n_supernodes(), flops)
            }
            SymbolicCholeskyRaw::Simplicial(_) => (0, 0.0),
        }
    }

    /// Sets `H` and `b` to zero before assembly.
    pub fn clear(&mut self) {
        self.values.fill(0.0);
        self.gradient.fill(0.0);
    }

    /// Adds edge `k`'s contribution: `H_ii = J_iᵀΩJ_i`, `H_ij = J_iᵀΩJ_j`,
    /// `H_jj = J_jᵀΩJ_j`, `b_i = J_iᵀΩe`, `b_j = J_jᵀΩe`. Blocks of fixed
    /// vertices are ignored.
    pub fn add_edge(
        &mut self,
        k: usize,
        h_ii: &SMatrix<f64, D, D>,
        h_ij: &SMatrix<f64, D, D>,
        h_jj: &SMatrix<f64, D, D>,
        b_i: &SVector<f64, D>,
        b_j: &SVector<f64, D>,
    ) {
        let slot = self.edges[k];
        if let Some(i) = slot.i {
            self.add_diagonal(i, h_ii, b_i);
        }
        if let Some(j) = slot.j {
            self.add_diagonal(j, h_jj, b_j);
        }
        if let Some(off) = slot.off {
            for a in 0..D {
                let col = &mut self.values[off.cols[a]..off.cols[a] + D];
                for (b, v) in col.iter_mut().enumerate() {
                    *v += if off.i_is_row {
                        h_ij[(b, a)]
                    } else {
                        h_ij[(a, b)]
                    };
                }
            }
        }
    }

    /// Sets `b` to zero, keeping `H` (and its factorisation): for solving
    /// the same system with several right-hand sides.
    pub fn clear_gradient(&mut self) {
        self.gradient.fill(0.0);
    }

    /// Adds edge `k`'s contribution to `b` only.
    pub fn add_edge_gradient(&mut self, k: usize, b_i: &SVector<f64, D>, b_j: &SVector<f64, D>) {
        let slot = self.edges[k];
        for (block, b) in [(slot.i, b_i), (slot.j, b_j)] {
            if let Some(block) = block {
                let p = self.position[block] * D;
                for a in 0..D {
                    self.gradient[p + a] += b[a];
                }
            }
        }
    }

    fn add_diagonal(&mut self, block: usize, h: &SMatrix<f64, D, D>, g: &SVector<f64, D>) {
        let diag = self.diagonal[block];
        for a in 0..D {
            let col = &mut self.values[diag[a]..diag[a] + (D - a)];
            for (r, v) in col.iter_mut().enumerate() {
                *v += h[(a + r, a)];
            }
        }
        let p = self.position[block] * D;
        for a in 0..D {
            self.gradient[p + a] += g[a];
        }
    }

    /// Factorises `H + λ·diag(H)` (Marquardt's scaling; diagonal entries are
    /// floored at `1e-9·max diag` so that a zero entry still gets damped).
    /// `λ = 0` factorises `H` itself (Gauss–Newton).
    pub fn factorize(&mut self, lambda: f64) -> Result<(), LinearError> {
        self.lambda = lambda;
        if self.n_blocks == 0 {
            return Ok(());
        }
        let mut max_diag = 0.0f64;
        for (block, diag) in self.diagonal.iter().enumerate() {
            let p = self.position[block] * D;
            for a in 0..D {
                let d = self.values[diag[a]];
                self.undamped_diagonal[p + a] = d;
                max_diag = max_diag.max(d);
            }
        }
        let floor = 1e-9 * max_diag;
        if lambda > 0.0 {
            for (block, diag) in self.diagonal.iter().enumerate() {
                let p = self.position[block] * D;
                for a in 0..D {
                    self.values[diag[a]] += lambda * self.undamped_diagonal[p + a].max(floor);
                }
            }
        }
        let n = self.n_blocks * D;
        let pattern =
            SymbolicSparseColMatRef::new_checked(n, n, &self.col_ptr, None, &self.row_idx);
        let a = SparseColMatRef::new(pattern, &self.values);
        let par = parallelism(self.threads);
        let result = self.symbolic.factorize_numeric_llt::<f64>(
            &mut self.factor,
            a,
            Side::Lower,
            LltRegularization::default(),
            par,
            MemStack::new(&mut self.scratch),
            Default::default(),
        );
        // Restore the undamped diagonal so that `H` can be damped again.
        if lambda > 0.0 {
            for (block, diag) in self.diagonal.iter().enumerate() {
                let p = self.position[block] * D;
                for a in 0..D {
                    self.values[diag[a]] = self.undamped_diagonal[p + a];
                }
            }
        }
        match result {
            Ok(_) => Ok(()),
            Err(LltError::NonPositivePivot { index }) => {
                let p = index / D;
                let block = self.position.iter().position(|&q| q == p).unwrap_or(p);
                Err(LinearError::NotPositiveDefinite { block })
            }
        }
    }

    /// Solves `(H + λ·diag H) δ = −b` with the last factorisation and writes
    /// `δ` by variable block (`step[k·D + a]`).
    pub fn solve(&mut self, step: &mut [f64]) {
        let n = self.n_blocks * D;
        if n == 0 {
            return;
        }
        let rhs = &mut self.rhs;
        for (r, g) in rhs.iter_mut().zip(&self.gradient) {
            *r = -g;
        }
        let llt = LltRef::<'_, usize, f64>::new(&self.symbolic, &self.factor);
        let par = parallelism(self.threads);
        llt.solve_in_place_with_conj(
            Conj::No,
            MatMut::from_column_major_slice_mut(rhs, n, 1),
            par,
            MemStack::new(&mut self.scratch),
        );
        for (block, &p) in self.position.iter().enumerate() {
            step[block * D..block * D + D].copy_from_slice(&rhs[p * D..p * D + D]);
        }
    }

    /// The decrease of χ² that the quadratic model predicts for `step`
    /// (as returned by [`Self::solve`]): `−2δᵀb − δᵀHδ`, which for the damped
    /// solution equals `−δᵀb + λ·δᵀ diag(H) δ`.
    pub fn predicted_decrease(&self, step: &[f64]) -> f64 {
        let max_diag = self.undamped_diagonal.iter().fold(0.0f64, |m, &d| m.max(d));
        let floor = 1e-9 * max_diag;
        let mut dot_b = 0.0;
        let mut dot_d = 0.0;
        for (block, &p) in self.position.iter().enumerate() {
            for a in 0..D {
                let s = step[block * D + a];
                dot_b += s * self.gradient[p * D + a];
                dot_d += s * s * self.undamped_diagonal[p * D + a].max(floor);
            }
        }
        -dot_b + self.lambda * dot_d
    }

    /// The largest absolute entry of `b`, for the gradient stopping test.
    pub fn gradient_max_norm(&self) -> f64 {
        self.gradient.iter().fold(0.0, |m, g| m.max(g.abs()))
    }
}

/// The CSC pattern of the transpose of an `n × n` CSC pattern (sorted rows).
fn transpose_pattern(n: usize, col_ptr: &[usize], row_idx: &[usize]) -> (Vec<usize>, Vec<usize>) {
    let mut count = vec![0usize; n + 1];
    for &r in row_idx {
        count[r + 1] += 1;
    }
    for k in 0..n {
        count[k + 1] += count[k];
    }
    let mut next = count.clone();
    let mut out = vec![0usize; row_idx.len()];
    for c in 0..n {
        for &r in &row_idx[col_ptr[c]..col_ptr[c + 1]] {
            out[next[r]] = c;
            next[r] += 1;
        }
    }
    (count, out)
}

/// faer's parallel kernels only split the dense products of large
/// supernodes, thousands of times per factorisation; on pose graphs (6×6 to
/// ~300×300 fronts) that costs more than it gains: sphere2500 factorises in
/// 18.6 ms sequentially and 28.3 ms with `Par::rayon(2)`, city10000 in 11.8
/// and 20.0 ms (`examples/probe.rs`, minimum of 20). Sequential, then.
fn parallelism(_threads: usize) -> Par {
    Par::Seq
}

/// AMD on the block graph: the elimination position of each block.
fn fill_reducing_order(
    n_blocks: usize,
    edges: &[(Option<usize>, Option<usize>)],
) -> Result<Vec<usize>, LinearError> {
    if n_blocks == 0 {
        return Ok(Vec::new());
    }
    let mut adjacency: Vec<Vec<usize>> = vec![Vec::new(); n_blocks];
    for &(i, j) in edges {
        if let (Some(i), Some(j)) = (i, j) {
            if i != j {
                adjacency[i].push(j);
                adjacency[j].push(i);
            }
        }
    }
    let mut col_ptr = Vec::with_capacity(n_blocks + 1);
    let mut row_idx = Vec::new();
    col_ptr.push(0usize);
    for (b, list) in adjacency.iter_mut().enumerate() {
        list.push(b);
        list.sort_unstable();
        list.dedup();
        row_idx.extend_from_slice(list);
        col_ptr.push(row_idx.len());
    }
    let pattern =
        SymbolicSparseColMatRef::new_checked(n_blocks, n_blocks, &col_ptr, None, &row_idx);
    let mut perm = vec![0usize; n_blocks];
    let mut perm_inv = vec![0usize; n_blocks];
    let mut mem = MemBuffer::try_new(amd::order_scratch::<usize>(n_blocks, row_idx.len()))
        .map_err(|_| LinearError::Factorization("out of memory for the ordering".into()))?;
    amd::order(
        &mut perm,
        &mut perm_inv,
        pattern,
        amd::Control::default(),
        MemStack::new(&mut mem),
    )
    .map_err(|e| LinearError::Factorization(format!("{e:?}")))?;
    // perm[k] = block eliminated k-th, so perm_inv[block] = its position.
    Ok(perm_inv)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{DMatrix, DVector, Matrix2, Vector2};
    use rand::{Rng, SeedableRng, rngs::StdRng};

    /// A random block system with known dense equivalent.
    fn random_system(seed: u64) -> (BlockSystem<2>, DMatrix<f64>, DVector<f64>) {
        let mut rng = StdRng::seed_from_u64(seed);
        let n = 12;
        let mut pairs: Vec<(Option<usize>, Option<usize>)> =
            (1..n).map(|k| (Some(k - 1), Some(k))).collect();
        for _ in 0..10 {
            let i = rng.random_range(0..n);
            let j = rng.random_range(0..n);
            if i != j {
                pairs.push((Some(i), Some(j)));
            }
        }
        pairs.push((Some(3), None)); // an edge to a fixed vertex
        pairs.push((Some(0), None));
        let mut sys = BlockSystem::<2>::new(n, &pairs, 1).unwrap();
        sys.clear();
        let mut h = DMatrix::zeros(2 * n, 2 * n);
        let mut b = DVector::zeros(2 * n);
        for (k, &(i, j)) in pairs.iter().enumerate() {
            let ji = Matrix2::new(rng.random(), rng.random(), rng.random(), rng.random());
            let jj = Matrix2::new(rng.random(), rng.random(), rng.random(), rng.random());
            let e = Vector2::new(rng.random(), rng.random());
            let (hii, hij, hjj) = (
                ji.transpose() * ji + Matrix2::identity(),
                ji.transpose() * jj,
                jj.transpose() * jj,
            );
            let (bi, bj) = (ji.transpose() * e, jj.transpose() * e);
            sys.add_edge(k, &hii, &hij, &hjj, &bi, &bj);
            if let Some(i) = i {
                h.view_mut((2 * i, 2 * i), (2, 2)).add_assign(&hii);
                b.rows_mut(2 * i, 2).add_assign(&bi);
            }
            if let Some(j) = j {
                h.view_mut((2 * j, 2 * j), (2, 2)).add_assign(&hjj);
                b.rows_mut(2 * j, 2).add_assign(&bj);
                if let Some(i) = i {
                    h.view_mut((2 * i, 2 * j), (2, 2)).add_assign(&hij);
                    h.view_mut((2 * j, 2 * i), (2, 2))
                        .add_assign(&hij.transpose());
                }
            }
        }
        (sys, h, b)
    }

    use std::ops::AddAssign;

    #[test]
    fn solves_like_a_dense_cholesky() {
        for seed in 0..5 {
            let (mut sys, h, b) = random_system(seed);
            sys.factorize(0.0).unwrap();
            let mut step = vec![0.0; 24];
            sys.solve(&mut step);
            let expected = h.clone().cholesky().unwrap().solve(&(-&b));
            let got = DVector::from_vec(step.clone());
            assert!(
                (&got - &expected).norm() < 1e-9 * expected.norm().max(1.0),
                "seed {seed}"
            );
            // Predicted decrease of the undamped model: −2δᵀb − δᵀHδ.
            let model = -2.0 * got.dot(&b) - got.dot(&(&h * &got));
            assert!((sys.predicted_decrease(&step) - model).abs() < 1e-9 * model.abs().max(1.0));
        }
    }

    #[test]
    fn damping_scales_the_diagonal_and_is_undone() {
        let (mut sys, h, b) = random_system(7);
        let lambda = 0.5;
        sys.factorize(lambda).unwrap();
        let mut step = vec![0.0; 24];
        sys.solve(&mut step);
        let damped = &h + DMatrix::from_diagonal(&h.diagonal()) * lambda;
        let expected = damped.cholesky().unwrap().solve(&(-&b));
        assert!((DVector::from_vec(step.clone()) - &expected).norm() < 1e-9 * expected.norm());
        // Refactorising without damping gives the undamped solution again.
        sys.factorize(0.0).unwrap();
        sys.solve(&mut step);
        let plain = h.cholesky().unwrap().solve(&(-&b));
        assert!((DVector::from_vec(step) - plain).norm() < 1e-9);
    }

    #[test]
    fn singular_systems_name_the_failing_block() {
        // Block 2 has no edge at all: its diagonal is zero.
        let pairs = [(Some(0), Some(1)), (Some(0), None)];
        let mut sys = BlockSystem::<1>::new(3, &pairs, 1).unwrap();
        sys.clear();
        let one = nalgebra::Matrix1::new(1.0);
        let z = nalgebra::Vector1::new(0.0);
        sys.add_edge(0, &one, &(-one), &one, &z, &z);
        sys.add_edge(1, &one, &(-one), &one, &z, &z);
        assert_eq!(
            sys.factorize(0.0),
            Err(LinearError::NotPositiveDefinite { block: 2 })
        );
    }
}
