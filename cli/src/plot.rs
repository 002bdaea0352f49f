//! Pictures for the user, as SVG files (the paper's Fig. 1 and Fig. 6):
//!
//! * [`plot_counts`]: the density histogram of the normalised inlier counts
//!   with the two weighted mixture components, their sum and `T_GV` marked;
//! * [`plot_trajectory`]: the trajectory before and after optimisation, side
//!   by side, with the loop closures coloured by their final weight;
//! * [`plot_loops`]: every candidate's innovation and prior against the
//!   loop model's densities and the line where its posterior is ½.
//!
//! All are drawn with plotters' SVG backend into a string and then written
//! atomically ([`pgo::output::write_atomically`]), so a reader never sees half
//! a picture. Text is emitted as SVG `<text>` elements and rendered by the
//! viewer with its own fonts: no font files are needed to draw.
//!
//! A trajectory of any size gives a file of bounded size: the odometry is
//! decimated to about [`MAX_POLYLINE_POINTS`] points and at most
//! [`MAX_LOOP_SEGMENTS`] loops are drawn, sampled evenly; the caption says
//! when either happened.

mod job;
mod loops;

pub use job::pictures;
pub use loops::{LoopPoint, plot_loops};

use pgo::Pose;
use pgo::{Component, LogNormalMixture, Threshold, ThresholdFit};
use plotters::coord::Shift;
use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use std::collections::HashSet;
use std::error::Error;
use std::io::Write;
use std::ops::Range;
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

/// Size of the counts picture in pixels.
const COUNTS_SIZE: (u32, u32) = (1100, 680);
/// Size of the trajectory picture in pixels.
const TRAJECTORY_SIZE: (u32, u32) = (1500, 820);
/// Font family of all text.
const FONT: &str = "sans-serif";

/// Density curves are clipped at this multiple of the tallest bar, so that a
/// narrow component (e.g. one sitting on saturated counts) does not flatten
/// the histogram.
const CURVE_CLIP: f64 = 2.5;
/// Head room above the data for the legend: the y axis ends at this multiple
/// of the tallest bar or (clipped) curve.
const HEADROOM: f64 = 1.5;

const BAR_FILL: RGBColor = RGBColor(215, 215, 215);
const BAR_EDGE: RGBColor = RGBColor(150, 150, 150);
const NOT_LOOP_COLOUR: RGBColor = RGBColor(31, 119, 180);
const LOOP_COLOUR: RGBColor = RGBColor(44, 160, 44);
const SUM_COLOUR: RGBColor = RGBColor(0, 0, 0);
const THRESHOLD_COLOUR: RGBColor = RGBColor(214, 39, 40);
const DEGENERATE_COLOUR: RGBColor = RGBColor(170, 0, 0);
const ODOMETRY_COLOUR: RGBColor = RGBColor(40, 40, 40);

/// Why a picture could not be made. Every variant names the file.
#[derive(Debug, thiserror::Error)]
pub enum PlotError {
    /// The file could not be written.
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

/// Errors while drawing, before they are tied to a path.
type DrawResult<T> = Result<T, Box<dyn Error>>;

fn write_svg(path: &Path, svg: &str) -> Result<(), PlotError> {
    pgo::output::write_atomically(path, |w| w.write_all(svg.as_bytes())).map_err(|source| {
        PlotError::Write {
            path: path.to_path_buf(),
            source,
        }
    })
}

fn draw_error(path: &Path, error: Box<dyn Error>) -> PlotError {
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

// ---------------------------------------------------------------------------
// Counts
// ---------------------------------------------------------------------------

/// Writes the density histogram of the non-zero normalised inlier counts
/// `v = count / max` to `path` as SVG, with the fitted mixture of `fit` over
/// it (Fig. 1 of the paper).
///
/// * Bars: the histogram over `(0, 1]` ([`HISTOGRAM_BINS`] bins, right-closed
///   so that `v = 1` is in the last one), normalised to unit area, like the
///   mixture density, which integrates to 1 over the non-zero counts. Zero
///   counts are left out, as they are left out of the fit; the legend says
///   how many there were.
/// * Curves: the weighted components `π_k · LogNormal(v | μ_k, σ_k)`
///   ("not a loop", "true loop") and their sum, clipped at
///   2.5 times the tallest bar (the subtitle says when).
/// * A vertical line at `v_T = T_GV / max`, labelled
///   `T_GV = 123.4 (v = 0.21)`, when the densities cross.
/// * A degenerate fit is named as such in the subtitle, with the reason.
///   Without a mixture (too few counts, all equal, ...) the histogram is
///   drawn alone.
///
/// `counts` must be the counts `fit` was learned from
/// ([`pgo::learn_threshold`]); other counts give
/// [`PlotError::InvalidInput`].
pub fn plot_counts(path: &Path, counts: &[u64], fit: &ThresholdFit) -> Result<(), PlotError> {
    let histogram = CountHistogram::new(counts, fit).map_err(|reason| invalid(path, reason))?;
    let svg = render_counts(&histogram, fit).map_err(|e| draw_error(path, e))?;
    write_svg(path, &svg)
}

/// The density histogram of the non-zero normalised counts.
#[derive(Clone, Debug, PartialEq)]
struct CountHistogram {
    /// Density of each bin; bin `j` covers `(j·w, (j+1)·w]`.
    density: Vec<f64>,
    /// Bin width `w` in `v`.
    width: f64,
    /// Number of non-zero counts.
    nonzero: usize,
    /// Number of zero counts (not in the histogram).
    zeros: usize,
}

impl CountHistogram {
    fn new(counts: &[u64], fit: &ThresholdFit) -> Result<Self, String> {
        let max = counts.iter().copied().max().unwrap_or(0);
        if counts.len() != fit.total_counts || max != fit.max_count {
            return Err(format!(
                "the {} counts (largest {max}) are not the ones the fit was made from ({} counts, largest {})",
                counts.len(),
                fit.total_counts,
                fit.max_count
            ));
        }
        let bins = HISTOGRAM_BINS.min(max).max(1);
        let mut tally = vec![0_u64; bins as usize];
        let mut nonzero = 0_usize;
        for &c in counts.iter().filter(|&&c| c > 0) {
            // Right-closed bins: c/max ∈ (j/B, (j+1)/B]  ⇔  j = ⌈c·B/max⌉ − 1,
            // in integers so that every count lands where it belongs.
            let (c, b, m) = (u128::from(c), u128::from(bins), u128::from(max));
            let j = (c * b).div_ceil(m).saturating_sub(1).min(b - 1);
            tally[j as usize] += 1;
            nonzero += 1;
        }
        let width = 1.0 / bins as f64;
        let scale = if nonzero > 0 {
            1.0 / (nonzero as f64 * width)
        } else {
            0.0
        };
        Ok(CountHistogram {
            density: tally.iter().map(|&t| t as f64 * scale).collect(),
            width,
            nonzero,
            zeros: counts.len() - nonzero,
        })
    }

    fn tallest(&self) -> f64 {
        self.density.iter().copied().fold(0.0, f64::max)
    }
}

/// Where the density curves are evaluated: uniform in `v` over `(0, 1]`,
/// plus points uniform in `ln v` across ±6σ of each component, so that a
/// narrow component's peak is not missed.
fn curve_grid(mixture: &LogNormalMixture) -> Vec<f64> {
    const UNIFORM: usize = 1000;
    const PER_COMPONENT: usize = 300;
    let mut v: Vec<f64> = (1..=UNIFORM).map(|i| i as f64 / UNIFORM as f64).collect();
    for k in 0..2 {
        let (mu, sigma) = (mixture.mu[k], mixture.sigma[k]);
        for i in 0..=PER_COMPONENT {
            let z = -6.0 + 12.0 * i as f64 / PER_COMPONENT as f64;
            v.push((mu + z * sigma).exp());
        }
    }
    v.retain(|x| x.is_finite() && *x > 0.0 && *x <= 1.0);
    v.sort_by(f64::total_cmp);
    v.dedup();
    v
}

/// The three curves of a mixture: not a loop, true loop, sum.
struct Curves {
    not_loop: Vec<(f64, f64)>,
    true_loop: Vec<(f64, f64)>,
    sum: Vec<(f64, f64)>,
}

impl Curves {
    fn new(mixture: &LogNormalMixture) -> Self {
        let grid = curve_grid(mixture);
        let curve = |f: &dyn Fn(f64) -> f64| -> Vec<(f64, f64)> {
            grid.iter()
                .map(|&v| (v, f(v)))
                .filter(|(_, d)| d.is_finite())
                .collect()
        };
        Curves {
            not_loop: curve(&|v| mixture.weighted_density(Component::NotLoop, v)),
            true_loop: curve(&|v| mixture.weighted_density(Component::Loop, v)),
            sum: curve(&|v| mixture.density(v)),
        }
    }

    fn tallest(&self) -> f64 {
        self.sum
            .iter()
            .chain(&self.not_loop)
            .chain(&self.true_loop)
            .map(|p| p.1)
            .fold(0.0, f64::max)
    }
}

fn clip(points: &[(f64, f64)], top: f64) -> Vec<(f64, f64)> {
    points.iter().map(|&(v, d)| (v, d.min(top))).collect()
}

/// A chart on `f64` axes: the counts picture's (`v` on x, density on y)
/// and the loop decisions picture's panels.
type Chart<'a, 'b> = ChartContext<'a, SVGBackend<'b>, Cartesian2d<RangedCoordf64, RangedCoordf64>>;

/// The heights of the counts picture.
struct CountsScale {
    /// Where bars and curves end: the tallest of them, or the clip height.
    data_top: f64,
    /// The top of the y axis, with head room for the legend.
    y_top: f64,
    /// Whether the curves are clipped at [`CURVE_CLIP`] times the tallest
    /// bar.
    clipped: bool,
}

impl CountsScale {
    fn new(histogram: &CountHistogram, curves: Option<&Curves>) -> Self {
        let bars_top = histogram.tallest();
        let curves_top = curves.map_or(0.0, Curves::tallest);
        let (data_top, clipped) = if bars_top > 0.0 && curves_top > CURVE_CLIP * bars_top {
            (CURVE_CLIP * bars_top, true)
        } else {
            (bars_top.max(curves_top), false)
        };
        let y_top = if data_top > 0.0 {
            data_top * HEADROOM
        } else {
            1.0
        };
        CountsScale {
            data_top,
            y_top,
            clipped,
        }
    }
}

fn render_counts(histogram: &CountHistogram, fit: &ThresholdFit) -> DrawResult<String> {
    let curves = fit.mixture.as_ref().map(Curves::new);
    let scale = CountsScale::new(histogram, curves.as_ref());
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, COUNTS_SIZE).into_drawing_area();
        root.fill(&WHITE)?;
        let (header, body) = root.split_vertically(76);
        draw_counts_header(&header, fit, scale.clipped)?;
        let mut chart = draw_counts_axes(&body, scale.y_top)?;
        draw_histogram(&mut chart, histogram)?;
        if let (Some(curves), Some(m)) = (&curves, &fit.mixture) {
            draw_mixture(&mut chart, curves, m, scale.data_top)?;
        }
        if let Some(t) = &fit.threshold {
            draw_threshold(&mut chart, t, scale.data_top)?;
        }
        if histogram.nonzero == 0 {
            chart.draw_series(std::iter::once(Text::new(
                "no non-zero counts to show",
                (0.5, scale.y_top / 2.0),
                text_style(18, BLACK).pos(Pos::new(HPos::Center, VPos::Center)),
            )))?;
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperRight)
            .margin(12)
            .label_font((FONT, 14))
            .background_style(WHITE.mix(0.9))
            .border_style(BLACK.mix(0.4))
            .draw()?;
        root.present()?;
    }
    Ok(svg)
}

