//! The library's surface for bindings (the C API and the Python module
//! use these instead of re-deriving them): error kinds, messages worded
//! with a binding's names, a readable `Debug` of errors, names of reasons
//! and update solves, pose and information widths, flat pose arrays; and
//! the ranges numbers are checked against where they enter. Runs with any
//! features.

use pgo::nalgebra::{Matrix3, Matrix6};
use pgo::{
    AnyPoseGraph, Error, ErrorKind, InformationProblem, Options, PoseGraph2, Reason, Se2, Setting,
    UpdateSolve,
};
use std::path::{Path, PathBuf};

mod common;
use common::{TempDir, sample, temp_dir, write};

/// `text` in a file `name` of a fresh temporary directory: the directory
/// (removed when dropped) and the file's path.
fn temp_file(name: &str, text: &str) -> (TempDir, PathBuf) {
    let dir = temp_dir(name);
    let file = write(&dir, name, text);
    (dir, file)
}

const I3: [f64; 9] = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];

/// A 2D line of `n` poses 1 m apart, the guess off by 10 %, with odometry
/// and one loop from the first to the last, every information matrix
/// `scale` times the identity.
fn line(n: u64, scale: f64) -> AnyPoseGraph {
    let mut g = AnyPoseGraph::new(2).unwrap();
    for k in 0..n {
        g.add_pose(k, &[k as f64 * 1.1, 0.0, 0.0]).unwrap();
    }
    let info = I3.map(|v| v * scale);
    for k in 1..n {
        g.add_edge(k - 1, k, &[1.0, 0.0, 0.0], &info).unwrap();
    }
    g.add_edge(0, n - 1, &[(n - 1) as f64, 0.0, 0.0], &info)
        .unwrap();
    g
}

/// One error of each kind, made through the public API.
fn one_of_each_kind() -> Vec<(Error, ErrorKind)> {
    let mut g = line(3, 1.0);
    let nan = [f64::NAN, 0.0, 0.0];
    let mut out = vec![
        (
            g.add_pose(0, &[0.0; 3]).unwrap_err(),
            ErrorKind::DuplicateVertex,
        ),
        (g.fix(9).unwrap_err(), ErrorKind::UnknownVertex),
        (
            g.add_edge(1, 1, &[0.0; 3], &I3).unwrap_err(),
            ErrorKind::SelfLoop,
        ),
        (g.add_pose(5, &nan).unwrap_err(), ErrorKind::InvalidPose),
        (
            g.add_edge(0, 1, &nan, &I3).unwrap_err(),
            ErrorKind::InvalidPose,
        ),
        (
            g.add_edge(0, 1, &[1.0, 0.0, 0.0], &I3.map(|v| -v))
                .unwrap_err(),
            ErrorKind::InvalidInformation,
        ),
        (g.add_pose(5, &[0.0; 2]).unwrap_err(), ErrorKind::Length),
        (AnyPoseGraph::new(4).unwrap_err(), ErrorKind::Dimension),
        (
            Options::default().set("nope", "1").unwrap_err(),
            ErrorKind::UnknownOption,
        ),
        (
            Options::default().set("alpha", "2").unwrap_err(),
            ErrorKind::InvalidOption,
        ),
        (
            AnyPoseGraph::read_g2o("/nonexistent/graph.g2o").unwrap_err(),
            ErrorKind::Io,
        ),
        (
            g.write_g2o("/nonexistent/dir/out.g2o").unwrap_err(),
            ErrorKind::Io,
        ),
        (
            AnyPoseGraph::read_g2o(temp_file("bad.g2o", "VERTEX_SE2 0 0 0\n").1).unwrap_err(),
            ErrorKind::Parse,
        ),
        (
            AnyPoseGraph::new(2)
                .unwrap()
                .optimize(&Options::default())
                .unwrap_err(),
            ErrorKind::EmptyGraph,
        ),
    ];
    g.add_pose(7, &[0.0; 3]).unwrap();
    out.push((
        g.optimize(&Options::default()).unwrap_err(),
        ErrorKind::Unconstrained,
    ));
    out.push((Error::Undetermined { vertex: 1 }, ErrorKind::Numerical));
    out.push((Error::NonFinite, ErrorKind::Numerical));
    out.push((Error::Internal("x".into()), ErrorKind::Internal));
    out
}

#[test]
fn every_error_has_its_kind() {
    for (error, kind) in one_of_each_kind() {
        assert_eq!(error.kind(), kind, "{error}");
    }
}

