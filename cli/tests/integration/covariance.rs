//! Marginal covariances: `pgo optimize --covariances` against the library,
//! and the library against GTSAM's `Marginals` (numbers stored by
//! `scripts/gtsam_covariance.py`).

use crate::common::{pgo, sample, stderr, temp_dir};

/// The CSV's rows by id.
fn read_csv(text: &str) -> Vec<(u64, Vec<f64>)> {
    text.lines()
        .skip(1)
        .map(|line| {
            let mut fields = line.split(',');
            let id = fields.next().unwrap().parse().unwrap();
            (id, fields.map(|v| v.parse().unwrap()).collect())
        })
        .collect()
}

#[test]
fn the_command_line_writes_the_library_s_covariances() {
    let dir = temp_dir("covariances");
    let path = dir.join("cov.csv");
    for (file, d) in [("grid2d.g2o", 3), ("sphere3d.g2o", 6)] {
        let input = sample(file);
        let out = pgo(&[
            "optimize",
            &input,
            "-q",
            "--covariances",
            path.to_str().unwrap(),
        ]);
        assert!(matches!(out.status.code(), Some(0 | 3)), "{}", stderr(&out));
        let text = std::fs::read_to_string(&path).unwrap();
        assert!(text.starts_with(if d == 3 {
            "id,x_x,x_y,x_theta,"
        } else {
            "id,x_x,x_y,x_z,x_rx,"
        }));
        let rows = read_csv(&text);
        // The same job in memory gives the same covariances (to round-off:
        // as two runs of the command line, two optima may differ in the
        // last bits).
        let graph = pgo::AnyPoseGraph::read_g2o(&input).unwrap();
        let solution = graph.optimize(&pgo::Options::default()).unwrap();
        let covariances = solution.covariances().unwrap();
        assert_eq!(rows.len(), graph.len());
        for (id, numbers) in &rows {
            let want = covariances.pose(*id).unwrap();
            for r in 0..d {
                for c in 0..d {
                    let scale = (want[r * d + r] * want[c * d + c]).sqrt();
                    let diff = (numbers[r * d + c] - want[r * d + c]).abs();
                    assert!(diff <= 1e-9 * scale, "{file} pose {id} ({r}, {c})");
                }
            }
        }
        // The first pose is the gauge.
        assert!(rows[0].1.iter().all(|&v| v == 0.0));
        assert!(rows[1].1[0] > 0.0);
    }
    // stdout twice is refused before anything runs.
    let out = pgo(&[
        "optimize",
        &sample("grid2d.g2o"),
        "--covariances",
        "-",
        "--json",
    ]);
    assert_eq!(out.status.code(), Some(2));
    assert!(
        stderr(&out).contains("--covariances and --json both write to stdout"),
        "{}",
        stderr(&out)
    );
}

/// GTSAM's matrices may differ from pgo's by this much of `√(σ_r²·σ_c²)`
/// (the bound; the script measured at most 6·10⁻¹³ on these files,
/// 2·10⁻⁸ on sphere2500).
const GTSAM_TOLERANCE: f64 = 1e-6;

/// Asserts pgo's `got` is GTSAM's `want` (both row by row, `n × n`): to
/// [`GTSAM_TOLERANCE`] on the rows and columns of free poses, exactly zero
/// on those of the fixed pose (GTSAM's prior leaves 10⁻¹⁸ there).
fn assert_like_gtsam(got: &[f64], want: &[f64], n: usize, what: &str) {
    assert_eq!(got.len(), n * n, "{what}");
    for r in 0..n {
        for c in 0..n {
            let (g, w) = (got[r * n + c], want[r * n + c]);
            if got[r * n + r] == 0.0 || got[c * n + c] == 0.0 {
                assert_eq!(g, 0.0, "{what} ({r}, {c}): a fixed pose's entry");
                assert!(w.abs() < 1e-15, "{what} ({r}, {c}): GTSAM {w}");
                continue;
            }
            let scale = (want[r * n + r] * want[c * n + c]).sqrt();
            assert!(
                (g - w).abs() <= GTSAM_TOLERANCE * scale,
                "{what} ({r}, {c}): pgo {g} GTSAM {w}"
            );
        }
    }
}

#[test]
fn covariances_are_gtsam_s_marginals_on_the_same_map() {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/integration/covariance_gtsam.json"
    );
    let reference: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
    let numbers = |v: &serde_json::Value| -> Vec<f64> {
        v.as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_f64().unwrap())
            .collect()
    };
    let id = |v: &serde_json::Value| v.as_u64().unwrap();
    for (file, r) in reference.as_object().unwrap() {
        let graph = pgo::AnyPoseGraph::read_g2o(sample(file)).unwrap();
        let solution = graph.optimize(&pgo::Options::default()).unwrap();
        let accepted = solution.loops().iter().filter(|l| l.accepted).count() as u64;
        assert_eq!(
            accepted,
            r["accepted_loops"].as_u64().unwrap(),
            "{file}: the map's decisions changed; regenerate the reference \
             (scripts/gtsam_covariance.py --reference)"
        );
        let c = solution.covariances().unwrap();
        let d = c.size();
        for p in r["poses"].as_array().unwrap() {
            let k = id(&p[0]);
            assert_like_gtsam(
                &c.pose(k).unwrap(),
                &numbers(&p[1]),
                d,
                &format!("{file} pose {k}"),
            );
        }
        for p in r["joint"].as_array().unwrap() {
            let (a, b) = (id(&p[0]), id(&p[1]));
            let what = format!("{file} joint {a} {b}");
            assert_like_gtsam(&c.joint(a, b).unwrap(), &numbers(&p[2]), 2 * d, &what);
        }
        for p in r["relative"].as_array().unwrap() {
            let (a, b) = (id(&p[0]), id(&p[1]));
            let what = format!("{file} relative {a} {b}");
            assert_like_gtsam(&c.relative(a, b).unwrap(), &numbers(&p[2]), d, &what);
        }
    }
}
