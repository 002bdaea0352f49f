//! Everything the job of `pgo optimize` can be told ([`Options`]), by field
//! or by the command line's flag names ([`Options::set`]), with the ranges
//! checked ([`Options::validate`]).
//!
//! The field docs double as the command line's help: with the `cli` feature
//! the option structs derive `clap::Args`, and each flag parses its value
//! with the same function as [`Options::set`].

use crate::error::Error;
use crate::gate::{DegeneratePolicy, GateMode};
use crate::robust::{Layers, RobustMethod};
use crate::solve::Method;
use crate::solve::init::Initialization;
use crate::stats::DofConvention;
use std::time::Duration;

/// The largest `--time-limit`, in seconds (about 31.7 years): beyond any
/// run, so a larger value is a mistake (leave the limit out for none), and
/// far inside what the clock can add without overflowing.
pub const MAX_TIME_LIMIT_S: f64 = 1e9;

/// The most `--threads`: far beyond where the factorisation stops gaining
/// from threads; more only costs their stacks.
pub const MAX_THREADS: usize = 256;

/// The kernel widths `--robust-c` takes. The kernels square the width
/// and weigh a loop by ratios such as `c²/(c² + r²)` of it to the squared
/// whitened residual `r²`: a width within 10^±100 keeps `c²` within
/// 10^±200, so that the ratio stays a normal float for residuals up to
/// 10^±100 times the width; beyond 10^±154, `c²` itself over- or
/// underflows and EM ends on a singular system (measured on the bundled
/// samples: they fail from 2·10⁻¹⁵⁴ and 1.35·10¹⁵⁴ on). Useful widths are
/// 0.1 to 100.
pub const ROBUST_C_RANGE: std::ops::RangeInclusive<f64> = 1e-100..=1e100;

/// Everything the job of `pgo optimize` can be told: the gate, the robust
/// back end, the solver and the χ² test. `Options::default()` is what
/// `pgo optimize` does without flags.
///
/// ```
/// let mut options = pgo::Options::default();
/// options.set("robust-c", "4.5")?;
/// options.set("max_iters", "50")?;
/// assert_eq!(options.robust.c, Some(4.5));
/// assert_eq!(options.solver.max_iterations, Some(50));
/// let err = options.set("alpha", "1.5").unwrap_err();
/// assert_eq!(err.to_string(), "--alpha must be in (0, 1), got 1.5");
/// # Ok::<(), pgo::Error>(())
/// ```
#[derive(Clone, Debug, Default, PartialEq)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct Options {
    /// The geometric-verification gate.
    #[cfg_attr(feature = "clap", command(flatten))]
    pub gate: GateOptions,
    /// The robust weighting of the loop candidates the gate passes.
    #[cfg_attr(feature = "clap", command(flatten))]
    pub robust: RobustOptions,
    /// The nonlinear least-squares solver.
    #[cfg_attr(feature = "clap", command(flatten))]
    pub solver: SolverOptions,
    /// The χ² test of the result.
    #[cfg_attr(feature = "clap", command(flatten))]
    pub test: TestOptions,
    /// Switches of the robust layers under review; no stability promise.
    #[doc(hidden)]
    #[cfg_attr(feature = "clap", command(flatten))]
    pub expert: ExpertOptions,
}

/// How loop candidates are gated by their inlier counts.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct GateOptions {
    /// Loop-candidate gate: `auto` learns T_GV from the inlier counts and
    /// drops candidates below it; `soft` drops nothing but gives each
    /// candidate its posterior P(true loop | count) as the robust prior;
    /// `off` keeps every candidate; a number N keeps candidates with
    /// count ≥ N.
    #[cfg_attr(
        feature = "clap",
        arg(id = "gate", long = "gate", value_name = "auto|soft|off|N", default_value = "auto",
            value_parser = parse_gate)
    )]
    pub mode: GateMode,
    /// What the learned gate does when the counts do not show two
    /// components.
    #[cfg_attr(
        feature = "clap",
        arg(long, default_value = "keep-all", value_parser = clap_choice::<DegeneratePolicy>())
    )]
    pub degenerate: DegeneratePolicy,
    /// Which edges are loop candidates: those with an inlier count, or also
    /// every edge between non-consecutive ids.
    #[cfg_attr(
        feature = "clap",
        arg(long, default_value = "counted", value_parser = clap_choice::<CandidateRule>())
    )]
    pub candidates: CandidateRule,
}