#[test]
fn a_missing_file_says_so_to_bindings() {
    let e = AnyPoseGraph::read_g2o("/nonexistent/graph.g2o").unwrap_err();
    let (path, io) = e.io_error().unwrap();
    assert_eq!(path, Path::new("/nonexistent/graph.g2o"));
    assert_eq!(io.kind(), std::io::ErrorKind::NotFound);
    assert!(Error::EmptyGraph.io_error().is_none());
}

#[test]
fn debug_of_an_error_is_its_message() {
    // What `fn main() -> Result<(), pgo::Error>` prints after "Error: ".
    for (error, kind) in one_of_each_kind() {
        assert_eq!(format!("{error:?}"), error.to_string());
        assert_eq!(format!("{error:#?}"), format!("{kind:?}: {error}"));
    }
    let e = AnyPoseGraph::new(4).unwrap_err();
    assert_eq!(
        format!("Error: {e:?}"),
        "Error: a pose graph is 2D or 3D, not 4D"
    );
}

/// Python's names for the settings, as the module words them.
fn python(s: Setting) -> String {
    match s {
        Setting::Option(name) => format!("option {}", name.replace('-', "_")),
        Setting::RepairAdded => "PoseGraph(dim, repair_information=True)".into(),
        Setting::RepairRead => "read_g2o(path, repair_information=True)".into(),
        _ => unreachable!(),
    }
}

#[test]
fn messages_name_settings_in_each_surfaces_words() {
    let e = Options::default().set("max_iters", "-1").unwrap_err();
    assert_eq!(
        e.to_string(),
        "--max-iters must be a non-negative integer, got '-1'"
    );
    assert_eq!(
        e.message_with(&python),
        "option max_iters must be a non-negative integer, got '-1'"
    );

    let mut g = line(3, 1.0);
    let e = g
        .add_edge(0, 2, &[2.0, 0.0, 0.0], &I3.map(|v| -v))
        .unwrap_err();
    let rust = e.to_string();
    assert!(
        rust.ends_with(
            "; PoseGraph::set_repair_information(true) projects such matrices to the nearest \
             positive-definite one"
        ),
        "{rust}"
    );
    let py = e.message_with(&python);
    assert!(
        py.starts_with("edge 0 → 2: information matrix is not positive definite (smallest eigenvalue -1e0); PoseGraph(dim, repair_information=True) projects"),
        "{py}"
    );
    assert!(!py.contains("set_repair_information") && !py.contains("--fix"));

    // A file's: the reader's own message (the command line's flag) for
    // the command line, the binding's function otherwise.
    let (_dir, file) = temp_file(
        "indefinite.g2o",
        "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nEDGE_SE2 0 1 1 0 0 -1 0 0 1 0 1\n",
    );
    let e = AnyPoseGraph::read_g2o(&file).unwrap_err();
    let Error::Read(read) = &e else { panic!("{e}") };
    let cli = e.message_with(&|s| match s {
        Setting::RepairRead => "--fix-information".into(),
        other => other.rust_name(),
    });
    assert_eq!(cli, read.to_string(), "the reader's text, the same words");
    assert!(
        e.to_string()
            .contains(":3: information matrix is not positive definite")
    );
    assert!(
        e.to_string()
            .contains("; PoseGraph::read_g2o_repairing projects")
    );
    assert!(
        e.message_with(&python)
            .contains("; read_g2o(path, repair_information=True) projects")
    );
    // Other messages are the same in every surface.
    let e = g.fix(9).unwrap_err();
    assert_eq!(e.message_with(&python), e.to_string());
}

#[test]
fn reasons_and_update_solves_are_named_as_the_json_spells_them() {
    let reasons = [
        Reason::Consistent,
        Reason::Inconsistent,
        Reason::Outlying,
        Reason::Unchecked,
        Reason::ExplainsChi2,
        Reason::Unsettled,
        Reason::Kernel,
        Reason::Dropped,
        Reason::Trusted,
    ];
    for r in reasons {
        assert_eq!(serde_json::to_value(r).unwrap(), r.as_str(), "{r:?}");
    }
    assert_eq!(Reason::ExplainsChi2.as_str(), "explains_chi2");
    for s in [
        UpdateSolve::Batch,
        UpdateSolve::None,
        UpdateSolve::Extended,
        UpdateSolve::Warm,
        UpdateSolve::Full,
    ] {
        assert_eq!(serde_json::to_value(s).unwrap(), s.as_str(), "{s:?}");
    }
}

