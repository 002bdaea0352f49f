//! `A·H⁻¹·Aᵀ` for the Jacobian rows of a group of edges at once: the
//! covariance, under the current factorisation, that a group of loop
//! candidates' errors inherit from the map.

use super::supernodal::OffPattern;
use super::{BlockSystem, SelectedInverse};
use faer::linalg::matmul::matmul;
use faer::{Accum, MatRef, Par};
use nalgebra::{DMatrix, SMatrix};

/// The Jacobian of one edge's error: its blocks (variable block index, or
/// `None` for a vertex held fixed) and their `D×D` derivatives.
pub type EdgeJacobian<const D: usize> = [(Option<usize>, SMatrix<f64, D, D>); 2];

/// Scratch of the sparse solve for a group's Gram matrix: its packed
/// right-hand sides, the supernodes they reach, a flag per supernode, each
/// block column's block row in the packed solution, and the solve's work
/// space. One per thread that propagates groups at the same time
/// ([`BlockSystem::propagate_group_cheaper`]).
#[derive(Clone, Debug, Default)]
pub struct GroupScratch {
    rhs: Vec<f64>,
    reach: Vec<u32>,
    mark: Vec<bool>,
    slot: Vec<u32>,
    /// Block rows of the packed solution (the reach's block columns).
    packed: usize,
    work: Vec<f64>,
}

/// What one `D×D` product of the recurrence for blocks of `H⁻¹` off the
/// factor's pattern costs, in multiply–adds of the sparse solve's dense
/// kernels: with its hash lookups and unvectorised small products, one
/// product took 35–80 ns for `D = 3` and 110–170 ns for `D = 6`, against
/// 0.05–0.14 ns per multiply–add of the solve — ratios of about 700 and
/// 2800 (both ways timed on each cluster of the aliasing benchmark's
/// intel, manhattan, city10000, sphere2500 and parking-garage files, one
/// thread), which `400 + 11·D³` fits.
const fn recurrence_product_cost(d: usize) -> usize {
    400 + 11 * d * d * d
}

impl<const D: usize> BlockSystem<D> {
    /// [`BlockSystem::propagate_group_solved`] by whichever of two ways costs
    /// less: the recurrence from the selected inverse `z` while its blocks
    /// off the factor's pattern cost less than the sparse solve would
    /// ([`BlockSystem::propagate_group_selected`]), else the solve. The
    /// recurrence is first counted without its arithmetic
    /// ([`Self::recurrence_fits`]) and run only if it fits the budget, so a
    /// group costs the cheaper way plus the count, which is at most the
    /// solve's cost too. Reads the system only: threads may share it, each
    /// with its own `scratch`.
    ///
    /// # Panics
    /// If no factorisation succeeded before, or a block index is out of
    /// range.
    pub fn propagate_group_cheaper(
        &self,
        z: &SelectedInverse,
        edges: &[EdgeJacobian<D>],
        scratch: &mut GroupScratch,
    ) -> DMatrix<f64> {
        let Some(solve_cost) = self.reach_group(edges, scratch) else {
            return DMatrix::zeros(D * edges.len(), D * edges.len());
        };
        let budget = solve_cost / recurrence_product_cost(D);
        // Counted first: a recurrence that runs out of budget would cost
        // the solve's time for nothing.
        if !self.recurrence_fits(edges, budget) {
            return self.solve_group(edges, scratch);
        }
        (self.propagate_group_selected(z, edges, budget))
            .unwrap_or_else(|| self.solve_group(edges, scratch))
    }

    /// The Gram matrix `A·H⁻¹·Aᵀ` of the stacked Jacobians `A` of `edges`
    /// (`D·m × D·m` for `m` edges, edge `e`'s rows at `D·e..D·e + D`) by
    /// the sparse solve alone, without a selected inverse: one sparse
    /// forward solve `Y = L⁻¹·Pᵀ·Aᵀ` with all `D·m` right-hand sides at
    /// once, over the supernodes the group reaches (their paths to the
    /// root), then `A·H⁻¹·Aᵀ = YᵀY`. Reads the system only: threads may
    /// share it, each with its own `scratch`.
    ///
    /// # Panics
    /// If no factorisation succeeded before, or a block index is out of
    /// range.
    pub fn propagate_group_solved(
        &self,
        edges: &[EdgeJacobian<D>],
        scratch: &mut GroupScratch,
    ) -> DMatrix<f64> {
        match self.reach_group(edges, scratch) {
            Some(_) => self.solve_group(edges, scratch),
            None => DMatrix::zeros(D * edges.len(), D * edges.len()),
        }
    }

