//! The library's public API, as a mapping tool uses it: a graph built call
//! by call runs the same job as `pgo optimize` on its file, and every bad
//! input is refused with an error naming it. Runs with any features.

use pgo::nalgebra::{Matrix3, Matrix6, SMatrix};
use pgo::{
    AnyPoseGraph, Error, InformationProblem, Options, Pose, PoseGraph, PoseGraph2, PoseGraph3,
    PoseProblem, Reason, Se2, Se3, Solution,
};
use std::path::Path;

mod common;
use common::{sample, temp_dir};

/// The symmetric matrix whose upper triangle, row by row, is `v`.
fn upper<const D: usize>(v: &[f64]) -> SMatrix<f64, D, D> {
    let mut m = SMatrix::<f64, D, D>::zeros();
    let mut k = 0;
    for r in 0..D {
        for c in r..D {
            m[(r, c)] = v[k];
            m[(c, r)] = v[k];
            k += 1;
        }
    }
    m
}

/// A g2o file of plain vertices and edges, added to a graph line by line
/// through the public calls (a front end's calls, here from a file).
fn build<P: pgo::GraphPose<D>, const D: usize>(
    path: &Path,
    pose: fn(&[f64]) -> P,
) -> PoseGraph<P, D> {
    let numbers = if D == 3 { 3 } else { 7 };
    let mut g = PoseGraph::new();
    for line in std::fs::read_to_string(path).unwrap().lines() {
        let t: Vec<&str> = line.split_whitespace().collect();
        let f = |r: &[&str]| -> Vec<f64> { r.iter().map(|x| x.parse().unwrap()).collect() };
        match t.first() {
            Some(tag) if tag.starts_with("VERTEX") => {
                g.add_pose(t[1].parse().unwrap(), pose(&f(&t[2..])))
                    .unwrap();
            }
            Some(tag) if tag.starts_with("EDGE") => {
                let (from, to) = (t[1].parse().unwrap(), t[2].parse().unwrap());
                let z = pose(&f(&t[3..3 + numbers]));
                let info_end = 3 + numbers + D * (D + 1) / 2;
                let info = upper::<D>(&f(&t[3 + numbers..info_end]));
                match t.get(info_end) {
                    Some(n) => g
                        .add_loop_candidate(from, to, z, info, Some(n.parse().unwrap()))
                        .unwrap(),
                    None => g.add_edge(from, to, z, info).unwrap(),
                };
            }
            _ => panic!("unexpected line {line}"),
        }
    }
    g
}

fn se2(v: &[f64]) -> Se2 {
    Se2::new(v[0], v[1], v[2])
}

fn se3(v: &[f64]) -> Se3 {
    Se3::from_translation_quaternion([v[0], v[1], v[2]], [v[3], v[4], v[5], v[6]]).unwrap()
}

/// The same poses, bit for bit, and the same decisions.
fn assert_same<P: Pose<D>, const D: usize>(a: &Solution<P>, b: &Solution<P>) {
    assert_eq!(a.poses().len(), b.poses().len());
    for ((ia, pa), (ib, pb)) in a.poses().zip(b.poses()) {
        assert_eq!(ia, ib);
        let (la, lb) = (pa.log(), pb.log());
        assert!(
            la.iter()
                .zip(lb.iter())
                .all(|(x, y)| x.to_bits() == y.to_bits()),
            "vertex {ia}: {pa:?} vs {pb:?}"
        );
    }
    assert_eq!(a.loops(), b.loops());
    assert_eq!(a.chi2().to_bits(), b.chi2().to_bits());
    assert_eq!(a.chi2_test(), b.chi2_test());
}

