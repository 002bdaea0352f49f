//! The sparse linear algebra of one Gauss–Newton step: the block sparsity
//! pattern of the normal equations `H δ = −b`, values written straight into
//! that pattern, and a block-supernodal sparse Cholesky (the private module
//! `supernodal`).
//!
//! Everything that depends only on the graph's structure is done once in
//! [`BlockSystem::new`]:
//!
//! * a fill-reducing ordering, computed with AMD on the graph of *blocks*
//!   (one node per free vertex), which is `D²` times smaller than the scalar
//!   matrix and keeps each vertex's `D` columns together;
//! * one `D×D` slot per diagonal block and per distinct pair of vertices
//!   joined by an edge, and for every edge the slots of its three blocks, so
//!   that assembly adds each Jacobian product in place (no triplets, no
//!   sort);
//! * the symbolic factorisation (supernodes, update lists, elimination
//!   tree) and where each slot goes in the factor.
//!
//! Each iteration then only refills the slots, copies them (with the
//! damping) into the factor's panels, factorises — the independent subtrees
//! in parallel — and runs the two triangular solves. The system of a graph
//! grown by poses and edges appended (an incremental update) starts from
//! the last one's [`Layout`]: the old blocks keep their positions, only the
//! new edges are placed and only the rows they add to the factor analysed.
//!
//! Covariances: [`BlockSystem::propagate_group_solved`] gives `A·H⁻¹·Aᵀ`
//! for the rows of one or several edges by a sparse solve;
//! [`BlockSystem::selected_inverse`] gives every block of `H⁻¹` on the
//! factor's pattern at once, for the blocks that an edge of `H` ties
//! ([`BlockSystem::propagate_selected`]);
//! [`BlockSystem::propagate_group_cheaper`] takes whichever of the two
//! costs less for a group of edges.

mod group;
mod layout;
mod parallel;
mod supernodal;

pub use parallel::Parallelism;

use crate::geometry::NormalBlocks;
use faer::dyn_stack::{MemBuffer, MemStack};
use faer::sparse::SymbolicSparseColMatRef;
use faer::sparse::linalg::amd;
pub use group::{EdgeJacobian, GroupScratch};
pub use layout::Layout;
use nalgebra::{SMatrix, SVector};
use rayon::prelude::*;
use supernodal::{Adjacency, Symbolic};

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
    /// The threads of a parallel solver could not be started.
    #[error("cannot start the solver's threads: {0}")]
    ThreadPool(String),
}

/// No block (a fixed vertex, or no off-diagonal block).
const NONE: u32 = u32::MAX;

/// Marquardt's damping scales each diagonal entry of `H`, floored at this
/// fraction of the largest one so that a zero entry (a direction no edge
/// constrains at these poses) is damped too. Far below the spread of a
/// pose graph's diagonal (the information of its edges, a few decades), it
/// acts only where an entry is zero to rounding.
const DIAGONAL_FLOOR: f64 = 1e-9;

/// The blocks one edge adds to: the elimination positions of its two
/// vertices and its off-diagonal slot.
#[derive(Clone, Copy, Debug, PartialEq)]
struct EdgeSlot {
    i: u32,
    j: u32,
    off: u32,
    /// Whether the slot holds `H_ij` (rows `i`, columns `j`: `i` comes later
    /// in the elimination order) rather than `H_ji = H_ijᵀ`.
    i_is_row: bool,
}

/// The blocks of `H⁻¹` on the pattern of a factor
/// ([`BlockSystem::selected_inverse`]).
#[derive(Clone, Debug)]
pub struct SelectedInverse {
    values: Vec<f64>,
}

/// The structure of a factor that a system grown from its system can keep
/// ([`BlockSystem::kept_factor`], [`BlockSystem::refactorize`]).
#[derive(Clone, Debug, Default)]
pub struct KeptFactor {
    begin: Vec<usize>,
    val_ptr: Vec<usize>,
    lambda: f64,
}

/// The normal equations of a pose graph with `D`-dimensional blocks, and
/// their factorisation.
pub struct BlockSystem<const D: usize> {
    n_blocks: usize,
    /// Elimination position of each variable block.
    position: Vec<usize>,
    edges: Vec<EdgeSlot>,
    /// Diagonal blocks of `H` by position (column-major, lower triangle).
    diag: Vec<f64>,
    /// Off-diagonal blocks of `H` (rows: the later block), grouped by the
    /// position of their column block, `later`'s: the blocks of column `p`
    /// from `later.starts()[p]` (in units of `D²`).
    off: Vec<f64>,
    /// The later neighbours of each position: the rows of its column's
    /// off-diagonal blocks.
    later: Adjacency,
    /// The variable block of each off-diagonal block's rows.
    off_row: Vec<u32>,
    /// Where each diagonal and off-diagonal block starts in the factor.
    diag_dest: Vec<usize>,
    off_dest: Vec<usize>,
    /// The undamped diagonal of `H`, by scalar column in elimination order.
    undamped_diagonal: Vec<f64>,
    /// `b = Σ Jᵀ Ω e`, in elimination order.
    gradient: Vec<f64>,
    /// The right-hand side and solution of the triangular solves, and their
    /// scratch.
    rhs: Vec<f64>,
    solve_work: Vec<f64>,
    lambda: f64,
    symbolic: Symbolic<D>,
    /// The factor's panels, allocated by the first factorisation (so that a
    /// system built early, e.g. to check the graph before the initial guess,
    /// costs little memory until it is used).
    factor: Vec<f64>,
    /// Whether `factor` is the factorisation of the `H` assembled now (an
    /// assembly since makes it the factor of an earlier `H`).
    factor_current: bool,
    /// Whether `H` and `b` are all zero (as built, or cleared with nothing
    /// added since): [`Self::clear`] then has nothing to zero — an
    /// update's system is assembled once, just after it is built.
    zero: bool,
    /// Where assembly and factorisation run.
    parallelism: Parallelism,
}

impl<const D: usize> BlockSystem<D> {
    /// Builds the pattern for `n_blocks` variable blocks and the given edges,
    /// each as the variable blocks `(i, j)` it joins (`None` for a fixed
    /// vertex). Assembly ([`Self::add_edges`]) and factorisation run as
    /// `parallelism` says; the results are the same bits for a given number
    /// of threads.
    pub fn new(
        n_blocks: usize,
        edges: &[(Option<usize>, Option<usize>)],
        parallelism: Parallelism,
    ) -> Result<Self, LinearError> {
        let position = fill_reducing_order(n_blocks, edges)?;
        Self::with_positions(n_blocks, edges, parallelism, position, None)
    }

