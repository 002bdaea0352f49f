//! A block-supernodal sparse Cholesky factorisation `H = L·Lᵀ` for
//! matrices made of `D×D` blocks (one block row and column per free pose),
//! already in elimination order.
//!
//! * The symbolic analysis runs on the graph of *blocks* (faer's supernodal
//!   symbolic Cholesky with its relaxed amalgamation, `D²` times smaller than
//!   the scalar problem). Each supernode is a run of consecutive block
//!   columns with one block-row pattern; its values are one dense
//!   column-major panel (diagonal block on top, then the off-diagonal block
//!   rows), so every block row is `D` contiguous scalars.
//! * The numeric factorisation is left-looking: a supernode gathers the
//!   updates of the descendants that have rows in its columns (one dense
//!   product each, scattered block row by block row), then factorises its
//!   diagonal block and solves for the rows below. A supernode only *writes*
//!   its own panel and only *reads* finished descendants, so the subtrees of
//!   the elimination tree are factorised in parallel; the result is the same
//!   bits whatever the number of threads.
//! * Everything the numeric phase needs (panel offsets, update lists, the
//!   tree and the work of each subtree) is computed once; a factorisation
//!   allocates nothing but its thread's workspace on first use.

mod off_pattern;

use super::{LinearError, Parallelism};
use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::cholesky::llt::factor::{
    LltError, LltRegularization, cholesky_in_place, cholesky_in_place_scratch,
};
use faer::linalg::matmul::matmul;
use faer::linalg::matmul::triangular::{self, BlockStructure};
use faer::linalg::triangular_solve::{
    solve_lower_triangular_in_place, solve_upper_triangular_in_place,
};
use faer::reborrow::{Reborrow, ReborrowMut};
use faer::sparse::SymbolicSparseColMatRef;
use faer::sparse::linalg::SupernodalThreshold;
use faer::sparse::linalg::cholesky::{
    CholeskySymbolicParams, SymbolicCholeskyRaw, SymmetricOrdering, factorize_symbolic_cholesky,
};
use faer::{Accum, MatMut, MatRef, Par, Side};
pub(super) use off_pattern::OffPattern;
use rayon::prelude::*;
use std::cell::RefCell;
use std::sync::atomic::{AtomicUsize, Ordering};

/// Diagonal blocks up to this width are factorised by the column kernel of
/// this module; wider ones by faer's blocked dense Cholesky.
const SMALL_WIDTH: usize = 12;

/// Dense products of more flops than this use all threads (when the
/// factorisation is parallel); the top separators of the elimination tree
/// are where the tree itself offers no parallelism.
const PARALLEL_PRODUCT: f64 = 2e6;

/// Update products of at most this many multiply-adds are formed by one
/// dense product of the whole rectangle — the top block's upper half too,
/// at most as much work again — rather than two (the top block's lower
/// triangle, then the rows below): a call into faer's kernels has a fixed
/// cost of a few thousand multiply-adds, which the small updates of a pose
/// graph's factor do not repay twice. One call for these took a
/// factorisation of intel from 548–569 to 457–461 µs and of a simulated
/// 3D graph of 10⁴ poses from 6.9–7.2 to 5.5–5.7 ms (`cargo bench
/// --features internals --bench pipeline -- factorize`, one thread).
const ONE_CALL_PRODUCT: usize = 4096;

/// Scratch for one update product, in scalars (2 MiB): the product is
/// formed this many entries at a time (at least one block column), not
/// whole — the largest update of a big graph's top separator would
/// otherwise need scratch the size of a good part of the factor.
const UPDATE_SCRATCH: usize = 1 << 18;

/// Block columns of an update product of `m` scalar rows and `count` block
/// columns formed at once with `scratch` scalars of scratch (see
/// [`UPDATE_SCRATCH`]).
fn chunk_blocks<const D: usize>(scratch: usize, m: usize, count: usize) -> usize {
    (scratch / (m * D).max(1)).clamp(1, count.max(1))
}

/// One descendant's update of a supernode: rows `start .. start + count` of
/// the descendant's pattern fall in the supernode's columns.
#[derive(Clone, Copy, Debug)]
struct Update {
    from: u32,
    start: u32,
    count: u32,
}

/// The structure of the factor.
#[derive(Debug)]
pub(super) struct Symbolic<const D: usize> {
    /// First block column of each supernode (and the end, length `ns + 1`).
    begin: Vec<usize>,
    /// Block rows below each supernode's diagonal block:
    /// `rows[row_ptr[s]..row_ptr[s + 1]]`, increasing.
    row_ptr: Vec<usize>,
    rows: Vec<u32>,
    /// Offset of each supernode's panel in the values (length `ns + 1`).
    val_ptr: Vec<usize>,
    /// Supernode of each block column.
    supernode_of: Vec<u32>,
    /// Updates received by each supernode: `updates[update_ptr[s]..update_ptr[s + 1]]`.
    update_ptr: Vec<usize>,
    updates: Vec<Update>,
    /// Parent of each supernode in the elimination tree (`u32::MAX` for a
    /// root).
    parent: Vec<u32>,
    /// Children of each supernode in the elimination tree, and the roots.
    child_ptr: Vec<usize>,
    children: Vec<u32>,
    roots: Vec<u32>,
    /// Floating-point operations of each supernode (its updates and its
    /// diagonal factorisation) and of each subtree (for the schedule).
    node_flops: Vec<f64>,
    subtree_flops: Vec<f64>,
    /// Floating-point operations of one factorisation.
    flops: f64,
    /// Largest update product (`m·n`) and largest number of rows below a
    /// diagonal block (workspace sizes).
    max_update: usize,
    max_below: usize,
    /// Scalars of scratch an update product is formed in (at least one
    /// block column of it at a time).
    update_scratch: usize,
}

/// The lower triangle's pattern of a block matrix by columns: the block
/// rows `q > p` of each block column `p`, increasing (its later neighbours
/// in the elimination order), all in one array.
#[derive(Clone, Debug, Default, PartialEq)]
pub(super) struct Adjacency {
    ptr: Vec<usize>,
    rows: Vec<usize>,
}

impl Adjacency {
    /// The pattern of the blocks `(max(p, q), min(p, q))` for `(p, q)` in
    /// `pairs` with `p ≠ q`, among `n` block columns (duplicates once).
    pub(super) fn from_pairs(
        n: usize,
        pairs: impl Iterator<Item = (usize, usize)> + Clone,
    ) -> Self {
        let mut ptr = vec![0usize; n + 1];
        for (p, q) in pairs.clone().filter(|(p, q)| p != q) {
            ptr[p.min(q) + 1] += 1;
        }
        for k in 0..n {
            ptr[k + 1] += ptr[k];
        }
        let mut next = ptr.clone();
        let mut rows = vec![0usize; ptr[n]];
        for (p, q) in pairs.filter(|(p, q)| p != q) {
            let c = p.min(q);
            rows[next[c]] = p.max(q);
            next[c] += 1;
        }
        // Each column's rows sorted and without repeats, moved down over
        // the repeats removed before it.
        let mut kept = 0;
        for c in 0..n {
            let (start, end) = (ptr[c], ptr[c + 1]);
            rows[start..end].sort_unstable();
            ptr[c] = kept;
            for k in start..end {
                if k == start || rows[k] != rows[k - 1] {
                    rows[kept] = rows[k];
                    kept += 1;
                }
            }
        }
        ptr[n] = kept;
        rows.truncate(kept);
        Self { ptr, rows }
    }

    /// The pattern whose column `p` has the rows `lists[p]` (each
    /// increasing, after `p`).
    #[cfg(test)]
    pub(super) fn from_lists(lists: &[Vec<usize>]) -> Self {
        let pairs = lists
            .iter()
            .enumerate()
            .flat_map(|(p, l)| l.iter().map(move |&q| (p, q)));
        Self::from_pairs(lists.len(), pairs)
    }

    /// This pattern grown to `n` block columns by `entries` (`(column,
    /// row)`, increasing, none in it already, each row at or after its
    /// number of columns): each column's new rows follow its old ones.
    pub(super) fn appended(&self, n: usize, entries: &[(usize, usize)]) -> Self {
        let n_old = self.len();
        let mut ptr = Vec::with_capacity(n + 1);
        let mut rows = Vec::with_capacity(self.rows.len() + entries.len());
        let mut new = entries.iter().peekable();
        ptr.push(0);
        for c in 0..n {
            if c < n_old {
                rows.extend_from_slice(&self[c]);
            }
            while let Some(&(_, r)) = new.next_if(|&&(col, _)| col == c) {
                rows.push(r);
            }
            ptr.push(rows.len());
        }
        Self { ptr, rows }
    }

    /// Block columns.
    pub(super) fn len(&self) -> usize {
        self.ptr.len().saturating_sub(1)
    }

    /// Where each column's rows start in the entries (and the end).
    pub(super) fn starts(&self) -> &[usize] {
        &self.ptr
    }

    /// Each column's rows, in column order.
    pub(super) fn iter(&self) -> impl Iterator<Item = &[usize]> {
        (0..self.len()).map(|p| &self[p])
    }
}

impl std::ops::Index<usize> for Adjacency {
    type Output = [usize];

    fn index(&self, p: usize) -> &[usize] {
        &self.rows[self.ptr[p]..self.ptr[p + 1]]
    }
}

/// A factor's supernodes (`begin`, with the end) and the block rows below
/// each one's diagonal block (`rows[row_ptr[s]..row_ptr[s + 1]]`).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Structure {
    begin: Vec<usize>,
    row_ptr: Vec<usize>,
    rows: Vec<u32>,
}

impl Structure {
    /// Block columns of the factor.
    pub fn len(&self) -> usize {
        self.begin.last().copied().unwrap_or(0)
    }

