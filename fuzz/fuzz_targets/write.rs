//! The two g2o writers on whatever the reader accepts:
//!
//! * the model writer (`write_graph`): its text reads back to the same
//!   graph (ids, poses, edges, gauge; SE(3) rotations within rounding, since
//!   quaternions are normalised on read);
//! * the line-preserving rewrite (`G2oFile::rewrite_from`): with the poses
//!   as read it gives the input back byte for byte, plus one vertex line per
//!   vertex that no line defined; with every pose moved, every line that is
//!   not a vertex line is still the input's, in order, and the text reads
//!   back to the moved poses; a text other than the one read is refused.
#![no_main]

use libfuzzer_sys::fuzz_target;
use pgo::geometry::{Pose, Se2, Se3};
use pgo::internals::{
    AnyGraph, G2oFile, G2oPose, Graph, ReadOptions, RewriteError, read_from, write_graph,
};
use std::collections::HashMap;
use std::path::Path;

fn read(text: &[u8], options: ReadOptions) -> Option<G2oFile> {
    read_from(text, Path::new("fuzz.g2o"), options).ok()
}

fn read_back(text: &[u8], options: ReadOptions) -> G2oFile {
    read_from(text, Path::new("written.g2o"), options).unwrap_or_else(|e| {
        panic!(
            "written text does not read back: {e}\n{}",
            String::from_utf8_lossy(text)
        )
    })
}

/// Whether two poses are the same, up to the normalisation of a quaternion.
trait Close {
    fn close(&self, other: &Self) -> bool;
}

impl Close for Se2 {
    fn close(&self, other: &Self) -> bool {
        self == other
    }
}

impl Close for Se3 {
    fn close(&self, other: &Self) -> bool {
        self.translation == other.translation && self.rotation.angle_to(&other.rotation) < 1e-12
    }
}

/// Poses by id.
fn poses<P: Pose<D>, const D: usize>(g: &Graph<P, D>) -> HashMap<u64, P> {
    (0..g.num_vertices())
        .map(|k| (g.id(k), g.poses[k]))
        .collect()
}

/// `a` and `b` hold the same graph: ids, poses, edges (by id), gauge.
fn assert_same<P: Pose<D> + Close, const D: usize>(a: &Graph<P, D>, b: &Graph<P, D>) {
    let (pa, pb) = (poses(a), poses(b));
    assert_eq!(pa.len(), pb.len());
    for (id, p) in &pa {
        assert!(p.close(&pb[id]), "vertex {id}: {p:?} vs {:?}", pb[id]);
    }
    assert_eq!(a.edges.len(), b.edges.len());
    for (x, y) in a.edges.iter().zip(&b.edges) {
        assert_eq!(
            (a.id(x.from), a.id(x.to), x.candidate),
            (b.id(y.from), b.id(y.to), y.candidate)
        );
        assert_eq!(x.information, y.information);
        assert!(x.measurement.close(&y.measurement));
    }
}

/// The ids of the gauge vertices, sorted.
fn gauge<P: Pose<D>, const D: usize>(g: &Graph<P, D>) -> Vec<u64> {
    let mut ids: Vec<u64> = g.gauge().iter().map(|&k| g.id(k)).collect();
    ids.sort_unstable();
    ids
}

/// The lines of `text` (line ends kept) that are not vertex lines of `P`.
fn other_lines<'a, P: G2oPose<D>, const D: usize>(text: &'a [u8]) -> Vec<&'a [u8]> {
    let mut lines: Vec<&[u8]> = text.split_inclusive(|&b| b == b'\n').collect();
    if let Some(first) = lines.first_mut() {
        *first = first.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(first);
    }
    lines
        .into_iter()
        .filter(|l| {
            let tag = std::str::from_utf8(l)
                .ok()
                .and_then(|t| t.split_whitespace().next());
            tag != Some(P::VERTEX_TAG)
        })
        .collect()
}