fn check_built_equals_read<P: pgo::GraphPose<D>, const D: usize>(
    name: &str,
    pose: fn(&[f64]) -> P,
    options: &Options,
) -> Solution<P> {
    let path = sample(name);
    let built: PoseGraph<P, D> = build(&path, pose);
    let read = PoseGraph::<P, D>::read_g2o(&path).unwrap();
    assert_eq!(built.ids(), read.ids());
    assert_eq!(built.num_loop_candidates(), read.num_loop_candidates());
    let solution = built.optimize(options).unwrap();
    assert_same(&solution, &read.optimize(options).unwrap());
    // Written and read back, the built graph is the same graph again.
    let dir = temp_dir(name);
    let copy = dir.join("copy.g2o");
    built.write_g2o(&copy).unwrap();
    assert_same(
        &solution,
        &PoseGraph::<P, D>::read_g2o(&copy)
            .unwrap()
            .optimize(options)
            .unwrap(),
    );
    let _ = std::fs::remove_dir_all(&dir);
    solution
}

#[test]
fn a_planar_graph_built_call_by_call_is_the_job_of_its_file() {
    let s = check_built_equals_read("grid2d.g2o", se2, &Options::default());
    // The job did its work: the gate passed some candidates and refused
    // others, and the χ² test has a verdict.
    let loops = s.loops();
    assert_eq!(loops.len(), 400);
    assert!(loops.iter().any(|l| l.kept) && loops.iter().any(|l| !l.kept));
    assert!(loops.iter().filter(|l| l.accepted).count() > 100);
    assert!(s.passed().is_some());
    assert_eq!(s.report().loops.len(), 400);
    for l in loops {
        assert_eq!(l.accepted, l.weight >= 0.5);
        if l.reason == Reason::Dropped {
            assert!(!l.accepted && !l.kept, "{l:?}");
        }
    }
}

#[test]
fn other_options_reach_the_job_as_the_flags_do() {
    let mut o = Options::default();
    o.set("robust-c", "4").unwrap();
    o.set("max-iters", "60").unwrap();
    o.set("alpha", "0.01").unwrap();
    let s = check_built_equals_read("grid2d.g2o", se2, &o);
    assert_eq!(s.chi2_test().unwrap().alpha, 0.01);
    assert_eq!(s.report().robust.c, 4.0);
    assert!(s.report().optimizer.iterations <= 60);
}

#[test]
fn a_spatial_graph_built_call_by_call_is_the_job_of_its_file() {
    let s = check_built_equals_read("sphere3d.g2o", se3, &Options::default());
    assert_eq!(s.loops().len(), 250);
    assert!(s.loops().iter().any(|l| l.accepted));
}

#[test]
fn a_solution_finds_each_pose_by_its_id_in_any_order() {
    // Ids increasing (found by search) and not (by a map): the same poses.
    for ids in [[3u64, 10, 11, 40], [40, 3, 11, 10]] {
        let mut g = PoseGraph2::new();
        for (k, &id) in ids.iter().enumerate() {
            g.add_pose(id, Se2::new(k as f64, 0.0, 0.0)).unwrap();
        }
        for w in ids.windows(2) {
            let step = Se2::new(1.0, 0.0, 0.0);
            g.add_edge(w[0], w[1], step, Matrix3::identity()).unwrap();
        }
        let s = g.optimize(&Options::default()).unwrap();
        for (k, &id) in ids.iter().enumerate() {
            assert!((s.pose(id).unwrap().x - k as f64).abs() < 1e-9, "{ids:?}");
        }
        assert!(s.pose(4).is_none() && s.pose(41).is_none() && s.pose(0).is_none());
    }
}