/// The title, and a subtitle with `T_GV` and Ashman's D, or why the fit is
/// degenerate, and whether the curves are clipped.
fn draw_counts_header(
    area: &DrawingArea<SVGBackend<'_>, Shift>,
    fit: &ThresholdFit,
    clipped: bool,
) -> DrawResult<()> {
    let title = format!(
        "Inlier counts of {} loop-closure candidates and the learned threshold",
        fit.total_counts
    );
    let (subtitle, subtitle_colour) = match (&fit.degeneracy, &fit.mixture) {
        (Some(reason), _) => (format!("Degenerate fit: {reason}"), DEGENERATE_COLOUR),
        (None, Some(m)) => (
            match &fit.threshold {
                Some(t) => format!(
                    "Candidates with fewer than T_GV = {:.1} inliers are dropped; Ashman's D = {:.2}",
                    t.count,
                    m.ashman_d()
                ),
                None => format!("Ashman's D = {:.2}", m.ashman_d()),
            },
            BLACK,
        ),
        (None, None) => ("No mixture was fitted".to_string(), BLACK),
    };
    let subtitle = if clipped {
        format!("{subtitle} (curves clipped at {CURVE_CLIP}× the tallest bar)")
    } else {
        subtitle
    };
    area.draw_text(&title, &text_style(22, BLACK), (24, 14))?;
    area.draw_text(&subtitle, &text_style(15, subtitle_colour), (24, 48))?;
    Ok(())
}

