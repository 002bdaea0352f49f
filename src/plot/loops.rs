//! The loop decisions picture: every candidate's two pieces of evidence
//! against the loop model that weighed them (docs/method.md §4).

use super::{
    Chart, DrawResult, FONT, LOOP_COLOUR, MAX_LOOP_SEGMENTS, PlotError, draw_error, draw_mesh,
    even_indices, invalid, text_style, write_svg,
};
use crate::report::Report;
use crate::robust::LoopModel;
use plotters::coord::Shift;
use plotters::prelude::*;
use std::path::Path;

/// Size of the loop decisions picture in pixels.
const LOOPS_SIZE: (u32, u32) = (1100, 900);
/// Points of each curve across the x range.
const CURVE_POINTS: usize = 400;
const ACCEPTED_COLOUR: RGBColor = LOOP_COLOUR;
const REJECTED_COLOUR: RGBColor = RGBColor(214, 39, 40);
const BOUNDARY_COLOUR: RGBColor = RGBColor(0, 0, 0);

/// One candidate as the loop model saw it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LoopPoint {
    /// Its squared innovation `ν²` (positive and finite; candidates that
    /// nothing else checks have none and are not drawn).
    pub innovation: f64,
    /// Its prior probability of a true loop, from its count.
    pub prior: f64,
    /// Whether the final map was solved with it.
    pub accepted: bool,
}

/// The candidates the loop model weighed in a job's `report`, for
/// [`plot_loops`]: those with an innovation and a prior, in file order.
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

/// Writes the loop decisions picture to `path` as SVG, in two panels over
/// one axis, `y = ln ν²`:
///
/// * top: the fitted densities of the true loops' `y` and of the wrong
///   loops' (all their populations);
/// * bottom: each candidate at its `y` and its prior (accepted green,
///   rejected red), and the line where the posterior is ½
///   ([`LoopModel::acceptance_prior`]): the model accepts what lies above
///   it. A candidate on the wrong side of the line was decided otherwise
///   after the model's last evaluation (its `reason` in the report says
///   why, e.g. taken out by the χ² search).
///
/// At most [`MAX_LOOP_SEGMENTS`] candidates are drawn, evenly sampled (the
/// caption says so). A point that is not finite, or a prior outside
/// `[0, 1]`, gives [`PlotError::InvalidInput`].
pub fn plot_loops(
    path: &Path,
    points: &[LoopPoint],
    unjudged: usize,
    model: &LoopModel,
) -> Result<(), PlotError> {
    if let Some(k) = points.iter().position(|p| {
        !(p.innovation.is_finite() && p.innovation > 0.0 && (0.0..=1.0).contains(&p.prior))
    }) {
        let p = points[k];
        return Err(invalid(
            path,
            format!(
                "candidate {k} has innovation {} and prior {}: an innovation must be positive and finite, a prior in [0, 1]",
                p.innovation, p.prior
            ),
        ));
    }
    let svg = render(points, unjudged, model).map_err(|e| draw_error(path, e))?;
    write_svg(path, &svg)
}

/// The x range: every candidate's `y` and the true loops' bulk, with a
/// margin.
fn x_range(points: &[LoopPoint], model: &LoopModel) -> (f64, f64) {
    let (mu, s) = (model.true_loops.mean, model.true_loops.sigma);
    let (lo, hi) = points
        .iter()
        .map(|p| p.innovation.ln())
        .fold((mu - 3.0 * s, mu + 3.0 * s), |(lo, hi), y| {
            (lo.min(y), hi.max(y))
        });
    let margin = 0.03 * (hi - lo).max(1.0);
    (lo - margin, hi + margin)
}

fn grid((lo, hi): (f64, f64)) -> impl Iterator<Item = f64> {
    (0..=CURVE_POINTS).map(move |i| lo + (hi - lo) * i as f64 / CURVE_POINTS as f64)
}

fn render(points: &[LoopPoint], unjudged: usize, model: &LoopModel) -> DrawResult<String> {
    let range = x_range(points, model);
    let drawn: Vec<LoopPoint> = even_indices(points.len(), MAX_LOOP_SEGMENTS)
        .into_iter()
        .map(|k| points[k])
        .collect();
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, LOOPS_SIZE).into_drawing_area();
        root.fill(&WHITE)?;
        let (header, body) = root.split_vertically(76);
        let (top, bottom) = body.split_vertically(300);
        draw_header(&header, points, (drawn.len(), unjudged), model)?;
        draw_densities(&top, model, range)?;
        draw_decisions(&bottom, &drawn, model, range)?;
        root.present()?;
    }
    Ok(svg)
}