#[test]
fn decisions_carry_the_index_the_candidate_was_added_under() {
    let mut g = PoseGraph2::new();
    for k in 0..6 {
        g.add_pose(k, Se2::new(k as f64, 0.0, 0.0)).unwrap();
    }
    let info = Matrix3::identity() * 100.0;
    let mut edges = Vec::new();
    for k in 1..6 {
        edges.push(g.add_edge(k - 1, k, Se2::new(1.0, 0.0, 0.0), info).unwrap());
    }
    let good = g
        .add_loop_candidate(0, 5, Se2::new(5.0, 0.0, 0.0), info, Some(200))
        .unwrap();
    let between = g.add_edge(2, 4, Se2::new(2.0, 0.0, 0.0), info).unwrap();
    let counted_none = g
        .add_loop_candidate(1, 4, Se2::new(3.0, 0.0, 0.0), info, None)
        .unwrap();
    assert_eq!(edges, vec![0, 1, 2, 3, 4]);
    assert_eq!((good, between, counted_none), (5, 6, 7));
    assert_eq!((g.len(), g.num_edges(), g.num_loop_candidates()), (6, 8, 2));
    let s = g.optimize(&Options::default()).unwrap();
    let indices: Vec<usize> = s.loops().iter().map(|l| l.index).collect();
    assert_eq!(indices, vec![5, 7]);
    assert_eq!((s.loops()[0].from, s.loops()[0].to), (0, 5));
    assert_eq!(s.loops()[0].inliers, Some(200));
    assert!(s.loops().iter().all(|l| l.accepted), "{:?}", s.loops());
    // With every edge between non-consecutive ids a candidate, the trusted
    // edge 2 → 4 is decided too, under its edge index.
    let mut o = Options::default();
    o.set("candidates", "non-sequential").unwrap();
    let s = g.optimize(&o).unwrap();
    let indices: Vec<usize> = s.loops().iter().map(|l| l.index).collect();
    assert_eq!(indices, vec![5, 6, 7]);
    // The graph is left as it was: optimising is repeatable.
    assert_eq!(g.pose(3), Some(&Se2::new(3.0, 0.0, 0.0)));
}

#[test]
fn a_wrong_loop_is_rejected_and_says_why() {
    let mut g = PoseGraph2::new();
    let step = Se2::new(1.0, 0.0, std::f64::consts::FRAC_PI_2);
    let mut x = Se2::identity();
    for k in 0..9 {
        g.add_pose(k, x).unwrap();
        x = x.compose(&step);
    }
    let odometry = Matrix3::from_diagonal(&[100.0, 100.0, 400.0].into());
    for k in 1..9 {
        g.add_edge(k - 1, k, step, odometry).unwrap();
    }
    let info = Matrix3::from_diagonal(&[50.0, 50.0, 200.0].into());
    let same = Se2::identity();
    g.add_loop_candidate(0, 4, same, info, Some(140)).unwrap();
    g.add_loop_candidate(0, 8, same, info, Some(155)).unwrap();
    let wrong = g
        .add_loop_candidate(2, 6, Se2::new(4.0, -3.0, 2.0), info, Some(9))
        .unwrap();
    let s = g.optimize(&Options::default()).unwrap();
    let w = s.loops().iter().find(|l| l.index == wrong).unwrap();
    assert!(!w.accepted && w.weight < 0.5);
    assert_ne!(
        w.reason,
        Reason::Dropped,
        "the robust back end weighed it: {w:?}"
    );
    assert_eq!(s.passed(), Some(true));
    assert!(s.d2().unwrap() < 1e-12);
    // Without a robust back end the wrong loop bends the map, and the χ²
    // test says so.
    let mut plain = Options::default();
    plain.set("robust", "none").unwrap();
    let bent = g.optimize(&plain).unwrap();
    assert!(
        bent.loops()
            .iter()
            .all(|l| l.accepted && l.reason == Reason::Trusted)
    );
    assert_eq!(bent.passed(), Some(false));
}