    /// The multiply–adds of [`Self::propagate_group_solved`] for `edges`
    /// (0 when they touch no variable block).
    pub fn group_solve_cost(&self, edges: &[EdgeJacobian<D>], scratch: &mut GroupScratch) -> usize {
        self.reach_group(edges, scratch).unwrap_or(0)
    }

    /// The supernodes the sparse solve for `edges` reaches, into
    /// `scratch` with each block column's packed slot; the solve's cost in
    /// multiply–adds (the panels it reads times its right-hand sides, then
    /// the Gram). `None` when the edges touch no variable block.
    fn reach_group(&self, edges: &[EdgeJacobian<D>], scratch: &mut GroupScratch) -> Option<usize> {
        let k = D * edges.len();
        let positions: Vec<usize> = edges
            .iter()
            .flat_map(|e| e.iter().filter_map(|(b, _)| b.map(|b| self.position[b])))
            .collect();
        if positions.is_empty() || self.n_blocks == 0 {
            return None;
        }
        assert!(
            !self.factor.is_empty(),
            "BlockSystem::propagate_group_* needs a factorisation first"
        );
        (self.symbolic).reach(&positions, &mut scratch.mark, &mut scratch.reach);
        // Y holds only the rows of the supernodes the solve reaches, packed
        // in their order; `slot` maps a block column to its packed block.
        if scratch.slot.len() < self.n_blocks {
            scratch.slot.resize(self.n_blocks, 0);
        }
        let (mut packed, mut values) = (0, 0);
        for &s in &scratch.reach {
            for b in self.symbolic.supernode_range(s as usize).0 {
                scratch.slot[b] = packed;
                packed += 1;
            }
            values += self.symbolic.panel_values(s as usize);
        }
        scratch.packed = packed as usize;
        Some(k * values + k * k * D * scratch.packed)
    }

    /// The sparse solve of [`BlockSystem::propagate_group_solved`] over the reach
    /// [`Self::reach_group`] left in `scratch`.
    fn solve_group(&self, edges: &[EdgeJacobian<D>], scratch: &mut GroupScratch) -> DMatrix<f64> {
        let k = D * edges.len();
        let slot = &scratch.slot;
        let packed = D * scratch.packed;
        let y = &mut scratch.rhs;
        y.clear();
        y.resize(packed * k, 0.0);
        // Column D·e + a of Aᵀ: row a of each of edge e's blocks.
        for (e, edge) in edges.iter().enumerate() {
            for (b, block) in edge {
                let Some(b) = b else { continue };
                let row = D * slot[self.position[*b]] as usize;
                for a in 0..D {
                    let column = &mut y[(D * e + a) * packed + row..][..D];
                    for (r, v) in column.iter_mut().enumerate() {
                        *v += block[(a, r)];
                    }
                }
            }
        }
        (self.symbolic).forward_packed(&self.factor, &scratch.reach, slot, y, k, &mut scratch.work);
        let y = MatRef::from_column_major_slice(y, packed, k);
        let mut gram = faer::Mat::<f64>::zeros(k, k);
        matmul(
            gram.as_mut(),
            Accum::Replace,
            y.transpose(),
            y,
            1.0,
            Par::Seq,
        );
        DMatrix::from_fn(k, k, |r, c| 0.5 * (gram[(r, c)] + gram[(c, r)]))
    }
}

impl<const D: usize> BlockSystem<D> {
    /// [`BlockSystem::propagate_group_solved`] from the selected inverse `z` of the
    /// current factorisation, without a solve. The blocks of `H⁻¹` between
    /// the edges' blocks that are off the factor's pattern follow from the
    /// selected inverse by its own recurrence, in at most `budget` `D×D`
    /// products (0: none off the pattern); `None` when that is not enough.
    pub fn propagate_group_selected(
        &self,
        z: &SelectedInverse,
        edges: &[EdgeJacobian<D>],
        budget: usize,
    ) -> Option<DMatrix<f64>> {
        let m = edges.len();
        let mut inverse = OffPattern::new(&self.symbolic, &self.factor, &z.values, budget);
        let mut inverse_block = |p: usize, q: usize| inverse.block(p, q);
        let mut gram = DMatrix::zeros(D * m, D * m);
        for (e, ea) in edges.iter().enumerate() {
            for (f, fa) in edges.iter().enumerate().take(e + 1) {
                let mut block = SMatrix::<f64, D, D>::zeros();
                for (p, a) in ea
                    .iter()
                    .filter_map(|(b, a)| Some((self.position[(*b)?], a)))
                {
                    for (q, b) in fa
                        .iter()
                        .filter_map(|(b, a)| Some((self.position[(*b)?], a)))
                    {
                        block += a * inverse_block(p, q)? * b.transpose();
                    }
                }
                gram.view_mut((D * e, D * f), (D, D)).copy_from(&block);
                gram.view_mut((D * f, D * e), (D, D))
                    .copy_from(&block.transpose());
            }
        }
        Some(gram)
    }

