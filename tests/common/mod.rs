//! The fixtures of the library's integration tests, one module for every
//! test file (`mod common;`) and for the command line's tests: the bundled samples, a temporary directory
//! per test, the public benchmark datasets, and the labels of the
//! samples' loop candidates.

// Each test file is its own crate and uses only some of the fixtures.
#![allow(dead_code)]

use std::path::{Path, PathBuf};

/// The repository's root: the library's crate is at its top, and the
/// command line's tests (`cli/`) include this module too.
pub fn repository() -> PathBuf {
    let crate_dir = Path::new(env!("CARGO_MANIFEST_DIR"));
    (crate_dir.ancestors())
        .find(|d| d.join("g2o_samples").is_dir())
        .unwrap_or(crate_dir)
        .to_owned()
}

/// A bundled sample file (`g2o_samples/`).
pub fn sample(name: &str) -> PathBuf {
    repository().join("g2o_samples").join(name)
}

/// A fresh, empty temporary directory named after the test file's crate
/// and `name` (tempfile makes each one unique, so tests that run in
/// parallel never share one). It is removed, with what the test wrote in
/// it, when the returned guard is dropped — unless the test is failing
/// (panicking), when it stays for inspection and its path is printed.
pub fn temp_dir(name: &str) -> TempDir {
    let dir = tempfile::Builder::new()
        .prefix(&format!("pgo-{}-{name}-", env!("CARGO_CRATE_NAME")))
        .tempdir()
        .expect("create temp dir");
    TempDir(dir)
}

/// A test's temporary directory ([`temp_dir`]); derefs to its path.
pub struct TempDir(tempfile::TempDir);

impl std::ops::Deref for TempDir {
    type Target = Path;
    fn deref(&self) -> &Path {
        self.0.path()
    }
}

impl AsRef<Path> for TempDir {
    fn as_ref(&self) -> &Path {
        self.0.path()
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        if std::thread::panicking() {
            self.0.disable_cleanup(true);
            eprintln!(
                "kept the failing test's files in {}",
                self.0.path().display()
            );
        }
    }
}

/// Writes `text` to `dir/name` and returns the path.
pub fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).expect("write test file");
    p
}

/// The public benchmark datasets: `$PGO_DATASETS`, else
/// `../shared/datasets` beside the repository. When they are absent,
/// `None` with the reason printed, so that the tests that need them skip —
/// unless `CI` is `true`, where a missing dataset directory fails the test.
pub fn datasets() -> Option<PathBuf> {
    let dir = std::env::var_os("PGO_DATASETS")
        .map(PathBuf::from)
        .unwrap_or_else(|| repository().join("../shared/datasets"));
    if dir.join("intel.g2o").is_file() {
        return Some(dir);
    }
    let reason = format!(
        "public datasets not found at {} (set PGO_DATASETS)",
        dir.display()
    );
    if std::env::var("CI").is_ok_and(|ci| ci == "true") {
        panic!("{reason}; CI=true, where the datasets must be present");
    }
    eprintln!("skipped: {reason}");
    None
}

/// For every loop candidate (an edge between poses not one apart) of a
/// labels CSV (`edge,from,to,wrong`, as `g2o_samples/make.sh` writes them),
/// in file order, whether it is wrong.
pub fn candidate_wrong(labels_csv: &str) -> Vec<bool> {
    labels_csv
        .lines()
        .skip(1)
        .filter_map(|line| {
            let f: Vec<&str> = line.split(',').collect();
            let (from, to): (u64, u64) = (f[1].parse().ok()?, f[2].parse().ok()?);
            (from.abs_diff(to) != 1).then(|| f[3] == "1")
        })
        .collect()
}

/// A copy of `graph` built call by call through the public API with each
/// edge passed through `change` (with its index): the poses of `ids()`
/// in order, the edges `change` returns (`None` leaves one out) as trusted
/// edges or loop candidates with their counts, and the fixed poses. For
/// tests that scale information, bend measurements or drop edges.
pub fn rebuilt<P: pgo::GraphPose<D>, const D: usize>(
    graph: &pgo::PoseGraph<P, D>,
    change: impl FnMut(usize, pgo::Edge<P, D>) -> Option<pgo::Edge<P, D>>,
) -> pgo::PoseGraph<P, D> {
    copied(graph, |_| true, change)
}

/// The first `n` poses of `graph` (ids below `n`) and the edges among
/// them, as a young map of a front end; with the index in `graph` of each
/// edge kept.
#[allow(dead_code)]
pub fn prefix<P: pgo::GraphPose<D>, const D: usize>(
    graph: &pgo::PoseGraph<P, D>,
    n: u64,
) -> (pgo::PoseGraph<P, D>, Vec<usize>) {
    let mut kept = Vec::new();
    let young = copied(
        graph,
        |id| id < n,
        |k, e| {
            let inside = e.from < n && e.to < n;
            inside.then(|| kept.push(k));
            inside.then_some(e)
        },
    );
    (young, kept)
}

