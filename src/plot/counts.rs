//! The counts picture: the density histogram of the normalised inlier
//! counts with the gate's mixture and `T_GV` (the paper's Fig. 1).

use super::{
    Chart, DrawResult, FONT, HISTOGRAM_BINS, LOOP_COLOUR, PlotError, draw_error, draw_mesh,
    invalid, text_style, write_svg,
};
use crate::gate::{Component, LogNormalMixture, Threshold, ThresholdFit};
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use std::path::Path;

/// Size of the counts picture in pixels.
const COUNTS_SIZE: (u32, u32) = (1100, 680);

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
const SUM_COLOUR: RGBColor = RGBColor(0, 0, 0);
const THRESHOLD_COLOUR: RGBColor = RGBColor(214, 39, 40);
const DEGENERATE_COLOUR: RGBColor = RGBColor(170, 0, 0);

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
/// ([`crate::learn_threshold`]); other counts give
/// [`PlotError::InvalidInput`].
pub fn plot_counts(path: &Path, counts: &[u64], fit: &ThresholdFit) -> Result<(), PlotError> {
    let histogram = CountHistogram::new(counts, fit).map_err(|reason| invalid(path, reason))?;
    let svg = render_counts(&histogram, fit).map_err(|e| draw_error(path, e))?;
    write_svg(path, &svg)
}

/// The density histogram of the non-zero normalised counts.
#[derive(Clone, Debug, PartialEq)]
pub(super) struct CountHistogram {
    /// Density of each bin; bin `j` covers `(j·w, (j+1)·w]`.
    pub(super) density: Vec<f64>,
    /// Bin width `w` in `v`.
    pub(super) width: f64,
    /// Number of non-zero counts.
    pub(super) nonzero: usize,
    /// Number of zero counts (not in the histogram).
    pub(super) zeros: usize,
}

impl CountHistogram {
    pub(super) fn new(counts: &[u64], fit: &ThresholdFit) -> Result<Self, String> {
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
pub(super) fn threshold_label(count: f64, normalized: f64) -> String {
    format!("T_GV = {count:.1} (v = {normalized:.2})")
}