#[test]
fn a_loop_decision_serialises_under_its_field_names() {
    let mut g = line(5, 100.0);
    g.add_loop_candidate(1, 4, &[3.0, 0.0, 0.0], &I3, Some(80))
        .unwrap();
    let s = g.optimize(&Options::default()).unwrap();
    let d = s.loops()[0];
    let json = serde_json::to_value(d).unwrap();
    assert_eq!(json["index"], d.index);
    assert_eq!(json["from"], 1);
    assert_eq!(json["to"], 4);
    assert_eq!(json["inliers"], 80);
    assert_eq!(json["accepted"], d.accepted);
    assert_eq!(json["reason"], d.reason.as_str());
    assert_eq!(json.as_object().unwrap().len(), 10);
}

#[test]
fn widths_and_flat_poses_are_the_graphs() {
    let g2 = line(4, 1.0);
    assert_eq!((g2.pose_width(), g2.information_width()), (3, 3));
    let s2 = g2.optimize(&Options::default()).unwrap();
    assert_eq!((s2.dimension(), s2.pose_width()), (2, 3));
    assert_eq!(s2.ids(), g2.ids());
    let flat = s2.poses_flat();
    assert_eq!(flat.len(), 4 * 3);
    for (k, &id) in s2.ids().iter().enumerate() {
        assert_eq!(&flat[k * 3..k * 3 + 3], s2.pose(id).unwrap().as_slice());
    }

    let mut g3 = AnyPoseGraph::new(3).unwrap();
    assert_eq!((g3.pose_width(), g3.information_width()), (7, 6));
    g3.add_pose(9, &[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])
        .unwrap();
    g3.add_pose(2, &[1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])
        .unwrap();
    let info: Vec<f64> = Matrix6::<f64>::identity().iter().copied().collect();
    g3.add_edge(9, 2, &[1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0], &info)
        .unwrap();
    let s3 = g3.optimize(&Options::default()).unwrap();
    assert_eq!((s3.dimension(), s3.pose_width()), (3, 7));
    assert_eq!(s3.ids(), &[9, 2]);
    let flat = s3.poses_flat();
    assert_eq!(&flat[7..], s3.pose(2).unwrap().as_slice());
}

#[test]
fn the_report_times_the_whole_job_in_memory_too() {
    let mut g = line(30, 100.0);
    let s = g.optimize(&Options::default()).unwrap();
    let t = &s.report().time;
    assert!(t.total_s > 0.0 && t.total_s >= t.solve_s, "{t:?}");
    let s = g.update(&Options::default()).unwrap();
    assert!(s.report().time.total_s > 0.0);
}

#[test]
fn a_huge_or_tiny_quaternion_is_normalised_not_called_zero() {
    let mut g = AnyPoseGraph::new(3).unwrap();
    g.add_pose(0, &[1.0, 2.0, 3.0, 0.0, 0.0, 1e200, 1e200])
        .unwrap();
    let q = g.pose(0).unwrap();
    let half = std::f64::consts::FRAC_1_SQRT_2;
    assert!(
        (q[5] - half).abs() < 1e-15 && (q[6] - half).abs() < 1e-15,
        "{q:?}"
    );
    g.add_pose(1, &[0.0, 0.0, 0.0, 1e-300, 0.0, 0.0, 0.0])
        .unwrap();
    assert_eq!(g.pose(1).unwrap()[3], 1.0);
    let e = g.add_pose(2, &[0.0; 7]).unwrap_err();
    assert_eq!(e.to_string(), "vertex 2: has a quaternion of zero norm");
    let e = g
        .add_pose(2, &[0.0, 0.0, 0.0, f64::INFINITY, 0.0, 0.0, 1.0])
        .unwrap_err();
    assert_eq!(e.to_string(), "vertex 2: is not finite");
    // As the reader does.
    let (_dir, file) = temp_file(
        "huge_quaternion.g2o",
        "VERTEX_SE3:QUAT 0 1 2 3 0 0 1e200 1e200\n",
    );
    let read = AnyPoseGraph::read_g2o(file).unwrap();
    assert_eq!(read.pose(0), g.pose(0));
}

