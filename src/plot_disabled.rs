//! Stands in for the picture module (src/plot.rs) when pgo is built without
//! its `plot` feature: the same names, and every picture an error saying
//! so. `pipeline::run` refuses `plot` before it reads anything, so a caller
//! never waits for an optimisation whose pictures cannot be drawn.

use crate::gate::ThresholdFit;
use crate::geometry::Pose;
use crate::robust::LoopModel;
use std::path::{Path, PathBuf};

/// Why a picture was not drawn.
#[derive(Debug, thiserror::Error)]
pub enum PlotError {
    /// pgo was built without the `plot` feature.
    #[error("cannot plot {}: pgo was built without its `plot` feature", path.display())]
    Disabled {
        /// The picture's path.
        path: PathBuf,
    },
}

/// A loop closure to draw: see the `plot` feature's module.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LoopLine {
    /// Index of the first pose.
    pub from: usize,
    /// Index of the second pose.
    pub to: usize,
    /// Final weight in `[0, 1]`.
    pub weight: f64,
}

/// A candidate as the loop model saw it: see the `plot` feature's module.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LoopPoint {
    /// Its squared innovation.
    pub innovation: f64,
    /// Its prior probability of a true loop.
    pub prior: f64,
    /// Whether the final map was solved with it.
    pub accepted: bool,
}

/// Always [`PlotError::Disabled`].
pub fn plot_loops(path: &Path, _points: &[LoopPoint], _model: &LoopModel) -> Result<(), PlotError> {
    Err(PlotError::Disabled {
        path: path.to_owned(),
    })
}

/// The (x, y) of every pose's position.
pub fn top_view<P: Pose<D>, const D: usize>(poses: &[P]) -> Vec<[f64; 2]> {
    poses
        .iter()
        .map(|p| {
            let t = p.position();
            [t.x, t.y]
        })
        .collect()
}

/// Always [`PlotError::Disabled`].
pub fn plot_counts(path: &Path, _counts: &[u64], _fit: &ThresholdFit) -> Result<(), PlotError> {
    Err(PlotError::Disabled {
        path: path.to_owned(),
    })
}

/// Always [`PlotError::Disabled`].
pub fn plot_trajectory(
    path: &Path,
    _before: &[[f64; 2]],
    _after: &[[f64; 2]],
    _odometry: &[(usize, usize)],
    _loops: &[LoopLine],
    _title: &str,
) -> Result<(), PlotError> {
    Err(PlotError::Disabled {
        path: path.to_owned(),
    })
}