    /// The new block rows (at or after the old size) of each old supernode
    /// in the factor of the grown matrix `later`: those of its columns'
    /// entries and of its children's, which all lie below its columns.
    /// `None` if an entry between old columns is outside the old factor.
    fn added_rows(&self, later: &Adjacency) -> Option<Vec<Vec<u32>>> {
        let ns = self.begin.len() - 1;
        let n_old = self.begin[ns];
        let supernode_of = self.supernode_of();
        let mut own: Vec<Vec<u32>> = vec![Vec::new(); ns];
        for (s, a) in own.iter_mut().enumerate() {
            let end = self.begin[s + 1];
            let below = &self.rows[self.row_ptr[s]..self.row_ptr[s + 1]];
            for p in self.begin[s]..end {
                for &q in &later[p] {
                    if q >= n_old {
                        a.push(q as u32);
                    } else if q >= end && below.binary_search(&(q as u32)).is_err() {
                        return None;
                    }
                }
            }
        }
        Some(self.passed_up(own, &supernode_of))
    }

    /// [`Self::added_rows`] of a grown matrix whose entries beyond this
    /// factor's matrix are `entries` (`(column, row)`, each row at or after
    /// the old size): only those are read.
    fn added_by(&self, entries: &[(usize, usize)]) -> Vec<Vec<u32>> {
        let ns = self.begin.len() - 1;
        let n_old = self.begin[ns];
        let supernode_of = self.supernode_of();
        let mut own: Vec<Vec<u32>> = vec![Vec::new(); ns];
        for &(c, r) in entries.iter().filter(|&&(c, _)| c < n_old) {
            own[supernode_of[c] as usize].push(r as u32);
        }
        self.passed_up(own, &supernode_of)
    }

    /// Each old supernode's new rows from those of its own columns
    /// (`own`): its children's are its too, as they all lie below its
    /// columns (children come before their parents).
    fn passed_up(&self, mut added: Vec<Vec<u32>>, supernode_of: &[u32]) -> Vec<Vec<u32>> {
        for s in 0..added.len() {
            let mut a = std::mem::take(&mut added[s]);
            a.sort_unstable();
            a.dedup();
            if let Some(&r) = self.rows[self.row_ptr[s]..self.row_ptr[s + 1]].first() {
                added[supernode_of[r as usize] as usize].extend_from_slice(&a);
            }
            added[s] = a;
        }
        added
    }

    /// The supernode of each block column.
    fn supernode_of(&self) -> Vec<u32> {
        supernode_of(&self.begin)
    }
}

/// The supernode of each block column, for supernodes starting at `begin`
/// (with the end).
fn supernode_of(begin: &[usize]) -> Vec<u32> {
    let ns = begin.len() - 1;
    let mut of = vec![0u32; begin[ns]];
    for s in 0..ns {
        of[begin[s]..begin[s + 1]].fill(s as u32);
    }
    of
}

/// The supernodes of the new columns `n_old..` of a grown factor: each
/// new column's block rows (its entries in `later`, and what its children
/// in the elimination tree pass on — old supernodes without old rows
/// among them, whose new rows `added` says), then runs of columns where
/// each has the next as its only first row and the same rows after it.
/// Returns where each starts and its rows below.
fn new_supernodes(
    n_old: usize,
    later: &Adjacency,
    prev: &Structure,
    added: &[Vec<u32>],
) -> (Vec<usize>, Vec<Vec<u32>>) {
    let n = later.len();
    let mut pending: Vec<Vec<u32>> = vec![Vec::new(); n - n_old];
    for (s, a) in added.iter().enumerate() {
        if prev.row_ptr[s + 1] == prev.row_ptr[s] && !a.is_empty() {
            pending[a[0] as usize - n_old].extend_from_slice(&a[1..]);
        }
    }
    let mut column = Vec::with_capacity(n - n_old);
    for q in n_old..n {
        let mut st = std::mem::take(&mut pending[q - n_old]);
        st.extend(later[q].iter().map(|&r| r as u32));
        st.sort_unstable();
        st.dedup();
        if let Some(&p) = st.first() {
            pending[p as usize - n_old].extend_from_slice(&st[1..]);
        }
        column.push(st);
    }
    let (mut begin, mut rows) = (Vec::new(), Vec::new());
    let mut q = n_old;
    while q < n {
        let start = q;
        while q + 1 < n && {
            let (this, next) = (&column[q - n_old], &column[q + 1 - n_old]);
            this.first() == Some(&((q + 1) as u32)) && this[1..] == next[..]
        } {
            q += 1;
        }
        begin.push(start);
        rows.push(std::mem::take(&mut column[q - n_old]));
        q += 1;
    }
    (begin, rows)
}

/// A panel's geometry: first block column, width in blocks, block rows below.
#[derive(Clone, Copy)]
struct Panel {
    b0: usize,
    w: usize,
    p: usize,
}

impl Panel {
    /// Scalar columns.
    fn cols<const D: usize>(self) -> usize {
        D * self.w
    }
    /// Scalar rows (the leading dimension).
    fn ld<const D: usize>(self) -> usize {
        D * (self.w + self.p)
    }
}

impl<const D: usize> Symbolic<D> {
    /// The structure of the factor of a block matrix whose lower triangle has
    /// block `(q, p)` for every `q` in `later[p]` (each list increasing, all
    /// `q > p`) and every diagonal block.
    pub(super) fn new(later: &Adjacency) -> Result<Self, LinearError> {
        Self::with_update_scratch(later, UPDATE_SCRATCH)
    }

    /// [`Self::new`] with the scratch of an update product given in scalars.
    fn with_update_scratch(later: &Adjacency, scratch: usize) -> Result<Self, LinearError> {
        let n = later.len();
        if n == 0 {
            return Ok(Self::from_structure(vec![0], vec![0], Vec::new(), scratch));
        }
        // faer's symbolic analysis (identity ordering) reads the upper
        // triangle: column q lists rows p < q, then the diagonal.
        let mut col_ptr = vec![0usize; n + 1];
        for (p, l) in later.iter().enumerate() {
            col_ptr[p + 1] += 1;
            for &q in l {
                col_ptr[q + 1] += 1;
            }
        }
        for k in 0..n {
            col_ptr[k + 1] += col_ptr[k];
        }
        let mut next = col_ptr.clone();
        let mut row_idx = vec![0usize; col_ptr[n]];
        for (p, l) in later.iter().enumerate() {
            // Column p has all its rows p' < p by now: the diagonal goes last.
            row_idx[next[p]] = p;
            next[p] += 1;
            for &q in l {
                row_idx[next[q]] = p;
                next[q] += 1;
            }
        }
        let pattern = SymbolicSparseColMatRef::new_checked(n, n, &col_ptr, None, &row_idx);
        // faer's default relaxation counts scalar columns; in blocks of D
        // columns the same thresholds are D times smaller.
        let relax: Vec<(usize, f64)> = [(4, 1.0), (16, 0.8), (48, 0.1)]
            .iter()
            .map(|&(c, z)| ((c / D).max(1), z))
            .chain([(usize::MAX, 0.05)])
            .collect();
        let mut params = CholeskySymbolicParams {
            supernodal_flop_ratio_threshold: SupernodalThreshold::FORCE_SUPERNODAL,
            ..Default::default()
        };
        params.supernodal_params.relax = Some(&relax);
        let symbolic =
            factorize_symbolic_cholesky(pattern, Side::Upper, SymmetricOrdering::Identity, params)
                .map_err(|e| LinearError::Factorization(format!("{e:?}")))?;
        let SymbolicCholeskyRaw::Supernodal(s) = symbolic.raw() else {
            return Err(LinearError::Factorization(
                "expected a supernodal structure".into(),
            ));
        };
        let ns = s.n_supernodes();
        let mut begin = Vec::with_capacity(ns + 1);
        begin.extend_from_slice(s.supernode_begin());
        begin.push(n);
        let (fa_row_ptr, fa_rows, fa_val_ptr) =
            (s.col_ptr_for_row_idx(), s.row_idx(), s.col_ptr_for_val());
        let mut row_ptr = Vec::with_capacity(ns + 1);
        let mut rows = Vec::new();
        row_ptr.push(0);
        for k in 0..ns {
            let w = begin[k + 1] - begin[k];
            let p = (fa_val_ptr[k + 1] - fa_val_ptr[k]) / w - w;
            rows.extend(fa_rows[fa_row_ptr[k]..][..p].iter().map(|&r| r as u32));
            row_ptr.push(rows.len());
        }
        drop(symbolic);
        Ok(Self::from_structure(begin, row_ptr, rows, scratch))
    }

    /// Every block row of block column `b` in the factor (its supernode's
    /// columns after `b`, then the rows below), for tests.
    #[cfg(test)]
    fn rows_of(&self, b: usize) -> Vec<usize> {
        let s = self.supernode_of[b] as usize;
        let below = self.rows[self.row_ptr[s]..self.row_ptr[s + 1]].iter();
        (b + 1..self.begin[s + 1])
            .chain(below.map(|&r| r as usize))
            .collect()
    }

    /// The supernodes and their block rows, without the numbers of `D`
    /// ([`Self::extended`] grows a factor from them).
    pub(super) fn structure(&self) -> Structure {
        Structure {
            begin: self.begin.clone(),
            row_ptr: self.row_ptr.clone(),
            rows: self.rows.clone(),
        }
    }

    /// The structure of the factor of the matrix of `prev` grown by block
    /// columns appended at the end (at least one): `later` as for [`Self::new`], its
    /// first `prev`'s-size lists holding no block between old columns that
    /// `prev` does not (else `None`). The old supernodes are kept, each
    /// with the new block rows its columns and its descendants reach (rows
    /// of zeros are allowed in a supernode, as faer's relaxed ones hold);
    /// the new columns form fundamental supernodes. Cheaper than the
    /// analysis afresh, which is what a kept elimination order with poses
    /// appended would otherwise cost at every update.
    pub(super) fn extended(prev: &Structure, later: &Adjacency) -> Option<Self> {
        Self::appends(prev, later)?;
        let added = prev.added_rows(later)?;
        Some(Self::grown(prev, later, &added))
    }