    /// Whether [`Self::propagate_group_selected`] of `edges` finishes within
    /// `budget` products: its recurrence run without the arithmetic
    /// ([`OffPattern::counting`]), asking for the same blocks in the same
    /// order.
    fn recurrence_fits(&self, edges: &[EdgeJacobian<D>], budget: usize) -> bool {
        let mut count = OffPattern::counting(&self.symbolic, budget);
        let positions = |e: &EdgeJacobian<D>| [e[0].0, e[1].0].map(|b| b.map(|b| self.position[b]));
        for (e, ea) in edges.iter().enumerate() {
            let ps = positions(ea);
            for fa in &edges[..=e] {
                let qs = positions(fa);
                for p in ps.into_iter().flatten() {
                    for q in qs.into_iter().flatten() {
                        if count.block(p, q).is_none() {
                            return false;
                        }
                    }
                }
            }
        }
        true
    }

    /// The largest trace of any variable block's `(H⁻¹)ᵢᵢ` in the selected
    /// inverse `z`: at least the largest variance of the map's marginals in
    /// any direction of one block.
    pub fn largest_marginal(&self, z: &SelectedInverse) -> f64 {
        (0..self.n_blocks)
            .filter_map(|b| {
                let p = self.position[b];
                let h = self.symbolic.inverse_block(&z.values, p, p)?;
                Some(h.trace())
            })
            .fold(0.0, f64::max)
    }

    /// An upper bound (in the positive semi-definite order) of one edge's
    /// `A·H⁻¹·Aᵀ` from the diagonal blocks of the selected inverse `z`:
    /// `2·(Aᵢ·(H⁻¹)ᵢᵢ·Aᵢᵀ + Aⱼ·(H⁻¹)ⱼⱼ·Aⱼᵀ)`, since
    /// `[[P, Q], [Qᵀ, R]] ≼ 2·diag(P, R)` for any positive semi-definite
    /// matrix.
    pub fn propagate_bound(
        &self,
        z: &SelectedInverse,
        edge: &EdgeJacobian<D>,
    ) -> SMatrix<f64, D, D> {
        let mut out = SMatrix::<f64, D, D>::zeros();
        for (b, a) in edge {
            if let Some(b) = b {
                let p = self.position[*b];
                if let Some(h) = self.symbolic.inverse_block(&z.values, p, p) {
                    out += a * h * a.transpose();
                }
            }
        }
        out * 2.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Matrix1, Vector1};

    /// A chain x₀ – x₁ – x₂ of 1-D blocks with unit information, x₀ also
    /// tied to the origin: H = [[2, −1, 0], [−1, 2, −1], [0, −1, 1]].
    fn chain() -> BlockSystem<1> {
        let pairs = [(Some(0), None), (Some(0), Some(1)), (Some(1), Some(2))];
        let mut sys =
            BlockSystem::<1>::new(3, &pairs, crate::linear::Parallelism::sequential()).unwrap();
        sys.clear();
        let one = Matrix1::new(1.0);
        let z = Vector1::zeros();
        sys.add_edge(0, &one, &Matrix1::zeros(), &Matrix1::zeros(), &z, &z);
        sys.add_edge(1, &one, &Matrix1::new(-1.0), &one, &z, &z);
        sys.add_edge(2, &one, &Matrix1::new(-1.0), &one, &z, &z);
        sys.factorize(0.0).unwrap();
        sys
    }

