//! What the system of a graph grown by blocks and edges appended reuses of
//! the last one's (an incremental update's): the factor's structure, the
//! off-diagonal blocks of `H` by column and each edge's slots. Only the new
//! edges are then placed, and only what they add to the factor analysed;
//! the system built is the same as one built afresh in the same order.

use super::supernodal::{Adjacency, Structure};
use super::{EdgeSlot, NONE, edge_slot};

/// The pattern of a [`super::BlockSystem`], for a system of the same graph
/// grown ([`super::BlockSystem::with_positions`]).
#[derive(Clone, Debug, Default)]
pub struct Layout {
    /// The factor's supernodes and their rows.
    pub(super) structure: Structure,
    /// The later neighbours of each elimination position (the off-diagonal
    /// blocks of `H`, column by column).
    pub(super) later: Adjacency,
    /// Each edge's blocks.
    pub(super) slots: Vec<EdgeSlot>,
}

/// A [`Layout`] extended to a grown graph's edges.
pub(super) struct Extension {
    /// The later neighbours of each position, the new ones appended.
    pub later: Adjacency,
    /// Every edge's blocks, the old edges' where they moved to.
    pub slots: Vec<EdgeSlot>,
    /// The entries of `later` the old one lacks, `(column, row)`,
    /// increasing; each row a new position.
    pub entries: Vec<(usize, usize)>,
}

impl Layout {
    /// Block columns of the factor.
    pub fn len(&self) -> usize {
        self.structure.len()
    }