/// [`rebuilt`] of the poses for which `keep` holds.
fn copied<P: pgo::GraphPose<D>, const D: usize>(
    graph: &pgo::PoseGraph<P, D>,
    keep: impl Fn(u64) -> bool,
    mut change: impl FnMut(usize, pgo::Edge<P, D>) -> Option<pgo::Edge<P, D>>,
) -> pgo::PoseGraph<P, D> {
    let mut copy = pgo::PoseGraph::new();
    for &id in graph.ids().iter().filter(|&&id| keep(id)) {
        let pose = *graph.pose(id).expect("every vertex has a pose");
        copy.add_pose(id, pose).expect("pose");
    }
    for (k, e) in graph.edges().enumerate() {
        let Some(e) = change(k, e) else { continue };
        if e.loop_candidate {
            copy.add_loop_candidate(e.from, e.to, e.measurement, e.information, e.inliers)
        } else {
            copy.add_edge(e.from, e.to, e.measurement, e.information)
        }
        .expect("edge");
    }
    for id in graph.fixed().into_iter().filter(|&id| keep(id)) {
        copy.fix(id).expect("fixed pose");
    }
    copy
}

/// For every loop candidate of `graph` in order, whether it is wrong
/// (`wrong`: per edge, as `pgo_sim` labels them).
pub fn candidate_labels<P: pgo::GraphPose<D>, const D: usize>(
    graph: &pgo::PoseGraph<P, D>,
    wrong: &[bool],
) -> Vec<bool> {
    assert_eq!(graph.num_edges(), wrong.len());
    graph
        .edges()
        .zip(wrong)
        .filter(|(e, _)| e.loop_candidate)
        .map(|(_, &w)| w)
        .collect()
}

/// The edges of `graph` due at each pose, as a front end adds them: those
/// whose later end it is.
pub fn edges_due<P: pgo::GraphPose<D>, const D: usize>(
    graph: &pgo::PoseGraph<P, D>,
) -> Vec<Vec<usize>> {
    let mut due: Vec<Vec<usize>> = vec![Vec::new(); graph.len()];
    for (k, e) in graph.edges().enumerate() {
        due[e.from.max(e.to) as usize].push(k);
    }
    due
}

/// Adds pose `k` of `graph` to `g`, then its edges `due` (indices into
/// `graph`'s edges); returns those of them that are loop candidates.
pub fn add_pose_and_edges<P: pgo::GraphPose<D>, const D: usize>(
    g: &mut pgo::PoseGraph<P, D>,
    graph: &pgo::PoseGraph<P, D>,
    k: usize,
    due: &[usize],
) -> Vec<usize> {
    g.add_pose(k as u64, *graph.pose(k as u64).unwrap())
        .unwrap();
    let mut candidates = Vec::new();
    for &i in due {
        let e = graph.edge(i).unwrap();
        if e.loop_candidate {
            candidates.push(i);
            g.add_loop_candidate(e.from, e.to, e.measurement, e.information, e.inliers)
                .unwrap();
        } else {
            g.add_edge(e.from, e.to, e.measurement, e.information)
                .unwrap();
        }
    }
    candidates
}

/// How far solution `u`'s poses are from `b`'s: the largest distance
/// between the same pose's positions, the diagonal of `b`'s positions'
/// bounding box (the map's size), and the largest angle between the same
/// pose's rotations (θ of SE(2)'s tangent `(x, y, θ)`, φ of SE(3)'s
/// `(ρ, φ)`). Panics if the two do not list the same poses.
#[allow(dead_code)]
pub fn poses_apart<P: pgo::GraphPose<D>, const D: usize>(
    u: &pgo::Solution<P>,
    b: &pgo::Solution<P>,
) -> (f64, f64, f64) {
    let (mut lo, mut hi) = (
        pgo::nalgebra::Vector3::repeat(f64::INFINITY),
        pgo::nalgebra::Vector3::repeat(f64::NEG_INFINITY),
    );
    let (mut apart, mut turned) = (0.0f64, 0.0f64);
    let translation = D.div_ceil(2);
    for ((iu, pu), (ib, pb)) in u.poses().zip(b.poses()) {
        assert_eq!(iu, ib);
        (lo, hi) = (lo.inf(&pb.position()), hi.sup(&pb.position()));
        apart = apart.max((pu.position() - pb.position()).norm());
        let rel = pu.inverse().compose(pb).log();
        turned = turned.max(rel.rows(translation, D - translation).norm());
    }
    (apart, (hi - lo).norm(), turned)
}