/// The robust weighting of the loop candidates that pass the gate.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct RobustOptions {
    /// Robust weighting of the loop candidates that pass the gate.
    #[cfg_attr(
        feature = "clap",
        arg(id = "robust", long = "robust", default_value = "em", value_parser = clap_choice::<RobustMethod>())
    )]
    pub method: RobustMethod,
    /// Kernel width c on the whitened residual norm (1e-100 to 1e100).
    /// Defaults: em √χ²_D(1 − 10⁻⁶) (5.54 in 2D, 6.19 in 3D); gnc
    /// √χ²_D(0.99) (3.368 / 4.100); huber and cauchy √χ²_D(0.95) (2.796 /
    /// 3.548); dcs 1 (Φ = 1).
    #[cfg_attr(
        feature = "clap",
        arg(id = "robust-c", long = "robust-c", value_name = "C", value_parser = parse_robust_c)
    )]
    pub c: Option<f64>,
}

/// The nonlinear least-squares solver.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct SolverOptions {
    /// Nonlinear least-squares method: lm (Levenberg–Marquardt) or gn
    /// (Gauss–Newton).
    #[cfg_attr(
        feature = "clap",
        arg(id = "solver", long = "solver", default_value = "lm", value_parser = clap_choice::<Method>())
    )]
    pub method: Method,
    /// Initial guess.
    #[cfg_attr(
        feature = "clap",
        arg(long, default_value = "chordal", value_parser = clap_choice::<Initialization>())
    )]
    pub init: Initialization,
    /// Most LM/GN iterations in all, robust reweighting rounds included.
    /// Without it, each solve stops after 100 (the last one, whose map the
    /// job returns, carries on to convergence, at most 1,000 more) and the
    /// robust rounds are bounded by their own limits.
    #[cfg_attr(
        feature = "clap",
        arg(id = "max-iters", long = "max-iters", value_name = "N", value_parser = parse_max_iters)
    )]
    pub max_iterations: Option<usize>,
    /// Stop optimising after this many seconds (at most 10⁹; checked
    /// between iterations; initialisation not counted) and return the best
    /// estimate so far.
    #[cfg_attr(
        feature = "clap",
        arg(id = "time-limit", long = "time-limit", value_name = "SECONDS", value_parser = parse_time_limit)
    )]
    pub time_limit: Option<Duration>,
    /// Threads: 0 (the default) and 1 optimise in one thread, which was the
    /// fastest on a 2-core machine shared with other work; N > 1 (at most
    /// 256) uses N.
    #[cfg_attr(feature = "clap", arg(long, default_value = "0", value_parser = parse_threads))]
    pub threads: usize,
    /// Most iterations of each solve in an incremental update
    /// ([`crate::PoseGraph::update`]), at least 1, for a bounded time per
    /// update as a live front end needs it: the map an update returns may
    /// then be short of the optimum (its report says not converged), the
    /// next update goes on from it, and an update that adds nothing
    /// continues the convergence (without this option, finishes it). A
    /// capped solve whose step the Gauss–Newton model foresaw to within an
    /// update's tolerance counts as converged, so that poses added by
    /// odometry alone are composed onto its map; an update that adds
    /// nothing still finishes it. A capped solve's first factorisation
    /// keeps the last one's panels where no pose moved by more than 10⁻²
    /// (docs/method.md §7b), as iSAM2 keeps its cliques. Loop
    /// candidates that EM decides are always solved to convergence (EM
    /// judges each by its innovation at the optimum). Without it every
    /// update converges to the map a batch job would find. `pgo optimize`
    /// has no use for it.
    #[cfg_attr(feature = "clap", arg(skip))]
    pub update_iterations: Option<usize>,
}

/// The χ² goodness-of-fit test of the result.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct TestOptions {
    /// Significance level of the χ² test of the result, in (0, 1).
    #[cfg_attr(feature = "clap", arg(long, default_value = "0.05", value_parser = parse_alpha))]
    pub alpha: f64,
    /// Degrees of freedom of the χ² test: residual (Σ edge dimensions −
    /// free pose parameters) or constraints (number of edges, as in the
    /// paper).
    #[cfg_attr(
        feature = "clap",
        arg(long, default_value = "residual", value_parser = clap_choice::<DofConvention>())
    )]
    pub dof: DofConvention,
}