    #[test]
    fn group_gram_is_the_dense_a_hinv_at() {
        let sys = chain();
        let h = nalgebra::Matrix3::new(2.0, -1.0, 0.0, -1.0, 2.0, -1.0, 0.0, -1.0, 1.0);
        let hinv = h.try_inverse().unwrap();
        let one = Matrix1::new(1.0);
        let minus = Matrix1::new(-1.0);
        // Rows: x₂ − x₀, x₁ (x₀'s block fixed), x₂ − x₁.
        let edges = [
            [(Some(0), minus), (Some(2), one)],
            [(None, one), (Some(1), one)],
            [(Some(1), minus), (Some(2), one)],
        ];
        let a = nalgebra::Matrix3::new(-1.0, 0.0, 1.0, 0.0, 1.0, 0.0, 0.0, -1.0, 1.0);
        let expected = a * hinv * a.transpose();
        let mut scratch = GroupScratch::default();
        let gram = sys.propagate_group_solved(&edges, &mut scratch);
        for r in 0..3 {
            for c in 0..3 {
                assert!((gram[(r, c)] - expected[(r, c)]).abs() < 1e-12, "{r},{c}");
            }
        }
        // One edge: the same as propagate.
        let single = sys.propagate_group_solved(&edges[..1], &mut scratch);
        let p = sys.propagate(Some(0), &minus, Some(2), &one);
        assert!((single[(0, 0)] - p[(0, 0)]).abs() < 1e-12);
        // The scratch is left zeroed: a second call gives the same.
        assert_eq!(sys.propagate_group_solved(&edges, &mut scratch), gram);
        // From the selected inverse: the same where the blocks are on the
        // pattern (a chain: x₀–x₂ is not).
        let z = sys.selected_inverse();
        assert!(sys.propagate_group_selected(&z, &edges, 0).is_none());
        let near = sys.propagate_group_selected(&z, &edges[1..], 0).unwrap();
        for r in 0..2 {
            for c in 0..2 {
                assert!((near[(r, c)] - expected[(r + 1, c + 1)]).abs() < 1e-12);
            }
        }
        // Off the pattern by the recurrence, with a budget: the whole Gram.
        let all = sys.propagate_group_selected(&z, &edges, 10).unwrap();
        for r in 0..3 {
            for c in 0..3 {
                assert!((all[(r, c)] - expected[(r, c)]).abs() < 1e-12, "{r},{c}");
            }
        }
        // The bound is above the Gram of each edge.
        for (k, e) in edges.iter().enumerate() {
            assert!(sys.propagate_bound(&z, e)[(0, 0)] >= expected[(k, k)] - 1e-12);
        }
    }

    /// Groups of 1, 3 and 8 unit edges between blocks of a ring of `n`,
    /// spread over it from each start: `(start, size, edges)`.
    fn ring_groups(n: usize) -> Vec<(usize, usize, Vec<EdgeJacobian<2>>)> {
        let one = nalgebra::Matrix2::identity();
        let edge = |i: usize, j: usize| [(Some(i), -one), (Some(j), one)];
        let group = |start: usize, size: usize| {
            (0..size)
                .map(|k| edge((start + 5 * k) % n, (start + 11 * k + 1) % n))
                .collect()
        };
        (0..n)
            .flat_map(|start| [1, 3, 8].map(|size| (start, size, group(start, size))))
            .collect()
    }

    /// A ring of `n` 2-D blocks with chords every few blocks and a prior on
    /// block 0, pseudo-random symmetric positive definite blocks.
    fn ring(n: usize) -> (BlockSystem<2>, nalgebra::DMatrix<f64>) {
        let mut pairs: Vec<(Option<usize>, Option<usize>)> = vec![(Some(0), None)];
        for i in 0..n {
            pairs.push((Some(i), Some((i + 1) % n)));
            if i % 5 == 0 {
                pairs.push((Some(i), Some((i + 7) % n)));
            }
        }
        let mut sys =
            BlockSystem::<2>::new(n, &pairs, crate::linear::Parallelism::sequential()).unwrap();
        sys.clear();
        let mut dense = nalgebra::DMatrix::<f64>::zeros(2 * n, 2 * n);
        let mut seed = 7u64;
        let mut next = || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        let z = nalgebra::Vector2::zeros();
        for (k, &(i, j)) in pairs.iter().enumerate() {
            // An edge's block [[A, −B], [−Bᵀ, C]] = Jᵀ·J of a random J.
            let j1 = nalgebra::Matrix2::from_fn(|_, _| next()) + nalgebra::Matrix2::identity();
            let j2 = nalgebra::Matrix2::from_fn(|_, _| next()) - nalgebra::Matrix2::identity();
            let (h_ii, h_ij, h_jj) = (
                j1.transpose() * j1,
                j1.transpose() * j2,
                j2.transpose() * j2,
            );
            sys.add_edge(k, &h_ii, &h_ij, &h_jj, &z, &z);
            let i = i.unwrap();
            let mut add = |r: usize, c: usize, m: &nalgebra::Matrix2<f64>| {
                let mut v = dense.view_mut((2 * r, 2 * c), (2, 2));
                v += m;
            };
            add(i, i, &h_ii);
            if let Some(j) = j {
                add(i, j, &h_ij);
                add(j, i, &h_ij.transpose());
                add(j, j, &h_jj);
            }
        }
        sys.factorize(0.0).unwrap();
        (sys, dense.try_inverse().unwrap())
    }