    /// Like [`Self::new`] with a given elimination position of each block;
    /// with `grown`, the [`Layout`] of an earlier system whose blocks hold
    /// the first positions: its edges, the first ones, are not placed again
    /// where they join the same positions and the new ones join new blocks,
    /// and its factor structure is extended to the new blocks where every
    /// edge between old blocks is in it; else analysed afresh. Either way
    /// the system is the same.
    pub fn with_positions(
        n_blocks: usize,
        edges: &[(Option<usize>, Option<usize>)],
        parallelism: Parallelism,
        position: Vec<usize>,
        grown: Option<&Layout>,
    ) -> Result<Self, LinearError> {
        if n_blocks >= NONE as usize {
            return Err(LinearError::Factorization(format!(
                "{n_blocks} variable blocks are too many"
            )));
        }
        let (later, slots, symbolic) = Self::placed(n_blocks, edges, &position, grown);
        let n_off = later.starts()[n_blocks];
        if n_off >= NONE as usize {
            return Err(LinearError::Factorization(format!(
                "{n_off} off-diagonal blocks are too many"
            )));
        }
        let symbolic = match symbolic {
            Some(extended) => extended,
            None => Symbolic::<D>::new(&later)?,
        };
        let (diag_dest, off_dest) = symbolic.destinations(&later);
        let mut block_at = vec![0u32; n_blocks];
        for (block, &p) in position.iter().enumerate() {
            block_at[p] = block as u32;
        }
        let off_row = later.iter().flatten().map(|&q| block_at[q]).collect();
        let n = n_blocks * D;
        Ok(Self {
            n_blocks,
            position,
            edges: slots,
            diag: vec![0.0; n_blocks * D * D],
            off: vec![0.0; n_off * D * D],
            later,
            off_row,
            diag_dest,
            off_dest,
            undamped_diagonal: vec![0.0; n],
            gradient: vec![0.0; n],
            rhs: vec![0.0; n],
            solve_work: Vec::new(),
            lambda: 0.0,
            symbolic,
            factor: Vec::new(),
            factor_current: false,
            zero: true,
            parallelism,
        })
    }

    /// The later neighbours of each position, each edge's slots and, where
    /// `grown`'s factor structure extends to them, the factor's structure
    /// ([`Self::with_positions`]): the new edges placed into `grown`'s
    /// layout where it extends, else every edge.
    fn placed(
        n_blocks: usize,
        edges: &[(Option<usize>, Option<usize>)],
        position: &[usize],
        grown: Option<&Layout>,
    ) -> (Adjacency, Vec<EdgeSlot>, Option<Symbolic<D>>) {
        if let Some((g, ext)) = grown.and_then(|g| Some((g, g.extend(position, edges)?))) {
            let symbolic = Symbolic::<D>::extended_by(&g.structure, &ext.later, &ext.entries);
            return (ext.later, ext.slots, symbolic);
        }
        let pairs = edges
            .iter()
            .filter_map(|&(i, j)| Some((position[i?], position[j?])));
        let later = Adjacency::from_pairs(n_blocks, pairs);
        let slots = edges
            .iter()
            .map(|&(i, j)| edge_slot(i, j, position, &later))
            .collect();
        let symbolic = grown.and_then(|g| Symbolic::<D>::extended(&g.structure, &later));
        (later, slots, symbolic)
    }

    /// Where assembly and factorisation run.
    pub fn parallelism(&self) -> &Parallelism {
        &self.parallelism
    }

    /// Where assembly and factorisation run from now on.
    pub fn set_parallelism(&mut self, parallelism: Parallelism) {
        self.parallelism = parallelism;
    }

    /// The elimination position of each variable block.
    pub fn positions(&self) -> &[usize] {
        &self.position
    }

    /// Number of variable blocks.
    pub fn num_blocks(&self) -> usize {
        self.n_blocks
    }

    /// Non-zeros of the lower triangle of `H`.
    pub fn nnz_hessian(&self) -> usize {
        self.n_blocks * D * (D + 1) / 2 + self.later.starts()[self.n_blocks] * D * D
    }

    /// Values stored for the Cholesky factor (its dense supernodal panels).
    pub fn nnz_factor(&self) -> usize {
        self.symbolic.len_values()
    }

    /// The upper triangle of `H` (undamped, scalar, in elimination order)
    /// in compressed sparse columns: column pointers, row indices (sorted in
    /// each column) and values — to hand the same matrix to another sparse
    /// solver (benchmarks, tests).
    #[cfg(any(test, feature = "internals"))]
    pub fn upper_csc(&self) -> (Vec<usize>, Vec<usize>, Vec<f64>) {
        // The off-diagonal blocks above each block column: (row block, slot).
        let mut above: Vec<Vec<(usize, usize)>> = vec![Vec::new(); self.n_blocks];
        for slot in &self.edges {
            if slot.off != NONE {
                let (p, q) = (slot.i.min(slot.j) as usize, slot.i.max(slot.j) as usize);
                above[q].push((p, slot.off as usize));
            }
        }
        let n = self.n_blocks * D;
        let mut col_ptr = Vec::with_capacity(n + 1);
        let mut rows = Vec::new();
        let mut values = Vec::new();
        col_ptr.push(0);
        for (q, list) in above.iter_mut().enumerate() {
            list.sort_unstable();
            list.dedup();
            for a in 0..D {
                // Entry (D·p + b, D·q + a) of the upper triangle is the
                // lower block (q, p) at row a, column b.
                for &(p, k) in list.iter() {
                    let block = &self.off[k * D * D..][..D * D];
                    for b in 0..D {
                        rows.push(D * p + b);
                        values.push(block[b * D + a]);
                    }
                }
                let diag = &self.diag[q * D * D..][..D * D];
                for b in 0..=a {
                    rows.push(D * q + b);
                    values.push(diag[b * D + a]);
                }
                col_ptr.push(rows.len());
            }
        }
        (col_ptr, rows, values)
    }

    /// The pattern (the factor's structure, the blocks of `H`, each edge's
    /// blocks), for a grown system's [`Self::with_positions`].
    pub fn layout(&self) -> Layout {
        Layout {
            structure: self.symbolic.structure(),
            later: self.later.clone(),
            slots: self.edges.clone(),
        }
    }

    /// Frees the factor's values (the next [`Self::factorize`] allocates
    /// them again).
    pub fn release_factor(&mut self) {
        self.factor = Vec::new();
    }

