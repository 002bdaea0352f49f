//! Trajectory export: `pgo optimize --tum FILE --kitti FILE` writes the
//! map's poses as evo reads them — the same poses as `-o`'s g2o, in the
//! graph's order — and its files are checked like every other output.

use crate::common::{pgo, sample, stderr, temp_dir};
use pgo::nalgebra::{Matrix3, Quaternion, UnitQuaternion, Vector3};

/// The numbers of each line of `text`.
fn numbers(text: &str) -> Vec<Vec<f64>> {
    text.lines()
        .map(|l| l.split(' ').map(|v| v.parse().unwrap()).collect())
        .collect()
}

/// A pose of a g2o file as a rotation and a translation in space.
fn embedded(g2o: &[f64]) -> (Matrix3<f64>, Vector3<f64>) {
    match g2o.len() {
        3 => {
            let (s, c) = g2o[2].sin_cos();
            let r = Matrix3::new(c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0);
            (r, Vector3::new(g2o[0], g2o[1], 0.0))
        }
        _ => {
            let q = Quaternion::new(g2o[6], g2o[3], g2o[4], g2o[5]);
            let r = UnitQuaternion::from_quaternion(q).to_rotation_matrix();
            (r.into_inner(), Vector3::new(g2o[0], g2o[1], g2o[2]))
        }
    }
}

#[test]
fn tum_and_kitti_read_back_to_the_poses_of_the_g2o_output() {
    let dir = temp_dir("trajectory");
    for file in ["grid2d.g2o", "sphere3d.g2o"] {
        let (g2o, tum, kitti) = (
            dir.join("map.g2o"),
            dir.join("map.tum"),
            dir.join("map.kitti"),
        );
        let out = pgo(&[
            "optimize",
            &sample(file),
            "-q",
            "--json",
            "-o",
            g2o.to_str().unwrap(),
            "--tum",
            tum.to_str().unwrap(),
            "--kitti",
            kitti.to_str().unwrap(),
        ]);
        assert!(matches!(out.status.code(), Some(0 | 3)), "{}", stderr(&out));
        let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        let written: Vec<&str> = (report["trajectories"].as_array().unwrap().iter())
            .map(|p| p.as_str().unwrap())
            .collect();
        assert_eq!(written, [tum.to_str().unwrap(), kitti.to_str().unwrap()]);

        let map = pgo::AnyPoseGraph::read_g2o(&g2o).unwrap();
        let tum = numbers(&std::fs::read_to_string(&tum).unwrap());
        let kitti = numbers(&std::fs::read_to_string(&kitti).unwrap());
        assert_eq!(tum.len(), map.len(), "{file}");
        assert_eq!(kitti.len(), map.len(), "{file}");
        for ((&id, t), k) in map.ids().iter().zip(&tum).zip(&kitti) {
            let pose = map.pose(id).unwrap();
            let (r, p) = embedded(&pose);
            // TUM: the id as the timestamp, the translation to the bit.
            assert_eq!(t.len(), 8);
            assert_eq!(t[0], id as f64, "{file}");
            assert_eq!(Vector3::new(t[1], t[2], t[3]), p, "{file} pose {id}");
            if pose.len() == 7 {
                // 3D: the g2o file's quaternion itself.
                assert_eq!(t[4..], pose[3..], "{file} pose {id}");
            }
            let q = UnitQuaternion::from_quaternion(Quaternion::new(t[7], t[4], t[5], t[6]));
            let dr = (q.to_rotation_matrix().into_inner() - r).amax();
            assert!(dr < 1e-12, "{file} pose {id}: {dr}");
            // KITTI: [R t] row by row.
            assert_eq!(k.len(), 12);
            for row in 0..3 {
                assert_eq!(k[4 * row + 3], p[row], "{file} pose {id}");
                for col in 0..3 {
                    let d = (k[4 * row + col] - r[(row, col)]).abs();
                    assert!(d < 1e-12, "{file} pose {id} ({row}, {col})");
                }
            }
        }
    }
}

#[test]
fn tum_to_stdout_is_the_only_thing_on_stdout() {
    let out = pgo(&["optimize", &sample("grid2d.g2o"), "-q", "--tum", "-"]);
    assert!(matches!(out.status.code(), Some(0 | 3)), "{}", stderr(&out));
    let lines = numbers(std::str::from_utf8(&out.stdout).unwrap());
    let graph = pgo::AnyPoseGraph::read_g2o(sample("grid2d.g2o")).unwrap();
    assert_eq!(lines.len(), graph.len());
    assert!(lines.iter().all(|l| l.len() == 8));
}

#[test]
fn tum_and_kitti_outputs_are_checked_before_anything_runs() {
    let dir = temp_dir("trajectory-checks");
    let g2o = dir.join("map.g2o");
    let input = sample("grid2d.g2o");
    let refused = |args: &[&str], message: &str| {
        let mut all = vec!["optimize", input.as_str(), "-o", g2o.to_str().unwrap()];
        all.extend(args);
        let out = pgo(&all);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {}", stderr(&out));
        assert!(stderr(&out).contains(message), "{args:?}: {}", stderr(&out));
        assert!(out.stdout.is_empty(), "{args:?}");
        // Nothing ran: not even -o was written.
        assert!(!g2o.exists(), "{args:?}");
    };
    refused(
        &["--tum", "-", "--json"],
        "--tum and --json both write to stdout",
    );
    refused(
        &["--kitti", "-", "--json"],
        "--kitti and --json both write to stdout",
    );
    refused(
        &["--tum", "-", "--kitti", "-"],
        "--tum and --kitti both write to stdout",
    );
    refused(
        &["--covariances", "-", "--tum", "-"],
        "--covariances and --tum both write to stdout",
    );
    let same = dir.join("same.txt");
    let same = same.to_str().unwrap();
    refused(
        &["--tum", same, "--kitti", same],
        "each output needs a file of its own",
    );
    refused(
        &["--kitti", g2o.to_str().unwrap()],
        "each output needs a file of its own",
    );
    refused(&["--tum", &input], "the output is the input file");
    // A file that cannot be written fails the run, naming it, with the
    // status of an `-o` that cannot be written.
    let missing = dir.join("missing/map.tum");
    let out = pgo(&["optimize", &input, "-q", "--tum", missing.to_str().unwrap()]);
    let as_o = pgo(&["optimize", &input, "-q", "-o", missing.to_str().unwrap()]);
    assert!(matches!(out.status.code(), Some(1 | 2)), "{}", stderr(&out));
    assert_eq!(out.status.code(), as_o.status.code(), "{}", stderr(&as_o));
    assert!(
        stderr(&out).contains(missing.to_str().unwrap()),
        "{}",
        stderr(&out)
    );
    assert!(!dir.join("missing").exists());
}
