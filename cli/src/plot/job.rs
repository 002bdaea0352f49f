//! The pictures of one `pgo optimize` run (`--plot DIR`): the counts with
//! the gate's fit, the loop decisions under the loop model, and the
//! trajectory before and after.

use super::{LoopLine, LoopPoint, PlotError, plot_counts, plot_loops, plot_trajectory, top_view};
use pgo::report::Report;
use pgo::{AnyPoseGraph, AnySolution, GraphPose, PoseGraph, Solution, VertexId};
use std::collections::HashMap;
use std::path::Path;

/// Writes `counts.svg` (when there are counts), `loops.svg` (when EM's
/// loop model decided) and `trajectory.svg` of the job that optimised
/// `graph` (read from `input`) into `solution`, into `dir`, and lists them
/// in the report.
pub fn pictures(
    dir: &Path,
    graph: &AnyPoseGraph,
    solution: &AnySolution,
    input: &Path,
    report: &mut Report,
) -> Result<(), PlotError> {
    std::fs::create_dir_all(dir).map_err(|source| PlotError::Write {
        path: dir.to_owned(),
        source,
    })?;
    let counts: Vec<u64> = report.loops.iter().filter_map(|l| l.inliers).collect();
    if let (false, Some(fit)) = (counts.is_empty(), &report.gate.fit) {
        let path = dir.join("counts.svg");
        plot_counts(&path, &counts, fit)?;
        report.plots.push(path.display().to_string());
    }
    if let Some(model) = &report.robust.model {
        let path = dir.join("loops.svg");
        let points = loop_points(report);
        plot_loops(&path, &points, report.loops.len() - points.len(), model)?;
        report.plots.push(path.display().to_string());
    }
    let mut title = input
        .file_name()
        .map_or_else(|| "pose graph".into(), |n| n.to_string_lossy().into_owned());
    if graph.dimension() == 3 {
        title.push_str(" (3D: seen from above, x and y)");
    }
    let path = dir.join("trajectory.svg");
    match (graph, solution) {
        (AnyPoseGraph::Planar(g), AnySolution::Planar(s)) => trajectory(&path, g, s, &title)?,
        (AnyPoseGraph::Spatial(g), AnySolution::Spatial(s)) => trajectory(&path, g, s, &title)?,
        _ => {
            return Err(PlotError::InvalidInput {
                path,
                reason: "the solution is not of the graph's dimension".into(),
            });
        }
    }
    report.plots.push(path.display().to_string());
    Ok(())
}

/// The candidates the loop model weighed, for its picture: those with an
/// innovation and a prior.
pub fn loop_points(report: &Report) -> Vec<LoopPoint> {
    (report.loops.iter())
        .filter_map(|l| {
            Some(LoopPoint {
                innovation: l.innovation?,
                prior: l.prior?,
                accepted: l.accepted,
            })
        })
        .collect()
}

/// The trajectory picture: the initial guess and the map, odometry (trusted
/// edges between consecutive ids) as lines, every other edge as a loop
/// coloured by its final weight (1 for trusted edges).
fn trajectory<P: GraphPose<D>, const D: usize>(
    path: &Path,
    graph: &PoseGraph<P, D>,
    solution: &Solution<P>,
    title: &str,
) -> Result<(), PlotError> {
    let index: HashMap<VertexId, usize> = (graph.ids().iter().enumerate())
        .map(|(k, &id)| (id, k))
        .collect();
    let weight: HashMap<usize, f64> = (solution.loops().iter())
        .map(|l| (l.index, l.weight))
        .collect();
    let (mut odometry, mut loops) = (Vec::new(), Vec::new());
    for (k, e) in graph.edges().enumerate() {
        let (from, to) = (index[&e.from], index[&e.to]);
        if !e.loop_candidate && e.from.abs_diff(e.to) == 1 {
            odometry.push((from, to));
        } else {
            let weight = weight.get(&k).copied().unwrap_or(1.0);
            loops.push(LoopLine { from, to, weight });
        }
    }
    let after: Vec<P> = solution.poses().map(|(_, p)| *p).collect();
    let before: Vec<P> = match solution.initial_guess() {
        Some(initial) => initial.map(|(_, p)| *p).collect(),
        None => after.clone(),
    };
    let (before, after) = (top_view(&before), top_view(&after));
    plot_trajectory(path, &before, &after, &odometry, &loops, title)
}