    /// Hands over the factor's allocation (its values mean nothing to a
    /// later system), leaving none.
    pub fn take_factor_allocation(&mut self) -> Vec<f64> {
        std::mem::take(&mut self.factor)
    }

    /// Gives the first factorisation `buffer` (an earlier system's
    /// [`Self::take_factor_allocation`]) to fill, rather than memory the
    /// system maps afresh — page by page, at a fault each. Its values are
    /// not read: each panel is zeroed as the factorisation reaches it,
    /// while it is in cache, rather than all of them in one pass before.
    /// Does nothing once the system has a factor.
    pub fn reuse_factor_allocation(&mut self, buffer: Vec<f64>) {
        if self.factor.is_empty() {
            self.factor = buffer;
        }
    }

    /// The factor values a covariance ([`Self::propagate`]) reads per block
    /// it starts from, on average: those on the block's path to the root
    /// of the elimination tree.
    pub fn mean_path_values(&self) -> f64 {
        self.symbolic.mean_path_values()
    }

    /// Supernodes of the factor and the floating-point operations of one
    /// numeric factorisation (a multiply–add counts as two).
    pub fn factor_stats(&self) -> (usize, f64) {
        (self.symbolic.supernodes(), self.symbolic.flops())
    }

    /// The floating-point operations of forming again only the factor's
    /// panels that a change of `H` in the rows and columns of `blocks`
    /// (variable blocks) reaches: those on the blocks' paths to the root of
    /// the elimination tree. Every other panel would keep its values; this
    /// is the work an incremental factorisation (iSAM2's Bayes tree) does
    /// for such a change.
    #[cfg(any(test, feature = "internals"))]
    pub fn refactor_flops(&self, blocks: &[usize]) -> f64 {
        self.symbolic
            .affected_flops(blocks.iter().map(|&b| self.position[b]))
    }

    /// Sets `H` and `b` to zero before assembly.
    pub fn clear(&mut self) {
        self.factor_current = false;
        if !self.zero {
            self.diag.fill(0.0);
            self.off.fill(0.0);
            self.gradient.fill(0.0);
            self.zero = true;
        }
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
        self.zero = false;
        let slot = self.edges[k];
        if slot.i != NONE {
            self.add_diagonal(slot.i as usize, h_ii, b_i);
        }
        if slot.j != NONE {
            self.add_diagonal(slot.j as usize, h_jj, b_j);
        }
        if slot.off != NONE {
            let block = &mut self.off[slot.off as usize * D * D..][..D * D];
            add_off_diagonal::<D>(block, h_ij, slot.i_is_row);
        }
    }

    /// Adds the contributions of edges `first`, `first + 1`, … (one per item;
    /// `blocks` returns `None` for an item to skip), like [`Self::add_edge`]
    /// for each but, with more than one thread, in parallel: each thread owns
    /// a range of elimination positions and adds, in edge order, only to the
    /// blocks of its range — no locks, and the same sums as sequentially.
    pub fn add_edges<T: Sync>(
        &mut self,
        first: usize,
        items: &[T],
        blocks: impl Fn(&T) -> Option<&NormalBlocks<D>> + Sync,
    ) {
        let threads = self.parallelism.threads();
        if threads <= 1 || items.len() < 512 {
            for (k, item) in items.iter().enumerate() {
                if let Some(c) = blocks(item) {
                    self.add_edge(first + k, &c.h_ii, &c.h_ij, &c.h_jj, &c.b_i, &c.b_j);
                }
            }
            return;
        }
        self.zero = false;
        let n = self.n_blocks;
        let diag = SharedSlice(self.diag.as_mut_ptr());
        let off = SharedSlice(self.off.as_mut_ptr());
        let gradient = SharedSlice(self.gradient.as_mut_ptr());
        let edges = &self.edges[first..first + items.len()];
        let blocks = &blocks;
        let add_owned = |t: usize| {
            let owned = (n * t / threads) as u32..(n * (t + 1) / threads) as u32;
            for (slot, item) in edges.iter().zip(items) {
                let mine_i = owned.contains(&slot.i);
                let mine_j = owned.contains(&slot.j);
                let mine_off = slot.off != NONE && owned.contains(&slot.i.min(slot.j));
                if !(mine_i || mine_j || mine_off) {
                    continue;
                }
                let Some(c) = blocks(item) else { continue };
                // SAFETY: the blocks and gradient entries of positions in
                // `owned` (off-diagonal blocks: of their column) are written
                // by this thread only; the vectors outlive the scope.
                unsafe {
                    if mine_i {
                        add_diagonal_raw::<D>(&diag, &gradient, slot.i as usize, &c.h_ii, &c.b_i);
                    }
                    if mine_j {
                        add_diagonal_raw::<D>(&diag, &gradient, slot.j as usize, &c.h_jj, &c.b_j);
                    }
                    if mine_off {
                        let block = std::slice::from_raw_parts_mut(
                            off.at(slot.off as usize * D * D),
                            D * D,
                        );
                        add_off_diagonal::<D>(block, &c.h_ij, slot.i_is_row);
                    }
                }
            }
        };
        self.parallelism
            .install(|| (0..threads).into_par_iter().for_each(add_owned));
    }

    /// Sets `b` to zero, keeping `H` (and its factorisation): for solving
    /// the same system with several right-hand sides.
    pub fn clear_gradient(&mut self) {
        self.gradient.fill(0.0);
    }

    /// Adds edge `k`'s contribution to `b` only.
    pub fn add_edge_gradient(&mut self, k: usize, b_i: &SVector<f64, D>, b_j: &SVector<f64, D>) {
        self.zero = false;
        let slot = self.edges[k];
        for (p, b) in [(slot.i, b_i), (slot.j, b_j)] {
            if p != NONE {
                let g = &mut self.gradient[p as usize * D..][..D];
                for a in 0..D {
                    g[a] += b[a];
                }
            }
        }
    }

    fn add_diagonal(&mut self, p: usize, h: &SMatrix<f64, D, D>, g: &SVector<f64, D>) {
        add_lower::<D>(&mut self.diag[p * D * D..][..D * D], h);
        let grad = &mut self.gradient[p * D..][..D];
        for a in 0..D {
            grad[a] += g[a];
        }
    }

