use super::*;
use crate::job::Settings;

/// An option's name, a value other than its default, and how to see it
/// was set.
type Case = (&'static str, &'static str, fn(&Options) -> bool);

/// Every option.
fn every_option() -> Vec<Case> {
    vec![
        ("gate", "37", |o| o.gate.mode == GateMode::Fixed(37)),
        ("degenerate", "drop-all", |o| {
            o.gate.degenerate == DegeneratePolicy::DropAll
        }),
        ("candidates", "non-sequential", |o| {
            o.gate.candidates == CandidateRule::NonSequential
        }),
        ("robust", "gnc", |o| o.robust.method == RobustMethod::Gnc),
        ("robust-c", "4.25", |o| o.robust.c == Some(4.25)),
        ("solver", "gn", |o| o.solver.method == Method::GaussNewton),
        ("init", "odometry", |o| {
            o.solver.init == Initialization::Odometry
        }),
        ("max-iters", "12", |o| o.solver.max_iterations == Some(12)),
        ("time-limit", "2.5", |o| {
            o.solver.time_limit == Some(Duration::from_millis(2500))
        }),
        ("threads", "3", |o| o.solver.threads == 3),
        ("update-iters", "2", |o| {
            o.solver.update_iterations == Some(2)
        }),
        ("alpha", "0.01", |o| o.test.alpha == 0.01),
        ("dof", "constraints", |o| {
            o.test.dof == DofConvention::Constraints
        }),
        ("expert", "no-clusters,no-search", |o| {
            !o.expert.layers.clusters && !o.expert.layers.search && o.expert.layers.decisions
        }),
    ]
}

#[test]
fn set_takes_every_option_by_its_flag_name() {
    let cases = every_option();
    let names: Vec<&str> = Options::names().collect();
    assert_eq!(
        names,
        cases.iter().map(|(n, _, _)| *n).collect::<Vec<_>>(),
        "every option has a case"
    );
    for (name, value, was_set) in cases {
        let mut o = Options::default();
        assert!(!was_set(&o), "{name}: the case differs from the default");
        o.set(name, value).unwrap();
        assert!(was_set(&o), "{name} {value}");
        // Nothing else changed.
        let mut again = Options::default();
        again.set(&name.replace('-', "_"), value).unwrap();
        assert_eq!(o, again, "{name}: '_' is '-'");
        assert_eq!(o.validate().map_err(|e| e.to_string()), Ok(()));
    }
}

#[test]
fn set_parses_each_kind_of_value() {
    let mut o = Options::default();
    for (gate, mode) in [
        ("auto", GateMode::Auto),
        ("soft", GateMode::Soft),
        ("off", GateMode::Off),
        ("0", GateMode::Fixed(0)),
    ] {
        o.set("gate", gate).unwrap();
        assert_eq!(o.gate.mode, mode);
    }
    o.set("expert", "no-annealing").unwrap();
    assert!(!o.expert.layers.annealing);
    o.set("expert", "").unwrap();
    assert_eq!(o.expert.layers, Layers::default());
    o.set("time-limit", "0").unwrap();
    assert_eq!(o.solver.time_limit, Some(Duration::ZERO));
    o.set("time-limit", "1e9").unwrap();
    assert_eq!(
        o.solver.time_limit,
        Some(Duration::from_secs(1_000_000_000))
    );
    o.set("threads", "256").unwrap();
    o.set("max-iters", "0").unwrap();
    assert_eq!(o.solver.max_iterations, Some(0));
}