    /// [`Self::extended`] where the entries of `later` beyond `prev`'s
    /// matrix are known: `entries` (`(column, row)`, each row at or after
    /// `prev`'s size), so that the old columns are not read again.
    pub(super) fn extended_by(
        prev: &Structure,
        later: &Adjacency,
        entries: &[(usize, usize)],
    ) -> Option<Self> {
        Self::appends(prev, later)?;
        Some(Self::grown(prev, later, &prev.added_by(entries)))
    }

    /// `Some` if `later` appends block columns to `prev`'s. Nothing
    /// appended: a pattern rebuilt without some edges (loops a robust
    /// method removed) is analysed afresh, for the fill it sheds.
    fn appends(prev: &Structure, later: &Adjacency) -> Option<()> {
        let n_old = *prev.begin.last()?;
        (n_old > 0 && later.len() > n_old).then_some(())
    }

    /// The factor structure of `prev` grown to `later`, the old
    /// supernodes gaining the rows `added`.
    fn grown(prev: &Structure, later: &Adjacency, added: &[Vec<u32>]) -> Self {
        let n_old = *prev.begin.last().unwrap_or(&0);
        let n = later.len();
        let (begin_new, rows_new) = new_supernodes(n_old, later, prev, added);
        let mut begin = prev.begin.clone();
        begin.pop();
        begin.extend(begin_new);
        begin.push(n);
        let mut row_ptr = vec![0usize];
        let mut rows = Vec::with_capacity(prev.rows.len());
        for (s, a) in added.iter().enumerate() {
            rows.extend_from_slice(&prev.rows[prev.row_ptr[s]..prev.row_ptr[s + 1]]);
            rows.extend_from_slice(a);
            row_ptr.push(rows.len());
        }
        for r in rows_new {
            rows.extend(r);
            row_ptr.push(rows.len());
        }
        Self::from_structure(begin, row_ptr, rows, UPDATE_SCRATCH)
    }

    /// Everything else from the supernodes and their patterns.
    fn from_structure(
        begin: Vec<usize>,
        row_ptr: Vec<usize>,
        rows: Vec<u32>,
        update_scratch: usize,
    ) -> Self {
        let supernode_of = supernode_of(&begin);
        let mut symbolic = Self {
            begin,
            row_ptr,
            rows,
            val_ptr: Vec::new(),
            supernode_of,
            update_ptr: Vec::new(),
            updates: Vec::new(),
            child_ptr: Vec::new(),
            parent: Vec::new(),
            children: Vec::new(),
            roots: Vec::new(),
            node_flops: Vec::new(),
            subtree_flops: Vec::new(),
            flops: 0.0,
            max_update: 0,
            max_below: 0,
            update_scratch,
        };
        symbolic.val_ptr = symbolic.panel_offsets();
        (symbolic.update_ptr, symbolic.updates) = symbolic.group_updates();
        symbolic.build_tree();
        symbolic.estimate_work();
        symbolic
    }

    /// Where each supernode's panel starts in the values (and the end).
    fn panel_offsets(&self) -> Vec<usize> {
        let ns = self.supernodes();
        let mut val_ptr = Vec::with_capacity(ns + 1);
        val_ptr.push(0usize);
        for s in 0..ns {
            let g = self.panel(s);
            val_ptr.push(val_ptr[s] + g.ld::<D>() * g.cols::<D>());
        }
        val_ptr
    }

    /// The updates each supernode receives (`update_ptr`, `updates`): the
    /// rows of each descendant, grouped by the supernode they fall in
    /// (consecutive, since rows increase and supernodes are runs).
    fn group_updates(&self) -> (Vec<usize>, Vec<Update>) {
        let ns = self.supernodes();
        let (rows, row_ptr, supernode_of) = (&self.rows, &self.row_ptr, &self.supernode_of);
        let mut counts = vec![0usize; ns + 1];
        let mut groups = Vec::new();
        for d in 0..ns {
            let r = &rows[row_ptr[d]..row_ptr[d + 1]];
            let mut i = 0;
            while i < r.len() {
                let t = supernode_of[r[i] as usize];
                let mut j = i + 1;
                while j < r.len() && supernode_of[r[j] as usize] == t {
                    j += 1;
                }
                groups.push((
                    t,
                    Update {
                        from: d as u32,
                        start: i as u32,
                        count: (j - i) as u32,
                    },
                ));
                counts[t as usize + 1] += 1;
                i = j;
            }
        }
        for k in 0..ns {
            counts[k + 1] += counts[k];
        }
        let update_ptr = counts.clone();
        let mut updates = vec![
            Update {
                from: 0,
                start: 0,
                count: 0
            };
            groups.len()
        ];
        for (t, u) in groups {
            updates[counts[t as usize]] = u;
            counts[t as usize] += 1;
        }
        (update_ptr, updates)
    }

    /// The elimination tree of the supernodes (`parent`, `child_ptr`,
    /// `children`, `roots`): the parent holds the first row below the
    /// diagonal block; parents come after their children.
    fn build_tree(&mut self) {
        let ns = self.supernodes();
        let (rows, row_ptr, supernode_of) = (&self.rows, &self.row_ptr, &self.supernode_of);
        let parent: Vec<u32> = (0..ns)
            .map(|s| {
                if row_ptr[s + 1] > row_ptr[s] {
                    supernode_of[rows[row_ptr[s]] as usize]
                } else {
                    u32::MAX
                }
            })
            .collect();
        let mut child_ptr = vec![0usize; ns + 1];
        for &p in &parent {
            if p != u32::MAX {
                child_ptr[p as usize + 1] += 1;
            }
        }
        for k in 0..ns {
            child_ptr[k + 1] += child_ptr[k];
        }
        let mut next = child_ptr.clone();
        let mut children = vec![0u32; child_ptr[ns]];
        let mut roots = Vec::new();
        for (s, &p) in parent.iter().enumerate() {
            if p == u32::MAX {
                roots.push(s as u32);
            } else {
                children[next[p as usize]] = s as u32;
                next[p as usize] += 1;
            }
        }
        (self.parent, self.child_ptr, self.children, self.roots) =
            (parent, child_ptr, children, roots);
    }

    /// The work of a factorisation (`flops`, `subtree_flops`) and the
    /// workspace sizes (`max_update`, `max_below`): each update product,
    /// each diagonal factorisation and solve.
    fn estimate_work(&mut self) {
        let ns = self.supernodes();
        let mut node_flops = vec![0.0f64; ns];
        let mut max_update = 0usize;
        let mut max_below = 0usize;
        for t in 0..ns {
            let g = self.panel(t);
            let (wc, below) = (g.cols::<D>() as f64, (D * g.p) as f64);
            node_flops[t] += wc * wc * wc / 3.0 + below * wc * wc;
            max_below = max_below.max(D * g.p);
            for u in &self.updates[self.update_ptr[t]..self.update_ptr[t + 1]] {
                let gd = self.panel(u.from as usize);
                let m = D * (gd.p - u.start as usize);
                let nn = D * u.count as usize;
                let chunk = chunk_blocks::<D>(self.update_scratch, m, u.count as usize);
                max_update = max_update.max(m * D * chunk);
                // The top n×n of the product is triangular.
                node_flops[t] += ((nn * (nn + 1) + 2 * (m - nn) * nn) * gd.cols::<D>()) as f64;
            }
        }
        self.flops = node_flops.iter().sum();
        let mut subtree_flops = node_flops.clone();
        for s in 0..ns {
            if self.parent[s] != u32::MAX {
                subtree_flops[self.parent[s] as usize] += subtree_flops[s];
            }
        }
        (self.node_flops, self.subtree_flops) = (node_flops, subtree_flops);
        (self.max_update, self.max_below) = (max_update, max_below);
    }

    fn panel(&self, s: usize) -> Panel {
        Panel {
            b0: self.begin[s],
            w: self.begin[s + 1] - self.begin[s],
            p: self.row_ptr[s + 1] - self.row_ptr[s],
        }
    }

    /// Number of supernodes.
    pub(super) fn supernodes(&self) -> usize {
        self.begin.len() - 1
    }

    /// The factor values a sparse solve from one block column reads, on
    /// average over the block columns: the panels on its path to the root
    /// of the elimination tree ([`Symbolic::reach`]).
    pub(super) fn mean_path_values(&self) -> f64 {
        let ns = self.supernodes();
        let n = self.begin[ns];
        if n == 0 {
            return 0.0;
        }
        // Parents come after their children: from the roots down.
        let mut path = vec![0usize; ns];
        let mut total = 0.0;
        for s in (0..ns).rev() {
            let above = match self.parent[s] {
                u32::MAX => 0,
                p => path[p as usize],
            };
            path[s] = above + self.val_ptr[s + 1] - self.val_ptr[s];
            total += (self.begin[s + 1] - self.begin[s]) as f64 * path[s] as f64;
        }
        total / n as f64
    }

    /// Values stored for the factor (dense panels, upper triangles of the
    /// diagonal blocks included).
    pub(super) fn len_values(&self) -> usize {
        self.val_ptr[self.supernodes()]
    }

    /// Floating-point operations of one numeric factorisation.
    pub(super) fn flops(&self) -> f64 {
        self.flops
    }

    /// The supernodes whose panels change when `H` changes only in the
    /// rows and columns of the block columns at `positions`: those holding
    /// one of them, and their ancestors in the elimination tree. Every
    /// other panel comes out of a factorisation the same bits, since a
    /// panel is formed from its own columns of `H` and its descendants'
    /// panels alone.
    pub(super) fn affected(&self, positions: impl IntoIterator<Item = usize>) -> Vec<bool> {
        let mut mark = vec![false; self.supernodes()];
        for p in positions {
            let mut s = self.supernode_of[p] as usize;
            while !mark[s] {
                mark[s] = true;
                match self.parent[s] {
                    u32::MAX => break,
                    q => s = q as usize,
                }
            }
        }
        mark
    }