#[test]
fn every_bad_addition_is_refused_naming_it() {
    let i3 = Matrix3::identity();
    let z = Se2::new(1.0, 0.0, 0.0);
    let mut g = PoseGraph2::new();
    g.add_pose(1, Se2::identity()).unwrap();
    g.add_pose(2, z).unwrap();
    let err = |r: Result<usize, Error>| r.unwrap_err();

    let e = g.add_pose(1, z).unwrap_err();
    assert!(matches!(e, Error::DuplicateVertex { id: 1 }));
    assert_eq!(e.to_string(), "vertex 1 already exists");
    let e = g.add_pose(3, Se2::new(f64::NAN, 0.0, 0.0)).unwrap_err();
    assert!(matches!(
        e,
        Error::InvalidPose {
            id: 3,
            problem: PoseProblem::NotFinite
        }
    ));
    assert_eq!(e.to_string(), "vertex 3: is not finite");
    assert!(!g.contains(3));

    assert!(matches!(
        err(g.add_edge(1, 1, z, i3)),
        Error::SelfLoop { id: 1 }
    ));
    assert!(matches!(
        err(g.add_edge(1, 9, z, i3)),
        Error::UnknownVertex { id: 9 }
    ));
    assert!(matches!(
        err(g.add_edge(8, 2, z, i3)),
        Error::UnknownVertex { id: 8 }
    ));
    let e = err(g.add_loop_candidate(1, 2, Se2::new(0.0, f64::INFINITY, 0.0), i3, Some(3)));
    assert!(matches!(
        e,
        Error::InvalidMeasurement {
            from: 1,
            to: 2,
            problem: PoseProblem::NotFinite
        }
    ));

    let mut nan = i3;
    nan[(2, 1)] = f64::NAN;
    let e = err(g.add_edge(1, 2, z, nan));
    assert!(matches!(
        e,
        Error::InvalidInformation {
            from: 1,
            to: 2,
            problem: InformationProblem::NotFinite { row: 2, col: 1 }
        }
    ));
    let mut asymmetric = i3;
    asymmetric[(0, 2)] = 0.5;
    let e = err(g.add_edge(1, 2, z, asymmetric));
    assert!(matches!(
        e,
        Error::InvalidInformation {
            problem: InformationProblem::NotSymmetric { row: 0, col: 2, .. },
            ..
        }
    ));
    let negative = -i3;
    let e = err(g.add_edge(1, 2, z, negative));
    assert!(matches!(
        e,
        Error::InvalidInformation { problem: InformationProblem::NotPositiveDefinite { min_eigenvalue }, .. }
            if min_eigenvalue == -1.0
    ));
    assert!(
        e.to_string()
            .starts_with("edge 1 → 2: information matrix is not positive definite"),
        "{e}"
    );
    let indefinite = Matrix3::new(10.0, 0.0, 84022.0, 0.0, 10.0, 0.0, 84022.0, 0.0, 10.0);
    assert!(matches!(
        err(g.add_edge(1, 2, z, indefinite)),
        Error::InvalidInformation {
            problem: InformationProblem::NotPositiveDefinite { .. },
            ..
        }
    ));
    assert_eq!(g.num_edges(), 0, "nothing refused was added");

    // Repair, asked for: the indefinite matrix is projected and counted; a
    // zero one cannot be.
    g.set_repair_information(true);
    g.add_edge(1, 2, z, indefinite).unwrap();
    assert_eq!(g.information_repaired(), 1);
    assert!(matches!(
        err(g.add_edge(1, 2, z, Matrix3::zeros())),
        Error::InvalidInformation {
            problem: InformationProblem::NotRepairable,
            ..
        }
    ));
    assert!(matches!(
        err(g.add_edge(1, 2, z, asymmetric)),
        Error::InvalidInformation {
            problem: InformationProblem::NotSymmetric { .. },
            ..
        }
    ));
    let s = g.optimize(&Options::default()).unwrap();
    assert_eq!(s.report().information_fixed, 1);
    assert!(
        s.report()
            .warnings
            .iter()
            .any(|w| w.contains("projected 1 information"))
    );

    assert!(matches!(g.fix(5), Err(Error::UnknownVertex { id: 5 })));
    // Round-off asymmetry is no error: the upper triangle is kept.
    let mut nearly = i3;
    nearly[(1, 0)] = 1e-14;
    g.add_edge(1, 2, z, nearly).unwrap();
}

#[test]
fn spatial_poses_are_checked_and_normalised_as_the_reader_does() {
    let mut g = PoseGraph3::new();
    let zero = Se3::new(
        pgo::nalgebra::UnitQuaternion::new_unchecked(pgo::nalgebra::Quaternion::new(
            0.0, 0.0, 0.0, 0.0,
        )),
        pgo::nalgebra::Vector3::zeros(),
    );
    assert!(matches!(
        g.add_pose(0, zero),
        Err(Error::InvalidPose {
            id: 0,
            problem: PoseProblem::ZeroQuaternion
        })
    ));
    let long = Se3::new(
        pgo::nalgebra::UnitQuaternion::new_unchecked(pgo::nalgebra::Quaternion::new(
            2.0, 0.0, 0.0, 0.0,
        )),
        pgo::nalgebra::Vector3::new(1.0, 2.0, 3.0),
    );
    g.add_pose(0, long).unwrap();
    assert_eq!(g.pose(0), Some(&se3(&[1.0, 2.0, 3.0, 0.0, 0.0, 0.0, 1.0])));
    g.add_pose(1, Se3::identity()).unwrap();
    g.add_edge(0, 1, Se3::identity(), Matrix6::identity())
        .unwrap();
}