/// The title and a caption: the decisions of the candidates drawn, how
/// many were not (`unjudged`: no innovation, or no prior), and the model's
/// groups of wrong loops and the share of wrong loops whose counts look
/// true.
fn draw_header(
    area: &DrawingArea<SVGBackend<'_>, Shift>,
    points: &[LoopPoint],
    (drawn, unjudged): (usize, usize),
    model: &LoopModel,
) -> DrawResult<()> {
    let accepted = points.iter().filter(|p| p.accepted).count();
    let wrong = model.wrong_loops.len();
    let mut caption = format!("{accepted} accepted, {} rejected", points.len() - accepted);
    if unjudged > 0 {
        caption.push_str(&format!(
            "; {unjudged} without an innovation (unchecked, or dropped by the gate) not drawn"
        ));
    }
    caption.push_str(&format!(
        "; the model: {wrong} group{} of wrong loops, {:.1} % of wrong loops with true-like counts",
        if wrong == 1 { "" } else { "s" },
        100.0 * model.aliasing_rate
    ));
    if drawn < points.len() {
        caption.push_str(&format!(
            "; {drawn} of {} drawn, evenly sampled",
            points.len()
        ));
    }
    let title = format!(
        "Loop decisions: {} candidates' innovations and priors under the loop model",
        points.len()
    );
    area.draw_text(&title, &text_style(22, BLACK), (24, 14))?;
    area.draw_text(&caption, &text_style(15, BLACK), (24, 48))?;
    Ok(())
}

/// Top panel: `f_true` and `f_wrong` over `y`.
fn draw_densities(
    area: &DrawingArea<SVGBackend<'_>, Shift>,
    model: &LoopModel,
    range: (f64, f64),
) -> DrawResult<()> {
    let curve = |f: &dyn Fn(f64) -> f64| -> Vec<(f64, f64)> {
        grid(range)
            .map(|y| (y, f(y)))
            .filter(|(_, d)| d.is_finite())
            .collect()
    };
    let true_loops = curve(&|y| model.true_density(y));
    let wrong_loops = curve(&|y| model.wrong_density(y));
    let top = true_loops
        .iter()
        .chain(&wrong_loops)
        .map(|p| p.1)
        .fold(0.0, f64::max)
        .max(f64::MIN_POSITIVE)
        * 1.15;
    let mut chart = panel(area, range, top, ("", "density of ln ν²"))?;
    for (points, colour, label) in [
        (true_loops, LOOP_COLOUR, "true loops"),
        (wrong_loops, REJECTED_COLOUR, "wrong loops"),
    ] {
        chart
            .draw_series(LineSeries::new(points, colour.stroke_width(2)))?
            .label(label)
            .legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 18, y)], colour.stroke_width(2))
            });
    }
    legend(&mut chart, SeriesLabelPosition::UpperRight)
}

/// Bottom panel: the candidates and the acceptance line.
fn draw_decisions(
    area: &DrawingArea<SVGBackend<'_>, Shift>,
    points: &[LoopPoint],
    model: &LoopModel,
    range: (f64, f64),
) -> DrawResult<()> {
    let x_desc = "ln ν² (squared innovation against the map without the candidate's cluster)";
    let mut chart = panel(area, range, 1.0, (x_desc, "prior P(true loop | count)"))?;
    // Rejected first, so that the accepted ones show where both meet.
    for (accepted, colour, label) in [
        (false, REJECTED_COLOUR, "rejected"),
        (true, ACCEPTED_COLOUR, "accepted"),
    ] {
        let dots = points
            .iter()
            .filter(|p| p.accepted == accepted)
            .map(|p| Circle::new((p.innovation.ln(), p.prior), 2, colour.filled()));
        chart
            .draw_series(dots)?
            .label(label)
            .legend(move |(x, y)| Circle::new((x + 9, y), 4, colour.filled()));
    }
    let line: Vec<(f64, f64)> = grid(range)
        .map(|y| (y, model.acceptance_prior(y)))
        .filter(|(_, p)| p.is_finite())
        .collect();
    chart
        .draw_series(LineSeries::new(line, BOUNDARY_COLOUR.stroke_width(2)))?
        .label("posterior ½: accepted above")
        .legend(|(x, y)| {
            PathElement::new(vec![(x, y), (x + 18, y)], BOUNDARY_COLOUR.stroke_width(2))
        });
    // Lower left: few candidates are both consistent and of a low prior.
    legend(&mut chart, SeriesLabelPosition::LowerLeft)
}