    /// The first block column of each supernode, and the end.
    pub(super) fn begins(&self) -> &[usize] {
        &self.begin
    }

    /// Where each supernode's panel starts in the values, and the end.
    pub(super) fn value_offsets(&self) -> &[usize] {
        &self.val_ptr
    }

    /// Whether this structure begins with the supernodes of an earlier one
    /// whose first columns were `begin` (its supernodes, then new ones):
    /// a structure grown from it ([`Self::extended_by`]).
    pub(super) fn keeps(&self, begin: &[usize]) -> bool {
        let old = begin.len().saturating_sub(1);
        old > 0 && old <= self.supernodes() && self.begin[..old] == begin[..old]
    }

    /// Moves the panels of an earlier factor of a structure this one
    /// [`Self::keeps`] (`values` holds them at `old_ptr`'s offsets) to
    /// their places in this one, except those `formed` marks; marks as
    /// well every supernode whose panel is not the same size as before
    /// (it gained rows) and every new one. `values` must already have this
    /// structure's length.
    pub(super) fn keep_panels(&self, values: &mut [f64], old_ptr: &[usize], formed: &mut [bool]) {
        let old = old_ptr.len() - 1;
        formed[old..].fill(true);
        for s in (0..old).rev() {
            let len = old_ptr[s + 1] - old_ptr[s];
            if self.val_ptr[s + 1] - self.val_ptr[s] != len {
                formed[s] = true;
            }
            if !formed[s] {
                // Panels only grow: each moves up, past none not yet moved.
                values.copy_within(old_ptr[s]..old_ptr[s + 1], self.val_ptr[s]);
            }
        }
        // A supernode formed again changes its ancestors' panels.
        for s in 0..self.supernodes() {
            if formed[s] && self.parent[s] != u32::MAX {
                formed[self.parent[s] as usize] = true;
            }
        }
    }

    /// Factorises only the supernodes `formed` marks, in this thread, in
    /// elimination order, each from its panel of `load` and the panels of
    /// its descendants as `values` holds them. Returns the first block
    /// column whose pivot is not positive.
    pub(super) fn factorize_only(
        &self,
        values: &mut [f64],
        formed: &[bool],
        load: &(dyn Fn(usize, &mut [f64]) + Sync),
    ) -> Result<(), usize> {
        assert_eq!(values.len(), self.len_values());
        let failed = AtomicUsize::new(usize::MAX);
        let shared = Shared {
            values: values.as_mut_ptr(),
            zeroed: false,
        };
        self.factor_in_order(&shared, load, &failed, |s| formed[s]);
        match failed.into_inner() {
            usize::MAX => Ok(()),
            b => Err(b),
        }
    }

    /// Factorises the supernodes `s` with `which(s)` in this thread, in
    /// elimination order (every descendant formed before, or kept), until
    /// a pivot fails.
    fn factor_in_order(
        &self,
        shared: &Shared,
        load: &(dyn Fn(usize, &mut [f64]) + Sync),
        failed: &AtomicUsize,
        which: impl Fn(usize) -> bool,
    ) {
        for s in (0..self.supernodes()).filter(|&s| which(s)) {
            // SAFETY: one thread, each supernode once, in elimination order.
            unsafe { self.factor_node(s, Par::Seq, shared, load, failed) };
            if failed.load(Ordering::Relaxed) != usize::MAX {
                break;
            }
        }
    }

    /// The floating-point operations of forming only the
    /// [`Self::affected`] supernodes' panels.
    #[cfg(any(test, feature = "internals"))]
    pub(super) fn affected_flops(&self, positions: impl IntoIterator<Item = usize>) -> f64 {
        let mark = self.affected(positions);
        (0..self.supernodes())
            .filter(|&s| mark[s])
            .map(|s| self.node_flops[s])
            .sum()
    }

    /// Supernode of block column `b` and where, in that supernode's panel,
    /// block `(row, b)` starts (`row ≥ b`, in the pattern): the offset of its
    /// first entry and the panel's leading dimension.
    #[cfg(test)]
    pub(super) fn block_offset(&self, row: usize, b: usize) -> (usize, usize) {
        // Cannot fail for a block of the pattern.
        let local = self
            .local_row(row, b)
            .unwrap_or_else(|first_below| first_below);
        self.offset(b, local)
    }

    /// Where each diagonal block of the matrix of `later` (its pattern)
    /// starts in the factor's values, and each of its off-diagonal blocks,
    /// column by column (the offset of each block's first entry), with one
    /// walk down each column's rows.
    pub(super) fn destinations(&self, later: &Adjacency) -> (Vec<usize>, Vec<usize>) {
        let n = later.len();
        let mut diag = Vec::with_capacity(n);
        let mut off = Vec::with_capacity(later.starts()[n]);
        for p in 0..n {
            let s = self.supernode_of[p] as usize;
            let g = self.panel(s);
            let below = &self.rows[self.row_ptr[s]..self.row_ptr[s + 1]];
            diag.push(self.offset(p, D * (p - g.b0)).0);
            let mut i = 0;
            for &q in &later[p] {
                let local = if q < g.b0 + g.w {
                    D * (q - g.b0)
                } else {
                    // Both increase, and every row of the pattern is one of
                    // the factor's.
                    while i < below.len() && (below[i] as usize) < q {
                        i += 1;
                    }
                    D * (g.w + i)
                };
                off.push(self.offset(p, local).0);
            }
        }
        (diag, off)
    }

    /// The first scalar row of block row `row` in the panel of block column
    /// `b`; if it is not on the pattern, `Err` with the first row below the
    /// diagonal block.
    fn local_row(&self, row: usize, b: usize) -> Result<usize, usize> {
        let s = self.supernode_of[b] as usize;
        let g = self.panel(s);
        if row < g.b0 + g.w {
            return Ok(D * (row - g.b0));
        }
        let r = &self.rows[self.row_ptr[s]..self.row_ptr[s + 1]];
        r.binary_search(&(row as u32))
            .map(|i| D * (g.w + i))
            .map_err(|_| D * g.w)
    }

    /// Where the entries of block column `b` at scalar row `local` of its
    /// panel start, and the panel's leading dimension.
    fn offset(&self, b: usize, local: usize) -> (usize, usize) {
        let s = self.supernode_of[b] as usize;
        let g = self.panel(s);
        let ld = g.ld::<D>();
        (self.val_ptr[s] + D * (b - g.b0) * ld + local, ld)
    }

    /// Values stored for supernode `s`'s panel.
    pub(super) fn panel_values(&self, s: usize) -> usize {
        self.val_ptr[s + 1] - self.val_ptr[s]
    }

    /// The block columns of supernode `s`, where its panel starts and its
    /// leading dimension.
    pub(super) fn supernode_range(&self, s: usize) -> (std::ops::Range<usize>, usize, usize) {
        (
            self.begin[s]..self.begin[s + 1],
            self.val_ptr[s],
            self.panel(s).ld::<D>(),
        )
    }

    /// Factorises in place: `load(s, panel)` must write the values of the
    /// matrix into supernode `s`'s (zeroed) panel; `zeroed` says `values`
    /// are all zero already (else each panel is zeroed first). Runs in the
    /// calling thread, or with a pool on its threads ([`Parallelism`]); the
    /// values are the same bits for a given number of threads. Returns the
    /// first block column (in elimination order) whose pivot is not
    /// positive.
    pub(super) fn factorize(
        &self,
        values: &mut [f64],
        zeroed: bool,
        load: &(dyn Fn(usize, &mut [f64]) + Sync),
        parallelism: &Parallelism,
    ) -> Result<(), usize> {
        self.factorize_with_grain(values, zeroed, load, parallelism, None)
    }

    /// [`Self::factorize`] with the size of the sequential tasks (default:
    /// 1/16 of each thread's share of the work, at least 2·10⁵ flops).
    fn factorize_with_grain(
        &self,
        values: &mut [f64],
        zeroed: bool,
        load: &(dyn Fn(usize, &mut [f64]) + Sync),
        parallelism: &Parallelism,
        grain: Option<f64>,
    ) -> Result<(), usize> {
        assert_eq!(values.len(), self.len_values());
        let ns = self.supernodes();
        let failed = AtomicUsize::new(usize::MAX);
        let shared = Shared {
            values: values.as_mut_ptr(),
            zeroed,
        };
        let threads = parallelism.threads();
        if threads == 1 || ns < 2 {
            self.factor_in_order(&shared, load, &failed, |_| true);
        } else {
            // Subtrees below this much work run sequentially in one task.
            let grain = grain.unwrap_or_else(|| (self.flops / (16 * threads) as f64).max(2e5));
            let par = Par::rayon(threads);
            let (shared, failed) = (&shared, &failed);
            parallelism.install(|| {
                self.roots.par_iter().for_each(|&r| {
                    self.factor_subtree(r as usize, grain, par, shared, load, failed)
                })
            });
        }
        match failed.into_inner() {
            usize::MAX => Ok(()),
            b => Err(b),
        }
    }