fn check<P: G2oPose<D> + Close, const D: usize>(
    data: &[u8],
    file: &G2oFile,
    g: &Graph<P, D>,
    graph_of: fn(&G2oFile) -> Option<&Graph<P, D>>,
    moved: fn(&P) -> P,
) {
    let options = ReadOptions::default();
    // The model writer.
    let mut model = Vec::new();
    write_graph(g, &mut model).expect("write to memory");
    let back = read_back(&model, options);
    let model_graph = graph_of(&back).expect("the dimension changed");
    assert_same(g, model_graph);
    // The vertices are written in their order, and FIX names the fixed
    // ones: the gauge is the same.
    assert_eq!(gauge(g), gauge(model_graph));
    // The rewrite with the poses as read: the input, plus the added lines.
    let mut same = Vec::new();
    file.rewrite_from(data, &mut same).expect("rewrite");
    let added: Vec<String> = file
        .missing
        .iter()
        .map(|&k| format!("{} {} ", P::VERTEX_TAG, g.id(k)))
        .collect();
    let kept: Vec<u8> = same
        .split_inclusive(|&b| b == b'\n')
        .filter(|l| !added.iter().any(|a| l.starts_with(a.as_bytes())))
        .flatten()
        .copied()
        .collect();
    let newline_added = !file.missing.is_empty() && !data.ends_with(b"\n");
    assert!(
        kept == data
            || (newline_added
                && (kept == [data, b"\n"].concat() || kept == [data, b"\r\n"].concat())),
        "rewrite changed the text:\n{}\n---\n{}",
        String::from_utf8_lossy(data),
        String::from_utf8_lossy(&same)
    );
    assert_eq!(
        same.split_inclusive(|&b| b == b'\n').count(),
        kept.split_inclusive(|&b| b == b'\n').count() + file.missing.len()
    );
    // Every pose moved: other lines kept, the new poses read back.
    let mut moved_graph = g.clone();
    for p in &mut moved_graph.poses {
        *p = moved(p);
    }
    let moved_file = with_graph(file.clone(), moved_graph.clone());
    let mut out = Vec::new();
    moved_file
        .rewrite_from(data, &mut out)
        .expect("rewrite moved");
    assert_eq!(other_lines::<P, D>(&out), other_lines::<P, D>(data));
    let back = read_back(&out, options);
    let back_graph = graph_of(&back).expect("the dimension changed");
    // The rewrite keeps the vertex lines in place: the gauge is the same.
    assert_eq!(gauge(g), gauge(back_graph));
    let (want, got) = (poses(&moved_graph), poses(back_graph));
    assert_eq!(want.len(), got.len());
    for (id, p) in &want {
        assert!(
            p.close(&got[id]),
            "vertex {id}: {p:?} written, {:?} read",
            got[id]
        );
    }
    // Another text is refused.
    let other = [data, b"\n# not what was read\n"].concat();
    match file.rewrite_from(other.as_slice(), &mut Vec::new()) {
        Err(RewriteError::Changed { .. }) => {}
        r => panic!("a different text was rewritten: {r:?}"),
    }
}

/// `file` with its graph replaced.
fn with_graph<P: G2oPose<D>, const D: usize>(mut file: G2oFile, g: Graph<P, D>) -> G2oFile {
    file.graph = P::wrap(g);
    file
}

fn planar(f: &G2oFile) -> Option<&Graph<Se2, 3>> {
    match &f.graph {
        AnyGraph::Planar(g) => Some(g),
        AnyGraph::Spatial(_) => None,
    }
}

fn spatial(f: &G2oFile) -> Option<&Graph<Se3, 6>> {
    match &f.graph {
        AnyGraph::Spatial(g) => Some(g),
        AnyGraph::Planar(_) => None,
    }
}

fuzz_target!(|data: &[u8]| {
    let Some(file) = read(data, ReadOptions::default()) else {
        return;
    };
    match &file.graph {
        AnyGraph::Planar(g) => check(data, &file, g, planar, |p| {
            Se2::new(p.x + 1.0, p.y - 0.5, p.theta * 0.5)
        }),
        AnyGraph::Spatial(g) => check(data, &file, g, spatial, |p| {
            Se3::new(p.rotation, p.translation.add_scalar(1.0))
        }),
    }
});