/// A panel's chart and its axes: `range` of `y = ln ν²` on x, `0..top`
/// on y, each described (no x description: no room kept for one).
fn panel<'a, 'b>(
    area: &'a DrawingArea<SVGBackend<'b>, Shift>,
    range: (f64, f64),
    top: f64,
    (x_desc, y_desc): (&str, &str),
) -> DrawResult<Chart<'a, 'b>> {
    let mut chart = ChartBuilder::on(area)
        .margin(24)
        .x_label_area_size(if x_desc.is_empty() { 20 } else { 56 })
        .y_label_area_size(72)
        .build_cartesian_2d(range.0..range.1, 0.0..top)?;
    draw_mesh(&mut chart, x_desc, y_desc)?;
    Ok(chart)
}

/// The chart's legend at `position`.
fn legend<'a, 'b: 'a>(chart: &mut Chart<'a, 'b>, position: SeriesLabelPosition) -> DrawResult<()> {
    chart
        .configure_series_labels()
        .position(position)
        .margin(12)
        .label_font((FONT, 14))
        .background_style(WHITE.mix(0.9))
        .border_style(BLACK.mix(0.4))
        .draw()?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The loop candidates of the bundled sample as the job decided them,
    /// and its loop model.
    fn candidates() -> (Vec<LoopPoint>, LoopModel) {
        let sample = concat!(env!("CARGO_MANIFEST_DIR"), "/g2o_samples/grid2d.g2o");
        let graph = crate::AnyPoseGraph::read_g2o(sample).unwrap();
        let report = graph
            .optimize(&crate::Options::default())
            .unwrap()
            .report()
            .clone();
        let points = loop_points(&report);
        (points, report.robust.model.unwrap())
    }

    fn draw(name: &str, points: &[LoopPoint], model: &LoopModel) -> Result<String, PlotError> {
        let dir = tempfile::Builder::new()
            .prefix("pgo-plot-loops-")
            .tempdir()
            .unwrap();
        let path = dir.path().join(name);
        plot_loops(&path, points, 0, model)?;
        Ok(std::fs::read_to_string(path).unwrap())
    }

    #[test]
    fn the_picture_shows_every_candidate_the_densities_and_the_acceptance_line() {
        let (points, model) = candidates();
        let accepted = points.iter().filter(|p| p.accepted).count();
        assert!(accepted > 100 && accepted < points.len(), "{accepted}");
        let svg = draw("loops.svg", &points, &model).unwrap();
        assert!(svg.starts_with("<svg") && svg.trim_end().ends_with("</svg>"));
        for text in [
            format!("Loop decisions: {} candidates", points.len()),
            format!("{accepted} accepted, {} rejected", points.len() - accepted),
            "true loops".into(),
            "wrong loops".into(),
            "posterior ½: accepted above".into(),
        ] {
            assert!(svg.contains(&text), "missing {text:?}");
        }
        // One dot per candidate, plus the two legend dots.
        assert_eq!(svg.matches("<circle").count(), points.len() + 2);
        assert!(!svg.contains("evenly sampled"));
    }

    #[test]
    fn more_candidates_than_the_picture_holds_are_sampled_and_said_so() {
        let (points, model) = candidates();
        let many: Vec<LoopPoint> = points
            .iter()
            .cycle()
            .take(MAX_LOOP_SEGMENTS + 500)
            .copied()
            .collect();
        let svg = draw("many.svg", &many, &model).unwrap();
        assert_eq!(svg.matches("<circle").count(), MAX_LOOP_SEGMENTS + 2);
        assert!(svg.contains(&format!(
            "{MAX_LOOP_SEGMENTS} of {} drawn, evenly sampled",
            many.len()
        )));
    }

    #[test]
    fn a_point_the_model_cannot_have_seen_is_an_error_naming_it() {
        let (mut points, model) = candidates();
        points[7].innovation = f64::NAN;
        let err = draw("bad.svg", &points, &model).unwrap_err().to_string();
        assert!(
            err.contains("bad.svg") && err.contains("candidate 7"),
            "{err}"
        );
        points[7].innovation = 1.0;
        points[9].prior = 1.5;
        let err = draw("bad.svg", &points, &model).unwrap_err().to_string();
        assert!(
            err.contains("candidate 9") && err.contains("prior 1.5"),
            "{err}"
        );
    }
}