    /// Factorises the subtree of `s`: subtrees of at most `grain` flops in
    /// one task, in post-order; above that, down the heaviest child at each
    /// node (a loop, so that a deep tree does not overflow the stack) while
    /// the other children's subtrees run as parallel tasks, then the path
    /// from the bottom up.
    fn factor_subtree(
        &self,
        s: usize,
        grain: f64,
        par: Par,
        shared: &Shared,
        load: &(dyn Fn(usize, &mut [f64]) + Sync),
        failed: &AtomicUsize,
    ) {
        let mut path = Vec::new();
        rayon::scope(|scope| {
            let mut t = s;
            loop {
                if self.subtree_flops[t] <= grain {
                    self.factor_postorder(t, shared, load, failed);
                    break;
                }
                path.push(t);
                let kids = &self.children[self.child_ptr[t]..self.child_ptr[t + 1]];
                let Some(&heavy) = kids.iter().max_by(|&&a, &&b| {
                    self.subtree_flops[a as usize].total_cmp(&self.subtree_flops[b as usize])
                }) else {
                    break;
                };
                for &c in kids {
                    if c != heavy {
                        scope.spawn(move |_| {
                            self.factor_subtree(c as usize, grain, par, shared, load, failed)
                        });
                    }
                }
                t = heavy as usize;
            }
        });
        for &t in path.iter().rev() {
            // SAFETY: all of `t`'s descendants are done (the scope has
            // ended); nobody else writes `t`.
            unsafe { self.factor_node(t, par, shared, load, failed) };
        }
    }

    /// Factorises the subtree of `t` in this thread, in post-order.
    fn factor_postorder(
        &self,
        t: usize,
        shared: &Shared,
        load: &(dyn Fn(usize, &mut [f64]) + Sync),
        failed: &AtomicUsize,
    ) {
        let mut stack = vec![(t, false)];
        while let Some((u, expanded)) = stack.pop() {
            if expanded {
                // SAFETY: `u`'s descendants are done; nobody else writes `u`.
                unsafe { self.factor_node(u, Par::Seq, shared, load, failed) };
            } else {
                stack.push((u, true));
                for &c in &self.children[self.child_ptr[u]..self.child_ptr[u + 1]] {
                    stack.push((c as usize, false));
                }
            }
        }
    }

    /// Loads, updates and factorises supernode `s`.
    ///
    /// # Safety
    /// Every descendant of `s` is factorised, and no other thread reads or
    /// writes `s`'s panel meanwhile.
    unsafe fn factor_node(
        &self,
        s: usize,
        par: Par,
        shared: &Shared,
        load: &(dyn Fn(usize, &mut [f64]) + Sync),
        failed: &AtomicUsize,
    ) {
        let g = self.panel(s);
        let (wc, ld) = (g.cols::<D>(), g.ld::<D>());
        let len = self.val_ptr[s + 1] - self.val_ptr[s];
        // SAFETY: the panels are disjoint; the caller owns this one.
        let panel =
            unsafe { std::slice::from_raw_parts_mut(shared.values.add(self.val_ptr[s]), len) };
        if !shared.zeroed {
            panel.fill(0.0);
        }
        load(s, panel);
        let pattern = &self.rows[self.row_ptr[s]..self.row_ptr[s + 1]];
        WORKSPACE.with_borrow_mut(|ws| {
            ws.reserve(self.supernode_of.len(), self.max_update);
            for (i, &r) in pattern.iter().enumerate() {
                ws.local[r as usize] = i as u32;
            }
            for u in &self.updates[self.update_ptr[s]..self.update_ptr[s + 1]] {
                // SAFETY: by the caller's contract.
                unsafe { self.apply_update(u, g, panel, ws, par, shared) };
            }
        });
        let result = if wc <= SMALL_WIDTH {
            column_cholesky(panel, wc, ld)
        } else {
            let par = if (wc * wc * ld) as f64 > PARALLEL_PRODUCT {
                par
            } else {
                Par::Seq
            };
            blocked_cholesky(panel, wc, ld, par)
        };
        if let Err(col) = result {
            failed.fetch_min(g.b0 + col / D, Ordering::Relaxed);
        }
    }

    /// Subtracts update `u` (from a descendant `d`) from the panel of the
    /// supernode of geometry `g`: the lower part of `A·Aᵀ`, `A` the rows of
    /// `d`'s panel that fall in or below `g`'s columns, formed a few block
    /// columns at a time so that the scratch stays small, and scattered
    /// block by block. `ws.local` holds the position of each block row of
    /// `g`'s pattern.
    ///
    /// # Safety
    /// `d` is factorised, and nobody writes its panel meanwhile.
    unsafe fn apply_update(
        &self,
        u: &Update,
        g: Panel,
        panel: &mut [f64],
        ws: &mut Workspace,
        par: Par,
        shared: &Shared,
    ) {
        let d = u.from as usize;
        let gd = self.panel(d);
        let (wd, ldd) = (gd.cols::<D>(), gd.ld::<D>());
        let (start, count) = (u.start as usize, u.count as usize);
        let m = D * (gd.p - start);
        let d_rows = &self.rows[self.row_ptr[d] + start..self.row_ptr[d + 1]];
        // SAFETY: `d` is a finished descendant; its panel is only read.
        let a = unsafe {
            MatRef::from_raw_parts(
                shared.values.add(self.val_ptr[d] + D * (gd.w + start)) as *const f64,
                m,
                wd,
                1,
                ldd as isize,
            )
        };
        // Where each block row of the product goes in the panel.
        let local = &mut ws.rows[..gd.p - start];
        for (l, &r) in local.iter_mut().zip(d_rows) {
            let r = r as usize;
            *l = if r < g.b0 + g.w {
                D * (r - g.b0)
            } else {
                D * (g.w + ws.local[r] as usize)
            };
        }
        // Columns j0..j1 of the product are rows j0.. of `a` times rows
        // j0..j1 of `a` transposed, their top block symmetric (its lower
        // half only: the scatter skips what lies above the diagonal).
        let chunk = chunk_blocks::<D>(self.update_scratch, m, count);
        for j0 in (0..count).step_by(chunk) {
            let j1 = (j0 + chunk).min(count);
            let (r0, nc) = (D * j0, D * (j1 - j0));
            let mc = m - r0;
            let temp = &mut ws.temp[..mc * nc];
            update_product(temp, a.subrows(r0, mc), nc, par);
            scatter_lower::<D>(panel, g.ld::<D>(), local, j0..j1, temp, mc);
        }
    }

    /// Solves `L·Lᵀ·x = b` in place (`x` in elimination order); `work` is
    /// scratch, grown on first use.
    pub(super) fn solve(&self, values: &[f64], x: &mut [f64], work: &mut Vec<f64>) {
        if work.len() < self.max_below {
            work.resize(self.max_below, 0.0);
        }
        let gathered = work;
        let ns = self.supernodes();
        // L·y = b.
        for s in 0..ns {
            self.forward_supernode(s, values, x, gathered);
        }
        // Lᵀ·x = y.
        for s in (0..ns).rev() {
            let g = self.panel(s);
            let (wc, ld) = (g.cols::<D>(), g.ld::<D>());
            let panel = &values[self.val_ptr[s]..self.val_ptr[s + 1]];
            let below = D * g.p;
            let y = &mut gathered[..below];
            for (i, &r) in self.rows[self.row_ptr[s]..self.row_ptr[s + 1]]
                .iter()
                .enumerate()
            {
                y[D * i..D * i + D].copy_from_slice(&x[D * r as usize..][..D]);
            }
            let xs = &mut x[D * g.b0..D * g.b0 + wc];
            for j in 0..wc {
                let col = &panel[j * ld + wc..(j + 1) * ld];
                xs[j] -= dot(col, y);
            }
            for j in (0..wc).rev() {
                let col = &panel[j * ld..j * ld + wc];
                let mut v = xs[j];
                for i in j + 1..wc {
                    v -= col[i] * xs[i];
                }
                xs[j] = v / col[j];
            }
        }
    }
}

impl<const D: usize> Symbolic<D> {
    /// [`Symbolic::solve`] for `k` right-hand sides at once: `x` is
    /// `n·D × k`, column-major, in elimination order. Each supernode does
    /// one dense triangular solve and one product for all columns, so the
    /// factor is read twice in all rather than twice per column.
    pub(super) fn solve_many(&self, values: &[f64], x: &mut [f64], k: usize, work: &mut Vec<f64>) {
        let ns = self.supernodes();
        let all: Vec<u32> = (0..ns as u32).collect();
        let identity: Vec<u32> = (0..self.supernode_of.len() as u32).collect();
        self.forward_packed(values, &all, &identity, x, k, work);
        let n = x.len() / k.max(1);
        // Lᵀ·X = Y, from the root down.
        for s in (0..ns).rev() {
            let g = self.panel(s);
            let (wc, ld, below) = (g.cols::<D>(), g.ld::<D>(), D * g.p);
            let l = MatRef::from_column_major_slice(
                &values[self.val_ptr[s]..self.val_ptr[s + 1]],
                ld,
                wc,
            );
            let rows = &self.rows[self.row_ptr[s]..self.row_ptr[s + 1]];
            for c in 0..k {
                for (i, &r) in rows.iter().enumerate() {
                    work[c * below + D * i..][..D]
                        .copy_from_slice(&x[c * n + D * r as usize..][..D]);
                }
            }
            let mut xs = MatMut::from_column_major_slice_mut(x, n, k).subrows_mut(D * g.b0, wc);
            if below > 0 {
                let y = MatRef::from_column_major_slice(&work[..below * k], below, k);
                matmul(
                    xs.rb_mut(),
                    Accum::Add,
                    l.submatrix(wc, 0, below, wc).transpose(),
                    y,
                    -1.0,
                    Par::Seq,
                );
            }
            solve_upper_triangular_in_place(l.submatrix(0, 0, wc, wc).transpose(), xs, Par::Seq);
        }
    }

    /// The supernodes a right-hand side nonzero only in the given block
    /// columns reaches in `L·y = b`: the paths from their supernodes to the
    /// root of the elimination tree, in increasing order (children before
    /// parents), written to `reach`; `mark` (one flag per supernode, all
    /// false) is left all false.
    pub(super) fn reach(&self, blocks: &[usize], mark: &mut Vec<bool>, reach: &mut Vec<u32>) {
        let ns = self.supernodes();
        if mark.len() < ns {
            mark.resize(ns, false);
        }
        reach.clear();
        for &b in blocks {
            let mut s = self.supernode_of[b];
            while s != u32::MAX && !mark[s as usize] {
                mark[s as usize] = true;
                reach.push(s);
                s = self.parent[s as usize];
            }
        }
        reach.sort_unstable();
        for &s in reach.iter() {
            mark[s as usize] = false;
        }
    }