/// The axes of the counts chart: `v` over `[0, 1]`, density up to `y_top`.
fn draw_counts_axes<'a, 'b>(
    area: &'a DrawingArea<SVGBackend<'b>, Shift>,
    y_top: f64,
) -> DrawResult<Chart<'a, 'b>> {
    let mut chart = ChartBuilder::on(area)
        .margin(24)
        .x_label_area_size(56)
        .y_label_area_size(72)
        .build_cartesian_2d(0.0..1.0, 0.0..y_top)?;
    draw_mesh(&mut chart, "normalised inlier count v = n / max", "density")?;
    Ok(chart)
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

/// The bars of the histogram (filled, then outlined), with their legend
/// entry.
fn draw_histogram(chart: &mut Chart<'_, '_>, histogram: &CountHistogram) -> DrawResult<()> {
    let label = if histogram.zeros > 0 {
        format!(
            "non-zero counts (n = {}; {} zero counts not shown)",
            histogram.nonzero, histogram.zeros
        )
    } else {
        format!("non-zero counts (n = {})", histogram.nonzero)
    };
    let w = histogram.width;
    let bars: Vec<(f64, f64, f64)> = histogram
        .density
        .iter()
        .enumerate()
        .filter(|(_, d)| **d > 0.0)
        .map(|(j, &d)| (j as f64 * w, (j + 1) as f64 * w, d))
        .collect();
    chart
        .draw_series(
            bars.iter()
                .map(|&(x0, x1, d)| Rectangle::new([(x0, 0.0), (x1, d)], BAR_FILL.filled())),
        )?
        .label(label)
        .legend(|(x, y)| Rectangle::new([(x, y - 6), (x + 18, y + 6)], BAR_FILL.filled()));
    chart.draw_series(
        bars.iter()
            .map(|&(x0, x1, d)| Rectangle::new([(x0, 0.0), (x1, d)], BAR_EDGE.stroke_width(1))),
    )?;
    Ok(())
}

/// The two weighted components, shaded so that they show where the sum
/// runs along them, and their sum, clipped at `top`, with legend entries.
fn draw_mixture(
    chart: &mut Chart<'_, '_>,
    curves: &Curves,
    m: &LogNormalMixture,
    top: f64,
) -> DrawResult<()> {
    let label = |name: &str, k: usize| {
        format!(
            "{name}: π = {:.3}, μ = {:.2}, σ = {} (ln v)",
            m.weight[k],
            m.mu[k],
            short(m.sigma[k])
        )
    };
    let components = [
        (&curves.not_loop, NOT_LOOP_COLOUR, label("not a loop", 0)),
        (&curves.true_loop, LOOP_COLOUR, label("true loop", 1)),
    ];
    for (points, colour, label) in components {
        chart
            .draw_series(
                AreaSeries::new(clip(points, top), 0.0, colour.mix(0.22))
                    .border_style(colour.stroke_width(2)),
            )?
            .label(label)
            .legend(move |(x, y)| {
                Rectangle::new([(x, y - 6), (x + 18, y + 6)], colour.mix(0.22).filled())
            });
    }
    chart
        .draw_series(LineSeries::new(
            clip(&curves.sum, top),
            SUM_COLOUR.stroke_width(1),
        ))?
        .label("mixture (sum)")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], SUM_COLOUR.stroke_width(1)));
    Ok(())
}

/// The vertical line at `v_T` up to `top`, with its legend entry, and its
/// label beside the top of the line, on the side with room.
fn draw_threshold(chart: &mut Chart<'_, '_>, t: &Threshold, top: f64) -> DrawResult<()> {
    chart
        .draw_series(LineSeries::new(
            vec![(t.normalized, 0.0), (t.normalized, top)],
            THRESHOLD_COLOUR.stroke_width(2),
        ))?
        .label(threshold_label(t.count, t.normalized))
        .legend(|(x, y)| {
            PathElement::new(
                vec![(x + 9, y - 7), (x + 9, y + 7)],
                THRESHOLD_COLOUR.stroke_width(2),
            )
        });
    let (h, dx) = if t.normalized < 0.75 {
        (HPos::Left, 0.006)
    } else {
        (HPos::Right, -0.006)
    };
    chart.draw_series(std::iter::once(Text::new(
        format!("T_GV = {:.1}", t.count),
        (t.normalized + dx, top),
        text_style(14, THRESHOLD_COLOUR).pos(Pos::new(h, VPos::Top)),
    )))?;
    Ok(())
}

/// Two decimals, or two significant digits for a small number.
fn short(x: f64) -> String {
    if x != 0.0 && x.abs() < 0.01 {
        format!("{x:.1e}")
    } else {
        format!("{x:.2}")
    }
}

/// `T_GV = 123.4 (v = 0.21)`.
fn threshold_label(count: f64, normalized: f64) -> String {
    format!("T_GV = {count:.1} (v = {normalized:.2})")
}

// ---------------------------------------------------------------------------
// Trajectory
// ---------------------------------------------------------------------------

/// A loop closure to draw in [`plot_trajectory`]: a segment between two poses
/// (indices into the position arrays), coloured by its final weight.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LoopLine {
    /// Index of the first pose.
    pub from: usize,
    /// Index of the second pose.
    pub to: usize,
    /// Final weight in `[0, 1]`: 0 = dropped / switched off, 1 = fully
    /// trusted. Values outside are clamped; NaN counts as 0.
    pub weight: f64,
}

impl LoopLine {
    fn clamped_weight(&self) -> f64 {
        if self.weight.is_nan() {
            0.0
        } else {
            self.weight.clamp(0.0, 1.0)
        }
    }

    /// Whether the loop counts as kept: weight ≥ ½.
    pub fn is_kept(&self) -> bool {
        self.clamped_weight() >= 0.5
    }
}

/// The (x, y) of every pose's position: the trajectory itself for SE(2),
/// the top view for SE(3).
pub fn top_view<P: Pose<D>, const D: usize>(poses: &[P]) -> Vec<[f64; 2]> {
    poses
        .iter()
        .map(|p| {
            let t = p.position();
            [t.x, t.y]
        })
        .collect()
}

/// Writes the trajectory before and after optimisation to `path` as SVG, in
/// two panels side by side (Fig. 6 of the paper).
///
/// * `before` and `after` are the 2-D positions of the same poses (see
///   [`top_view`]); each panel has its own range, with equal scales on x and
///   y (1 m in x is as long as 1 m in y).
/// * `odometry` pairs of pose indices are drawn as a thin dark line;
///   consecutive pairs that share a pose (`(0, 1), (1, 2), ...`) form one
///   polyline, decimated to about [`MAX_POLYLINE_POINTS`] points in all
///   (every k-th pose, keeping the ends). A circle marks the first pose.
/// * `loops` are segments coloured from red (weight 0, rejected) through
///   yellow to green (weight 1, accepted), in steps of 0.05. Before
///   optimisation loops with weight < ½ are drawn under the odometry,
///   loops with weight ≥ ½ over it, each group in increasing weight; after
///   it, the accepted loops only. At most [`MAX_LOOP_SEGMENTS`] loops are drawn, evenly sampled;
///   segments that fall on the same pixels with the same colour, or on a
///   single pixel, are drawn once or not at all. Lines are opaque: SVG
///   renderers slow down badly on tens of thousands of translucent elements.
/// * The caption gives the counts over all loops, e.g.
///   `accepted 120 loops, rejected 40` (weight ≥ ½ or not), and says when the
///   odometry or the loops were sampled. A colour bar under the panels reads
///   the weights.
///
/// Points that are not finite are left out (a polyline breaks there).
/// Indices beyond the poses, or `before` and `after` of different lengths,
/// give [`PlotError::InvalidInput`].
pub fn plot_trajectory(
    path: &Path,
    before: &[[f64; 2]],
    after: &[[f64; 2]],
    odometry: &[(usize, usize)],
    loops: &[LoopLine],
    title: &str,
) -> Result<(), PlotError> {
    if before.len() != after.len() {
        return Err(invalid(
            path,
            format!(
                "{} poses before optimisation but {} after",
                before.len(),
                after.len()
            ),
        ));
    }
    let scene = Scene::new(before.len(), odometry, loops).map_err(|r| invalid(path, r))?;
    let svg = render_trajectory(&scene, before, after, title).map_err(|e| draw_error(path, e))?;
    write_svg(path, &svg)
}

/// What a trajectory picture draws, shared by both panels.
#[derive(Clone, Debug, PartialEq)]
struct Scene {
    poses: usize,
    odometry_edges: usize,
    odometry: OdometryPlan,
    /// Loops to draw, sorted by weight (clamped), lowest first.
    loops: Vec<LoopLine>,
    kept: usize,
    dropped: usize,
}

