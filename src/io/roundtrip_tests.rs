//! Writer/reader round trip on random graphs (proptest): any finite numbers,
//! ids up to `u64::MAX`, inlier counts up to `u64::MAX`, `FIX` lines.
//! SE(2) graphs come back bit for bit; SE(3) quaternions are normalised on
//! read, so they come back within rounding once and exactly from then on.

use super::g2o::{G2oFile, G2oPose, ReadOptions, read_from, write_graph};
use crate::geometry::{Pose, Se2, Se3};
use crate::graph::{AnyGraph, Graph, LoopCandidate};
use nalgebra::{SMatrix, UnitQuaternion, Vector3};
use proptest::prelude::*;
use std::path::Path;

/// Finite numbers of every magnitude, signed zeros and subnormals included.
fn number() -> impl Strategy<Value = f64> {
    prop_oneof![
        -1e3..1e3f64,
        any::<f64>().prop_filter("finite", |v| v.is_finite()),
        Just(-0.0),
        Just(f64::MIN_POSITIVE / 4.0),
    ]
}

/// Distinct vertex ids, `u64::MAX` and 0 likely.
fn ids(n: usize) -> impl Strategy<Value = Vec<u64>> {
    prop::collection::hash_set(prop_oneof![Just(u64::MAX), Just(0u64), any::<u64>()], n)
        .prop_map(|s| s.into_iter().collect())
}

/// A symmetric positive-definite matrix `LLᵀ + I·s` with entries of any
/// sign.
fn information<const D: usize>() -> impl Strategy<Value = SMatrix<f64, D, D>> {
    (prop::collection::vec(-10.0..10.0f64, D * D), 0.01..1e6f64).prop_map(|(v, s)| {
        let mut l = SMatrix::<f64, D, D>::from_column_slice(&v);
        for r in 0..D {
            for c in r + 1..D {
                l[(r, c)] = 0.0;
            }
        }
        l * l.transpose() + SMatrix::<f64, D, D>::identity() * s
    })
}

/// `(from index, to index, count)` per edge, with `from != to`.
fn edge_ends(n: usize) -> impl Strategy<Value = Vec<(usize, usize, Option<u64>)>> {
    prop::collection::vec(
        (
            0..n,
            1..n,
            prop_oneof![
                Just(None),
                any::<u64>().prop_map(Some),
                Just(Some(u64::MAX))
            ],
        )
            .prop_map(move |(a, d, c)| (a, (a + d) % n, c)),
        0..12,
    )
}

fn build<P: G2oPose<D>, const D: usize>(
    ids: &[u64],
    poses: Vec<P>,
    edges: &[(usize, usize, Option<u64>)],
    measurements: Vec<P>,
    infos: Vec<SMatrix<f64, D, D>>,
    fixed: &[bool],
) -> Graph<P, D> {
    let mut g = Graph::new();
    for (id, p) in ids.iter().zip(poses) {
        g.add_vertex(*id, p).expect("distinct ids");
    }
    for (((a, b, count), z), info) in edges.iter().zip(measurements).zip(infos) {
        let candidate = count.map(|n| LoopCandidate { inliers: Some(n) });
        g.add_edge(ids[*a], ids[*b], z, info, candidate)
            .expect("known ids");
    }
    for (id, f) in ids.iter().zip(fixed) {
        if *f {
            g.fix(*id).expect("known id");
        }
    }
    g
}

fn text_of<P: G2oPose<D>, const D: usize>(g: &Graph<P, D>) -> Vec<u8> {
    let mut out = Vec::new();
    write_graph(g, &[], &mut out).expect("write to memory");
    out
}

fn read_text(text: &[u8]) -> G2oFile {
    read_from(text, Path::new("round-trip.g2o"), ReadOptions::default())
        .unwrap_or_else(|e| panic!("{e}\n{}", String::from_utf8_lossy(text)))
}

fn file_text(f: &G2oFile) -> Vec<u8> {
    match &f.graph {
        AnyGraph::Planar(g) => text_of(g),
        AnyGraph::Spatial(g) => text_of(g),
    }
}

