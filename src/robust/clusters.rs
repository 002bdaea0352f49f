//! Clusters of loop candidates that may support each other: candidates
//! whose two ends are both a few poses apart, as the loops of one
//! place-recognition event are (consecutive keyframes matched to
//! consecutive keyframes). Perceptual aliasing comes in such runs — every
//! loop of a repeated corridor shifted by the same few poses — and a run of
//! wrong loops holds the map it bent: judged one at a time, each member
//! finds the map agreeing with it. So a candidate is judged against the map
//! made without its whole cluster.

use crate::geometry::Pose;
use crate::graph::{Graph, UnionFind};

/// Candidates whose ends are at most this many poses apart, at both ends,
/// are in one cluster: consecutive keyframes are 1 apart, and 2 lets a run
/// skip one.
pub const NEIGHBOURHOOD: u64 = 2;

/// Most candidates in one cluster: a longer run is cut into pieces of this
/// size, in order along the trajectory (the cost of judging a cluster grows
/// with the cube of its size; a run of wrong loops longer than this is
/// judged piece by piece, each against a map the rest of the run still
/// bends).
pub const MAX_CLUSTER: usize = 32;

/// The clusters of the candidate edges `edges` of `graph` (indices into
/// `edges`, as [`clusters`] gives them for their end ids).
pub fn of_edges<P: Pose<D>, const D: usize>(
    graph: &Graph<P, D>,
    edges: &[usize],
) -> Vec<Vec<usize>> {
    let ends: Vec<(u64, u64)> = (edges.iter())
        .map(|&k| (graph.id(graph.edges[k].from), graph.id(graph.edges[k].to)))
        .collect();
    clusters(&ends)
}

/// The clusters of candidates with end ids `ends` (in any order): lists of
/// indices into `ends`, each in increasing order, every index in exactly
/// one list.
pub fn clusters(ends: &[(u64, u64)]) -> Vec<Vec<usize>> {
    let n = ends.len();
    let key = |k: usize| {
        let (a, b) = ends[k];
        (a.min(b), a.max(b))
    };
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by_key(|&k| (key(k), k));
    let mut parts = UnionFind::new(n);
    for (x, &k) in order.iter().enumerate() {
        let (a, b) = key(k);
        for &l in &order[x + 1..] {
            let (a2, b2) = key(l);
            if a2 > a + NEIGHBOURHOOD {
                break;
            }
            if b2.abs_diff(b) <= NEIGHBOURHOOD {
                parts.union(k, l);
            }
        }
    }
    // The members of each root, in the order along the trajectory, cut
    // into pieces of at most MAX_CLUSTER.
    let mut members: Vec<Vec<usize>> = vec![Vec::new(); n];
    for &k in &order {
        members[parts.find(k)].push(k);
    }
    let mut out: Vec<Vec<usize>> = members
        .into_iter()
        .filter(|m| !m.is_empty())
        .flat_map(|m| {
            m.chunks(MAX_CLUSTER)
                .map(|c| {
                    let mut c = c.to_vec();
                    c.sort_unstable();
                    c
                })
                .collect::<Vec<_>>()
        })
        .collect();
    out.sort_unstable_by_key(|c| c[0]);
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn runs_of_neighbouring_candidates_form_one_cluster() {
        // A run of five (i+q, j+q), a lone loop, a run reversed in
        // direction, and one whose second end is too far from the run's.
        let ends = [
            (100, 500),
            (101, 501),
            (102, 502),
            (104, 504),
            (103, 503),
            (300, 900),
            (702, 201),
            (703, 202),
            (105, 520),
        ];
        let c = clusters(&ends);
        assert_eq!(c, vec![vec![0, 1, 2, 3, 4], vec![5], vec![6, 7], vec![8]]);
    }

    #[test]
    fn long_runs_are_cut_into_pieces() {
        let ends: Vec<(u64, u64)> = (0..70).map(|q| (q, 1000 + q)).collect();
        let c = clusters(&ends);
        assert_eq!(c.len(), 3);
        assert_eq!(c[0].len(), MAX_CLUSTER);
        assert_eq!(c.iter().map(Vec::len).sum::<usize>(), 70);
    }
}