impl Default for TestOptions {
    fn default() -> Self {
        Self {
            alpha: 0.05,
            dof: DofConvention::default(),
        }
    }
}

/// EM's layers, each of which can be switched off for an ablation;
/// hidden from the documentation, no stability promise.
#[doc(hidden)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct ExpertOptions {
    /// EM: switch layers off, `no-LAYER,…` with LAYER one of
    /// [`Layers::NAMES`].
    #[cfg_attr(
        feature = "clap",
        arg(id = "expert", long = "expert", value_name = "no-LAYER,…", hide = true, default_value = "", value_parser = Layers::parse)
    )]
    pub layers: Layers,
}

/// One option by its command-line name: how to set it from text.
struct Setter {
    name: &'static str,
    set: fn(&mut Options, &str) -> Result<(), String>,
}

/// Every option, by its long flag without `--`, in the order of `--help`.
const SETTERS: &[Setter] = &[
    Setter {
        name: "gate",
        set: |o, v| {
            o.gate.mode = parse_gate(v)?;
            Ok(())
        },
    },
    Setter {
        name: "degenerate",
        set: |o, v| {
            o.gate.degenerate = choice(v)?;
            Ok(())
        },
    },
    Setter {
        name: "candidates",
        set: |o, v| {
            o.gate.candidates = choice(v)?;
            Ok(())
        },
    },
    Setter {
        name: "robust",
        set: |o, v| {
            o.robust.method = choice(v)?;
            Ok(())
        },
    },
    Setter {
        name: "robust-c",
        set: |o, v| {
            o.robust.c = Some(parse_robust_c(v)?);
            Ok(())
        },
    },
    Setter {
        name: "solver",
        set: |o, v| {
            o.solver.method = choice(v)?;
            Ok(())
        },
    },
    Setter {
        name: "init",
        set: |o, v| {
            o.solver.init = choice(v)?;
            Ok(())
        },
    },
    Setter {
        name: "max-iters",
        set: |o, v| {
            o.solver.max_iterations = Some(parse_max_iters(v)?);
            Ok(())
        },
    },
    Setter {
        name: "time-limit",
        set: |o, v| {
            o.solver.time_limit = Some(parse_time_limit(v)?);
            Ok(())
        },
    },
    Setter {
        name: "threads",
        set: |o, v| {
            o.solver.threads = parse_threads(v)?;
            Ok(())
        },
    },
    Setter {
        name: "update-iters",
        set: |o, v| {
            o.solver.update_iterations = Some(parse_update_iters(v)?);
            Ok(())
        },
    },
    Setter {
        name: "alpha",
        set: |o, v| {
            o.test.alpha = parse_alpha(v)?;
            Ok(())
        },
    },
    Setter {
        name: "dof",
        set: |o, v| {
            o.test.dof = choice(v)?;
            Ok(())
        },
    },
    Setter {
        name: "expert",
        set: |o, v| {
            o.expert.layers = Layers::parse(v)?;
            Ok(())
        },
    },
];

/// Which edges are loop-closure candidates.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum CandidateRule {
    /// Edges with an inlier count (in the file or the `--inliers` CSV).
    #[default]
    Counted,
    /// Also every edge between non-consecutive ids (|i − j| ≠ 1), with or
    /// without a count: robust weighting applies to them, gating only to
    /// those with a count.
    NonSequential,
}

impl Options {
    /// Sets one option by the long flag `pgo optimize` spells it with,
    /// without the `--` (`-` and `_` are the same: `robust-c` or
    /// `robust_c`), from its value as text, parsed as the command line
    /// parses it and range-checked as [`Options::validate`] does. The names
    /// are [`Options::names`].
    ///
    /// Errors: [`Error::UnknownOption`] for a name that is none of them,
    /// [`Error::InvalidOption`] (naming the flag) for a value that does not
    /// parse or is out of range; the options are then unchanged.
    pub fn set(&mut self, name: &str, value: &str) -> Result<(), Error> {
        let flag = name.replace('_', "-");
        let setter =
            SETTERS
                .iter()
                .find(|s| s.name == flag)
                .ok_or_else(|| Error::UnknownOption {
                    name: name.to_owned(),
                })?;
        (setter.set)(self, value).map_err(|message| Error::InvalidOption {
            option: setter.name,
            message,
        })
    }