#[test]
fn bad_values_name_the_option_and_change_nothing() {
    let cases = [
        (
            "gate",
            "half",
            "--gate must be auto, soft, off or a non-negative integer, got 'half'",
        ),
        (
            "gate",
            "-3",
            "--gate must be auto, soft, off or a non-negative integer, got '-3'",
        ),
        (
            "degenerate",
            "keep",
            "--degenerate must be one of keep-all, drop-all, threshold, got 'keep'",
        ),
        (
            "candidates",
            "all",
            "--candidates must be one of counted, non-sequential, got 'all'",
        ),
        (
            "robust",
            "EM",
            "--robust must be one of none, em, huber, cauchy, dcs, gnc, got 'EM'",
        ),
        (
            "robust-c",
            "nan",
            "--robust-c must be between 1e-100 and 1e100, got nan",
        ),
        (
            "robust-c",
            "0",
            "--robust-c must be between 1e-100 and 1e100, got 0",
        ),
        (
            "robust-c",
            "-1",
            "--robust-c must be between 1e-100 and 1e100, got -1",
        ),
        (
            "robust-c",
            "inf",
            "--robust-c must be between 1e-100 and 1e100, got inf",
        ),
        (
            "robust-c",
            "1e-101",
            "--robust-c must be between 1e-100 and 1e100, got 1e-101",
        ),
        (
            "robust-c",
            "2e100",
            "--robust-c must be between 1e-100 and 1e100, got 2e100",
        ),
        (
            "robust-c",
            "wide",
            "--robust-c must be a number, got 'wide'",
        ),
        (
            "expert",
            "no-such-layer",
            "--expert unknown layer 'no-such-layer': expected no-LAYER with LAYER one of annealing, decisions, clusters, agreement, aliasing, populations, search, relaxation, rescue, starts, reach, recheck, keystone",
        ),
        ("solver", "cg", "--solver must be one of lm, gn, got 'cg'"),
        (
            "init",
            "zero",
            "--init must be one of file, odometry, chordal, got 'zero'",
        ),
        (
            "max-iters",
            "-1",
            "--max-iters must be a non-negative integer, got '-1'",
        ),
        (
            "max-iters",
            "1.5",
            "--max-iters must be a non-negative integer, got '1.5'",
        ),
        (
            "time-limit",
            "-1",
            "--time-limit must be between 0 and 1e9 seconds (leave it out for no limit), got -1",
        ),
        (
            "time-limit",
            "1e300",
            "--time-limit must be between 0 and 1e9 seconds (leave it out for no limit), got 1e300",
        ),
        (
            "time-limit",
            "nan",
            "--time-limit must be between 0 and 1e9 seconds (leave it out for no limit), got nan",
        ),
        ("threads", "257", "--threads must be at most 256, got 257"),
        (
            "threads",
            "-2",
            "--threads must be a non-negative integer, got '-2'",
        ),
        (
            "update-iters",
            "0",
            "--update-iters must be at least 1, got 0",
        ),
        ("alpha", "0", "--alpha must be in (0, 1), got 0"),
        ("alpha", "1", "--alpha must be in (0, 1), got 1"),
        ("alpha", "NaN", "--alpha must be in (0, 1), got NaN"),
        (
            "dof",
            "k",
            "--dof must be one of residual, constraints, got 'k'",
        ),
    ];
    for (name, value, message) in cases {
        let mut o = Options::default();
        let e = o.set(name, value).unwrap_err();
        assert!(
            matches!(e, Error::InvalidOption { option, .. } if option == name),
            "{e:?}"
        );
        assert_eq!(e.to_string(), message);
        assert_eq!(o, Options::default(), "{name} {value}");
    }
    // The limits are the documented constants.
    assert_eq!(MAX_THREADS, 256);
    assert_eq!(MAX_TIME_LIMIT_S, 1e9);
}

#[test]
fn unknown_names_are_refused_with_the_list() {
    let mut o = Options::default();
    for name in [
        "robust-width",
        "--alpha",
        "Alpha",
        "",
        "output",
        "fix-information",
    ] {
        let e = o.set(name, "1").unwrap_err();
        assert!(
            matches!(&e, Error::UnknownOption { name: n } if n == name),
            "{e:?}"
        );
        assert!(e.to_string().contains("options: gate, degenerate"), "{e}");
    }
}