impl Scene {
    fn new(poses: usize, odometry: &[(usize, usize)], loops: &[LoopLine]) -> Result<Self, String> {
        for (k, &(i, j)) in odometry.iter().enumerate() {
            if i >= poses || j >= poses {
                return Err(format!(
                    "odometry edge {k} ({i}, {j}) names a pose beyond the {poses} poses"
                ));
            }
        }
        for (k, l) in loops.iter().enumerate() {
            if l.from >= poses || l.to >= poses {
                return Err(format!(
                    "loop {k} ({}, {}) names a pose beyond the {poses} poses",
                    l.from, l.to
                ));
            }
        }
        let kept = loops.iter().filter(|l| l.is_kept()).count();
        let mut drawn: Vec<LoopLine> = even_indices(loops.len(), MAX_LOOP_SEGMENTS)
            .into_iter()
            .map(|k| LoopLine {
                weight: loops[k].clamped_weight(),
                ..loops[k]
            })
            .collect();
        drawn.sort_by(|a, b| a.weight.total_cmp(&b.weight));
        Ok(Scene {
            poses,
            odometry_edges: odometry.len(),
            odometry: OdometryPlan::new(odometry, MAX_POLYLINE_POINTS),
            loops: drawn,
            kept,
            dropped: loops.len() - kept,
        })
    }

    fn loops_sampled(&self) -> bool {
        self.loops.len() < self.kept + self.dropped
    }

    fn caption(&self) -> String {
        let plural = |n: usize, one: &str, many: &str| {
            if n == 1 {
                format!("{n} {one}")
            } else {
                format!("{n} {many}")
            }
        };
        let mut s = format!(
            "{}, {}; accepted {}, rejected {} (accepted: final weight ≥ ½)",
            plural(self.poses, "pose", "poses"),
            plural(self.odometry_edges, "odometry edge", "odometry edges"),
            plural(self.kept, "loop", "loops"),
            self.dropped
        );
        if self.odometry.sampled {
            s.push_str(&format!(
                "; odometry decimated to {} of {} points",
                self.odometry.drawn_points, self.odometry.total_points
            ));
        }
        if self.loops_sampled() {
            s.push_str(&format!(
                "; {} of {} loops drawn, evenly sampled",
                self.loops.len(),
                self.kept + self.dropped
            ));
        }
        s
    }
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

/// Every `stride`-th point of a polyline, always with its first and last.
fn decimate(chain: &[usize], stride: usize) -> Vec<usize> {
    if stride <= 1 || chain.len() <= 2 {
        return chain.to_vec();
    }
    let mut out: Vec<usize> = chain.iter().copied().step_by(stride).collect();
    if (chain.len() - 1) % stride != 0 {
        if let Some(&last) = chain.last() {
            out.push(last);
        }
    }
    out
}

/// The odometry as polylines of pose indices, decimated.
#[derive(Clone, Debug, PartialEq)]
struct OdometryPlan {
    chains: Vec<Vec<usize>>,
    total_points: usize,
    drawn_points: usize,
    sampled: bool,
}

impl OdometryPlan {
    fn new(pairs: &[(usize, usize)], max_points: usize) -> Self {
        let mut chains: Vec<Vec<usize>> = Vec::new();
        for &(i, j) in pairs {
            match chains.last_mut() {
                Some(chain) if chain.last() == Some(&i) => chain.push(j),
                _ => chains.push(vec![i, j]),
            }
        }
        let total_points: usize = chains.iter().map(Vec::len).sum();
        if total_points <= max_points {
            return OdometryPlan {
                chains,
                total_points,
                drawn_points: total_points,
                sampled: false,
            };
        }
        // Every chain keeps at least its two ends: with many short chains
        // (edges that do not follow each other), draw an even sample of them.
        let max_points = max_points.max(2);
        let max_chains = max_points / 2;
        if chains.len() > max_chains {
            chains = even_indices(chains.len(), max_chains)
                .into_iter()
                .map(|k| std::mem::take(&mut chains[k]))
                .collect();
        }
        // A chain of L points decimated with stride s keeps at most
        // (L − 1)/s + 2 points, so this stride keeps at most `max_points`.
        let points: usize = chains.iter().map(Vec::len).sum();
        let budget = max_points.saturating_sub(2 * chains.len()).max(1);
        let stride = points.div_ceil(budget);
        let chains: Vec<Vec<usize>> = chains.iter().map(|c| decimate(c, stride)).collect();
        let drawn_points = chains.iter().map(Vec::len).sum();
        OdometryPlan {
            chains,
            total_points,
            drawn_points,
            sampled: true,
        }
    }
}

/// The bounding box of the finite points, or `None` when there is none.
fn finite_bounds(points: &[[f64; 2]]) -> Option<([f64; 2], [f64; 2])> {
    points
        .iter()
        .filter(|p| p[0].is_finite() && p[1].is_finite())
        .fold(None, |acc, p| match acc {
            None => Some((*p, *p)),
            Some((lo, hi)) => Some((
                [lo[0].min(p[0]), lo[1].min(p[1])],
                [hi[0].max(p[0]), hi[1].max(p[1])],
            )),
        })
}

/// x and y ranges around `bounds` (with a 3 % margin on each side) for a
/// plotting area of `pixels`, with the same length per pixel on both axes.
/// No points: a 2 × 2 box around the origin; a single point (or a zero
/// extent): a 2 m box around it.
fn equal_aspect_ranges(
    bounds: Option<([f64; 2], [f64; 2])>,
    pixels: (u32, u32),
) -> (Range<f64>, Range<f64>) {
    let (lo, hi) = bounds.unwrap_or(([-1.0, -1.0], [1.0, 1.0]));
    let centre = [lo[0] / 2.0 + hi[0] / 2.0, lo[1] / 2.0 + hi[1] / 2.0];
    let extent = |k: usize| {
        let e = (hi[k] - lo[k]) * 1.06;
        // Far from the origin, keep the extent resolvable in f64.
        let resolvable = 1e-9 * (1.0 + centre[0].abs() + centre[1].abs());
        if e > 0.0 && e.is_finite() {
            e.max(resolvable)
        } else {
            2.0
        }
    };
    let (pw, ph) = (f64::from(pixels.0.max(1)), f64::from(pixels.1.max(1)));
    let per_pixel = (extent(0) / pw).max(extent(1) / ph);
    let (half_x, half_y) = (per_pixel * pw / 2.0, per_pixel * ph / 2.0);
    (
        centre[0] - half_x..centre[0] + half_x,
        centre[1] - half_y..centre[1] + half_y,
    )
}

/// The colour of a loop of weight `w`: hue from red (0) through yellow to
/// green (1).
fn weight_colour(w: f64) -> RGBColor {
    let w = if w.is_nan() { 0.0 } else { w.clamp(0.0, 1.0) };
    let c = HSLColor(w / 3.0, 0.85, 0.42).to_backend_color();
    RGBColor(c.rgb.0, c.rgb.1, c.rgb.2)
}

/// Loops are drawn in one of this many colours.
const WEIGHT_LEVELS: f64 = 20.0;

fn quantised_weight(w: f64) -> f64 {
    (w * WEIGHT_LEVELS).round() / WEIGHT_LEVELS
}

/// A drawn loop segment: its end pixels (ordered) and its colour level.
type SegmentKey = ((i32, i32), (i32, i32), u32);

fn render_trajectory(
    scene: &Scene,
    before: &[[f64; 2]],
    after: &[[f64; 2]],
    title: &str,
) -> DrawResult<String> {
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, TRAJECTORY_SIZE).into_drawing_area();
        root.fill(&WHITE)?;
        let (header, rest) = root.split_vertically(72);
        let (panels, footer) = rest.split_vertically(TRAJECTORY_SIZE.1 - 72 - 56);
        header.draw_text(title, &text_style(22, BLACK), (24, 12))?;
        header.draw_text(&scene.caption(), &text_style(15, BLACK), (24, 44))?;
        let (left, right) = panels.split_horizontally(TRAJECTORY_SIZE.0 / 2);
        draw_panel(
            &left,
            "before optimisation: every loop",
            before,
            (scene, true),
        )?;
        draw_panel(
            &right,
            "after optimisation: the accepted loops",
            after,
            (scene, false),
        )?;
        draw_key(&footer)?;
        root.present()?;
    }
    Ok(svg)
}