    /// Whether `other` asks for the same map as these options: they differ
    /// at most in how many iterations an update may take
    /// ([`SolverOptions::update_iterations`]), which changes when the map is
    /// reached, not which.
    pub(crate) fn same_job(&self, other: &Options) -> bool {
        let mut other = other.clone();
        other.solver.update_iterations = self.solver.update_iterations;
        *self == other
    }

    /// The names [`Options::set`] takes, in the order of `pgo optimize
    /// --help` (which has all but `update-iters`).
    pub fn names() -> impl Iterator<Item = &'static str> {
        SETTERS.iter().map(|s| s.name)
    }

    /// Checks the range of every number (for options set through the
    /// fields rather than [`Options::set`]); the error names the first
    /// option out of range as the command line spells it, e.g.
    /// `--robust-c must be between 1e-100 and 1e100, got NaN`.
    pub fn validate(&self) -> Result<(), Error> {
        fn check<T: std::fmt::Display>(
            option: &'static str,
            value: T,
            check: impl Fn(&T) -> Result<(), &'static str>,
        ) -> Result<(), Error> {
            check(&value).map_err(|m| Error::InvalidOption {
                option,
                message: format!("{m}, got {value}"),
            })
        }
        if let Some(c) = self.robust.c {
            check("robust-c", c, |c| check_robust_c(*c))?;
        }
        if let Some(t) = self.solver.time_limit {
            check("time-limit", t.as_secs_f64(), |t| check_time_limit(*t))?;
        }
        check("threads", self.solver.threads, |n| check_threads(*n))?;
        if let Some(k) = self.solver.update_iterations {
            check("update-iters", k, |k| check_update_iters(*k))?;
        }
        check("alpha", self.test.alpha, |a| check_alpha(*a))
    }
}

/// An enum option: its values as the command line spells them, with their
/// help.
trait Choice: Copy + Clone + Send + Sync + 'static {
    const CHOICES: &'static [(&'static str, Self, &'static str)];
}

impl Choice for DegeneratePolicy {
    const CHOICES: &'static [(&'static str, Self, &'static str)] = &[
        (
            "keep-all",
            Self::KeepAll,
            "Keep every candidate: the robust back end decides them by geometry",
        ),
        (
            "drop-all",
            Self::DropAll,
            "Drop every counted candidate: no wrong loop gets in (the choice with --robust none)",
        ),
        (
            "threshold",
            Self::Threshold,
            "Use the crossing anyway when there is one",
        ),
    ];
}

impl Choice for CandidateRule {
    const CHOICES: &'static [(&'static str, Self, &'static str)] = &[
        ("counted", Self::Counted, "Edges with an inlier count"),
        (
            "non-sequential",
            Self::NonSequential,
            "Also every edge with |i − j| ≠ 1",
        ),
    ];
}

impl Choice for RobustMethod {
    const CHOICES: &'static [(&'static str, Self, &'static str)] = &[
        ("none", Self::None, "Plain least squares"),
        (
            "em",
            Self::Em,
            "EM over a model of true and wrong loops from their counts and innovations (docs/method.md)",
        ),
        ("huber", Self::Huber, "Huber kernel"),
        ("cauchy", Self::Cauchy, "Cauchy kernel"),
        ("dcs", Self::Dcs, "Dynamic covariance scaling"),
        (
            "gnc",
            Self::Gnc,
            "Graduated non-convexity (truncated least squares)",
        ),
    ];
}

impl Choice for Method {
    const CHOICES: &'static [(&'static str, Self, &'static str)] = &[
        ("lm", Self::LevenbergMarquardt, "Levenberg–Marquardt"),
        ("gn", Self::GaussNewton, "Gauss–Newton"),
    ];
}

impl Choice for Initialization {
    const CHOICES: &'static [(&'static str, Self, &'static str)] = &[
        (
            "file",
            Self::File,
            "The poses in the file (missing ones composed along a spanning tree)",
        ),
        (
            "odometry",
            Self::Odometry,
            "Odometry composed along a spanning tree from the gauge",
        ),
        (
            "chordal",
            Self::Chordal,
            "Chordal relaxation of rotations, then linear translations",
        ),
    ];
}

impl Choice for DofConvention {
    const CHOICES: &'static [(&'static str, Self, &'static str)] = &[
        (
            "residual",
            Self::Residual,
            "Σ edge dimensions − free pose parameters (the textbook value)",
        ),
        (
            "constraints",
            Self::Constraints,
            "The number of constraints (the paper's K)",
        ),
    ];
}

