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
        // The same job in memory gives the same covariances, to the bit.
        let graph = pgo::AnyPoseGraph::read_g2o(&input).unwrap();
        let covariances = graph
            .optimize(&pgo::Options::default())
            .unwrap()
            .covariances()
            .unwrap();
        assert_eq!(rows.len(), graph.len());
        for (id, numbers) in &rows {
            assert_eq!(numbers, &covariances.pose(*id).unwrap(), "{file} pose {id}");
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