/// The chart of a trajectory panel: x and y in metres.
type PanelChart<'a, 'b> =
    ChartContext<'a, SVGBackend<'b>, Cartesian2d<RangedCoordf64, RangedCoordf64>>;

/// One panel: the loops accepted (weight ≥ ½) over the odometry over the
/// loops rejected (when `rejected`; the map after optimisation is drawn
/// with the loops it holds only), the first pose circled.
fn draw_panel(
    area: &DrawingArea<SVGBackend<'_>, Shift>,
    caption: &str,
    points: &[[f64; 2]],
    (scene, rejected): (&Scene, bool),
) -> DrawResult<()> {
    let area = area.titled(caption, (FONT, 18))?;
    let mut chart = draw_panel_axes(&area, points)?;
    let at = |k: usize| -> Option<(f64, f64)> {
        let p = points.get(k)?;
        (p[0].is_finite() && p[1].is_finite()).then_some((p[0], p[1]))
    };
    let mut seen: HashSet<SegmentKey> = HashSet::new();
    let dropped = if rejected {
        loop_segments(&chart, scene, false, &at, &mut seen)
    } else {
        Vec::new()
    };
    let kept = loop_segments(&chart, scene, true, &at, &mut seen);
    chart.draw_series(dropped)?;
    chart.draw_series(
        odometry_lines(scene, &at)
            .into_iter()
            .map(|l| PathElement::new(l, ODOMETRY_COLOUR.stroke_width(1))),
    )?;
    chart.draw_series(kept)?;
    if let Some(first) = (0..points.len()).find_map(at) {
        chart.draw_series(std::iter::once(Circle::new(
            first,
            5,
            ODOMETRY_COLOUR.stroke_width(2),
        )))?;
    }
    if points.is_empty() {
        let (x, y) = (chart.x_range(), chart.y_range());
        chart.draw_series(std::iter::once(Text::new(
            "no poses",
            ((x.start + x.end) / 2.0, (y.start + y.end) / 2.0),
            text_style(18, BLACK).pos(Pos::new(HPos::Center, VPos::Center)),
        )))?;
    }
    Ok(())
}

/// The axes of a panel, around the finite `points` with equal scales on x
/// and y.
fn draw_panel_axes<'a, 'b>(
    area: &'a DrawingArea<SVGBackend<'b>, Shift>,
    points: &[[f64; 2]],
) -> DrawResult<PanelChart<'a, 'b>> {
    let mut builder = ChartBuilder::on(area);
    builder
        .margin(16)
        .x_label_area_size(44)
        .y_label_area_size(76);
    // The plotting area's size does not depend on the ranges: find it with
    // a chart that draws nothing, then choose ranges with equal scales.
    let pixels = builder
        .build_cartesian_2d(0.0..1.0, 0.0..1.0)?
        .plotting_area()
        .dim_in_pixel();
    let (x_range, y_range) = equal_aspect_ranges(finite_bounds(points), pixels);
    let mut chart = builder.build_cartesian_2d(x_range, y_range)?;
    chart
        .configure_mesh()
        .x_desc("x [m]")
        .y_desc("y [m]")
        .axis_desc_style((FONT, 15))
        .label_style((FONT, 13))
        .light_line_style(TRANSPARENT)
        .bold_line_style(BLACK.mix(0.08))
        .draw()?;
    Ok(chart)
}

/// The segments of the loops that are `kept` (weight ≥ ½) or not, in the
/// scene's order, coloured by weight; a segment on a single pixel, or on
/// the pixels and colour of one already in `seen`, is left out. `at` gives
/// a pose's finite position.
fn loop_segments(
    chart: &PanelChart<'_, '_>,
    scene: &Scene,
    kept: bool,
    at: &impl Fn(usize) -> Option<(f64, f64)>,
    seen: &mut HashSet<SegmentKey>,
) -> Vec<PathElement<(f64, f64)>> {
    scene
        .loops
        .iter()
        .filter(|l| (l.weight >= 0.5) == kept)
        .filter_map(|l| {
            let (a, b) = (at(l.from)?, at(l.to)?);
            let w = quantised_weight(l.weight);
            let (pa, pb) = (chart.backend_coord(&a), chart.backend_coord(&b));
            let key = (pa.min(pb), pa.max(pb), (w * WEIGHT_LEVELS) as u32);
            (pa != pb && seen.insert(key))
                .then(|| PathElement::new(vec![a, b], weight_colour(w).stroke_width(1)))
        })
        .collect()
}

/// The odometry polylines with at least two points, broken where a pose
/// has no finite position (`at` gives a pose's finite position).
fn odometry_lines(
    scene: &Scene,
    at: &impl Fn(usize) -> Option<(f64, f64)>,
) -> Vec<Vec<(f64, f64)>> {
    let mut lines: Vec<Vec<(f64, f64)>> = Vec::new();
    for chain in &scene.odometry.chains {
        let mut line = Vec::new();
        for &k in chain {
            match at(k) {
                Some(p) => line.push(p),
                None => lines.push(std::mem::take(&mut line)),
            }
        }
        lines.push(line);
    }
    lines.retain(|l| l.len() >= 2);
    lines
}

