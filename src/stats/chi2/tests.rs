use super::*;

/// Reference values from SciPy 1.17.1, `scipy.stats.chi2.isf(alpha, dof)`.
const SCIPY: &[(u64, f64, f64)] = &[
    (1, 0.05, 3.8414588206941285),
    (1, 1e-6, 23.928126976934827),
    (1, 0.95, 0.003932140000019531),
    (2, 0.05, 5.991464547107983),
    (5, 0.025, 12.83250199403003),
    (10, 0.01, 23.20925115895436),
    (100, 0.5, 99.33412923598846),
    (1589, 0.05, 1682.8496020082057),
    (1589, 1e-6, 1871.5060764034274),
    (9713, 0.05, 9943.386455227124),
    (12840, 0.05, 13104.719594668884),
    (17506, 0.05, 17814.909511763613),
    (17506, 0.95, 17199.364532127165),
    (100_000, 0.05, 100736.736177319),
    (1_000_000, 0.05, 1002327.310781219),
    (1_000_000, 1e-6, 1006736.7596362906),
    (1_000_000, 0.95, 997674.9632764738),
];

#[test]
fn critical_values_match_scipy() {
    for &(dof, alpha, expected) in SCIPY {
        let x = chi2_critical(dof, alpha).unwrap();
        let rel = (x - expected).abs() / expected;
        assert!(
            rel < 1e-12,
            "dof {dof} alpha {alpha}: {x} vs {expected} (rel {rel:e})"
        );
    }
}

#[test]
fn two_dof_has_a_closed_form() {
    // χ²(2) is exponential with mean 2: the critical value is −2 ln α,
    // also for α so small that 1 − α rounds to 1.
    for alpha in [0.5, 0.05, 1e-3, 1e-10, 1e-16, 1e-20, 1e-100] {
        let x = chi2_critical(2, alpha).unwrap();
        let expected = -2.0 * f64::ln(alpha);
        assert!(
            (x - expected).abs() <= 1e-12 * expected,
            "alpha {alpha}: {x} vs {expected}"
        );
    }
}

#[test]
fn large_dof_agrees_with_wilson_hilferty() {
    // Wilson–Hilferty's relative error shrinks like 1/dof; at these sizes
    // it is far below 1e-4.
    for dof in [1000u64, 1589, 9713, 12840, 17506, 100_000, 1_000_000] {
        for alpha in [0.1, 0.05, 0.025, 0.01] {
            let x = chi2_critical(dof, alpha).unwrap();
            let wh = wilson_hilferty(dof as f64, alpha);
            let rel = (x - wh).abs() / x;
            assert!(rel < 1e-5, "dof {dof} alpha {alpha}: {x} vs WH {wh}");
        }
    }
}

/// `table` is given to 5 significant digits: it must be the rounding of `x`.
fn rounds_to(x: f64, table: f64) -> bool {
    let ulp = 10f64.powf(table.abs().log10().floor() - 4.0);
    (x - table).abs() <= 0.5 * ulp
}

#[test]
fn paper_table_one() {
    // (dataset, DOF, χ²_{α=0.05}, D², passes)
    let table = [
        ("Wolfsburg", 12840, 1.3105e4, 4.1249e3, true),
        ("Carpark", 17506, 1.7815e4, 1.0325e4, true),
        ("New College", 9713, 9.9434e3, 644.7097, true),
        ("Degenerated", 1589, 1.6828e3, 4.8715e3, false),
    ];
    for (name, dof, critical, d2, passes) in table {
        let t = Chi2Test::new(d2, dof, 0, DofConvention::Constraints, 0.05).unwrap();
        assert!(
            rounds_to(t.critical, critical),
            "{name}: {} vs {critical}",
            t.critical
        );
        assert_eq!(t.passed, passes, "{name}");
        assert_eq!(t.dof, dof);
        assert!((t.p_value < 0.05) != passes, "{name}: p = {}", t.p_value);
    }
}

#[test]
fn rounding_check_is_strict() {
    assert!(rounds_to(13104.72, 1.3105e4));
    assert!(!rounds_to(13104.0, 1.3105e4));
}