    /// Factorises `H + λ·diag(H)` (Marquardt's scaling; diagonal entries are
    /// floored at [`DIAGONAL_FLOOR`]` · max diag` so that a zero entry still
    /// gets damped).
    /// `λ = 0` factorises `H` itself (Gauss–Newton).
    pub fn factorize(&mut self, lambda: f64) -> Result<(), LinearError> {
        self.lambda = lambda;
        self.factor_current = false;
        if self.n_blocks == 0 {
            return Ok(());
        }
        let floor = self.damping_floor();
        // A fresh allocation is zeroed here, and its panels need not be;
        // a reused one ([`Self::reuse_factor_allocation`]) is only fitted
        // to the length, its panels zeroed one by one.
        let zeroed = self.factor.is_empty();
        self.fit_factor()?;
        let mut factor = std::mem::take(&mut self.factor);
        let load = |s: usize, panel: &mut [f64]| self.load_panel(s, panel, lambda, floor);
        let factorized = (self.symbolic).factorize(&mut factor, zeroed, &load, &self.parallelism);
        self.factor = factor;
        self.factorized(factorized)
    }

    /// [`Self::factorize`] at `λ = 0` that forms again only the panels a
    /// change of `H` since `kept` reaches: `kept` is this system's
    /// allocation's factor ([`Self::kept_factor`] of the system this one
    /// grew from, [`Self::reuse_factor_allocation`]), and `changed` the
    /// variable blocks whose rows and columns of `H` changed since — new
    /// blocks count as changed. The panels of every other supernode are
    /// moved to their places in this factor as they are; those on the
    /// changed blocks' paths to the root of the elimination tree are
    /// formed from this `H` and the panels below them. Where `H` did
    /// change elsewhere, the factor is that of a matrix whose columns
    /// there are the earlier `H`'s. Returns the supernodes formed again,
    /// or `None` where the factor cannot be kept (another structure, a
    /// damped or multi-threaded factorisation, no factor): then nothing
    /// was done. A pivot that is not positive leaves no factor, as
    /// [`Self::factorize`] does.
    pub fn refactorize(
        &mut self,
        kept: &KeptFactor,
        changed: &[usize],
    ) -> Result<Option<usize>, LinearError> {
        let usable = kept.lambda == 0.0
            && !self.parallelism.is_parallel()
            && self.n_blocks > 0
            && self.factor.len() == kept.val_ptr.last().copied().unwrap_or(usize::MAX)
            && self.symbolic.keeps(&kept.begin);
        if !usable {
            return Ok(None);
        }
        self.lambda = 0.0;
        self.factor_current = false;
        let floor = self.damping_floor();
        self.fit_factor()?;
        let positions = changed.iter().map(|&b| self.position[b]);
        let mut formed = self.symbolic.affected(positions);
        self.symbolic
            .keep_panels(&mut self.factor, &kept.val_ptr, &mut formed);
        let count = formed.iter().filter(|&&f| f).count();
        let mut factor = std::mem::take(&mut self.factor);
        let load = |s: usize, panel: &mut [f64]| self.load_panel(s, panel, 0.0, floor);
        let factorized = (self.symbolic).factorize_only(&mut factor, &formed, &load);
        self.factor = factor;
        self.factorized(factorized).map(|()| Some(count))
    }

    /// What a system grown from this one needs to keep its factor
    /// ([`Self::refactorize`]): the supernodes' first columns, their panels'
    /// offsets and the damping; `None` without a factor of the `H`
    /// assembled now.
    pub fn kept_factor(&self) -> Option<KeptFactor> {
        (self.factor_current && !self.factor.is_empty()).then(|| KeptFactor {
            begin: self.symbolic.begins().to_vec(),
            val_ptr: self.symbolic.value_offsets().to_vec(),
            lambda: self.lambda,
        })
    }

    /// `DIAGONAL_FLOOR · max diag H`, the least diagonal entry the damping
    /// scales (recording the undamped diagonal).
    fn damping_floor(&mut self) -> f64 {
        let mut max_diag = 0.0f64;
        for p in 0..self.n_blocks {
            for a in 0..D {
                let d = self.diag[p * D * D + a * D + a];
                self.undamped_diagonal[p * D + a] = d;
                max_diag = max_diag.max(d);
            }
        }
        DIAGONAL_FLOOR * max_diag
    }

    /// Fits the factor's allocation to the structure's length.
    fn fit_factor(&mut self) -> Result<(), LinearError> {
        let len = self.symbolic.len_values();
        if self.factor.len() != len {
            let more = len.saturating_sub(self.factor.len());
            self.factor
                .try_reserve_exact(more)
                .map_err(|_| LinearError::Factorization("out of memory for the factor".into()))?;
            self.factor.resize(len, 0.0);
        }
        Ok(())
    }

    /// Writes `H + λ·diag H` (the diagonal floored at `floor`) into
    /// supernode `s`'s zeroed panel.
    fn load_panel(&self, s: usize, panel: &mut [f64], lambda: f64, floor: f64) {
        let (diag, off, off_ptr) = (&self.diag, &self.off, self.later.starts());
        let (cols, start, ld) = self.symbolic.supernode_range(s);
        for p in cols {
            let dst = &mut panel[self.diag_dest[p] - start..];
            let src = &diag[p * D * D..][..D * D];
            for c in 0..D {
                for r in c..D {
                    dst[c * ld + r] = src[c * D + r];
                }
                if lambda > 0.0 {
                    dst[c * ld + c] += lambda * src[c * D + c].max(floor);
                }
            }
            for k in off_ptr[p]..off_ptr[p + 1] {
                let dst = &mut panel[self.off_dest[k] - start..];
                let src = &off[k * D * D..][..D * D];
                for c in 0..D {
                    dst[c * ld..c * ld + D].copy_from_slice(&src[c * D..c * D + D]);
                }
            }
        }
    }

    /// Records a factorisation's outcome: the factor is current, or the
    /// block whose pivot was not positive.
    fn factorized(&mut self, outcome: Result<(), usize>) -> Result<(), LinearError> {
        match outcome {
            Ok(()) => {
                self.factor_current = true;
                Ok(())
            }
            Err(p) => {
                let block = self.position.iter().position(|&q| q == p).unwrap_or(p);
                Err(LinearError::NotPositiveDefinite { block })
            }
        }
    }