    /// The forward half of [`Symbolic::solve`], `L·y = b` in place, for `k`
    /// right-hand sides at once, on the supernodes of `reach` only
    /// ([`Symbolic::reach`] of the block columns where `b` is nonzero), with
    /// dense kernels per supernode. `x` (`packed × k`, column-major) holds
    /// only the scalar rows of those supernodes, block column `b`'s at
    /// `D·slot[b]`, each supernode's columns consecutive: `b` on entry,
    /// `y` on return (`y` is zero on every other row).
    pub(super) fn forward_packed(
        &self,
        values: &[f64],
        reach: &[u32],
        slot: &[u32],
        x: &mut [f64],
        k: usize,
        work: &mut Vec<f64>,
    ) {
        let packed = x.len() / k.max(1);
        if work.len() < self.max_below * k {
            work.resize(self.max_below * k, 0.0);
        }
        for &s in reach {
            let s = s as usize;
            let g = self.panel(s);
            let (wc, ld, below) = (g.cols::<D>(), g.ld::<D>(), D * g.p);
            let l = MatRef::from_column_major_slice(
                &values[self.val_ptr[s]..self.val_ptr[s + 1]],
                ld,
                wc,
            );
            let at = D * slot[g.b0] as usize;
            {
                let mut xs = MatMut::from_column_major_slice_mut(x, packed, k).subrows_mut(at, wc);
                solve_lower_triangular_in_place(l.submatrix(0, 0, wc, wc), xs.rb_mut(), Par::Seq);
                if below == 0 {
                    continue;
                }
                let y = MatMut::from_column_major_slice_mut(&mut work[..below * k], below, k);
                matmul(
                    y,
                    Accum::Replace,
                    l.submatrix(wc, 0, below, wc),
                    xs.rb(),
                    1.0,
                    Par::Seq,
                );
            }
            for (i, &r) in self.rows[self.row_ptr[s]..self.row_ptr[s + 1]]
                .iter()
                .enumerate()
            {
                let dst = D * slot[r as usize] as usize;
                for c in 0..k {
                    let (to, from) = (
                        &mut x[c * packed + dst..][..D],
                        &work[c * below + D * i..][..D],
                    );
                    for (t, f) in to.iter_mut().zip(from) {
                        *t -= f;
                    }
                }
            }
        }
    }

    /// One supernode's step of the forward solve: its diagonal block, then
    /// the update of the rows below.
    fn forward_supernode(&self, s: usize, values: &[f64], x: &mut [f64], work: &mut [f64]) {
        let g = self.panel(s);
        let (wc, ld) = (g.cols::<D>(), g.ld::<D>());
        let panel = &values[self.val_ptr[s]..self.val_ptr[s + 1]];
        let xs = &mut x[D * g.b0..D * g.b0 + wc];
        for j in 0..wc {
            let col = &panel[j * ld..j * ld + wc];
            xs[j] /= col[j];
            let xj = xs[j];
            for i in j + 1..wc {
                xs[i] -= col[i] * xj;
            }
        }
        let below = D * g.p;
        if below == 0 {
            return;
        }
        let y = &mut work[..below];
        y.fill(0.0);
        for j in 0..wc {
            let xj = xs[j];
            let col = &panel[j * ld + wc..(j + 1) * ld];
            for (yi, &l) in y.iter_mut().zip(col) {
                *yi += l * xj;
            }
        }
        for (i, &r) in self.rows[self.row_ptr[s]..self.row_ptr[s + 1]]
            .iter()
            .enumerate()
        {
            let dst = &mut x[D * r as usize..][..D];
            for a in 0..D {
                dst[a] -= y[D * i + a];
            }
        }
    }
}

impl<const D: usize> Symbolic<D> {
    /// The *selected inverse* of `H = L·Lᵀ` (`values` the factor): the
    /// blocks of `Z = H⁻¹` on the pattern of `L`, in the factor's layout
    /// (diagonal blocks stored whole), read with [`Symbolic::block_offset`].
    /// Takahashi's recurrence, one supernode at a time from the root down:
    /// with `C` its columns and `R` the block rows below, `Y = L_RC·L_CC⁻¹`,
    /// `Z_RC = −Z_RR·Y` and `Z_CC = L_CC⁻ᵀ·L_CC⁻¹ − Yᵀ·Z_RC`, where `Z_RR`
    /// lies on the pattern of the ancestors (the rows below a column form a
    /// clique of `L`). About the cost of a factorisation, and its memory.
    pub(super) fn selected_inverse(&self, values: &[f64]) -> Vec<f64> {
        let mut z = vec![0.0; values.len()];
        let mut zrr = Vec::new();
        for s in (0..self.supernodes()).rev() {
            let g = self.panel(s);
            let (wc, ld, below) = (g.cols::<D>(), g.ld::<D>(), D * g.p);
            let panel = &values[self.val_ptr[s]..self.val_ptr[s + 1]];
            let l = MatRef::from_column_major_slice(panel, ld, wc);
            let l_cc = l.submatrix(0, 0, wc, wc);
            // L_CC⁻¹, from the identity.
            let mut l_inv = faer::Mat::<f64>::identity(wc, wc);
            solve_lower_triangular_in_place(l_cc, l_inv.as_mut(), Par::Seq);
            // Z_CC starts as L_CC⁻ᵀ·L_CC⁻¹.
            let mut z_cc = faer::Mat::<f64>::zeros(wc, wc);
            matmul(
                z_cc.as_mut(),
                Accum::Replace,
                l_inv.transpose(),
                l_inv.as_ref(),
                1.0,
                Par::Seq,
            );
            let mut z_rc = faer::Mat::<f64>::zeros(below, wc);
            if below > 0 {
                // Y = L_RC·L_CC⁻¹.
                let mut y = faer::Mat::<f64>::zeros(below, wc);
                matmul(
                    y.as_mut(),
                    Accum::Replace,
                    l.submatrix(wc, 0, below, wc),
                    l_inv.as_ref(),
                    1.0,
                    Par::Seq,
                );
                let rows = &self.rows[self.row_ptr[s]..self.row_ptr[s + 1]];
                zrr.clear();
                zrr.resize(below * below, 0.0);
                self.gather_inverse(&z, rows, &mut zrr);
                let z_rr = MatRef::from_column_major_slice(&zrr, below, below);
                matmul(
                    z_rc.as_mut(),
                    Accum::Replace,
                    z_rr,
                    y.as_ref(),
                    -1.0,
                    Par::Seq,
                );
                matmul(
                    z_cc.as_mut(),
                    Accum::Add,
                    y.transpose(),
                    z_rc.as_ref(),
                    -1.0,
                    Par::Seq,
                );
            }
            let out = &mut z[self.val_ptr[s]..self.val_ptr[s + 1]];
            for j in 0..wc {
                for i in 0..wc {
                    // Symmetric up to rounding: the mean of both halves.
                    out[j * ld + i] = 0.5 * (z_cc[(i, j)] + z_cc[(j, i)]);
                }
                for i in 0..below {
                    out[j * ld + wc + i] = z_rc[(i, j)];
                }
            }
        }
        z
    }

    /// Block `(row, col)` of `H⁻¹` from its selected inverse `z`
    /// ([`Symbolic::selected_inverse`]), in elimination positions; `None`
    /// when the block is not on the pattern of `L` (nor its transpose).
    pub(super) fn inverse_block(
        &self,
        z: &[f64],
        row: usize,
        col: usize,
    ) -> Option<nalgebra::SMatrix<f64, D, D>> {
        if row < col {
            return self.inverse_block(z, col, row).map(|m| m.transpose());
        }
        let (off, ld) = self.offset(col, self.local_row(row, col).ok()?);
        Some(nalgebra::SMatrix::from_fn(|a, b| z[off + b * ld + a]))
    }

    /// `Z_RR` (column-major, `D·|rows|` square) from the selected inverse of
    /// the ancestors: block `(rows[i], rows[j])`, `i ≥ j`, lies in the panel
    /// of `rows[j]`'s supernode, found by walking its rows alongside.
    fn gather_inverse(&self, z: &[f64], rows: &[u32], out: &mut [f64]) {
        let n = D * rows.len();
        for (j, &r2) in rows.iter().enumerate() {
            let t = self.supernode_of[r2 as usize] as usize;
            let g = self.panel(t);
            let ld = g.ld::<D>();
            let below_t = &self.rows[self.row_ptr[t]..self.row_ptr[t + 1]];
            let column = self.val_ptr[t] + D * (r2 as usize - g.b0) * ld;
            let mut k = 0;
            for (i, &r1) in rows.iter().enumerate().skip(j) {
                let local = if (r1 as usize) < g.b0 + g.w {
                    D * (r1 as usize - g.b0)
                } else {
                    // r1 is in t's rows (the clique); both lists increase.
                    while below_t[k] < r1 {
                        k += 1;
                    }
                    D * (g.w + k)
                };
                for b in 0..D {
                    for a in 0..D {
                        let v = z[column + b * ld + local + a];
                        out[(D * j + b) * n + D * i + a] = v;
                        out[(D * i + a) * n + D * j + b] = v;
                    }
                }
            }
        }
    }
}

