//! Blocks of `Z = H⁻¹` off the factor's pattern, from the selected inverse
//! and the factor, by the recurrence the selected inverse itself follows.
//!
//! `Z·L = L⁻ᵀ` is upper triangular, so for block column `b` of `L`, whose
//! rows below the diagonal are `s(b)`, and any block row `r` eliminated
//! after `b`:
//!
//! `Z_rb = −(Σ_{k ∈ s(b)} Z_rk·L_kb)·L_bb⁻¹`.
//!
//! For `r ∈ s(b)` that block is on the pattern (the selected inverse has
//! it). For `r ∉ s(b)` each `Z_rk` is again on the pattern or, off it, the
//! same recurrence on the column eliminated first of `r` and `k`, which
//! comes after `b`: the dependencies end at the root. For two blocks whose
//! paths in the elimination tree meet soon (the ends of neighbouring loop
//! candidates) that is a handful of `D×D` products, where a sparse solve
//! ([`super::super::BlockSystem::propagate_group_solved`]) reads every panel on
//! the paths to the root. For two far apart it can be more; a budget of
//! block products bounds it, and the caller falls back to the solve.

use super::Symbolic;
use nalgebra::SMatrix;
use rustc_hash::FxHashMap;

/// Blocks of `Z = H⁻¹` of one factorisation, read on the factor's pattern
/// from its selected inverse and computed off it by the recurrence of the
/// module doc: the factor and the selected inverse, the blocks computed so
/// far, and the budget of `D×D` products (and blocks queued) left.
pub(in crate::linear) struct OffPattern<'a, const D: usize> {
    symbolic: &'a Symbolic<D>,
    /// The factor's values.
    l: &'a [f64],
    /// The selected inverse's values.
    z: &'a [f64],
    /// Blocks computed off the pattern, by `(row, column)` in elimination
    /// positions (row after column).
    memo: FxHashMap<(u32, u32), SMatrix<f64, D, D>>,
    budget: usize,
    /// Only count: which blocks the recurrence needs and what they cost,
    /// every block's value left zero ([`Self::counting`]).
    dry: bool,
}

impl<'a, const D: usize> OffPattern<'a, D> {
    /// The blocks of `Z` of the factor `l` of `symbolic` and its selected
    /// inverse `z`, at most `budget` products off the pattern.
    pub(in crate::linear) fn new(
        symbolic: &'a Symbolic<D>,
        l: &'a [f64],
        z: &'a [f64],
        budget: usize,
    ) -> Self {
        Self {
            symbolic,
            l,
            z,
            memo: FxHashMap::default(),
            budget,
            dry: false,
        }
    }

    /// [`Self::new`] that only counts: its blocks are zero, but it needs
    /// and pays for the same blocks in the same order, so it runs out of
    /// budget exactly where the real recurrence would. Its lookups cost
    /// a fraction of the `D×D` products.
    pub(in crate::linear) fn counting(symbolic: &'a Symbolic<D>, budget: usize) -> Self {
        Self {
            dry: true,
            ..Self::new(symbolic, &[], &[], budget)
        }
    }

    /// Block `(row, col)` of `Z` (elimination positions): on the pattern,
    /// read; off it, by the recurrence of the module doc, each block
    /// computed kept. `None` once the budget runs out.
    pub(in crate::linear) fn block(
        &mut self,
        row: usize,
        col: usize,
    ) -> Option<SMatrix<f64, D, D>> {
        if let Some(block) = self.known_block(row, col) {
            return Some(block);
        }
        let (hi, lo) = (row.max(col), row.min(col));
        let mut stack = vec![(hi, lo)];
        while let Some(&(r, b)) = stack.last() {
            if self.memo.contains_key(&(r as u32, b as u32)) {
                stack.pop();
                continue;
            }
            if let Some(block) = self.recurrence(r, b, &mut stack)? {
                self.memo.insert((r as u32, b as u32), block);
                stack.pop();
            }
        }
        self.known_block(row, col)
    }