    /// Solves `(H + λ·diag H) δ = −b` with the last factorisation and writes
    /// `δ` by variable block (`step[k·D + a]`). After an assembly since that
    /// factorisation the factor is of an earlier `H`, and `δ` is the chord step `−(H₀ + λ·diag H₀)⁻¹ b`.
    ///
    /// # Panics
    /// If no factorisation succeeded before.
    pub fn solve(&mut self, step: &mut [f64]) {
        if self.n_blocks == 0 {
            return;
        }
        assert!(
            !self.factor.is_empty(),
            "BlockSystem::solve needs a factorisation first"
        );
        for (r, g) in self.rhs.iter_mut().zip(&self.gradient) {
            *r = -g;
        }
        self.symbolic
            .solve(&self.factor, &mut self.rhs, &mut self.solve_work);
        for (block, &p) in self.position.iter().enumerate() {
            step[block * D..block * D + D].copy_from_slice(&self.rhs[p * D..p * D + D]);
        }
    }

    /// Writes the assembled gradient `b` by variable block (`out[k·D + a]`),
    /// to be solved later with others by [`Self::solve_many`].
    pub fn gradient_into(&self, out: &mut [f64]) {
        for (block, &p) in self.position.iter().enumerate() {
            out[block * D..block * D + D].copy_from_slice(&self.gradient[p * D..p * D + D]);
        }
    }

    /// [`Self::solve`] for `k` gradients at once, each `n·D` long and by
    /// variable block in `rhs` (one after the other): each is replaced by
    /// its step `−(H + λ·diag H)⁻¹ b`. One pass over the factor for all of
    /// them, instead of one per gradient.
    ///
    /// # Panics
    /// If no factorisation succeeded before, or `rhs` is not `k·n·D` long.
    pub fn solve_many(&mut self, rhs: &mut [f64], k: usize) {
        let n = self.n_blocks * D;
        assert_eq!(rhs.len(), n * k, "BlockSystem::solve_many: k gradients");
        if n == 0 {
            return;
        }
        assert!(
            !self.factor.is_empty(),
            "BlockSystem::solve_many needs a factorisation first"
        );
        let mut x = vec![0.0; n * k];
        for c in 0..k {
            for (block, &p) in self.position.iter().enumerate() {
                for a in 0..D {
                    x[c * n + p * D + a] = -rhs[c * n + block * D + a];
                }
            }
        }
        self.symbolic
            .solve_many(&self.factor, &mut x, k, &mut self.solve_work);
        for c in 0..k {
            for (block, &p) in self.position.iter().enumerate() {
                rhs[c * n + block * D..][..D].copy_from_slice(&x[c * n + p * D..][..D]);
            }
        }
    }

    /// `A·H⁻¹·Aᵀ` for the `D×(n·D)` matrix `A` whose only nonzero blocks are
    /// `a_i` at variable block `i` and `a_j` at `j` (`None`: a fixed vertex,
    /// no block), from the last factorisation (of `H + λ·diag H`: call
    /// [`Self::factorize`] with `λ = 0` for `H` itself).
    ///
    /// With `A` an edge's Jacobian this is the covariance the solution's
    /// uncertainty adds to the edge's predicted error: the error of an edge
    /// left out of the solution has covariance `Ω⁻¹ + J·H⁻¹·Jᵀ` (its
    /// *innovation* covariance). `H⁻¹` is never formed: `A·H⁻¹·Aᵀ = YᵀY`
    /// with `L·Y = Aᵀ`, and `Aᵀ` is nonzero on two block rows only, so the
    /// forward solve visits just the supernodes on their paths to the root
    /// of the elimination tree.
    ///
    /// # Panics
    /// If no factorisation succeeded before, or a block index is out of
    /// range.
    #[cfg(test)]
    pub fn propagate(
        &self,
        i: Option<usize>,
        a_i: &SMatrix<f64, D, D>,
        j: Option<usize>,
        a_j: &SMatrix<f64, D, D>,
    ) -> SMatrix<f64, D, D> {
        let edge = [[(i, *a_i), (j, *a_j)]];
        let gram = self.propagate_group_solved(&edge, &mut GroupScratch::default());
        SMatrix::from_fn(|r, c| gram[(r, c)])
    }

    /// The *selected inverse* of the last factorisation: the blocks of
    /// `H⁻¹` on the pattern of its factor — every block of `H` among them —
    /// at about the cost and the memory of a factorisation (Takahashi's
    /// recurrence). [`BlockSystem::propagate_selected`] reads it.
    ///
    /// # Panics
    /// If no factorisation succeeded before.
    pub fn selected_inverse(&self) -> SelectedInverse {
        assert!(
            !self.factor.is_empty() || self.n_blocks == 0,
            "BlockSystem::selected_inverse needs a factorisation first"
        );
        SelectedInverse {
            values: self.symbolic.selected_inverse(&self.factor),
        }
    }

    /// [`BlockSystem::propagate`] from the selected inverse `z` of the
    /// current factorisation ([`BlockSystem::selected_inverse`]), without a
    /// solve: for blocks `i` and `j` that share a block of `H` (an edge of
    /// the pattern), `None` for two that do not.
    pub fn propagate_selected(
        &self,
        z: &SelectedInverse,
        i: Option<usize>,
        a_i: &SMatrix<f64, D, D>,
        j: Option<usize>,
        a_j: &SMatrix<f64, D, D>,
    ) -> Option<SMatrix<f64, D, D>> {
        // The blocks present, at their elimination positions.
        let present = [(i, a_i), (j, a_j)]
            .into_iter()
            .filter_map(|(b, a)| Some((self.position[b?], a)));
        let mut out = SMatrix::<f64, D, D>::zeros();
        for (p, a) in present.clone() {
            for (q, b) in present.clone() {
                out += a * self.symbolic.inverse_block(&z.values, p, q)? * b.transpose();
            }
        }
        Some(out)
    }

    /// The decrease of χ² that the quadratic model predicts for `step`
    /// (as returned by [`Self::solve`]): `−2δᵀb − δᵀHδ`, which for the damped
    /// solution of the current factor equals `−δᵀb + λ·δᵀ diag(H) δ`; for a
    /// chord step (the factor of an earlier `H`) it is computed as it is.
    pub fn predicted_decrease(&self, step: &[f64]) -> f64 {
        let (dot_b, dot_d) = self.model_terms(step);
        if self.factor_current {
            -dot_b + self.lambda * dot_d
        } else {
            -2.0 * dot_b - self.quadratic_form(step)
        }
    }