#[test]
fn information_out_of_range_is_refused_where_it_enters() {
    let (lo, hi) = (
        *pgo::INFORMATION_RANGE.start(),
        *pgo::INFORMATION_RANGE.end(),
    );
    let mut g = PoseGraph2::new();
    g.add_pose(0, Se2::new(0.0, 0.0, 0.0)).unwrap();
    g.add_pose(1, Se2::new(1.0, 0.0, 0.0)).unwrap();
    let z = Se2::new(1.0, 0.0, 0.0);
    let too_small = Matrix3::from_diagonal(&[1.0, 1.0, lo / 2.0].into());
    let e = g.add_edge(0, 1, z, too_small).unwrap_err();
    assert!(matches!(
        e,
        Error::InvalidInformation {
            problem: InformationProblem::OutOfRange { index: 2, .. },
            ..
        }
    ));
    assert_eq!(
        e.to_string(),
        "edge 0 → 1: information matrix has diagonal entry (2, 2) = 5e-101, outside the range \
         pgo computes with (1e-100 to 1e100; rescale the information or the units)"
    );
    assert_eq!(e.kind(), ErrorKind::InvalidInformation);
    let too_large = Matrix3::identity() * hi * 2.0;
    assert!(g.add_edge(0, 1, z, too_large).is_err());
    // Repair does not change the scale.
    g.set_repair_information(true);
    assert!(g.add_edge(0, 1, z, too_large).is_err());
    assert_eq!(g.num_edges(), 0);
    g.add_edge(0, 1, z, Matrix3::identity() * hi).unwrap();

    // A file's, when it is read for a job (the reader itself takes any
    // finite scale: the simulator's files reach 10^±300).
    let (_dir, file) = temp_file(
        "tiny_information.g2o",
        "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nEDGE_SE2 0 1 1 0 0 1e-120 0 0 1e-120 0 1e-120\n",
    );
    for e in [
        AnyPoseGraph::read_g2o(&file).unwrap_err(),
        PoseGraph2::read_g2o(&file).unwrap_err(),
    ] {
        assert_eq!(e.kind(), ErrorKind::InvalidInformation);
        assert!(
            e.to_string().starts_with(
                "edge 0 → 1: information matrix has diagonal entry (0, 0) = 1e-120, outside"
            ),
            "{e}"
        );
    }
}

#[test]
fn information_at_the_ends_of_its_range_gives_the_same_map() {
    // A weighted least-squares optimum does not change when every
    // information matrix is scaled alike; at the range's ends no step may
    // under- or overflow (the chordal guess used to: "the edges at vertex
    // 1 do not determine its pose" from 10^±103 in 2D).
    let unit = line(5, 1.0).optimize(&Options::default()).unwrap();
    for scale in [1e-100, 1e-60, 1e60, 1e100] {
        let s = line(5, scale).optimize(&Options::default()).unwrap();
        for id in 0..5 {
            let (a, b) = (s.pose(id).unwrap(), unit.pose(id).unwrap());
            for (x, y) in a.iter().zip(&b) {
                assert!((x - y).abs() < 1e-9, "{scale}, pose {id}: {a:?} vs {b:?}");
            }
        }
    }
}

#[test]
fn robust_c_at_the_ends_of_its_range_decides_without_failing() {
    let graph = AnyPoseGraph::read_g2o(sample("grid2d.g2o")).unwrap();
    for c in [pgo::ROBUST_C_RANGE.start(), pgo::ROBUST_C_RANGE.end()] {
        let mut options = Options::default();
        options.set("robust-c", &c.to_string()).unwrap();
        let s = graph.optimize(&options);
        assert!(s.is_ok(), "c = {c}: {:?}", s.err());
    }
    let mut options = Options::default();
    let e = options.set("robust-c", "1e-101").unwrap_err();
    assert_eq!(e.kind(), ErrorKind::InvalidOption);
    assert_eq!(
        e.to_string(),
        "--robust-c must be between 1e-100 and 1e100, got 1e-101"
    );
}

#[test]
fn spatial_information_at_the_ends_of_its_range_is_taken() {
    let mut g = AnyPoseGraph::new(3).unwrap();
    let id = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0];
    g.add_pose(0, &id).unwrap();
    g.add_pose(1, &[1.1, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]).unwrap();
    let z = [1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0];
    for scale in [1e-100, 1e100] {
        let info: Vec<f64> = (Matrix6::<f64>::identity() * scale)
            .iter()
            .copied()
            .collect();
        g.add_edge(0, 1, &z, &info).unwrap();
    }
    let s = g.optimize(&Options::default()).unwrap();
    assert!((s.pose(1).unwrap()[0] - 1.0).abs() < 1e-9);
}
