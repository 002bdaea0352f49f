//! The counts and trajectory pictures drawn and read back.

use super::counts::{CountHistogram, threshold_label};
use super::trajectory::{
    ODOMETRY_COLOUR, OdometryPlan, decimate, equal_aspect_ranges, weight_colour,
};
use super::*;
use crate::gate::{Degeneracy, MixtureOptions, learn_threshold};
use crate::geometry::{Se2, Se3};
use nalgebra::{UnitQuaternion, Vector3};
use rand::SeedableRng;
use rand::rngs::StdRng;
use rand_distr::{Distribution, LogNormal};

/// A fresh directory for one test's files, removed when dropped.
fn test_dir(name: &str) -> tempfile::TempDir {
    tempfile::Builder::new()
        .prefix(&format!("pgo-plot-{name}-"))
        .tempdir()
        .unwrap()
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
    let dir = test_dir("counts");
    let path = dir.path().join("counts.svg");
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
    let dir = test_dir("spike");
    let path = dir.path().join("spike.svg");
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
    let path = dir.path().join("overlapping.svg");
    plot_counts(&path, &counts, &fit).unwrap();
    let svg = read_svg(&path);
    assert!(svg.contains(&escaped(&format!("Degenerate fit: {reason}"))));
    let t = fit.threshold.unwrap();
    assert!(svg.contains(&escaped(&threshold_label(t.count, t.normalized))));

    // No mixture at all: the histogram alone.
    let counts = vec![12; 30];
    let fit = learn_threshold(&counts, &MixtureOptions::default());
    assert!(fit.mixture.is_none());
    let path = dir.path().join("all-equal.svg");
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
        let path = dir.path().join(format!("{name}.svg"));
        plot_counts(&path, &counts, &fit).unwrap();
        let svg = read_svg(&path);
        let reason = fit.degeneracy.unwrap().to_string();
        assert!(svg.contains(&escaped(&reason)), "{name}: {reason}");
    }
    let svg = read_svg(&dir.path().join("zeros.svg"));
    assert!(svg.contains("no non-zero counts to show"));
    assert!(svg.contains("3 zero counts not shown"));
}

#[test]
fn counts_that_are_not_the_fits_are_refused() {
    let counts = realistic_counts(5);
    let fit = learn_threshold(&counts, &MixtureOptions::default());
    let dir = test_dir("mismatch");
    let path = dir.path().join("counts.svg");
    let err = plot_counts(&path, &counts[1..], &fit).unwrap_err();
    assert!(matches!(err, PlotError::InvalidInput { .. }), "{err}");
    assert!(err.to_string().contains(&path.display().to_string()));
    assert!(!path.exists());
}

#[test]
fn unwritable_paths_name_the_file() {
    let dir = test_dir("unwritable");
    let path = dir.path().join("no-such-directory").join("plot.svg");
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
    let dir = test_dir("trajectory");
    let path = dir.path().join("trajectory.svg");
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
    let path = dir.path().join("empty.svg");
    plot_trajectory(&path, &[], &[], &[], &[], "nothing").unwrap();
    let svg = read_svg(&path);
    assert!(svg.contains("no poses") && svg.contains("accepted 0 loops, rejected 0"));

    let path = dir.path().join("single.svg");
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
    let path = dir.path().join("nan.svg");
    plot_trajectory(&path, &before, &after, &odometry, &loops, "nan").unwrap();
    assert!(read_svg(&path).contains("accepted 0 loops, rejected 1"));
    // A straight line: zero extent in y.
    assert!(!read_svg(&path).contains("NaN"));

    // Coordinates at the ends of f64.
    let huge = [[-1e308, 0.0], [1e308, -1e308], [f64::MAX, f64::MIN]];
    let path = dir.path().join("huge.svg");
    plot_trajectory(&path, &huge, &huge, &[(0, 1), (1, 2)], &[], "huge").unwrap();
    read_svg(&path);
}

#[test]
fn bad_trajectory_inputs_are_clear_errors() {
    let dir = test_dir("bad-trajectory");
    let path = dir.path().join("bad.svg");
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
    let dir = test_dir("aspect");
    let path = dir.path().join("aspect.svg");
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
    let dir = test_dir("large");
    let path = dir.path().join("large.svg");
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