#[test]
fn the_dimension_free_graph_checks_lengths_and_dimensions() {
    assert!(matches!(
        AnyPoseGraph::new(4),
        Err(Error::UnsupportedDimension { dimension: 4 })
    ));
    let mut g = AnyPoseGraph::new(3).unwrap();
    assert_eq!(g.dimension(), 3);
    let e = g.add_pose(0, &[0.0; 3]).unwrap_err();
    assert!(matches!(
        e,
        Error::Length {
            what: "pose",
            dimension: 3,
            expected: 7,
            found: 3
        }
    ));
    g.add_pose(0, &[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]).unwrap();
    g.add_pose(1, &[1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 2.0]).unwrap();
    assert_eq!(g.pose(1), Some(vec![1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]));
    let z = [1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0];
    let identity: Vec<f64> = (0..36)
        .map(|k| if k % 7 == 0 { 1.0 } else { 0.0 })
        .collect();
    let e = g.add_edge(0, 1, &z, &identity[..21]).unwrap_err();
    assert_eq!(
        e.to_string(),
        "information: expected 36 numbers for a 3D graph, got 21"
    );
    let e = g
        .add_edge(0, 1, &[1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0], &identity)
        .unwrap_err();
    assert!(matches!(
        e,
        Error::InvalidMeasurement {
            problem: PoseProblem::ZeroQuaternion,
            ..
        }
    ));
    let e = g
        .add_pose(2, &[f64::NAN, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])
        .unwrap_err();
    assert!(matches!(
        e,
        Error::InvalidPose {
            id: 2,
            problem: PoseProblem::NotFinite
        }
    ));
    assert_eq!(g.add_edge(0, 1, &z, &identity).unwrap(), 0);
    assert_eq!(
        g.add_loop_candidate(0, 1, &z, &identity, Some(5)).unwrap(),
        1
    );
    assert_eq!((g.len(), g.num_edges(), g.num_loop_candidates()), (2, 2, 1));
    let s = g.optimize(&Options::default()).unwrap();
    assert_eq!(s.loops().len(), 1);
    assert_eq!(s.pose(1).unwrap().len(), 7);

    // Files: either dimension into the free graph, the wrong one refused.
    let g = AnyPoseGraph::read_g2o(sample("sphere3d.g2o")).unwrap();
    assert_eq!((g.dimension(), g.len()), (3, 900));
    assert!(matches!(
        PoseGraph2::read_g2o(sample("sphere3d.g2o")),
        Err(Error::Dimension {
            expected: 2,
            found: 3
        })
    ));
    assert!(matches!(
        PoseGraph3::read_g2o(sample("grid2d.g2o")),
        Err(Error::Dimension {
            expected: 3,
            found: 2
        })
    ));
    let e = PoseGraph2::read_g2o(sample("no-such-file.g2o")).unwrap_err();
    assert!(matches!(e, Error::Read(_)), "{e:?}");
    assert!(e.to_string().contains("no-such-file.g2o"), "{e}");
}