/// The value of an enum option named `text`.
fn choice<T: Choice>(text: &str) -> Result<T, String> {
    T::CHOICES
        .iter()
        .find(|(name, _, _)| *name == text)
        .map(|(_, value, _)| *value)
        .ok_or_else(|| {
            let names: Vec<&str> = T::CHOICES.iter().map(|(name, _, _)| *name).collect();
            format!("must be one of {}, got '{text}'", names.join(", "))
        })
}

/// clap's parser of an enum option: its possible values with their help
/// (listed by `--help`), each mapped by [`choice`].
#[cfg(feature = "clap")]
fn clap_choice<T: Choice>() -> impl clap::builder::TypedValueParser<Value = T> {
    use clap::builder::{PossibleValue, PossibleValuesParser, TypedValueParser};
    let values = T::CHOICES
        .iter()
        .map(|(name, _, help)| PossibleValue::new(*name).help(*help));
    PossibleValuesParser::new(values).try_map(|text: String| choice::<T>(&text))
}

fn parse_gate(text: &str) -> Result<GateMode, String> {
    match text {
        "auto" => Ok(GateMode::Auto),
        "off" => Ok(GateMode::Off),
        "soft" => Ok(GateMode::Soft),
        n => n.parse::<u64>().map(GateMode::Fixed).map_err(|_| {
            format!("must be auto, soft, off or a non-negative integer, got '{text}'")
        }),
    }
}

/// A number as Rust reads it (`nan`, `inf` and `1e3` included), in the
/// range `check` requires.
fn parse_f64(text: &str, check: fn(f64) -> Result<(), &'static str>) -> Result<f64, String> {
    match text.trim().parse::<f64>() {
        Ok(x) if check(x).is_ok() => Ok(x),
        Ok(x) => Err(format!(
            "{}, got {text}",
            check(x).err().unwrap_or_default()
        )),
        Err(_) => Err(format!("must be a number, got '{text}'")),
    }
}

fn parse_usize(text: &str, check: fn(usize) -> Result<(), &'static str>) -> Result<usize, String> {
    match text.trim().parse::<usize>() {
        Ok(n) if check(n).is_ok() => Ok(n),
        Ok(n) => Err(format!(
            "{}, got {text}",
            check(n).err().unwrap_or_default()
        )),
        Err(_) => Err(format!("must be a non-negative integer, got '{text}'")),
    }
}

fn parse_robust_c(text: &str) -> Result<f64, String> {
    parse_f64(text, check_robust_c)
}

fn parse_max_iters(text: &str) -> Result<usize, String> {
    parse_usize(text, |_| Ok(()))
}

fn parse_update_iters(text: &str) -> Result<usize, String> {
    parse_usize(text, check_update_iters)
}

fn check_update_iters(k: usize) -> Result<(), &'static str> {
    if k == 0 {
        Err("must be at least 1")
    } else {
        Ok(())
    }
}

fn parse_time_limit(text: &str) -> Result<Duration, String> {
    // In range the conversion cannot fail: the fallback is never taken.
    parse_f64(text, check_time_limit).map(|s| Duration::try_from_secs_f64(s).unwrap_or_default())
}

fn parse_threads(text: &str) -> Result<usize, String> {
    parse_usize(text, check_threads)
}

fn parse_alpha(text: &str) -> Result<f64, String> {
    parse_f64(text, check_alpha)
}

fn check_robust_c(c: f64) -> Result<(), &'static str> {
    if ROBUST_C_RANGE.contains(&c) {
        Ok(())
    } else {
        Err("must be between 1e-100 and 1e100")
    }
}

fn check_time_limit(seconds: f64) -> Result<(), &'static str> {
    if (0.0..=MAX_TIME_LIMIT_S).contains(&seconds) {
        Ok(())
    } else {
        Err("must be between 0 and 1e9 seconds (leave it out for no limit)")
    }
}

fn check_threads(n: usize) -> Result<(), &'static str> {
    if n <= MAX_THREADS {
        Ok(())
    } else {
        Err("must be at most 256")
    }
}

fn check_alpha(alpha: f64) -> Result<(), &'static str> {
    if alpha > 0.0 && alpha < 1.0 {
        Ok(())
    } else {
        Err("must be in (0, 1)")
    }
}

#[cfg(test)]
mod tests;
