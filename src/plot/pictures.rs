//! The pictures of one job ([`crate::Solution::write_plots`], `pgo
//! optimize --plot DIR`): the counts with the gate's fit, the loop
//! decisions under the loop model, and the trajectory before and after.

use super::{LoopLine, PlotError, loop_points, plot_counts, plot_loops, plot_trajectory};
use crate::report::Report;
use std::path::{Path, PathBuf};

/// What the trajectory picture of a job draws ([`plot_trajectory`]'s
/// arguments), gathered from the solution by its owner.
#[derive(Clone, Debug, Default)]
pub(crate) struct TrajectoryPicture {
    /// The top view of the initial guess.
    pub before: Vec<[f64; 2]>,
    /// The top view of the map.
    pub after: Vec<[f64; 2]>,
    /// Trusted edges between consecutive ids, as pose indices.
    pub odometry: Vec<(usize, usize)>,
    /// Every other edge, with its final weight (1 for trusted edges).
    pub loops: Vec<LoopLine>,
    /// The picture's title.
    pub title: String,
}

/// Writes `counts.svg` (when the job's `report` has counts and a gate
/// fit), `loops.svg` (when EM's loop model decided) and `trajectory.svg`
/// (of `trajectory`) into `dir`, made if missing; returns the paths
/// written, in that order.
pub(crate) fn write_pictures(
    dir: &Path,
    report: &Report,
    trajectory: &TrajectoryPicture,
) -> Result<Vec<PathBuf>, PlotError> {
    std::fs::create_dir_all(dir).map_err(|source| PlotError::Write {
        path: dir.to_owned(),
        source,
    })?;
    let mut written = Vec::new();
    let counts: Vec<u64> = report.loops.iter().filter_map(|l| l.inliers).collect();
    if let (false, Some(fit)) = (counts.is_empty(), &report.gate.fit) {
        let path = dir.join("counts.svg");
        plot_counts(&path, &counts, fit)?;
        written.push(path);
    }
    if let Some(model) = &report.robust.model {
        let path = dir.join("loops.svg");
        let points = loop_points(report);
        plot_loops(&path, &points, report.loops.len() - points.len(), model)?;
        written.push(path);
    }
    let path = dir.join("trajectory.svg");
    let t = trajectory;
    plot_trajectory(&path, &t.before, &t.after, &t.odometry, &t.loops, &t.title)?;
    written.push(path);
    Ok(written)
}