/// Subtracts block columns `cols` of an update product (`temp`, `mc` rows
/// from block row `cols.start` down, column-major) from a panel of leading
/// dimension `ld`, the lower part block by block: block row `i` of the
/// product goes to panel row `local[i]`, block column `j` to panel column
/// `local[j]`.
fn scatter_lower<const D: usize>(
    panel: &mut [f64],
    ld: usize,
    local: &[usize],
    cols: std::ops::Range<usize>,
    temp: &[f64],
    mc: usize,
) {
    let j0 = cols.start;
    for jb in cols {
        let col = local[jb];
        for (ib, &row) in local.iter().enumerate().skip(jb) {
            for a in 0..D {
                let dst = &mut panel[(col + a) * ld + row..][..D];
                let src = &temp[(D * (jb - j0) + a) * mc + D * (ib - j0)..][..D];
                for (x, y) in dst.iter_mut().zip(src) {
                    *x -= y;
                }
            }
        }
    }
}

/// `temp = a·a[..nc]ᵀ` (`temp` column-major, `a.nrows() × nc`; of its top
/// `nc × nc` block only the lower triangle is needed): one dense product
/// for a small one ([`ONE_CALL_PRODUCT`]), else the top block's lower
/// triangle and the rows below, on `par`'s threads when large
/// ([`PARALLEL_PRODUCT`]).
fn update_product(temp: &mut [f64], a: MatRef<'_, f64>, nc: usize, par: Par) {
    let (mc, wd) = (a.nrows(), a.ncols());
    let out = MatMut::from_column_major_slice_mut(temp, mc, nc);
    let b = a.subrows(0, nc);
    if mc * nc * wd <= ONE_CALL_PRODUCT {
        matmul(out, Accum::Replace, a, b.transpose(), 1.0, Par::Seq);
        return;
    }
    let par = if (mc * nc * wd) as f64 > PARALLEL_PRODUCT {
        par
    } else {
        Par::Seq
    };
    let (top, bottom) = out.split_at_row_mut(nc);
    triangular::matmul(
        top,
        BlockStructure::TriangularLower,
        Accum::Replace,
        b,
        BlockStructure::Rectangular,
        b.transpose(),
        BlockStructure::Rectangular,
        1.0,
        par,
    );
    matmul(
        bottom,
        Accum::Replace,
        a.subrows(nc, mc - nc),
        b.transpose(),
        1.0,
        par,
    );
}

/// `Σ aᵢbᵢ` with eight partial sums (so that it vectorises).
fn dot(a: &[f64], b: &[f64]) -> f64 {
    let mut acc = [0.0; 8];
    let (ca, cb) = (a.chunks_exact(8), b.chunks_exact(8));
    let tail: f64 = ca
        .remainder()
        .iter()
        .zip(cb.remainder())
        .map(|(x, y)| x * y)
        .sum();
    for (x, y) in ca.zip(cb) {
        for k in 0..8 {
            acc[k] += x[k] * y[k];
        }
    }
    acc.iter().sum::<f64>() + tail
}

/// The factor's values, shared by the threads of one factorisation: each
/// supernode's panel is written by exactly one task; and whether they are
/// all zero already (a fresh allocation), so that no panel needs zeroing.
struct Shared {
    values: *mut f64,
    zeroed: bool,
}
// SAFETY: see `factor_node`: disjoint writes, reads of finished panels only.
unsafe impl Sync for Shared {}
unsafe impl Send for Shared {}

/// Per-thread scratch of the numeric factorisation.
#[derive(Default)]
struct Workspace {
    /// Position of each block row in the current supernode's pattern.
    local: Vec<u32>,
    /// One update product.
    temp: Vec<f64>,
    /// Where each block row of the update goes in the panel.
    rows: Vec<usize>,
}

impl Workspace {
    fn reserve(&mut self, blocks: usize, update: usize) {
        if self.local.len() < blocks {
            self.local.resize(blocks, 0);
            self.rows.resize(blocks, 0);
        }
        if self.temp.len() < update {
            self.temp.resize(update, 0.0);
        }
    }
}

thread_local! {
    static WORKSPACE: RefCell<Workspace> = RefCell::new(Workspace::default());
}

/// Cholesky of the `w×w` top of a column-major panel with leading dimension
/// `ld`, and `L₂₁ = A₂₁·L₁₁⁻ᵀ` for the rows below, one column at a time
/// (left-looking; each column update is an axpy over contiguous rows).
/// Returns the column of a non-positive pivot.
fn column_cholesky(panel: &mut [f64], w: usize, ld: usize) -> Result<(), usize> {
    for j in 0..w {
        let (done, rest) = panel.split_at_mut(j * ld);
        let col = &mut rest[j..ld];
        for k in 0..j {
            let prev = &done[k * ld + j..k * ld + ld];
            let f = prev[0];
            if f != 0.0 {
                for (c, &p) in col.iter_mut().zip(prev) {
                    *c -= f * p;
                }
            }
        }
        let d = col[0];
        // NaN is not positive either.
        if d.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
            return Err(j);
        }
        let inv = 1.0 / d.sqrt();
        for c in col.iter_mut() {
            *c *= inv;
        }
    }
    Ok(())
}

