//! The trajectory picture: the poses before and after optimisation, side
//! by side, with the loop closures coloured by their final weight (the
//! paper's Fig. 6).

use super::{
    Chart, DrawResult, FONT, MAX_LOOP_SEGMENTS, MAX_POLYLINE_POINTS, PlotError, draw_error,
    even_indices, invalid, text_style, write_svg,
};
use crate::geometry::Pose;
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use std::collections::HashSet;
use std::ops::Range;
use std::path::Path;

/// Size of the trajectory picture in pixels.
const TRAJECTORY_SIZE: (u32, u32) = (1500, 820);
/// The colour of the odometry.
pub(super) const ODOMETRY_COLOUR: RGBColor = RGBColor(40, 40, 40);

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

/// Every `stride`-th point of a polyline, always with its first and last.
pub(super) fn decimate(chain: &[usize], stride: usize) -> Vec<usize> {
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
pub(super) struct OdometryPlan {
    pub(super) chains: Vec<Vec<usize>>,
    pub(super) total_points: usize,
    pub(super) drawn_points: usize,
    pub(super) sampled: bool,
}

impl OdometryPlan {
    pub(super) fn new(pairs: &[(usize, usize)], max_points: usize) -> Self {
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
pub(super) fn equal_aspect_ranges(
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
pub(super) fn weight_colour(w: f64) -> RGBColor {
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
) -> DrawResult<Chart<'a, 'b>> {
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
    chart: &Chart<'_, '_>,
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