#[test]
fn critical_value_decreases_with_alpha_and_grows_with_dof() {
    let alphas = [0.9, 0.5, 0.2, 0.1, 0.05, 0.025, 0.01, 1e-3, 1e-6, 1e-12];
    for dof in [1u64, 3, 30, 1589, 100_000] {
        let xs: Vec<f64> = alphas
            .iter()
            .map(|&a| chi2_critical(dof, a).unwrap())
            .collect();
        assert!(xs.windows(2).all(|w| w[0] < w[1]), "dof {dof}: {xs:?}");
    }
    for alpha in [0.5, 0.05, 1e-6] {
        let xs: Vec<f64> = [1u64, 2, 5, 50, 500, 5000, 50_000]
            .iter()
            .map(|&k| chi2_critical(k, alpha).unwrap())
            .collect();
        assert!(xs.windows(2).all(|w| w[0] < w[1]), "alpha {alpha}: {xs:?}");
    }
}

#[test]
fn critical_value_has_the_right_tail_probability() {
    for dof in [1u64, 4, 77, 3000] {
        for alpha in [0.3, 0.05, 1e-4] {
            let x = chi2_critical(dof, alpha).unwrap();
            let sf = ChiSquared::new(dof as f64).unwrap().sf(x);
            assert!(
                (sf - alpha).abs() < 1e-12 * alpha.max(1e-3),
                "dof {dof} alpha {alpha}: sf {sf}"
            );
        }
    }
}

#[test]
fn invalid_inputs_are_errors() {
    assert_eq!(chi2_critical(0, 0.05), Err(StatsError::ZeroDof));
    for alpha in [0.0, 1.0, -0.1, 1.5, f64::NAN, f64::INFINITY] {
        assert!(
            matches!(chi2_critical(10, alpha), Err(StatsError::InvalidAlpha(_))),
            "{alpha}"
        );
    }
    for d2 in [-1.0, f64::NAN, f64::INFINITY] {
        let r = Chi2Test::new(d2, 10, 10, DofConvention::Residual, 0.05);
        assert!(matches!(r, Err(StatsError::InvalidDistance(_))), "{d2}");
    }
    assert_eq!(
        Chi2Test::new(1.0, 10, 0, DofConvention::Residual, 0.05),
        Err(StatsError::NoResidualDof(0))
    );
    assert_eq!(
        Chi2Test::new(1.0, 10, -3, DofConvention::Residual, 0.05),
        Err(StatsError::NoResidualDof(-3))
    );
    assert_eq!(
        Chi2Test::new(1.0, 0, 5, DofConvention::Constraints, 0.05),
        Err(StatsError::ZeroDof)
    );
}

#[test]
fn conventions_pick_their_dof() {
    let r = Chi2Test::new(50.0, 40, 60, DofConvention::Residual, 0.05).unwrap();
    assert_eq!((r.dof, r.dof_constraints, r.dof_residual), (60, 40, 60));
    assert!(r.passed);
    let c = Chi2Test::new(50.0, 40, 60, DofConvention::Constraints, 0.05).unwrap();
    assert_eq!(c.dof, 40);
    // χ²(40) at α = 0.05 is 55.76: 50 passes, 60 fails.
    assert!(c.passed);
    assert!(
        !Chi2Test::new(60.0, 40, 60, DofConvention::Constraints, 0.05)
            .unwrap()
            .passed
    );
    // Non-positive residual dof is fine under the paper's convention.
    let p = Chi2Test::new(5.0, 12, -6, DofConvention::Constraints, 0.05).unwrap();
    assert_eq!((p.dof, p.dof_residual), (12, -6));
}

#[test]
fn boundary_d2_equal_to_critical_passes() {
    let x = chi2_critical(25, 0.05).unwrap();
    assert!(
        Chi2Test::new(x, 25, 25, DofConvention::Residual, 0.05)
            .unwrap()
            .passed
    );
    assert!(
        !Chi2Test::new(x * (1.0 + 1e-12), 25, 25, DofConvention::Residual, 0.05)
            .unwrap()
            .passed
    );
    assert!(
        Chi2Test::new(0.0, 25, 25, DofConvention::Residual, 0.05)
            .unwrap()
            .passed
    );
}

#[test]
fn convention_serializes_lowercase() {
    assert_eq!(
        serde_json::to_string(&DofConvention::Constraints).unwrap(),
        "\"constraints\""
    );
    assert_eq!(
        serde_json::to_string(&DofConvention::Residual).unwrap(),
        "\"residual\""
    );
    assert_eq!(DofConvention::default(), DofConvention::Residual);
}

#[test]
fn normal_upper_quantile_at_two_and_a_half_percent() {
    assert!((normal_upper_quantile(0.025) - 1.959964).abs() < 1e-6);
}
