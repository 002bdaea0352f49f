//! A solution's pictures ([`Solution::write_plots`], the `plot`
//! feature): what the trajectory picture draws, gathered from the solved
//! graph, the loop decisions and the initial guess; the pictures
//! themselves are [`crate::plot`]'s.
//!
//! [`Solution::write_plots`]: super::Solution::write_plots

use super::Solution;
use crate::geometry::Pose;
use crate::plot::{LoopLine, PlotError, TrajectoryPicture, top_view, write_pictures};
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// The title of a picture of a graph that was not read from a file.
const UNNAMED: &str = "pose graph";

/// What the title of a 3D trajectory picture adds.
const TOP_VIEW: &str = " (3D: seen from above, x and y)";

impl<P> Solution<P> {
    /// Writes the job's pictures into `dir` ([`write_pictures`]).
    pub(super) fn plots<const D: usize>(&self, dir: &Path) -> Result<Vec<PathBuf>, PlotError>
    where
        P: Pose<D>,
    {
        let trajectory = self.trajectory_picture::<D>(&dir.join("trajectory.svg"))?;
        write_pictures(dir, &self.report, &trajectory)
    }

    /// The trajectory picture (to be written at `path`): the initial guess
    /// (the map, for an update that resumed from the last one) and the map;
    /// trusted edges between consecutive ids as the odometry, every other
    /// edge as a loop coloured by its final weight (1 for trusted edges).
    /// Titled with the input file's name.
    fn trajectory_picture<const D: usize>(
        &self,
        path: &Path,
    ) -> Result<TrajectoryPicture, PlotError>
    where
        P: Pose<D>,
    {
        let graph = self
            .solved_graph::<D>()
            .map_err(|e| PlotError::InvalidInput {
                path: path.to_owned(),
                reason: e.to_string(),
            })?;
        let weight: HashMap<usize, f64> =
            (self.loops.iter()).map(|l| (l.index, l.weight)).collect();
        let (mut odometry, mut loops) = (Vec::new(), Vec::new());
        for (k, e) in graph.edges.iter().enumerate() {
            let (from, to) = (e.from, e.to);
            if !e.is_candidate() && graph.id(from).abs_diff(graph.id(to)) == 1 {
                odometry.push((from, to));
            } else {
                let weight = weight.get(&k).copied().unwrap_or(1.0);
                loops.push(LoopLine { from, to, weight });
            }
        }
        let mut title = (self.text.as_ref())
            .and_then(|text| text.name().file_name())
            .map_or_else(|| UNNAMED.into(), |n| n.to_string_lossy().into_owned());
        if D > 3 {
            title.push_str(TOP_VIEW);
        }
        Ok(TrajectoryPicture {
            before: top_view(self.initial.as_deref().unwrap_or(&self.poses)),
            after: top_view(&self.poses),
            odometry,
            loops,
            title,
        })
    }
}

#[cfg(test)]
mod tests {
    use crate::nalgebra::{Matrix3, Matrix6, UnitQuaternion, Vector3};
    use crate::plot::PlotError;
    use crate::{AnyPoseGraph, Error, Options, Pose, PoseGraph2, PoseGraph3, Se2, Se3};

    /// A fresh directory for one test's pictures, removed when dropped.
    fn dir(name: &str) -> tempfile::TempDir {
        tempfile::Builder::new()
            .prefix(&format!("pgo-plots-{name}-"))
            .tempdir()
            .unwrap()
    }

    fn read(path: &std::path::Path) -> String {
        let svg = std::fs::read_to_string(path).unwrap();
        assert!(svg.starts_with("<svg") && svg.trim_end().ends_with("</svg>"));
        svg
    }

    #[test]
    fn plot_the_bundled_sample_as_the_command_line_does() {
        let sample = concat!(env!("CARGO_MANIFEST_DIR"), "/g2o_samples/grid2d.g2o");
        let solution = AnyPoseGraph::read_g2o(sample)
            .unwrap()
            .optimize(&Options::default())
            .unwrap();
        let root = dir("sample");
        let dir = root.path().join("made");
        let written = solution.write_plots(&dir).unwrap();
        let names: Vec<_> = (written.iter())
            .map(|p| p.strip_prefix(&dir).unwrap().to_str().unwrap())
            .collect();
        assert_eq!(names, ["counts.svg", "loops.svg", "trajectory.svg"]);
        assert!(read(&written[0]).contains("T_GV = "));
        assert!(read(&written[1]).contains("posterior ½: accepted above"));
        let trajectory = read(&written[2]);
        assert!(trajectory.contains("grid2d.g2o"));
        let accepted = solution.loops().iter().filter(|l| l.accepted).count();
        assert!(
            trajectory.contains(&format!("accepted {accepted} loops")),
            "{accepted}"
        );
    }

    #[test]
    fn a_graph_built_in_memory_gets_the_trajectory_only() {
        let mut graph = PoseGraph3::new();
        let step = Se3::new(
            UnitQuaternion::from_euler_angles(0.0, 0.0, 0.3),
            Vector3::new(1.0, 0.0, 0.1),
        );
        let mut pose = Se3::identity();
        for k in 0..5 {
            graph.add_pose(k, pose).unwrap();
            pose = pose.compose(&step);
        }
        for k in 1..5 {
            graph.add_edge(k - 1, k, step, Matrix6::identity()).unwrap();
        }
        let solution = graph.optimize(&Options::default()).unwrap();
        let memory = dir("memory");
        let written = solution.write_plots(memory.path().join("made")).unwrap();
        assert_eq!(written.len(), 1);
        let svg = read(&written[0]);
        assert!(svg.contains("pose graph (3D: seen from above, x and y)"));
        assert!(svg.contains("5 poses, 4 odometry edges; accepted 0 loops, rejected 0"));
    }

    #[test]
    fn a_directory_that_cannot_be_made_is_a_write_error_naming_it() {
        let mut graph = PoseGraph2::new();
        graph.add_pose(0, Se2::new(0.0, 0.0, 0.0)).unwrap();
        graph.add_pose(1, Se2::new(1.0, 0.0, 0.0)).unwrap();
        let step = Se2::new(1.0, 0.0, 0.0);
        graph.add_edge(0, 1, step, Matrix3::identity()).unwrap();
        let solution = graph.optimize(&Options::default()).unwrap();
        let base = dir("file");
        let file = base.path().join("a-file");
        std::fs::write(&file, "x").unwrap();
        let err = solution.write_plots(file.join("pictures")).unwrap_err();
        assert!(matches!(err, PlotError::Write { .. }), "{err}");
        assert!(err.to_string().contains("a-file"), "{err}");
        // The bindings see it as the library's write error.
        let err = Error::from(err);
        assert!(err.io_error().is_some(), "{err}");
        assert_eq!(std::fs::read_to_string(&file).unwrap(), "x");
    }
}