/// Same ids, edges (ends, measurements, information, counts) and gauge.
fn assert_same_structure<P: Pose<D>, const D: usize>(a: &Graph<P, D>, b: &Graph<P, D>) {
    assert_eq!(a.ids(), b.ids());
    assert_eq!(a.gauge(), b.gauge());
    assert_eq!(a.edges.len(), b.edges.len());
    for (x, y) in a.edges.iter().zip(&b.edges) {
        assert_eq!((x.from, x.to, x.candidate), (y.from, y.to, y.candidate));
        assert_eq!(x.information, y.information);
    }
}

fn se2_pose() -> impl Strategy<Value = Se2> {
    (number(), number(), number()).prop_map(|(x, y, t)| Se2::new(x, y, t))
}

fn se3_pose() -> impl Strategy<Value = Se3> {
    (
        (number(), number(), number()),
        (-4.0..4.0f64, -4.0..4.0f64, -4.0..4.0f64),
    )
        .prop_map(|((x, y, z), (a, b, c))| {
            Se3::new(
                UnitQuaternion::from_scaled_axis(Vector3::new(a, b, c)),
                Vector3::new(x, y, z),
            )
        })
}

fn se2_graph() -> impl Strategy<Value = Graph<Se2, 3>> {
    (2usize..10).prop_flat_map(|n| {
        (
            ids(n),
            edge_ends(n),
            prop::collection::vec(any::<bool>(), n),
        )
            .prop_flat_map(move |(ids, edges, fixed)| {
                let m = edges.len();
                (
                    prop::collection::vec(se2_pose(), n),
                    prop::collection::vec(se2_pose(), m),
                    prop::collection::vec(information::<3>(), m),
                )
                    .prop_map(move |(poses, zs, infos)| {
                        build(&ids, poses, &edges, zs, infos, &fixed)
                    })
            })
    })
}

fn se3_graph() -> impl Strategy<Value = Graph<Se3, 6>> {
    (2usize..8).prop_flat_map(|n| {
        (
            ids(n),
            edge_ends(n),
            prop::collection::vec(any::<bool>(), n),
        )
            .prop_flat_map(move |(ids, edges, fixed)| {
                let m = edges.len();
                (
                    prop::collection::vec(se3_pose(), n),
                    prop::collection::vec(se3_pose(), m),
                    prop::collection::vec(information::<6>(), m),
                )
                    .prop_map(move |(poses, zs, infos)| {
                        build(&ids, poses, &edges, zs, infos, &fixed)
                    })
            })
    })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(128))]

    #[test]
    fn se2_graphs_round_trip_bit_for_bit(g in se2_graph()) {
        let text = text_of(&g);
        let f = read_text(&text);
        let AnyGraph::Planar(back) = &f.graph else {
            panic!("dimension changed");
        };
        assert_same_structure(&g, back);
        prop_assert_eq!(&g.poses, &back.poses);
        for (x, y) in g.edges.iter().zip(&back.edges) {
            prop_assert_eq!(x.measurement, y.measurement);
        }
        // Writing what was read gives the same text.
        prop_assert_eq!(file_text(&f), text);
    }

    #[test]
    fn se3_graphs_round_trip_exactly_after_one_normalisation(g in se3_graph()) {
        let text = text_of(&g);
        let f = read_text(&text);
        let AnyGraph::Spatial(once) = &f.graph else {
            panic!("dimension changed");
        };
        assert_same_structure(&g, once);
        for (a, b) in g.poses.iter().zip(&once.poses) {
            prop_assert_eq!(a.translation, b.translation);
            prop_assert!(a.rotation.angle_to(&b.rotation) < 1e-15);
        }
        let text2 = file_text(&f);
        let f2 = read_text(&text2);
        let AnyGraph::Spatial(twice) = &f2.graph else {
            panic!("dimension changed");
        };
        assert_same_structure(once, twice);
        prop_assert_eq!(&once.poses, &twice.poses);
        prop_assert_eq!(file_text(&f2), text2);
    }
}