#[test]
fn validate_names_each_field_out_of_range() {
    type Break = fn(&mut Options);
    let cases: Vec<(Break, &str)> = vec![
        (
            |o| o.robust.c = Some(f64::NAN),
            "--robust-c must be between 1e-100 and 1e100, got NaN",
        ),
        (
            |o| o.robust.c = Some(-2.0),
            "--robust-c must be between 1e-100 and 1e100, got -2",
        ),
        (
            |o| o.robust.c = Some(f64::INFINITY),
            "--robust-c must be between 1e-100 and 1e100, got inf",
        ),
        (
            |o| o.solver.time_limit = Some(Duration::MAX),
            "--time-limit must be between 0 and 1e9 seconds (leave it out for no limit), got 18446744073709552000",
        ),
        (
            |o| o.solver.threads = 100_000,
            "--threads must be at most 256, got 100000",
        ),
        (
            |o| o.solver.update_iterations = Some(0),
            "--update-iters must be at least 1, got 0",
        ),
        (|o| o.test.alpha = 0.0, "--alpha must be in (0, 1), got 0"),
        (|o| o.test.alpha = 1.0, "--alpha must be in (0, 1), got 1"),
        (
            |o| o.test.alpha = f64::NAN,
            "--alpha must be in (0, 1), got NaN",
        ),
    ];
    for (break_it, message) in cases {
        let mut o = Options::default();
        assert!(o.validate().is_ok());
        break_it(&mut o);
        assert_eq!(o.validate().unwrap_err().to_string(), message);
    }
}

#[test]
fn the_solver_takes_its_settings_from_options() {
    // The defaults: each solve bounded by 100 iterations, no time limit.
    let o = Options::default();
    let c = Settings::new(&o);
    assert_eq!(c.solver.max_iterations, 100);
    assert_eq!(c.solver.time_limit, None);
    assert_eq!(c.solver.threads, 0);
    assert_eq!(c.solver.method, Method::LevenbergMarquardt);
    // --max-iters bounds each solve (and the whole run), --time-limit each.
    let mut o = Options::default();
    o.set("max-iters", "7").unwrap();
    o.set("time-limit", "3").unwrap();
    o.set("solver", "gn").unwrap();
    o.set("threads", "2").unwrap();
    let c = Settings::new(&o);
    assert_eq!(c.solver.max_iterations, 7);
    assert_eq!(c.solver.time_limit, Some(Duration::from_secs(3)));
    assert_eq!(c.solver.method, Method::GaussNewton);
    assert_eq!(c.solver.threads, 2);
}

/// With the `cli` feature the option structs are clap arguments: parsing
/// the flags gives what `set` gives, flag by flag, and no flags give the
/// defaults.
#[cfg(feature = "clap")]
mod cli {
    use super::*;
    use clap::Parser;

    #[derive(Parser, Debug)]
    struct Cli {
        #[command(flatten)]
        options: Options,
    }

    fn parse(args: &[&str]) -> Result<Options, clap::Error> {
        Cli::try_parse_from(std::iter::once("pgo").chain(args.iter().copied())).map(|c| c.options)
    }

    #[test]
    fn no_flags_are_the_defaults() {
        assert_eq!(parse(&[]).unwrap(), Options::default());
    }

    #[test]
    fn every_flag_parses_as_set_does() {
        // `update-iters` bounds incremental updates only: no flag of
        // `pgo optimize`.
        let flags = every_option().into_iter();
        for (name, value, _) in flags.filter(|(n, ..)| *n != "update-iters") {
            let flag = format!("--{name}");
            let args: Vec<&str> = match value {
                // A switch takes no value on the command line.
                "true" => vec![&flag],
                _ => vec![&flag, value],
            };
            let mut by_name = Options::default();
            by_name.set(name, value).unwrap();
            assert_eq!(parse(&args).unwrap(), by_name, "{args:?}");
        }
    }

    #[test]
    fn bad_values_are_refused_by_both() {
        for (name, value) in [
            ("robust-c", "nan"),
            ("alpha", "1"),
            ("threads", "257"),
            ("time-limit", "1e300"),
            ("gate", "half"),
            ("robust", "EM"),
        ] {
            let flag = format!("--{name}");
            let e = parse(&[&flag, value]).unwrap_err();
            use clap::error::ErrorKind::{InvalidValue, ValueValidation};
            assert!(
                matches!(e.kind(), ValueValidation | InvalidValue),
                "{flag} {value}: {e}"
            );
            assert!(Options::default().set(name, value).is_err());
        }
    }

    #[test]
    fn help_lists_the_values_of_each_choice() {
        use clap::CommandFactory;
        let help = Cli::command().render_long_help().to_string();
        for needle in [
            "keep-all",
            "non-sequential",
            "cauchy",
            "odometry",
            "constraints",
        ] {
            assert!(help.contains(needle), "{needle} in\n{help}");
        }
    }
}