/// The same with faer's blocked dense kernels, for wide diagonal blocks.
fn blocked_cholesky(panel: &mut [f64], w: usize, ld: usize, par: Par) -> Result<(), usize> {
    let rows = ld;
    let mat = MatMut::from_column_major_slice_with_stride_mut(panel, rows, w, ld);
    let (mut top, bottom) = mat.split_at_row_mut(w);
    let mut mem = MemBuffer::new(cholesky_in_place_scratch::<f64>(w, par, Default::default()));
    match cholesky_in_place(
        top.rb_mut(),
        LltRegularization::default(),
        par,
        MemStack::new(&mut mem),
        Default::default(),
    ) {
        Ok(_) => {}
        Err(LltError::NonPositivePivot { index }) => return Err(index),
    }
    solve_lower_triangular_in_place(top.rb(), bottom.transpose_mut(), par);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{DMatrix, DVector};
    use rand::{Rng, SeedableRng, rngs::StdRng};

    /// A random SPD block matrix with a random sparse block pattern, dense.
    fn random_problem(seed: u64, n: usize) -> (Vec<Vec<usize>>, DMatrix<f64>) {
        const D: usize = 2;
        let mut rng = StdRng::seed_from_u64(seed);
        let mut later = vec![Vec::new(); n];
        // A chain broken in two places (a forest), plus random blocks.
        let breaks = [n / 3, n / 3 + 1 + (seed as usize % 5)];
        for p in 0..n {
            for q in p + 1..n {
                if (q == p + 1 && !breaks.contains(&p)) || rng.random_bool(0.1) {
                    later[p].push(q);
                }
            }
        }
        let mut a = DMatrix::<f64>::zeros(D * n, D * n);
        for p in 0..n {
            for &q in &later[p] {
                for x in 0..D {
                    for y in 0..D {
                        let v = rng.random_range(-1.0..1.0);
                        a[(D * q + x, D * p + y)] = v;
                        a[(D * p + y, D * q + x)] = v;
                    }
                }
            }
        }
        // Diagonally dominant, hence positive definite.
        for i in 0..D * n {
            let s: f64 = (0..D * n).map(|j| a[(i, j)].abs()).sum();
            a[(i, i)] = s + 1.0;
        }
        (later, a)
    }

    /// The factor of `a` (pattern `later`) on `sym`.
    fn factor_dense(
        sym: &Symbolic<2>,
        later: &[Vec<usize>],
        a: &DMatrix<f64>,
        threads: usize,
        grain: Option<f64>,
    ) -> Vec<f64> {
        let parallelism = Parallelism::new(threads).unwrap();
        const D: usize = 2;
        let mut values = vec![0.0; sym.len_values()];
        let load = |s: usize, panel: &mut [f64]| {
            let (cols, start, _) = sym.supernode_range(s);
            for b in cols {
                for row in std::iter::once(b).chain(later[b].iter().copied()) {
                    let (off, ld) = sym.block_offset(row, b);
                    for y in 0..D {
                        for x in 0..D {
                            panel[off - start + y * ld + x] = a[(D * row + x, D * b + y)];
                        }
                    }
                }
            }
        };
        sym.factorize_with_grain(&mut values, true, &load, &parallelism, grain)
            .unwrap();
        values
    }

    fn factor_and_solve(
        later: &[Vec<usize>],
        a: &DMatrix<f64>,
        threads: usize,
        grain: Option<f64>,
        scratch: usize,
    ) -> Vec<f64> {
        let sym =
            Symbolic::<2>::with_update_scratch(&Adjacency::from_lists(later), scratch).unwrap();
        let values = factor_dense(&sym, later, a, threads, grain);
        let mut x: Vec<f64> = (0..2 * later.len()).map(|i| i as f64 - 3.0).collect();
        sym.solve(&values, &mut x, &mut Vec::new());
        x
    }

    #[test]
    fn an_adjacency_holds_each_pair_once_below_the_diagonal_in_order() {
        let pairs = [(3, 1), (1, 3), (0, 2), (2, 2), (4, 0), (0, 2), (1, 2)];
        let a = Adjacency::from_pairs(5, pairs.iter().copied());
        let lists: Vec<Vec<usize>> = a.iter().map(<[usize]>::to_vec).collect();
        assert_eq!(lists, [vec![2, 4], vec![2, 3], vec![], vec![], vec![]]);
        assert_eq!(a.starts(), [0, 2, 4, 4, 4, 4]);
        assert_eq!(Adjacency::from_lists(&lists).starts(), a.starts());
        assert_eq!(Adjacency::from_pairs(0, std::iter::empty()).len(), 0);
    }

    #[test]
    fn an_extended_structure_factorises_the_grown_matrix() {
        let mut refused = 0;
        for seed in 0..12 {
            let n = 30 + seed as usize;
            let (later, a) = random_problem(100 + seed, n);
            let n_old = n - 1 - (seed as usize % 9);
            // The matrix before: its first n_old blocks (no entry reaching
            // a new block).
            let old_later: Vec<Vec<usize>> = later[..n_old]
                .iter()
                .map(|l| l.iter().copied().filter(|&q| q < n_old).collect())
                .collect();
            let old = Symbolic::<2>::new(&Adjacency::from_lists(&old_later))
                .unwrap()
                .structure();
            let sym = Symbolic::<2>::extended(&old, &Adjacency::from_lists(&later))
                .expect("no new entry between old blocks");
            let values = factor_dense(&sym, &later, &a, 1, None);
            let mut x: Vec<f64> = (0..2 * n).map(|i| i as f64 - 3.0).collect();
            let b = DVector::from_vec(x.clone());
            sym.solve(&values, &mut x, &mut Vec::new());
            let expected = a.clone().cholesky().unwrap().solve(&b);
            let err = (DVector::from_vec(x) - &expected).norm();
            assert!(err < 1e-10 * expected.norm(), "seed {seed}: {err:e}");
            // An entry between old blocks the old factor lacks: analysed
            // afresh instead.
            let missing = (0..n_old).find_map(|p| {
                let rows = sym.rows_of(p);
                (p + 1..n_old).find(|q| !rows.contains(q)).map(|q| (p, q))
            });
            if let Some((p, q)) = missing {
                let mut more = later.clone();
                more[p].push(q);
                more[p].sort_unstable();
                assert!(
                    Symbolic::<2>::extended(&old, &Adjacency::from_lists(&more)).is_none(),
                    "seed {seed}"
                );
                refused += 1;
            }
        }
        assert!(refused > 0);
    }

    #[test]
    fn a_change_at_some_columns_reaches_only_their_paths_to_the_root() {
        for seed in 0..12 {
            let n = 30 + seed as usize;
            let (later, a) = random_problem(200 + seed, n);
            let sym = Symbolic::<2>::new(&Adjacency::from_lists(&later)).unwrap();
            let before = factor_dense(&sym, &later, &a, 1, None);
            // Every column affected: the whole factorisation's work.
            let all = sym.affected_flops(0..n);
            assert!(
                (all - sym.flops()).abs() <= 1e-12 * sym.flops(),
                "seed {seed}"
            );
            // A change of the diagonal block of one column and of one block
            // that column shares with a later one.
            let c = (seed as usize * 7) % n;
            let mut b = a.clone();
            b[(2 * c, 2 * c)] += 0.5;
            let changed: Vec<usize> = match later[c].first() {
                Some(&q) => {
                    for (x, y) in [(2 * q, 2 * c), (2 * c, 2 * q)] {
                        b[(x, y)] += 0.01;
                    }
                    vec![c, q]
                }
                None => vec![c],
            };
            let after = factor_dense(&sym, &later, &b, 1, None);
            let mark = sym.affected(changed.iter().copied());
            for t in 0..sym.supernodes() {
                // The factor's entries: on and below the diagonal (the
                // diagonal block's upper triangle is scratch).
                let ld = sym.panel(t).ld::<2>();
                let same = (sym.val_ptr[t]..sym.val_ptr[t + 1])
                    .filter(|&i| (i - sym.val_ptr[t]) % ld >= (i - sym.val_ptr[t]) / ld)
                    .all(|i| before[i] == after[i]);
                assert_eq!(same, !mark[t], "seed {seed}, supernode {t}");
            }
            let part = sym.affected_flops(changed.iter().copied());
            assert!(part > 0.0 && part <= all, "seed {seed}");
        }
    }

    #[test]
    fn solves_like_a_dense_cholesky_with_any_number_of_threads() {
        for seed in 0..7 {
            // The last one has wide top supernodes (parallel dense kernels).
            let n = if seed == 6 {
                400
            } else {
                40 + 20 * seed as usize
            };
            let (later, a) = random_problem(seed, n);
            let b =
                nalgebra::DVector::from_iterator(a.nrows(), (0..a.nrows()).map(|i| i as f64 - 3.0));
            let expected = a.clone().cholesky().unwrap().solve(&b);
            let one = factor_and_solve(&later, &a, 1, None, UPDATE_SCRATCH);
            // Every supernode a task of its own.
            let two = factor_and_solve(&later, &a, 2, Some(0.0), UPDATE_SCRATCH);
            let err = (nalgebra::DVector::from_vec(one.clone()) - &expected).norm();
            assert!(err < 1e-10 * expected.norm(), "seed {seed}: {err}");
            assert_eq!(one, two, "seed {seed}: threads change the bits");
            // Update products formed one block column at a time.
            let narrow = factor_and_solve(&later, &a, 1, None, 1);
            let err = (nalgebra::DVector::from_vec(narrow) - &expected).norm();
            assert!(
                err < 1e-10 * expected.norm(),
                "seed {seed}, narrow scratch: {err}"
            );
        }
    }

    #[test]
    fn selected_inverse_matches_the_dense_inverse_on_the_pattern() {
        const D: usize = 2;
        for seed in 0..4 {
            let (later, a) = random_problem(seed, 30 + 25 * seed as usize);
            let sym = Symbolic::<D>::new(&Adjacency::from_lists(&later)).unwrap();
            let values = factor_dense(&sym, &later, &a, 1, None);
            let z = sym.selected_inverse(&values);
            let inverse = a.clone().try_inverse().unwrap();
            // Every block of L's pattern: each supernode's columns, its
            // diagonal blocks and the rows below (fill included).
            let mut checked = 0;
            for s in 0..sym.supernodes() {
                let (cols, _, _) = sym.supernode_range(s);
                let below = &sym.rows[sym.row_ptr[s]..sym.row_ptr[s + 1]];
                for b in cols.clone() {
                    let rows = cols.clone().filter(|&r| r >= b);
                    for row in rows.chain(below.iter().map(|&r| r as usize)) {
                        let (off, ld) = sym.block_offset(row, b);
                        for y in 0..D {
                            for x in 0..D {
                                let got = z[off + y * ld + x];
                                let want = inverse[(D * row + x, D * b + y)];
                                assert!(
                                    (got - want).abs() < 1e-12,
                                    "seed {seed} block ({row}, {b}): {got} vs {want}"
                                );
                            }
                        }
                        checked += 1;
                    }
                }
            }
            assert!(checked > later.len(), "off-diagonal blocks checked");
        }
    }

    #[test]
    fn solving_many_columns_at_once_equals_solving_each() {
        for seed in [1, 6] {
            let n = if seed == 6 { 400 } else { 60 };
            let (later, a) = random_problem(seed, n);
            let sym = Symbolic::<2>::new(&Adjacency::from_lists(&later)).unwrap();
            let values = factor_dense(&sym, &later, &a, 1, None);
            let rows = 2 * n;
            let k = 3;
            let b: Vec<f64> = (0..rows * k)
                .map(|i| ((i * 7919) % 23) as f64 - 11.0)
                .collect();
            let mut many = b.clone();
            sym.solve_many(&values, &mut many, k, &mut Vec::new());
            for c in 0..k {
                let mut one = b[c * rows..(c + 1) * rows].to_vec();
                sym.solve(&values, &mut one, &mut Vec::new());
                for (x, y) in one.iter().zip(&many[c * rows..(c + 1) * rows]) {
                    assert!((x - y).abs() <= 1e-10 * (1.0 + x.abs()), "{x} vs {y}");
                }
            }
        }
    }

    #[test]
    fn empty_and_single_block_systems() {
        let empty = Symbolic::<3>::new(&Adjacency::from_lists(&[])).unwrap();
        assert_eq!((empty.supernodes(), empty.len_values()), (0, 0));
        let seq = Parallelism::sequential();
        empty.factorize(&mut [], true, &|_, _| {}, &seq).unwrap();
        let one = Symbolic::<1>::new(&Adjacency::from_lists(&[Vec::new()])).unwrap();
        let mut values = vec![0.0; one.len_values()];
        one.factorize(
            &mut values,
            false,
            &|_, panel: &mut [f64]| panel[0] = 4.0,
            &seq,
        )
        .unwrap();
        let mut x = vec![8.0];
        one.solve(&values, &mut x, &mut Vec::new());
        assert_eq!(x, vec![2.0]);
    }

    #[test]
    fn column_and_blocked_kernels_agree() {
        let mut rng = StdRng::seed_from_u64(9);
        let (w, ld) = (60, 75);
        let m = DMatrix::<f64>::from_fn(ld, w, |_, _| rng.random_range(-1.0..1.0));
        let mut a = &m * m.transpose();
        for i in 0..ld {
            a[(i, i)] += ld as f64;
        }
        let mut p1: Vec<f64> = a.columns(0, w).iter().copied().collect();
        let mut p2 = p1.clone();
        column_cholesky(&mut p1, w, ld).unwrap();
        blocked_cholesky(&mut p2, w, ld, Par::Seq).unwrap();
        for j in 0..w {
            for i in j..ld {
                assert!((p1[j * ld + i] - p2[j * ld + i]).abs() < 1e-10);
            }
        }
        // Neither kernel reads above the diagonal.
        let mut q1 = p1.clone();
        let mut q2 = p2.clone();
        for (q, src) in [(&mut q1, &a), (&mut q2, &a)] {
            for j in 0..w {
                for i in 0..ld {
                    q[j * ld + i] = if i < j { f64::NAN } else { src[(i, j)] };
                }
            }
        }
        column_cholesky(&mut q1, w, ld).unwrap();
        blocked_cholesky(&mut q2, w, ld, Par::Seq).unwrap();
        for j in 0..w {
            for i in j..ld {
                assert_eq!(q1[j * ld + i], p1[j * ld + i]);
                assert!((q2[j * ld + i] - p2[j * ld + i]).abs() < 1e-12);
            }
        }
        // A non-positive pivot names its column.
        let mut bad = vec![1.0, 2.0, 2.0, 1.0];
        assert_eq!(column_cholesky(&mut bad, 2, 2), Err(1));
    }
}
