//! Pictures for the user, as SVG files (the paper's Fig. 1 and Fig. 6), with
//! the `plot` feature:
//!
//! * [`plot_counts`]: the density histogram of the normalised inlier counts
//!   with the two weighted mixture components, their sum and `T_GV` marked;
//! * [`plot_trajectory`]: the trajectory before and after optimisation, side
//!   by side, with the loop closures coloured by their final weight;
//! * [`plot_loops`]: every candidate's innovation and prior against the
//!   loop model's densities and the line where its posterior is ½.
//!
//! [`Solution::write_plots`](crate::Solution::write_plots) draws all three of
//! a job (what `pgo optimize --plot DIR` writes); the functions here draw one
//! picture from its numbers.
//!
//! All are drawn with plotters' SVG backend into a string and then written
//! atomically ([`crate::output::write_atomically`]), so a reader never sees
//! half a picture. Text is emitted as SVG `<text>` elements and rendered by
//! the viewer with its own fonts: no font files are needed to draw.
//!
//! A trajectory of any size gives a file of bounded size: the odometry is
//! decimated to about [`MAX_POLYLINE_POINTS`] points and at most
//! [`MAX_LOOP_SEGMENTS`] loops are drawn, sampled evenly; the caption says
//! when either happened.

mod counts;
mod loops;
mod pictures;
mod trajectory;

pub use counts::plot_counts;
pub use loops::{LoopPoint, loop_points, plot_loops};
pub(crate) use pictures::{TrajectoryPicture, write_pictures};
pub use trajectory::{LoopLine, plot_trajectory, top_view};

use crate::error::Error;
use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;
use std::io::Write;
use std::path::{Path, PathBuf};

/// The odometry of a trajectory picture is decimated to about this many
/// points (every k-th pose, keeping the first and last pose of every chain).
pub const MAX_POLYLINE_POINTS: usize = 20_000;

/// At most this many loop closures are drawn per panel, sampled evenly from
/// the input when there are more: beyond a few thousand the lines bury the
/// trajectory (city10000 has 10,688 loops) and say nothing more.
pub const MAX_LOOP_SEGMENTS: usize = 3_000;

/// The histogram of [`plot_counts`] has this many bins over `(0, 1]`, or one
/// bin per integer count when the largest count is smaller.
pub const HISTOGRAM_BINS: u64 = 40;

/// Font family of all text.
const FONT: &str = "sans-serif";
/// The colour of true loops, in the counts and the loop decisions pictures.
const LOOP_COLOUR: RGBColor = RGBColor(44, 160, 44);

/// Why a picture could not be made. Every variant names the file.
#[derive(Debug, thiserror::Error)]
pub enum PlotError {
    /// The file (or the directory of the pictures) could not be written.
    #[error("cannot write plot {}: {source}", path.display())]
    Write {
        /// The picture's path.
        path: PathBuf,
        /// The underlying error.
        #[source]
        source: std::io::Error,
    },
    /// plotters failed while drawing.
    #[error("cannot draw plot {}: {message}", path.display())]
    Draw {
        /// The picture's path.
        path: PathBuf,
        /// plotters' message.
        message: String,
    },
    /// The inputs do not fit together (an index beyond the poses, counts
    /// that are not the ones the fit was made from, ...).
    #[error("cannot plot {}: {reason}", path.display())]
    InvalidInput {
        /// The picture's path.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
}

/// A picture that cannot be made as the library's error, for the
/// bindings: a file that cannot be written is [`Error::Write`] (naming the
/// file, with the OS's error), anything else [`Error::Internal`] (the
/// pictures of a solution are drawn from the solution itself).
impl From<PlotError> for Error {
    fn from(error: PlotError) -> Self {
        match error {
            PlotError::Write { path, source } => Error::Write { path, source },
            other => Error::Internal(other.to_string()),
        }
    }
}

/// Errors while drawing, before they are tied to a path.
type DrawResult<T> = Result<T, Box<dyn std::error::Error>>;

/// A chart on `f64` axes: the counts picture's (`v` on x, density on y),
/// the trajectory's panels and the loop decisions picture's panels.
type Chart<'a, 'b> = ChartContext<'a, SVGBackend<'b>, Cartesian2d<RangedCoordf64, RangedCoordf64>>;

fn write_svg(path: &Path, svg: &str) -> Result<(), PlotError> {
    crate::output::write_atomically(path, |w| w.write_all(svg.as_bytes())).map_err(|source| {
        PlotError::Write {
            path: path.to_path_buf(),
            source,
        }
    })
}

fn draw_error(path: &Path, error: Box<dyn std::error::Error>) -> PlotError {
    PlotError::Draw {
        path: path.to_path_buf(),
        message: error.to_string(),
    }
}

fn invalid(path: &Path, reason: String) -> PlotError {
    PlotError::InvalidInput {
        path: path.to_path_buf(),
        reason,
    }
}

fn text_style(size: u32, colour: RGBColor) -> TextStyle<'static> {
    (FONT, size).into_font().color(&colour)
}

/// The mesh of a full-size chart: the axis descriptions (none on x when
/// `x_desc` is empty) at 17 px, tick labels at 14 px, faint bold lines and
/// no light ones.
fn draw_mesh<'a, 'b: 'a>(chart: &mut Chart<'a, 'b>, x_desc: &str, y_desc: &str) -> DrawResult<()> {
    let mut mesh = chart.configure_mesh();
    if !x_desc.is_empty() {
        mesh.x_desc(x_desc);
    }
    mesh.y_desc(y_desc)
        .axis_desc_style((FONT, 17))
        .label_style((FONT, 14))
        .light_line_style(TRANSPARENT)
        .bold_line_style(BLACK.mix(0.08))
        .draw()?;
    Ok(())
}

/// `k` indices spread evenly over `0..len` (all of them when `len ≤ k`),
/// increasing, starting at 0.
fn even_indices(len: usize, k: usize) -> Vec<usize> {
    if len <= k {
        return (0..len).collect();
    }
    (0..k)
        .map(|i| (i as u128 * len as u128 / k as u128) as usize)
        .collect()
}

#[cfg(test)]
mod tests;