    /// `Z_rb = −(Σ_{k ∈ s(b)} Z_rk·L_kb)·L_bb⁻¹` if every `Z_rk` is known;
    /// otherwise `Some(None)`, with the unknown ones pushed on `stack`. The
    /// budget pays one product per unknown block pushed, then one per
    /// block of the sum; `None` when it runs out.
    fn recurrence(
        &mut self,
        r: usize,
        b: usize,
        stack: &mut Vec<(usize, usize)>,
    ) -> Option<Option<SMatrix<f64, D, D>>> {
        let (symbolic, l, z) = (self.symbolic, self.l, self.z);
        let mut sum = SMatrix::<f64, D, D>::zeros();
        let mut ready = true;
        let mut terms = 0;
        // The rows after `r` of column `r`, walked alongside `s(b)` (both
        // increase): where `Z_kr` lies for the `k > r` on the pattern.
        let mut after_r = symbolic.column_structure(r).peekable();
        for (k, local) in symbolic.column_structure(b) {
            let z_rk = if k > r {
                while after_r.next_if(|&(row, _)| row < k).is_some() {}
                match after_r.peek() {
                    Some(&(row, _)) if row == k && self.dry => Some(SMatrix::zeros()),
                    Some(&(row, at)) if row == k => {
                        let (off, ld) = symbolic.offset(r, at);
                        Some(SMatrix::<f64, D, D>::from_fn(|a, c| z[off + c * ld + a]).transpose())
                    }
                    _ => self.memo.get(&(k as u32, r as u32)).map(|m| m.transpose()),
                }
            } else {
                self.known_block(r, k)
            };
            match z_rk {
                Some(z_rk) if ready => {
                    if !self.dry {
                        let (off, ld) = symbolic.offset(b, local);
                        sum += z_rk * SMatrix::<f64, D, D>::from_fn(|a, c| l[off + c * ld + a]);
                    }
                    terms += 1;
                }
                Some(_) => {}
                None => {
                    self.budget = self.budget.checked_sub(1)?;
                    stack.push((r.max(k), r.min(k)));
                    ready = false;
                }
            }
        }
        if !ready {
            return Some(None);
        }
        self.budget = self.budget.checked_sub(terms)?;
        if self.dry {
            return Some(Some(sum));
        }
        let l_bb = symbolic.factor_block(l, b, b)?.lower_triangle();
        // X·L_bb = −sum, as L_bbᵀ·Xᵀ = −sumᵀ.
        let xt = l_bb
            .transpose()
            .solve_upper_triangular(&(-sum.transpose()))?;
        Some(Some(xt.transpose()))
    }

    /// Block `(r, c)` of `Z` if it is on the pattern or computed.
    fn known_block(&self, r: usize, c: usize) -> Option<SMatrix<f64, D, D>> {
        let on_pattern = if self.dry {
            (self.symbolic.local_row(r.max(c), r.min(c)).is_ok()).then(SMatrix::zeros)
        } else {
            self.symbolic.inverse_block(self.z, r, c)
        };
        if on_pattern.is_some() {
            return on_pattern;
        }
        if r > c {
            self.memo.get(&(r as u32, c as u32)).copied()
        } else {
            self.memo.get(&(c as u32, r as u32)).map(|m| m.transpose())
        }
    }
}

impl<const D: usize> Symbolic<D> {
    /// Block `(row, b)` of the factor (`row` on column `b`'s pattern, at or
    /// below its diagonal).
    fn factor_block(&self, l: &[f64], row: usize, b: usize) -> Option<SMatrix<f64, D, D>> {
        let (off, ld) = self.offset(b, self.local_row(row, b).ok()?);
        Some(SMatrix::from_fn(|a, c| l[off + c * ld + a]))
    }

    /// The block rows of column `b` below its diagonal block, `s(b)` — the
    /// later columns of its supernode, then the rows below the supernode —
    /// each with its scalar row in the supernode's panel.
    fn column_structure(&self, b: usize) -> impl Iterator<Item = (usize, usize)> + '_ {
        let s = self.supernode_of[b] as usize;
        let (b0, end) = (self.begin[s], self.begin[s + 1]);
        let below = &self.rows[self.row_ptr[s]..self.row_ptr[s + 1]];
        (b + 1..end)
            .map(move |k| (k, D * (k - b0)))
            .chain((below.iter().enumerate()).map(move |(i, &r)| (r as usize, D * (end - b0 + i))))
    }
}
