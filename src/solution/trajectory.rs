//! The optimised trajectory as the evaluation tools read it (evo, the TUM
//! RGB-D and KITTI odometry benchmarks): [`Solution::write_tum`] and
//! [`Solution::write_kitti`](super::Solution::write_kitti).
//!
//! * **TUM**: one line per pose, `timestamp tx ty tz qx qy qz qw`. pgo's
//!   poses have no time, so the timestamp is the vertex id (an integer).
//! * **KITTI**: one line per pose, the first three rows of its 4 × 4
//!   matrix `[R t; 0 0 0 1]` row by row: `r11 r12 r13 tx r21 r22 r23 ty
//!   r31 r32 r33 tz`. The format has no ids: line k is the k-th pose in
//!   the graph's order.
//!
//! Both list the poses in the graph's order (as they were added, or as the
//! file had them), each the pose of the body in the world (the fixed
//! poses') frame. An SE(2) pose `(x, y, θ)` is embedded in SE(3) as the
//! translation `(x, y, 0)` and the rotation by θ about z (quaternion
//! `(0, 0, sin θ/2, cos θ/2)`, taken with `qw ≥ 0`); an SE(3) pose's
//! quaternion is written as the pose holds it (q and −q are the same
//! rotation). Numbers are in their shortest form that reads back to the
//! same bits (`ryu`), separated by single spaces, each line ended by `\n`.
//!
//! [`Solution::write_tum`]: super::Solution::write_tum

use crate::geometry::{Se2, Se3};
use crate::graph::VertexId;
use nalgebra::{Matrix3, Vector3};
use std::io::{self, Write};

/// A trajectory file format.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Format {
    /// `timestamp tx ty tz qx qy qz qw`, the timestamp the vertex id.
    Tum,
    /// The 3 × 4 matrix `[R t]`, row by row.
    Kitti,
}

/// A pose as a pose in space: what the trajectory formats need.
pub(crate) trait Embed {
    /// The translation (z = 0 in the plane).
    fn translation3(&self) -> Vector3<f64>;
    /// The rotation as a unit quaternion `(qx, qy, qz, qw)`.
    fn quaternion(&self) -> [f64; 4];
    /// The rotation matrix.
    fn rotation3(&self) -> Matrix3<f64>;
}

impl Embed for Se2 {
    fn translation3(&self) -> Vector3<f64> {
        Vector3::new(self.x, self.y, 0.0)
    }

    fn quaternion(&self) -> [f64; 4] {
        let (s, c) = (0.5 * self.theta).sin_cos();
        // θ and θ + 2π are the same heading: the same sign for both.
        let sign = if c < 0.0 { -1.0 } else { 1.0 };
        [0.0, 0.0, sign * s, sign * c]
    }

    fn rotation3(&self) -> Matrix3<f64> {
        let (s, c) = self.theta.sin_cos();
        // `+ 0.0`: no `-0` in the file for a heading of 0.
        Matrix3::new(c, -s + 0.0, 0.0, s, c, 0.0, 0.0, 0.0, 1.0)
    }
}

impl Embed for Se3 {
    fn translation3(&self) -> Vector3<f64> {
        self.translation
    }

    fn quaternion(&self) -> [f64; 4] {
        self.quaternion_xyzw()
    }

    fn rotation3(&self) -> Matrix3<f64> {
        self.rotation_matrix()
    }
}