/// The key under the panels: odometry, first pose, and the weight colours.
fn draw_key(area: &DrawingArea<SVGBackend<'_>, Shift>) -> DrawResult<()> {
    let y = 26;
    let label = text_style(15, BLACK).pos(Pos::new(HPos::Left, VPos::Center));
    area.draw(&PathElement::new(
        vec![(40, y), (80, y)],
        ODOMETRY_COLOUR.stroke_width(1),
    ))?;
    area.draw_text("odometry", &label, (88, y))?;
    area.draw(&Circle::new((200, y), 5, ODOMETRY_COLOUR.stroke_width(2)))?;
    area.draw_text("first pose", &label, (212, y))?;
    let right = text_style(15, BLACK).pos(Pos::new(HPos::Right, VPos::Center));
    let (x0, x1) = (620, 920);
    area.draw_text("loop weight 0 (rejected)", &right, (x0 - 10, y))?;
    let steps = 60;
    for s in 0..steps {
        let a = x0 + (x1 - x0) * s / steps;
        let b = x0 + (x1 - x0) * (s + 1) / steps;
        let w = (f64::from(s) + 0.5) / f64::from(steps);
        area.draw(&Rectangle::new(
            [(a, y - 8), (b, y + 8)],
            weight_colour(w).filled(),
        ))?;
    }
    area.draw(&Rectangle::new(
        [(x0, y - 8), (x1, y + 8)],
        BLACK.mix(0.5).stroke_width(1),
    ))?;
    let middle = text_style(13, BLACK).pos(Pos::new(HPos::Center, VPos::Top));
    area.draw_text("½", &middle, ((x0 + x1) / 2, y + 10))?;
    area.draw_text("1 (accepted)", &label, (x1 + 10, y))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use pgo::nalgebra::{UnitQuaternion, Vector3};
    use pgo::{Degeneracy, MixtureOptions, learn_threshold};
    use pgo::{Se2, Se3};
    use rand::SeedableRng;
    use rand::rngs::StdRng;
    use rand_distr::{Distribution, LogNormal};

    /// A fresh directory for one test's files.
    fn test_dir(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("pgo-plot-{}-{name}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    /// Text as plotters' SVG backend writes it.
    fn escaped(text: &str) -> String {
        text.replace('&', "&amp;")
            .replace('<', "&lt;")
            .replace('>', "&gt;")
            .replace('"', "&quot;")
            .replace('\'', "&apos;")
    }

    fn read_svg(path: &Path) -> String {
        let svg = std::fs::read_to_string(path).unwrap();
        assert!(svg.starts_with("<svg"), "{}", &svg[..svg.len().min(200)]);
        assert!(svg.trim_end().ends_with("</svg>"));
        svg
    }

    /// Seeded counts from two log-normal populations (wrong candidates with
    /// ~15 inliers, true loops with ~150), plus some zeros.
    fn realistic_counts(seed: u64) -> Vec<u64> {
        let mut rng = StdRng::seed_from_u64(seed);
        let wrong = LogNormal::new(15f64.ln(), 0.45).unwrap();
        let right = LogNormal::new(150f64.ln(), 0.2).unwrap();
        let mut counts: Vec<u64> = (0..800)
            .map(|_| wrong.sample(&mut rng).round() as u64)
            .collect();
        counts.extend((0..200).map(|_| right.sample(&mut rng).round() as u64));
        counts.extend([0; 25]);
        counts
    }

    #[test]
    fn counts_plot_shows_the_fit_and_the_threshold() {
        let counts = realistic_counts(1);
        let fit = learn_threshold(&counts, &MixtureOptions::default());
        assert!(!fit.is_degenerate(), "{:?}", fit.degeneracy);
        let t = fit.threshold.clone().unwrap();
        let path = test_dir("counts").join("counts.svg");
        plot_counts(&path, &counts, &fit).unwrap();
        let svg = read_svg(&path);
        let label = threshold_label(t.count, t.normalized);
        assert!(label.starts_with("T_GV = ") && label.contains("(v = 0."));
        for text in [
            label.as_str(),
            "normalised inlier count v = n / max",
            "density",
            "not a loop",
            "true loop",
            "mixture (sum)",
            "non-zero counts (n = 1000; 25 zero counts not shown)",
        ] {
            assert!(svg.contains(&escaped(text)), "missing {text:?}");
        }
        assert!(!svg.contains("Degenerate"));
        // The threshold line is at v_T: a red vertical line.
        assert!(svg.contains("#D62728"));
    }

    #[test]
    fn a_spike_of_saturated_counts_is_clipped_and_said_so() {
        let mut counts = realistic_counts(7);
        counts.retain(|&c| c < 60);
        counts.extend([3000; 60]);
        let fit = learn_threshold(&counts, &MixtureOptions::default());
        let m = fit.mixture.clone().unwrap();
        assert!(m.sigma[1] < 0.01, "{m:?}");
        let path = test_dir("spike").join("spike.svg");
        plot_counts(&path, &counts, &fit).unwrap();
        let svg = read_svg(&path);
        assert!(svg.contains("curves clipped at 2.5× the tallest bar"));
    }

    #[test]
    fn histogram_has_unit_area_and_right_closed_integer_bins() {
        let counts = realistic_counts(2);
        let fit = learn_threshold(&counts, &MixtureOptions::default());
        let h = CountHistogram::new(&counts, &fit).unwrap();
        assert_eq!(h.density.len(), HISTOGRAM_BINS as usize);
        let area: f64 = h.density.iter().map(|d| d * h.width).sum();
        assert!((area - 1.0).abs() < 1e-12, "{area}");
        assert_eq!((h.nonzero, h.zeros), (1000, 25));
        // Few distinct counts: one bin per count, v = 1 in the last bin.
        let counts = [1, 2, 2, 3, 5, 5, 5, 0];
        let fit = learn_threshold(&counts, &MixtureOptions::default());
        let h = CountHistogram::new(&counts, &fit).unwrap();
        let tallies: Vec<f64> = h.density.iter().map(|d| d * h.width * 7.0).collect();
        let want = [1.0, 2.0, 1.0, 0.0, 3.0];
        assert!(
            tallies.iter().zip(want).all(|(a, b)| (a - b).abs() < 1e-12),
            "{tallies:?}"
        );
        // The mixture's curves integrate like the bars.
        let fit = learn_threshold(&realistic_counts(3), &MixtureOptions::default());
        let m = fit.mixture.unwrap();
        let steps = 200_000;
        let integral: f64 = (0..steps)
            .map(|i| (i as f64 + 0.5) / steps as f64)
            .map(|v| m.density(v) / steps as f64)
            .sum();
        assert!((integral - 1.0).abs() < 0.01, "{integral}");
    }

    #[test]
    fn degenerate_fits_say_why() {
        let dir = test_dir("degenerate");
        // A mixture, but judged degenerate: the threshold is still drawn.
        let counts = realistic_counts(4);
        let picky = MixtureOptions {
            min_ashman_d: 1e6,
            ..Default::default()
        };
        let fit = learn_threshold(&counts, &picky);
        let reason = fit.degeneracy.clone().unwrap();
        assert!(matches!(reason, Degeneracy::Overlapping { .. }));
        let path = dir.join("overlapping.svg");
        plot_counts(&path, &counts, &fit).unwrap();
        let svg = read_svg(&path);
        assert!(svg.contains(&escaped(&format!("Degenerate fit: {reason}"))));
        let t = fit.threshold.unwrap();
        assert!(svg.contains(&escaped(&threshold_label(t.count, t.normalized))));

        // No mixture at all: the histogram alone.
        let counts = vec![12; 30];
        let fit = learn_threshold(&counts, &MixtureOptions::default());
        assert!(fit.mixture.is_none());
        let path = dir.join("all-equal.svg");
        plot_counts(&path, &counts, &fit).unwrap();
        let svg = read_svg(&path);
        let reason = fit.degeneracy.unwrap().to_string();
        assert!(svg.contains(&escaped(&reason)), "{reason}");
        assert!(svg.contains("non-zero counts (n = 30)"));
        assert!(!svg.contains("T_GV"));
    }

    #[test]
    fn empty_and_zero_counts_plot_without_panicking() {
        let dir = test_dir("empty-counts");
        for (name, counts) in [
            ("none", vec![]),
            ("zeros", vec![0, 0, 0]),
            ("few", vec![3, 9]),
            ("one", vec![u64::MAX]),
        ] {
            let fit = learn_threshold(&counts, &MixtureOptions::default());
            let path = dir.join(format!("{name}.svg"));
            plot_counts(&path, &counts, &fit).unwrap();
            let svg = read_svg(&path);
            let reason = fit.degeneracy.unwrap().to_string();
            assert!(svg.contains(&escaped(&reason)), "{name}: {reason}");
        }
        let svg = read_svg(&dir.join("zeros.svg"));
        assert!(svg.contains("no non-zero counts to show"));
        assert!(svg.contains("3 zero counts not shown"));
    }

    #[test]
    fn counts_that_are_not_the_fits_are_refused() {
        let counts = realistic_counts(5);
        let fit = learn_threshold(&counts, &MixtureOptions::default());
        let path = test_dir("mismatch").join("counts.svg");
        let err = plot_counts(&path, &counts[1..], &fit).unwrap_err();
        assert!(matches!(err, PlotError::InvalidInput { .. }), "{err}");
        assert!(err.to_string().contains(&path.display().to_string()));
        assert!(!path.exists());
    }

    #[test]
    fn unwritable_paths_name_the_file() {
        let dir = test_dir("unwritable");
        let path = dir.join("no-such-directory").join("plot.svg");
        let counts = realistic_counts(6);
        let fit = learn_threshold(&counts, &MixtureOptions::default());
        let err = plot_counts(&path, &counts, &fit).unwrap_err();
        assert!(matches!(err, PlotError::Write { .. }), "{err}");
        assert!(
            err.to_string().contains(&path.display().to_string()),
            "{err}"
        );
        let err = plot_trajectory(&path, &[], &[], &[], &[], "t").unwrap_err();
        assert!(matches!(err, PlotError::Write { .. }), "{err}");
        assert!(
            err.to_string().contains(&path.display().to_string()),
            "{err}"
        );
    }

    /// A square loop driven twice, with drift before optimisation.
    fn square_loop(n: usize) -> (Vec<[f64; 2]>, Vec<[f64; 2]>) {
        let after: Vec<[f64; 2]> = (0..n)
            .map(|k| {
                let s = (k % (n / 2)) as f64 / (n / 2) as f64 * 4.0;
                let (side, t) = (s.floor(), s.fract() * 10.0);
                match side as u32 {
                    0 => [t, 0.0],
                    1 => [10.0, t],
                    2 => [10.0 - t, 10.0],
                    _ => [0.0, 10.0 - t],
                }
            })
            .collect();
        let before = after
            .iter()
            .enumerate()
            .map(|(k, p)| {
                let drift = k as f64 / n as f64;
                let (c, s) = ((0.3 * drift).cos(), (0.3 * drift).sin());
                [c * p[0] - s * p[1] + 2.0 * drift, s * p[0] + c * p[1]]
            })
            .collect();
        (before, after)
    }

    #[test]
    fn trajectory_plot_has_both_panels_the_counts_and_kept_loops_on_top() {
        let n = 200;
        let (before, after) = square_loop(n);
        let odometry: Vec<(usize, usize)> = (1..n).map(|k| (k - 1, k)).collect();
        let loops = vec![
            LoopLine {
                from: 105,
                to: 5,
                weight: 1.0,
            },
            LoopLine {
                from: 130,
                to: 30,
                weight: 0.9,
            },
            LoopLine {
                from: 160,
                to: 60,
                weight: 0.5,
            },
            LoopLine {
                from: 150,
                to: 20,
                weight: 0.0,
            },
            LoopLine {
                from: 190,
                to: 40,
                weight: 0.2,
            },
        ];
        let path = test_dir("trajectory").join("trajectory.svg");
        plot_trajectory(&path, &before, &after, &odometry, &loops, "A square, twice").unwrap();
        let svg = read_svg(&path);
        for text in [
            "A square, twice",
            "before optimisation",
            "after optimisation",
            "200 poses, 199 odometry edges; accepted 3 loops, rejected 2",
            "loop weight 0 (rejected)",
            "1 (accepted)",
            "x [m]",
            "y [m]",
        ] {
            assert!(svg.contains(text), "missing {text:?}");
        }
        assert!(!svg.contains("sampled") && !svg.contains("decimated"));
        // Per panel: red (weight 0) is drawn before the odometry, green
        // (weight 1) after it.
        let red = format!("stroke=\"{}\"", svg_colour(weight_colour(0.0)));
        let green = format!("stroke=\"{}\"", svg_colour(weight_colour(1.0)));
        let odometry_line = format!("stroke=\"{}\"", svg_colour(ODOMETRY_COLOUR));
        let middle = svg.find("after optimisation").unwrap();
        let (first, second) = svg.split_at(middle);
        let (r, o, g) = (
            first.find(&red).unwrap(),
            first.find(&odometry_line).unwrap(),
            first.find(&green).unwrap(),
        );
        assert!(r < o && o < g, "{r} {o} {g}");
        // After optimisation the accepted loops join poses at the same
        // place: zero-length segments are not drawn. The rejected ones are
        // left out of the map after optimisation.
        assert!(!second.contains(&green));
        assert!(!second.contains(&red));
    }

    fn svg_colour(c: RGBColor) -> String {
        format!("#{:02X}{:02X}{:02X}", c.0, c.1, c.2)
    }

    #[test]
    fn loop_colours_run_from_red_to_green() {
        let red = weight_colour(0.0);
        let green = weight_colour(1.0);
        assert!(red.0 > 150 && red.1 < 60 && red.2 < 60, "{red:?}");
        assert!(green.1 > 150 && green.0 < 60 && green.2 < 60, "{green:?}");
        assert_eq!(weight_colour(f64::NAN), red);
        assert_eq!(weight_colour(7.0), green);
        let kept = |w| {
            LoopLine {
                from: 0,
                to: 1,
                weight: w,
            }
            .is_kept()
        };
        assert!(kept(0.5) && kept(2.0) && !kept(0.49) && !kept(f64::NAN));
    }

    #[test]
    fn degenerate_trajectories_plot_without_panicking() {
        let dir = test_dir("degenerate-trajectory");
        let path = dir.join("empty.svg");
        plot_trajectory(&path, &[], &[], &[], &[], "nothing").unwrap();
        let svg = read_svg(&path);
        assert!(svg.contains("no poses") && svg.contains("accepted 0 loops, rejected 0"));

        let path = dir.join("single.svg");
        plot_trajectory(&path, &[[3.0, 4.0]], &[[3.0, 4.0]], &[], &[], "one").unwrap();
        assert!(read_svg(&path).contains("1 pose, 0 odometry edges"));

        // Non-finite positions are left out; the rest is drawn.
        let before = [
            [0.0, 0.0],
            [f64::NAN, 1.0],
            [2.0, 0.0],
            [3.0, f64::INFINITY],
        ];
        let after = [[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [3.0, 0.0]];
        let odometry = [(0, 1), (1, 2), (2, 3)];
        let loops = [LoopLine {
            from: 3,
            to: 0,
            weight: f64::NAN,
        }];
        let path = dir.join("nan.svg");
        plot_trajectory(&path, &before, &after, &odometry, &loops, "nan").unwrap();
        assert!(read_svg(&path).contains("accepted 0 loops, rejected 1"));
        // A straight line: zero extent in y.
        assert!(!read_svg(&path).contains("NaN"));

        // Coordinates at the ends of f64.
        let huge = [[-1e308, 0.0], [1e308, -1e308], [f64::MAX, f64::MIN]];
        let path = dir.join("huge.svg");
        plot_trajectory(&path, &huge, &huge, &[(0, 1), (1, 2)], &[], "huge").unwrap();
        read_svg(&path);
    }

    #[test]
    fn bad_trajectory_inputs_are_clear_errors() {
        let dir = test_dir("bad-trajectory");
        let path = dir.join("bad.svg");
        let p = [[0.0, 0.0], [1.0, 0.0]];
        let err = plot_trajectory(&path, &p, &p[..1], &[], &[], "t").unwrap_err();
        assert!(
            err.to_string()
                .contains("2 poses before optimisation but 1 after"),
            "{err}"
        );
        let err = plot_trajectory(&path, &p, &p, &[(0, 2)], &[], "t").unwrap_err();
        assert!(err.to_string().contains("odometry edge 0 (0, 2)"), "{err}");
        let l = LoopLine {
            from: 1,
            to: 5,
            weight: 1.0,
        };
        let err = plot_trajectory(&path, &p, &p, &[(0, 1)], &[l], "t").unwrap_err();
        assert!(matches!(err, PlotError::InvalidInput { .. }));
        assert!(
            err.to_string().contains(&path.display().to_string()),
            "{err}"
        );
        assert!(err.to_string().contains("loop 0 (1, 5)"), "{err}");
        assert!(!path.exists());
    }

    #[test]
    fn decimation_keeps_the_ends() {
        let chain: Vec<usize> = (0..1001).collect();
        for stride in [1, 2, 3, 7, 10, 999, 1000, 5000] {
            let d = decimate(&chain, stride);
            assert_eq!(d.first(), Some(&0), "stride {stride}");
            assert_eq!(d.last(), Some(&1000), "stride {stride}");
            assert!(d.windows(2).all(|w| w[0] < w[1]));
            assert!(d.len() <= 1000 / stride + 2, "stride {stride}: {}", d.len());
        }
        assert_eq!(decimate(&[4, 5], 10), vec![4, 5]);
        assert_eq!(decimate(&[], 10), Vec::<usize>::new());

        // Odometry of 10⁵ poses in two sessions.
        let mut pairs: Vec<(usize, usize)> = (1..60_000).map(|k| (k - 1, k)).collect();
        pairs.extend((60_001..100_000).map(|k| (k - 1, k)));
        let plan = OdometryPlan::new(&pairs, MAX_POLYLINE_POINTS);
        assert!(plan.sampled && plan.chains.len() == 2);
        assert!(
            plan.drawn_points <= MAX_POLYLINE_POINTS + 2,
            "{}",
            plan.drawn_points
        );
        assert_eq!(
            (plan.chains[0][0], plan.chains[0].last()),
            (0, Some(&59_999))
        );
        assert_eq!(
            (plan.chains[1][0], plan.chains[1].last()),
            (60_000, Some(&99_999))
        );
        // Many disconnected edges are sampled evenly instead.
        let pairs: Vec<(usize, usize)> = (0..50_000).map(|k| (2 * k, 2 * k + 1)).collect();
        let plan = OdometryPlan::new(&pairs, MAX_POLYLINE_POINTS);
        assert!(plan.sampled && plan.drawn_points <= MAX_POLYLINE_POINTS);
        assert!(plan.drawn_points >= MAX_POLYLINE_POINTS / 2);
        assert_eq!(plan.chains[0], vec![0, 1]);
        // Small odometry is drawn as given.
        let plan = OdometryPlan::new(&[(0, 1), (1, 2), (5, 6)], 100);
        assert_eq!(plan.chains, vec![vec![0, 1, 2], vec![5, 6]]);
        assert!(!plan.sampled);

        assert_eq!(even_indices(10, 3), vec![0, 3, 6]);
        assert_eq!(even_indices(3, 10), vec![0, 1, 2]);
    }

    #[test]
    fn ranges_have_equal_scales() {
        for (bounds, pixels) in [
            (Some(([0.0, 0.0], [100.0, 10.0])), (600, 500)),
            (Some(([-5.0, 3.0], [-4.0, 300.0])), (600, 500)),
            (Some(([1e6, 1e6], [1e6, 1e6])), (400, 700)),
            (None, (300, 300)),
            (Some(([0.0, 0.0], [1.0, 1.0])), (0, 0)),
        ] {
            let (x, y) = equal_aspect_ranges(bounds, pixels);
            let (pw, ph) = (f64::from(pixels.0.max(1)), f64::from(pixels.1.max(1)));
            let (sx, sy) = ((x.end - x.start) / pw, (y.end - y.start) / ph);
            assert!(sx > 0.0 && (sx - sy).abs() <= 1e-12 * sx, "{x:?} {y:?}");
            if let Some((lo, hi)) = bounds {
                assert!(x.start <= lo[0] && x.end >= hi[0] && y.start <= lo[1] && y.end >= hi[1]);
            }
        }
        // The panels' plotting areas get equal scales too.
        let (before, after) = square_loop(100);
        let path = test_dir("aspect").join("aspect.svg");
        plot_trajectory(&path, &before, &after, &[], &[], "aspect").unwrap();
    }

    #[test]
    fn large_trajectories_are_sampled_and_stay_small() {
        let n = 100_000;
        let after: Vec<[f64; 2]> = (0..n)
            .map(|k| {
                let a = k as f64 * 1e-3;
                [50.0 * a.cos() + 0.01 * k as f64, 30.0 * a.sin()]
            })
            .collect();
        let before: Vec<[f64; 2]> = after.iter().map(|p| [p[0] * 1.1, p[1] + 5.0]).collect();
        let odometry: Vec<(usize, usize)> = (1..n).map(|k| (k - 1, k)).collect();
        let loops: Vec<LoopLine> = (0..50_000)
            .map(|k| LoopLine {
                from: (k * 7919) % n,
                to: (k * 104_729) % n,
                weight: if k % 4 == 0 { 0.0 } else { 1.0 },
            })
            .collect();
        let path = test_dir("large").join("large.svg");
        let start = std::time::Instant::now();
        plot_trajectory(&path, &before, &after, &odometry, &loops, "large").unwrap();
        let elapsed = start.elapsed();
        let svg = read_svg(&path);
        assert!(svg.contains("accepted 37500 loops, rejected 12500"));
        assert!(svg.contains("odometry decimated to"));
        assert!(svg.contains(&format!(
            "{MAX_LOOP_SEGMENTS} of 50000 loops drawn, evenly sampled"
        )));
        assert!(svg.len() < 8 << 20, "{} bytes", svg.len());
        assert!(elapsed.as_secs_f64() < 20.0, "{elapsed:?}");
    }

    #[test]
    fn top_view_takes_x_and_y() {
        let planar = [Se2::new(1.0, 2.0, 0.3), Se2::new(-4.0, 0.5, -1.0)];
        assert_eq!(top_view(&planar), vec![[1.0, 2.0], [-4.0, 0.5]]);
        let spatial = [Se3::new(
            UnitQuaternion::from_euler_angles(0.1, 0.2, 0.3),
            Vector3::new(7.0, -8.0, 9.0),
        )];
        assert_eq!(top_view(&spatial), vec![[7.0, -8.0]]);
        assert!(top_view::<Se2, 3>(&[]).is_empty());
    }
}
