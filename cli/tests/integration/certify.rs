//! `pgo optimize --certify`: the certificate in the JSON report and the
//! human summary; on the public datasets, every file SE-Sync's published
//! results certify (sphere2500, torus3D, parking-garage, intel, cubicle;
//! city10000 and manhattan besides) is certified, and a map left in a wrong
//! basin is not.

use crate::common::{datasets, pgo, sample, stderr};
use serde_json::Value;

/// The report of `pgo optimize --certify --json` with `extra` arguments.
fn certified_report(input: &str, extra: &[&str]) -> Value {
    let mut args = vec!["optimize", input, "--certify", "--json", "-q"];
    args.extend_from_slice(extra);
    let out = pgo(&args);
    assert!(
        out.status.code().is_some_and(|c| c == 0 || c == 3),
        "{input}: {}",
        stderr(&out)
    );
    serde_json::from_slice(&out.stdout).unwrap_or_else(|e| panic!("{input}: {e}"))
}

#[test]
fn the_report_holds_the_certificate_only_when_asked() {
    let input = sample("grid2d.g2o");
    let c = &certified_report(&input, &[])["certificate"];
    assert_eq!(c["certified"], Value::Bool(true), "{c}");
    for field in [
        "eta",
        "cost",
        "map_cost",
        "gap_bound",
        "max_translation_change",
    ] {
        assert!(
            c[field].as_f64().is_some_and(f64::is_finite),
            "{field}: {c}"
        );
    }
    assert!(c["lambda_min"].is_null() && c["eigenvector_poses"] == Value::Array(vec![]));
    let plain = pgo(&["optimize", &input, "--json", "-q"]);
    let report: Value = serde_json::from_slice(&plain.stdout).unwrap();
    assert!(report.get("certificate").is_none());
    let human = pgo(&["optimize", &input, "--certify"]);
    assert!(
        stderr(&human).contains("certificate: globally optimal"),
        "{}",
        stderr(&human)
    );
}

/// The files of SE-Sync's published results that are here (rim is not),
/// and the two largest planar ones.
const CERTIFIED: &[&str] = &[
    "intel.g2o",
    "parking-garage.g2o",
    "sphere2500.g2o",
    "torus3D.g2o",
    "cubicle.g2o",
    "city10000.g2o",
    "manhattan.g2o",
];

#[test]
fn the_standard_datasets_are_certified() {
    let Some(dir) = datasets() else { return };
    for name in CERTIFIED {
        let input = dir.join(name);
        // cubicle has information matrices that are not positive definite.
        let report = certified_report(input.to_str().unwrap(), &["--fix-information"]);
        let c = &report["certificate"];
        eprintln!("{name}: {c}");
        assert_eq!(c["certified"], Value::Bool(true), "{name}: {c}");
        let (cost, gap) = (
            c["cost"].as_f64().unwrap(),
            c["gap_bound"].as_f64().unwrap(),
        );
        assert!(gap >= 0.0 && gap < 1e-4 * cost, "{name}: {c}");
        assert!(cost <= c["map_cost"].as_f64().unwrap() * (1.0 + 1e-12));
    }
}

#[test]
fn a_map_left_in_a_wrong_basin_is_not_certified() {
    let Some(dir) = datasets() else { return };
    let input = dir.join("sphere_bignoise_vertex3.g2o");
    let odometry = ["--init", "odometry", "--max-iters", "5"];
    let report = certified_report(input.to_str().unwrap(), &odometry);
    let c = &report["certificate"];
    assert_eq!(c["certified"], Value::Bool(false), "{c}");
    let lambda = c["lambda_min"].as_f64().unwrap();
    assert!(lambda < -1e3 * c["eta"].as_f64().unwrap(), "{c}");
    let poses = c["eigenvector_poses"].as_array().unwrap();
    assert_eq!(poses.len(), 10);
    assert!(poses[0]["share"].as_f64().unwrap() > 0.05, "{c}");
}