/// Writes `poses` (each with its id) in `format` on `out`, one line each.
pub(crate) fn write<'a, P: Embed + 'a>(
    poses: impl Iterator<Item = (VertexId, &'a P)>,
    format: Format,
    out: &mut impl Write,
) -> io::Result<()> {
    let mut buffer = ryu::Buffer::new();
    let mut line = String::new();
    for (id, pose) in poses {
        line.clear();
        let t = pose.translation3();
        let mut push = |line: &mut String, v: f64| {
            if !line.is_empty() {
                line.push(' ');
            }
            line.push_str(buffer.format(v));
        };
        match format {
            Format::Tum => {
                line.push_str(&id.to_string());
                for v in t.iter().copied().chain(pose.quaternion()) {
                    push(&mut line, v);
                }
            }
            Format::Kitti => {
                let r = pose.rotation3();
                for row in 0..3 {
                    for col in 0..3 {
                        push(&mut line, r[(row, col)]);
                    }
                    push(&mut line, t[row]);
                }
            }
        }
        line.push('\n');
        out.write_all(line.as_bytes())?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use crate::geometry::{Pose, Se2, Se3};
    use crate::{Error, Options, PoseGraph2, PoseGraph3, Solution};
    use nalgebra::{Matrix3, Matrix6, UnitQuaternion, Vector3};
    use std::path::Path;

    /// A square loop of five poses, from drifted guesses.
    fn planar() -> Solution<Se2> {
        let mut graph = PoseGraph2::new();
        for k in 0..5u64 {
            graph
                .add_pose(
                    10 + k,
                    Se2::new(k as f64 * 1.1, 0.1 * k as f64, 0.2 * k as f64),
                )
                .unwrap();
        }
        let step = Se2::new(1.0, 0.0, std::f64::consts::FRAC_PI_2);
        for k in 1..5u64 {
            graph
                .add_edge(9 + k, 10 + k, step, Matrix3::identity())
                .unwrap();
        }
        graph
            .add_edge(10, 14, Se2::new(0.0, 0.0, 0.01), Matrix3::identity())
            .unwrap();
        graph.optimize(&Options::default()).unwrap()
    }

    /// A helix of six poses, ids not increasing.
    fn spatial() -> Solution<Se3> {
        let ids = [7u64, 3, 9, 1, 4, 2];
        let step = Se3::new(
            UnitQuaternion::from_euler_angles(0.1, -0.2, 0.9),
            Vector3::new(1.0, 0.2, 0.3),
        );
        let mut graph = PoseGraph3::new();
        let mut pose = Se3::identity();
        for &id in &ids {
            graph.add_pose(id, pose).unwrap();
            pose = pose.compose(&step);
        }
        for w in ids.windows(2) {
            graph
                .add_edge(w[0], w[1], step, Matrix6::identity())
                .unwrap();
        }
        graph.optimize(&Options::default()).unwrap()
    }

    /// The numbers of each line of the file at `path`.
    fn lines(path: &Path) -> Vec<Vec<f64>> {
        let text = std::fs::read_to_string(path).unwrap();
        assert!(text.ends_with('\n'));
        text.lines()
            .map(|l| l.split(' ').map(|v| v.parse().unwrap()).collect())
            .collect()
    }

    /// The rotation and translation of each pose, in space.
    fn embedded<P: super::Embed>(solution: &Solution<P>) -> Vec<(u64, Matrix3<f64>, Vector3<f64>)> {
        (solution.poses())
            .map(|(id, p)| (id, p.rotation3(), p.translation3()))
            .collect()
    }

    /// Reads back a TUM and a KITTI file and compares them with the poses:
    /// translations to the bit, rotations to rounding.
    fn check_both<P: super::Embed>(solution: &Solution<P>, tum: &Path, kitti: &Path) {
        let expected = embedded(solution);
        let tum = lines(tum);
        let kitti = lines(kitti);
        assert_eq!(tum.len(), expected.len());
        assert_eq!(kitti.len(), expected.len());
        for ((id, r, t), (a, b)) in expected.iter().zip(tum.iter().zip(&kitti)) {
            assert_eq!(a.len(), 8);
            assert_eq!(a[0], *id as f64);
            assert_eq!(Vector3::new(a[1], a[2], a[3]), *t);
            let q =
                UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(a[7], a[4], a[5], a[6]));
            assert!((q.to_rotation_matrix().into_inner() - r).amax() < 1e-12);
            assert_eq!(b.len(), 12);
            for row in 0..3 {
                assert_eq!(b[4 * row + 3], t[row]);
                for col in 0..3 {
                    assert!((b[4 * row + col] - r[(row, col)]).abs() < 1e-15);
                }
            }
        }
    }

    #[test]
    fn solution_trajectories_read_back_to_the_poses_in_2d() {
        let solution = planar();
        let dir = tempfile::tempdir().unwrap();
        let (tum, kitti) = (dir.path().join("map.tum"), dir.path().join("map.kitti"));
        solution.write_tum(&tum).unwrap();
        solution.write_kitti(&kitti).unwrap();
        check_both(&solution, &tum, &kitti);
        // The plane: z = 0, a rotation about z, and the heading itself.
        for (line, (_, pose)) in lines(&tum).iter().zip(solution.poses()) {
            assert_eq!((line[3], line[4], line[5]), (0.0, 0.0, 0.0));
            let heading = 2.0 * line[6].atan2(line[7]);
            assert!(crate::geometry::wrap_angle(heading - pose.theta).abs() < 1e-12);
            assert!(line[7] >= 0.0);
        }
        let ids: Vec<f64> = lines(&tum).iter().map(|l| l[0]).collect();
        assert_eq!(ids, [10.0, 11.0, 12.0, 13.0, 14.0]);
        // The fixed first pose, exactly.
        let text = std::fs::read_to_string(&kitti).unwrap();
        assert_eq!(
            text.lines().next(),
            Some("1.0 0.0 0.0 0.0 0.0 1.0 0.0 0.0 0.0 0.0 1.0 0.0")
        );
    }

    #[test]
    fn solution_trajectories_read_back_to_the_poses_in_3d() {
        let solution = spatial();
        let dir = tempfile::tempdir().unwrap();
        let (tum, kitti) = (dir.path().join("map.txt"), dir.path().join("kitti.txt"));
        crate::AnySolution::Spatial(solution.clone())
            .write_tum(&tum)
            .unwrap();
        crate::AnySolution::Spatial(solution.clone())
            .write_kitti(&kitti)
            .unwrap();
        check_both(&solution, &tum, &kitti);
        // The graph's order, not the ids'.
        let ids: Vec<f64> = lines(&tum).iter().map(|l| l[0]).collect();
        assert_eq!(ids, [7.0, 3.0, 9.0, 1.0, 4.0, 2.0]);
        // The quaternion as the pose holds it, to the bit.
        for (line, (_, pose)) in lines(&tum).iter().zip(solution.poses()) {
            assert_eq!(line[4..], pose.quaternion_xyzw());
        }
    }

    #[test]
    fn solution_trajectory_in_a_missing_directory_is_a_write_error_and_leaves_nothing() {
        let solution = planar();
        let dir = tempfile::tempdir().unwrap();
        let missing = dir.path().join("missing");
        for (format, path) in [
            ("tum", missing.join("map.tum")),
            ("kitti", missing.join("map.kitti")),
        ] {
            let result = match format {
                "tum" => solution.write_tum(&path),
                _ => solution.write_kitti(&path),
            };
            match result {
                Err(e @ Error::Write { .. }) => {
                    let Error::Write { path: named, .. } = &e else {
                        unreachable!()
                    };
                    assert_eq!(named, &path);
                    assert!(e.to_string().contains(&path.display().to_string()), "{e}");
                    assert_eq!(e.kind(), crate::ErrorKind::Io);
                }
                other => panic!("{format}: {other:?}"),
            }
            assert!(!missing.exists());
        }
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
    }
}