    /// `δᵀHδ` for `step` by variable block.
    fn quadratic_form(&self, step: &[f64]) -> f64 {
        let x = |block: usize| &step[block * D..block * D + D];
        let mut sum = 0.0;
        for (block, &p) in self.position.iter().enumerate() {
            let (xp, h) = (x(block), &self.diag[p * D * D..][..D * D]);
            // The lower triangle, column-major: the diagonal once, the rest twice.
            for c in 0..D {
                sum += xp[c] * h[c * D + c] * xp[c];
                for r in c + 1..D {
                    sum += 2.0 * xp[r] * h[c * D + r] * xp[c];
                }
            }
            for k in self.later.starts()[p]..self.later.starts()[p + 1] {
                let (xq, h) = (x(self.off_row[k] as usize), &self.off[k * D * D..][..D * D]);
                // Rows of the later block, columns of this one, column-major.
                for c in 0..D {
                    for r in 0..D {
                        sum += 2.0 * xq[r] * h[c * D + r] * xp[c];
                    }
                }
            }
        }
        sum
    }

    /// The share of the damping in the quadratic model along `step` (as
    /// returned by [`Self::solve`]): `λ·δᵀDδ / (−δᵀb)`, `D` the (floored)
    /// diagonal of `H`. For the damped solution `−δᵀb = δᵀHδ + λ·δᵀDδ`, so
    /// the share is 0 without damping, ½ where the damping adds as much
    /// curvature along the step as `H` has — the step is half as long as
    /// the undamped model's minimiser along the same direction — and tends
    /// to 1 as the damping takes over. 1 for a damped step that does not
    /// descend (`−δᵀb ≤ 0`).
    pub fn damping_share(&self, step: &[f64]) -> f64 {
        if self.lambda == 0.0 {
            return 0.0;
        }
        let (dot_b, dot_d) = self.model_terms(step);
        if -dot_b > 0.0 {
            (self.lambda * dot_d / -dot_b).min(1.0)
        } else {
            1.0
        }
    }

    /// `δᵀb` and `δᵀDδ` for `step` by variable block (`D` the diagonal of
    /// `H`, floored as the damping floors it).
    fn model_terms(&self, step: &[f64]) -> (f64, f64) {
        let max_diag = self.undamped_diagonal.iter().fold(0.0f64, |m, &d| m.max(d));
        let floor = DIAGONAL_FLOOR * max_diag;
        let mut dot_b = 0.0;
        let mut dot_d = 0.0;
        for (block, &p) in self.position.iter().enumerate() {
            for a in 0..D {
                let s = step[block * D + a];
                dot_b += s * self.gradient[p * D + a];
                dot_d += s * s * self.undamped_diagonal[p * D + a].max(floor);
            }
        }
        (dot_b, dot_d)
    }
}

/// The slots of an edge between variable blocks `i` and `j` (`None`: a
/// fixed vertex), given the later neighbours of each position (whose
/// entries are the off-diagonal blocks, in order).
fn edge_slot(
    i: Option<usize>,
    j: Option<usize>,
    position: &[usize],
    later: &Adjacency,
) -> EdgeSlot {
    let pos = |b: Option<usize>| b.map_or(NONE, |b| position[b] as u32);
    let (pi, pj) = (pos(i), pos(j));
    let mut slot = EdgeSlot {
        i: pi,
        j: pj,
        off: NONE,
        i_is_row: false,
    };
    if pi != NONE && pj != NONE && pi != pj {
        let (col, row) = (pi.min(pj) as usize, pi.max(pj) as usize);
        // Cannot fail: `row` was recorded as a later neighbour of `col`.
        let rank = later[col].binary_search(&row).unwrap_or(0);
        slot.off = (later.starts()[col] + rank) as u32;
        slot.i_is_row = pi > pj;
    }
    slot
}

/// Adds the lower triangle of `h` to a column-major `D×D` block.
#[inline]
fn add_lower<const D: usize>(block: &mut [f64], h: &SMatrix<f64, D, D>) {
    for c in 0..D {
        for r in c..D {
            block[c * D + r] += h[(r, c)];
        }
    }
}

/// Adds `H_ij` (or its transpose) to an off-diagonal slot.
#[inline]
fn add_off_diagonal<const D: usize>(block: &mut [f64], h_ij: &SMatrix<f64, D, D>, i_is_row: bool) {
    for c in 0..D {
        for r in 0..D {
            block[c * D + r] += if i_is_row { h_ij[(r, c)] } else { h_ij[(c, r)] };
        }
    }
}

/// A vector written by several threads at disjoint places.
struct SharedSlice(*mut f64);
// SAFETY: used only where every element has one writer (see `add_edges`).
unsafe impl Sync for SharedSlice {}
unsafe impl Send for SharedSlice {}

impl SharedSlice {
    /// The element at `offset` (a method, so that closures capture the
    /// whole `Sync` wrapper rather than its raw pointer).
    ///
    /// # Safety
    /// `offset` is in bounds.
    unsafe fn at(&self, offset: usize) -> *mut f64 {
        // SAFETY: in bounds by the caller's contract.
        unsafe { self.0.add(offset) }
    }
}