    /// This layout extended to `edges` (each as the variable blocks it
    /// joins) between blocks at `position`, if its edges are the first
    /// ones, joining the same positions, and every new block of `H` has a
    /// new position among its two (the old positions come first): else
    /// `None`, and the pattern is built afresh.
    pub(super) fn extend(
        &self,
        position: &[usize],
        edges: &[(Option<usize>, Option<usize>)],
    ) -> Option<Extension> {
        let (n_old, e_old) = (self.later.len(), self.slots.len());
        if n_old == 0 || e_old > edges.len() || n_old > position.len() {
            return None;
        }
        let pos = |b: Option<usize>| b.map_or(NONE, |b| position[b] as u32);
        let same = (edges[..e_old].iter().zip(&self.slots))
            .all(|(&(i, j), slot)| pos(i) == slot.i && pos(j) == slot.j);
        if !same {
            return None;
        }
        let mut entries = Vec::new();
        for &(i, j) in &edges[e_old..] {
            let (p, q) = (pos(i), pos(j));
            if p == NONE || q == NONE || p == q {
                continue;
            }
            let (c, r) = (p.min(q) as usize, p.max(q) as usize);
            if r >= n_old {
                entries.push((c, r));
            } else if self.later[c].binary_search(&r).is_err() {
                return None;
            }
        }
        entries.sort_unstable();
        entries.dedup();
        let later = self.later.appended(position.len(), &entries);
        let (old_starts, starts) = (self.later.starts(), later.starts());
        let moved = |slot: &EdgeSlot| {
            let mut slot = *slot;
            if slot.off != NONE {
                let c = slot.i.min(slot.j) as usize;
                slot.off = (slot.off as usize - old_starts[c] + starts[c]) as u32;
            }
            slot
        };
        let mut slots = Vec::with_capacity(edges.len());
        slots.extend(self.slots.iter().map(moved));
        slots.extend((edges[e_old..].iter()).map(|&(i, j)| edge_slot(i, j, position, &later)));
        Some(Extension {
            later,
            slots,
            entries,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::super::{BlockSystem, KeptFactor, Parallelism, fill_reducing_order};
    use super::*;
    use rand::{Rng, SeedableRng, rngs::StdRng};

    type Edges = Vec<(Option<usize>, Option<usize>)>;

    /// A chain of `n` blocks with random loops among them (and an edge to
    /// a fixed vertex), then `more` blocks appended with their chain and
    /// loops to any earlier block; and the old edges alone.
    fn grown_graph(seed: u64, n: usize, more: usize) -> (Edges, Edges) {
        let mut rng = StdRng::seed_from_u64(seed);
        let mut edges: Edges = (1..n).map(|k| (Some(k - 1), Some(k))).collect();
        edges.push((Some(n / 2), None));
        for _ in 0..n / 3 {
            let (i, j) = (rng.random_range(0..n), rng.random_range(0..n));
            edges.push((Some(i), Some(j)));
        }
        let old = edges.clone();
        for k in n..n + more {
            edges.push((Some(k - 1), Some(k)));
            for _ in 0..rng.random_range(0..3) {
                let j = rng.random_range(0..k);
                edges.push(if rng.random() {
                    (Some(k), Some(j))
                } else {
                    (Some(j), Some(k))
                });
            }
        }
        (old, edges)
    }

    /// The grown system's pattern, as the reference build makes it
    /// (every edge placed, the old factor structure extended).
    fn reference(
        n: usize,
        edges: &[(Option<usize>, Option<usize>)],
        position: &[usize],
        old: &Layout,
    ) -> BlockSystem<2> {
        let structure_only = Layout {
            structure: old.structure.clone(),
            ..Layout::default()
        };
        let seq = Parallelism::sequential();
        BlockSystem::with_positions(n, edges, seq, position.to_vec(), Some(&structure_only))
            .unwrap()
    }

    fn assert_same(a: &BlockSystem<2>, b: &BlockSystem<2>, what: &str) {
        assert_eq!(a.position, b.position, "{what}");
        assert_eq!(a.edges, b.edges, "{what}");
        assert_eq!(a.later, b.later, "{what}");
        assert_eq!(a.off_row, b.off_row, "{what}");
        assert_eq!(a.diag_dest, b.diag_dest, "{what}");
        assert_eq!(a.off_dest, b.off_dest, "{what}");
        assert_eq!(a.symbolic.structure(), b.symbolic.structure(), "{what}");
    }

    #[test]
    fn a_grown_layout_builds_the_system_every_edge_placed_would() {
        let seq = Parallelism::sequential;
        let mut refused = 0;
        for seed in 0..20 {
            let (n, more) = (20 + seed as usize, 1 + seed as usize % 7);
            let (old_edges, mut edges) = grown_graph(seed, n, more);
            let old_position = fill_reducing_order(n, &old_edges).unwrap();
            let old =
                BlockSystem::<2>::with_positions(n, &old_edges, seq(), old_position.clone(), None)
                    .unwrap()
                    .layout();
            let mut position = old_position;
            position.extend(n..n + more);
            // An edge between old blocks already joined adds nothing.
            if seed % 3 == 0 {
                edges.push(old_edges[0]);
            }
            assert!(old.extend(&position, &edges).is_some(), "seed {seed}");
            let grown =
                BlockSystem::with_positions(n + more, &edges, seq(), position.clone(), Some(&old))
                    .unwrap();
            assert_same(
                &grown,
                &reference(n + more, &edges, &position, &old),
                &format!("seed {seed}"),
            );
            // A new block of `H` between old blocks, or old edges changed:
            // built afresh, the same way.
            let absent = (0..n)
                .flat_map(|i| (0..n).map(move |j| (i, j)))
                .find(|&(i, j)| {
                    let (p, q) = (position[i].min(position[j]), position[i].max(position[j]));
                    p != q && old.later[p].binary_search(&q).is_err()
                });
            if let Some((i, j)) = absent {
                edges.push((Some(i), Some(j)));
                assert!(old.extend(&position, &edges).is_none(), "seed {seed}");
                refused += 1;
                let built = BlockSystem::with_positions(
                    n + more,
                    &edges,
                    seq(),
                    position.clone(),
                    Some(&old),
                )
                .unwrap();
                assert_same(
                    &built,
                    &reference(n + more, &edges, &position, &old),
                    &format!("seed {seed}, old pair"),
                );
            }
            edges[0] = (Some(1), None);
            assert!(old.extend(&position, &edges).is_none(), "seed {seed}");
        }
        assert!(refused > 0);
    }

    /// Adds to `system` a positive-definite contribution of every edge,
    /// each drawn from its own seed (the same edge the same numbers), edge
    /// `moved` (a pose moved there) stiffer.
    fn assemble(system: &mut BlockSystem<2>, edges: &Edges, moved: usize) {
        use nalgebra::{Matrix2, Vector2};
        system.clear();
        for (k, _) in edges.iter().enumerate() {
            let mut rng = StdRng::seed_from_u64(k as u64);
            let a = Matrix2::from_fn(|_, _| rng.random_range(-1.0..1.0));
            let stiff = if k == moved { 2.0 } else { 1.0 };
            let h = a * a.transpose() + Matrix2::identity() * stiff;
            let b = Vector2::from_fn(|_, _| rng.random_range(-1.0..1.0));
            system.add_edge(k, &h, &(-h * 0.5), &h, &b, &(-b));
        }
    }

    #[test]
    fn a_kept_factor_formed_again_where_h_changed_is_the_whole_factorisation() {
        let seq = Parallelism::sequential;
        let mut kept_some = 0;
        for seed in 0..20 {
            let (n, more) = (20 + seed as usize, 1 + seed as usize % 7);
            let (old_edges, edges) = grown_graph(seed, n, more);
            let old_position = fill_reducing_order(n, &old_edges).unwrap();
            let mut old =
                BlockSystem::<2>::with_positions(n, &old_edges, seq(), old_position.clone(), None)
                    .unwrap();
            assemble(&mut old, &old_edges, usize::MAX);
            old.factorize(0.0).unwrap();
            let kept = old.kept_factor().unwrap();
            let mut position = old_position;
            position.extend(n..n + more);
            let layout = old.layout();
            let grown = || {
                BlockSystem::<2>::with_positions(
                    n + more,
                    &edges,
                    seq(),
                    position.clone(),
                    Some(&layout),
                )
                .unwrap()
            };
            // The new blocks, the old ones the new edges reach and the ends
            // of an old edge linearised again changed.
            let moved = seed as usize % old_edges.len();
            let mut changed: Vec<usize> = (n..n + more).collect();
            for &(i, j) in edges[old_edges.len()..].iter().chain([&edges[moved]]) {
                changed.extend(i.into_iter().chain(j));
            }
            let mut whole = grown();
            assemble(&mut whole, &edges, moved);
            whole.factorize(0.0).unwrap();
            let mut partial = grown();
            partial.reuse_factor_allocation(old.take_factor_allocation());
            assemble(&mut partial, &edges, moved);
            let formed = partial.refactorize(&kept, &changed).unwrap().unwrap();
            assert_eq!(partial.factor, whole.factor, "seed {seed}: the same bits");
            if formed < partial.symbolic.supernodes() {
                kept_some += 1;
            }
            // Another damping or structure: nothing kept, nothing done.
            let damped = KeptFactor {
                lambda: 1e-3,
                ..kept.clone()
            };
            assert_eq!(grown().refactorize(&damped, &changed).unwrap(), None);
        }
        assert!(kept_some > 0, "some panels were kept");
    }
}