    #[test]
    fn the_cheaper_way_and_the_solve_alone_are_the_dense_gram() {
        let n = 40;
        let (sys, hinv) = ring(n);
        let z = sys.selected_inverse();
        // One scratch for every group: what one group leaves in it does not
        // leak into the next.
        let mut scratch = GroupScratch::default();
        let (mut by_recurrence, mut by_solve) = (0, 0);
        for (start, size, edges) in ring_groups(n) {
            let gram = sys.propagate_group_cheaper(&z, &edges, &mut scratch);
            // The solve alone, without the selected inverse, agrees.
            let solved = sys.propagate_group_solved(&edges, &mut scratch);
            assert!((&solved - &gram).abs().max() < 1e-9);
            assert!(sys.group_solve_cost(&edges, &mut scratch) > 0);
            for (e, ea) in edges.iter().enumerate() {
                for (f, fa) in edges.iter().enumerate() {
                    let mut want = nalgebra::Matrix2::zeros();
                    for (p, a) in ea {
                        for (q, b) in fa {
                            let h = hinv.fixed_view::<2, 2>(2 * p.unwrap(), 2 * q.unwrap());
                            want += a * h * b.transpose();
                        }
                    }
                    let got = gram.fixed_view::<2, 2>(2 * e, 2 * f);
                    assert!((got - want).abs().max() < 1e-9, "{start} {size} {e} {f}");
                }
            }
            let budget =
                sys.reach_group(&edges, &mut scratch).unwrap() / recurrence_product_cost(2);
            match sys.propagate_group_selected(&z, &edges, budget) {
                Some(_) => by_recurrence += 1,
                None => by_solve += 1,
            }
        }
        // Both ways were taken.
        assert!(
            by_recurrence > 0 && by_solve > 0,
            "{by_recurrence} {by_solve}"
        );
    }

    #[test]
    fn blocks_off_the_pattern_follow_from_the_selected_inverse() {
        let n = 40;
        let (sys, hinv) = ring(n);
        let z = sys.selected_inverse();
        let one = nalgebra::Matrix2::identity();
        let mut off_pattern = 0;
        for i in 0..n {
            for j in (i + 1)..n {
                // The edge x_j − x_i: A = [−I, I].
                let edge = [(Some(i), -one), (Some(j), one)];
                let m = sys
                    .propagate_group_selected(&z, &[edge], usize::MAX)
                    .unwrap();
                let expected = hinv.view((2 * i, 2 * i), (2, 2))
                    - hinv.view((2 * i, 2 * j), (2, 2))
                    - hinv.view((2 * j, 2 * i), (2, 2))
                    + hinv.view((2 * j, 2 * j), (2, 2));
                assert!(
                    (&m - &expected).abs().max() < 1e-9,
                    "{i} {j}: {m} {expected}"
                );
                off_pattern += usize::from(sys.propagate_group_selected(&z, &[edge], 0).is_none());
            }
        }
        // Most pairs of a ring are off its factor's pattern.
        assert!(off_pattern > n * (n - 1) / 4, "{off_pattern}");
        // A budget too small for a pair off the pattern gives up rather
        // than guess.
        let far = (0..n)
            .flat_map(|i| ((i + 1)..n).map(move |j| [(Some(i), -one), (Some(j), one)]))
            .find(|e| sys.propagate_group_selected(&z, &[*e], 0).is_none())
            .unwrap();
        assert!(sys.propagate_group_selected(&z, &[far], 1).is_none());
        assert!(
            sys.propagate_group_selected(&z, &[far], usize::MAX)
                .is_some()
        );
    }

    #[test]
    fn the_count_runs_out_of_budget_where_the_recurrence_does() {
        let n = 40;
        let (sys, _) = ring(n);
        let z = sys.selected_inverse();
        let (mut fits, mut not) = (0, 0);
        for (start, size, edges) in ring_groups(n) {
            // Every budget from none to past what the group needs.
            let needs = (0..)
                .find(|&b| sys.propagate_group_selected(&z, &edges, b).is_some())
                .unwrap();
            for budget in [0, needs / 2, needs.saturating_sub(1), needs, needs + 1] {
                let counted = sys.recurrence_fits(&edges, budget);
                let real = sys.propagate_group_selected(&z, &edges, budget).is_some();
                assert_eq!(counted, real, "{start} {size} {budget} of {needs}");
                (fits, not) = (fits + usize::from(real), not + usize::from(!real));
            }
        }
        assert!(fits > 0 && not > 0, "{fits} {not}");
    }
}