/// `add_diagonal` through shared pointers.
///
/// # Safety
/// The caller is the only writer of block `p` and gradient entries `p·D..`.
unsafe fn add_diagonal_raw<const D: usize>(
    diag: &SharedSlice,
    gradient: &SharedSlice,
    p: usize,
    h: &SMatrix<f64, D, D>,
    g: &SVector<f64, D>,
) {
    // SAFETY: see above; the offsets are in bounds for a position p < n.
    let (block, grad) = unsafe {
        (
            std::slice::from_raw_parts_mut(diag.at(p * D * D), D * D),
            std::slice::from_raw_parts_mut(gradient.at(p * D), D),
        )
    };
    add_lower::<D>(block, h);
    for a in 0..D {
        grad[a] += g[a];
    }
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
    use nalgebra::{DMatrix, DVector, Matrix1, Matrix2, Vector1, Vector2};
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
        let mut sys = BlockSystem::<2>::new(n, &pairs, Parallelism::sequential()).unwrap();
        let (h, b) = assemble_random(&mut sys, &pairs, &mut rng);
        (sys, h, b)
    }

    /// Assembles random edge terms on `pairs` into `sys` (cleared first)
    /// and returns the dense `H` and `b`.
    fn assemble_random(
        sys: &mut BlockSystem<2>,
        pairs: &[(Option<usize>, Option<usize>)],
        rng: &mut StdRng,
    ) -> (DMatrix<f64>, DVector<f64>) {
        let n = sys.num_blocks();
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
        (h, b)
    }

    use std::ops::AddAssign;

    #[test]
    fn a_change_at_every_block_refactors_all_and_the_root_is_on_every_path() {
        for seed in 0..4 {
            let (sys, _, _) = random_system(seed);
            let all = sys.factor_stats().1;
            let blocks: Vec<usize> = (0..sys.num_blocks()).collect();
            assert!((sys.refactor_flops(&blocks) - all).abs() <= 1e-12 * all);
            assert_eq!(sys.refactor_flops(&[]), 0.0);
            // A chain joins every block: one tree, whose root holds the
            // block eliminated last, and every change redoes the root.
            let last = sys.positions().iter().position(|&p| p == blocks.len() - 1);
            let root = sys.refactor_flops(&[last.unwrap()]);
            assert!(root > 0.0 && root < all);
            for b in blocks {
                assert!(sys.refactor_flops(&[b]) >= root, "seed {seed}, block {b}");
            }
        }
    }

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
    fn a_chord_step_solves_with_the_old_factor_and_predicts_with_the_new_h() {
        for seed in 0..5 {
            let (mut sys, h0, _) = random_system(seed);
            sys.factorize(0.0).unwrap();
            // The same edges assembled again with other values: the factor
            // is H₀'s.
            let pairs: Vec<_> = sys
                .edges
                .iter()
                .map(|e| {
                    let block = |p: u32| {
                        (p != NONE)
                            .then(|| sys.position.iter().position(|&q| q == p as usize).unwrap())
                    };
                    (block(e.i), block(e.j))
                })
                .collect();
            let mut rng = StdRng::seed_from_u64(seed + 100);
            let (h, b) = assemble_random(&mut sys, &pairs, &mut rng);
            let mut step = vec![0.0; 24];
            sys.solve(&mut step);
            let expected = h0.clone().cholesky().unwrap().solve(&(-&b));
            let got = DVector::from_vec(step.clone());
            assert!((&got - &expected).norm() < 1e-9 * expected.norm().max(1.0));
            // The model at the new H: −2δᵀb − δᵀHδ.
            let model = -2.0 * got.dot(&b) - got.dot(&(&h * &got));
            let predicted = sys.predicted_decrease(&step);
            assert!(
                (predicted - model).abs() < 1e-9 * model.abs().max(1.0),
                "seed {seed}: {predicted} vs {model}"
            );
        }
    }

    #[test]
    fn a_system_cleared_after_an_assembly_is_assembled_as_a_fresh_one() {
        let pairs: Vec<(Option<usize>, Option<usize>)> = (1..8)
            .map(|k| (Some(k - 1), Some(k)))
            .chain([(Some(0), Some(5)), (Some(2), None)])
            .collect();
        let build = || BlockSystem::<2>::new(8, &pairs, Parallelism::sequential()).unwrap();
        let (mut used, mut fresh) = (build(), build());
        // Other terms and a gradient first, then the same terms as `fresh`'s.
        assemble_random(&mut used, &pairs, &mut StdRng::seed_from_u64(1));
        used.add_edge_gradient(0, &Vector2::new(1.0, 2.0), &Vector2::new(3.0, 4.0));
        let again = assemble_random(&mut used, &pairs, &mut StdRng::seed_from_u64(2));
        let first = assemble_random(&mut fresh, &pairs, &mut StdRng::seed_from_u64(2));
        assert_eq!(again, first);
        assert_eq!(used.diag, fresh.diag);
        assert_eq!(used.off, fresh.off);
        assert_eq!(used.gradient, fresh.gradient);
        fresh.clear();
        let values = fresh.diag.iter().chain(&fresh.off).chain(&fresh.gradient);
        assert!(values.copied().all(|x| x == 0.0));
    }

    #[test]
    fn a_reused_allocation_factorises_to_the_same_bits() {
        for seed in 0..3 {
            let (mut fresh, _, _) = random_system(seed);
            fresh.factorize(0.0).unwrap();
            let mut expected = vec![0.0; 24];
            fresh.solve(&mut expected);
            // Another system's allocation, holding garbage, larger or smaller.
            for len in [1, 10_000] {
                let (mut sys, _, _) = random_system(seed);
                sys.reuse_factor_allocation(vec![f64::NAN; len]);
                sys.factorize(0.0).unwrap();
                let mut step = vec![0.0; 24];
                sys.solve(&mut step);
                assert_eq!(step, expected, "seed {seed}, buffer of {len}");
                let taken = sys.take_factor_allocation();
                assert_eq!(taken.len(), fresh.nnz_factor());
            }
        }
    }

    #[test]
    fn propagate_is_a_h_inverse_a_transpose_also_from_the_selected_inverse() {
        use nalgebra::Matrix2;
        for seed in 0..5 {
            let (mut sys, h, _) = random_system(seed);
            sys.factorize(0.0).unwrap();
            let z = sys.selected_inverse();
            let mut selected = 0;
            let h_inv = h.clone().try_inverse().unwrap();
            let n = sys.num_blocks();
            let a_i = Matrix2::new(1.0, 0.5 + seed as f64, -2.0, 0.25);
            let a_j = Matrix2::new(-1.0, 0.3, 0.7, 2.0);
            // Every pair, one block only, none: the scratch must be clean
            // between calls.
            let mut pairs = vec![(Some(0), None), (None, None)];
            for i in 0..n {
                for j in 0..n {
                    if i != j {
                        pairs.push((Some(i), Some(j)));
                    }
                }
            }
            for (i, j) in pairs {
                let mut a = DMatrix::<f64>::zeros(2, 2 * n);
                if let Some(i) = i {
                    a.view_mut((0, 2 * i), (2, 2)).copy_from(&a_i);
                }
                if let Some(j) = j {
                    a.view_mut((0, 2 * j), (2, 2)).copy_from(&a_j);
                }
                let expected = &a * &h_inv * a.transpose();
                let close = |got: &Matrix2<f64>| {
                    (0..4).all(|k| (got[k] - expected[k]).abs() < 1e-9 * expected.norm().max(1.0))
                };
                let got = sys.propagate(i, &a_i, j, &a_j);
                assert!(
                    close(&got),
                    "seed {seed}, blocks {i:?} {j:?}: {got} vs {expected}"
                );
                // From the selected inverse: the same where the two blocks
                // are tied in H (and always for one block or none); where
                // they are not, nothing unless the factor filled them in.
                let tied = match (i, j) {
                    (Some(i), Some(j)) => h[(2 * i, 2 * j)] != 0.0,
                    _ => true,
                };
                match sys.propagate_selected(&z, i, &a_i, j, &a_j) {
                    Some(got) => assert!(close(&got), "seed {seed}, selected {i:?} {j:?}"),
                    None => assert!(!tied, "seed {seed}: {i:?} {j:?} tied but no block"),
                }
                selected += usize::from(tied);
            }
            assert!(selected > n, "seed {seed}: off-diagonal pairs read");
        }
    }

    #[test]
    fn upper_csc_is_h_and_faer_solves_it_alike() {
        use faer::Side;
        use faer::sparse::linalg::cholesky::{
            CholeskySymbolicParams, LltRef, SymmetricOrdering, factorize_symbolic_cholesky,
        };
        use faer::sparse::{SparseColMatRef, SymbolicSparseColMatRef};
        let (mut sys, h, b) = random_system(3);
        let (col_ptr, rows, values) = sys.upper_csc();
        let n = 24;
        // Dense, by elimination position, from the CSC.
        let mut dense = DMatrix::zeros(n, n);
        for c in 0..n {
            for k in col_ptr[c]..col_ptr[c + 1] {
                assert!(rows[k] <= c && (k == col_ptr[c] || rows[k] > rows[k - 1]));
                dense[(rows[k], c)] = values[k];
                dense[(c, rows[k])] = values[k];
            }
        }
        let position = sys.position.clone();
        let scalar = |block: usize, a: usize| 2 * position[block] + a;
        for i in 0..n {
            for j in 0..n {
                assert_eq!(
                    dense[(scalar(i / 2, i % 2), scalar(j / 2, j % 2))],
                    h[(i, j)]
                );
            }
        }
        // faer's supernodal Cholesky of the same matrix, same solution.
        let pattern = SymbolicSparseColMatRef::new_checked(n, n, &col_ptr, None, &rows);
        let symbolic = factorize_symbolic_cholesky(
            pattern,
            Side::Upper,
            SymmetricOrdering::Identity,
            CholeskySymbolicParams::default(),
        )
        .unwrap();
        let mut l = vec![0.0; symbolic.len_val()];
        let mut mem = MemBuffer::new(
            symbolic.factorize_numeric_llt_scratch::<f64>(faer::Par::Seq, Default::default()),
        );
        symbolic
            .factorize_numeric_llt::<f64>(
                &mut l,
                SparseColMatRef::new(pattern, &values),
                Side::Upper,
                Default::default(),
                faer::Par::Seq,
                MemStack::new(&mut mem),
                Default::default(),
            )
            .unwrap();
        let mut rhs = faer::Mat::<f64>::zeros(n, 1);
        for i in 0..n {
            rhs[(scalar(i / 2, i % 2), 0)] = -b[i];
        }
        let mut mem = MemBuffer::new(symbolic.solve_in_place_scratch::<f64>(1, faer::Par::Seq));
        LltRef::<'_, usize, f64>::new(&symbolic, &l).solve_in_place_with_conj(
            faer::Conj::No,
            rhs.as_mut(),
            faer::Par::Seq,
            MemStack::new(&mut mem),
        );
        sys.factorize(0.0).unwrap();
        let mut step = vec![0.0; n];
        sys.solve(&mut step);
        for i in 0..n {
            let theirs = rhs[(scalar(i / 2, i % 2), 0)];
            assert!(
                (step[i] - theirs).abs() < 1e-10 * theirs.abs().max(1.0),
                "{i}"
            );
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
        // The damping's share of the model along the step: λ·δᵀDδ / (−δᵀb),
        // strictly between 0 and 1, growing with λ.
        let curvature = |d: &DVector<f64>| {
            d.dot(&DVector::from_iterator(
                24,
                (0..24).map(|i| h[(i, i)] * d[i]),
            ))
        };
        let share = lambda * curvature(&expected) / -expected.dot(&b);
        assert!(share > 0.0 && share < 1.0, "{share}");
        assert!((sys.damping_share(&step) - share).abs() < 1e-9, "{share}");
        sys.factorize(50.0).unwrap();
        let mut heavy = vec![0.0; 24];
        sys.solve(&mut heavy);
        assert!(sys.damping_share(&heavy) > 0.9);
        // Refactorising without damping gives the undamped solution again,
        // whose share is 0.
        sys.factorize(0.0).unwrap();
        sys.solve(&mut step);
        let plain = h.cholesky().unwrap().solve(&(-&b));
        assert!((DVector::from_vec(step.clone()) - plain).norm() < 1e-9);
        assert_eq!(sys.damping_share(&step), 0.0);
    }

    #[test]
    fn singular_systems_name_the_failing_block() {
        // Block 2 has no edge at all: its diagonal is zero.
        let pairs = [(Some(0), Some(1)), (Some(0), None)];
        let mut sys = BlockSystem::<1>::new(3, &pairs, Parallelism::sequential()).unwrap();
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

    #[test]
    fn a_two_variable_system_by_hand() {
        // Two scalar variables tied by one edge, plus a prior on the first:
        // H = [[2, −1], [−1, 1]], b = [0, −1], so δ = −H⁻¹b = [1, 2].
        let mut sys = BlockSystem::<1>::new(
            2,
            &[(Some(0), Some(1)), (Some(0), None)],
            Parallelism::sequential(),
        )
        .unwrap();
        sys.clear();
        let one = Matrix1::new(1.0);
        sys.add_edge(
            0,
            &one,
            &Matrix1::new(-1.0),
            &one,
            &Vector1::new(0.0),
            &Vector1::new(-1.0),
        );
        sys.add_edge(
            1,
            &one,
            &Matrix1::zeros(),
            &Matrix1::zeros(),
            &Vector1::new(0.0),
            &Vector1::zeros(),
        );
        sys.factorize(0.0).unwrap();
        let mut step = vec![0.0; 2];
        sys.solve(&mut step);
        assert!((step[0] - 1.0).abs() < 1e-12 && (step[1] - 2.0).abs() < 1e-12);
        // H⁻¹ = [[1, 1], [1, 2]]; for the edge error e = x₁ − x₀,
        // A = [−1, 1] and A·H⁻¹·Aᵀ = 1 − 2 + 2 = 1.
        let m = sys.propagate(Some(0), &Matrix1::new(-1.0), Some(1), &one);
        assert!((m[(0, 0)] - 1.0).abs() < 1e-12);
        // The variance of x₁ alone: (H⁻¹)₁₁ = 2.
        assert!((sys.propagate(None, &one, Some(1), &one)[(0, 0)] - 2.0).abs() < 1e-12);
    }
}