#[test]
fn a_graph_the_job_cannot_run_on_is_refused() {
    let options = Options::default();
    assert!(matches!(
        PoseGraph2::new().optimize(&options),
        Err(Error::EmptyGraph)
    ));
    let mut g = PoseGraph2::new();
    for k in 0..4 {
        g.add_pose(k, Se2::new(k as f64, 0.0, 0.0)).unwrap();
    }
    g.add_edge(0, 1, Se2::new(1.0, 0.0, 0.0), Matrix3::identity())
        .unwrap();
    g.add_edge(2, 3, Se2::new(1.0, 0.0, 0.0), Matrix3::identity())
        .unwrap();
    let e = g.optimize(&options).unwrap_err();
    assert!(
        matches!(&e, Error::Unconstrained { gauge: 0, vertices } if vertices == &[2, 3]),
        "{e:?}"
    );
    // A loop candidate the gate drops does not tie the map together.
    g.add_loop_candidate(1, 2, Se2::new(1.0, 0.0, 0.0), Matrix3::identity(), Some(0))
        .unwrap();
    assert!(matches!(
        g.optimize(&options),
        Err(Error::Unconstrained { .. })
    ));
    g.add_edge(1, 2, Se2::new(1.0, 0.0, 0.0), Matrix3::identity())
        .unwrap();
    assert!(g.optimize(&options).is_ok());
    let mut bad = Options::default();
    bad.robust.c = Some(f64::NAN);
    let e = g.optimize(&bad).unwrap_err();
    assert_eq!(
        e.to_string(),
        "--robust-c must be between 1e-100 and 1e100, got NaN"
    );
    bad.robust.c = None;
    bad.solver.threads = 2;
    assert!(g.optimize(&bad).is_ok(), "two threads of its own");
}

/// A second session joined to the first only by a loop candidate the gate
/// drops: the initial guess places it by that candidate, and the job holds
/// it there while the loop decisions (which start some accepted sets from
/// their chordal relaxation) go on without it, instead of failing because
/// the accepted set leaves it apart from the gauge. Session one drives
/// three laps of a 20-pose circle (40 true loops with high counts, 10
/// wrong ones with low counts); session two is a straight chain of 20
/// poses.
#[test]
fn a_session_joined_only_by_a_dropped_candidate_is_held_where_it_was_placed() {
    let info = Matrix3::from_diagonal(&[100.0, 100.0, 1000.0].into());
    let lap = 20;
    let on_circle = |k: u64| {
        let a = std::f64::consts::TAU * (k % lap) as f64 / lap as f64;
        Se2::new(
            5.0 * a.cos(),
            5.0 * a.sin(),
            a + std::f64::consts::FRAC_PI_2,
        )
    };
    let mut g = PoseGraph2::new();
    for k in 0..3 * lap {
        g.add_pose(k, on_circle(k)).unwrap();
    }
    let between = |a: &Se2, b: &Se2| a.inverse().compose(b);
    for k in 1..3 * lap {
        let z = between(&on_circle(k - 1), &on_circle(k));
        g.add_edge(k - 1, k, z, info).unwrap();
    }
    for k in 0..2 * lap {
        let count = 150 + (k * 37) % 100;
        g.add_loop_candidate(k, k + lap, Se2::identity(), info, Some(count))
            .unwrap();
    }
    for k in 0..10 {
        let z = Se2::new(3.0 + k as f64, -2.0, 1.0);
        g.add_loop_candidate(k, k + 25, z, info, Some(8 + k))
            .unwrap();
    }
    let second = 1000;
    for k in 0..20 {
        g.add_pose(second + k, Se2::new(k as f64, 20.0, 0.0))
            .unwrap();
    }
    for k in 1..20 {
        g.add_edge(second + k - 1, second + k, Se2::new(1.0, 0.0, 0.0), info)
            .unwrap();
    }
    let join = Se2::new(0.0, 10.0, 0.0);
    g.add_loop_candidate(5, second, join, info, Some(9))
        .unwrap();
    let s = g.optimize(&Options::default()).unwrap();
    let joining = s.loops().last().unwrap();
    assert!(!joining.kept && !joining.accepted, "{joining:?}");
    let true_loops = s.loops()[..2 * lap as usize].iter();
    assert!(true_loops.clone().all(|l| l.accepted), "{:?}", s.loops());
    // Session two keeps its own shape where the dropped candidate put it.
    let placed = s.pose(5).unwrap().compose(&join);
    let start = s.pose(second).unwrap();
    assert!((start.x - placed.x).abs() < 1e-6 && (start.y - placed.y).abs() < 1e-6);
    let step = between(start, s.pose(second + 19).unwrap());
    assert!(
        (step.x - 19.0).abs() < 1e-9 && step.y.abs() < 1e-9,
        "{step:?}"
    );
}
