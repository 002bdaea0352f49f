//! `pgo`: the command-line interface, a thin clap layer over the library.

use clap::{Parser, Subcommand, ValueEnum};
use pgo::gate::{DegeneratePolicy, GateMode};
use pgo::pipeline::{self, OptimizeConfig};
use pgo::solve::init::Initialization;
use pgo::solve::{IterationRecord, Method};
use pgo::stats::DofConvention;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

/// Pose-graph optimisation with unsupervised loop-closure gating.
#[derive(Parser, Debug)]
#[command(name = "pgo", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Optimise a pose graph read from a g2o file.
    Optimize(OptimizeArgs),
    /// Learn the geometric-verification threshold T_GV from inlier counts
    /// alone and print it (exit status 1 when the counts are degenerate).
    Gate(GateArgs),
}

#[derive(clap::Args, Debug)]
struct GateArgs {
    /// A g2o file (the counts of its loop candidates), a CSV whose last field
    /// is the count, or one count per line; `-` or nothing reads stdin.
    counts: Option<PathBuf>,
    /// Print the whole fit as JSON on stdout instead of the number.
    #[arg(long)]
    json: bool,
}

#[derive(clap::Args, Debug)]
struct OptimizeArgs {
    /// Input g2o file (VERTEX_SE2/EDGE_SE2 or VERTEX_SE3:QUAT/EDGE_SE3:QUAT).
    input: PathBuf,
    /// Write the optimised graph here (atomically: temporary file, then rename).
    #[arg(short, long, value_name = "OUT.g2o")]
    output: Option<PathBuf>,
    /// Write the optimised graph over the input file.
    #[arg(long, conflicts_with = "output")]
    in_place: bool,
    /// Nonlinear least-squares method.
    #[arg(long, value_enum, default_value_t = SolverArg::Lm)]
    solver: SolverArg,
    /// Most iterations.
    #[arg(long, value_name = "N", default_value_t = 100)]
    max_iters: usize,
    /// Stop after this many seconds and keep the best estimate so far.
    #[arg(long, value_name = "SECONDS")]
    time_limit: Option<f64>,
    /// Initial guess.
    #[arg(long, value_enum, default_value_t = InitArg::Chordal)]
    init: InitArg,
    /// Inlier counts of loop candidates from a CSV file (from,to,inliers).
    #[arg(long, value_name = "FILE")]
    inliers: Option<PathBuf>,
    /// Project information matrices that are not positive definite to the
    /// nearest positive-definite ones instead of failing.
    #[arg(long)]
    fix_information: bool,
    /// Loop-candidate gate: `auto` learns T_GV from the inlier counts, `off`
    /// keeps every candidate, a number N keeps candidates with count ≥ N.
    #[arg(long, value_name = "auto|off|N", default_value = "auto", value_parser = parse_gate)]
    gate: GateMode,
    /// What the learned gate does when the counts do not show two components.
    #[arg(long, value_enum, default_value_t = DegenerateArg::DropAll)]
    degenerate: DegenerateArg,
    /// Significance level of the χ² test of the result.
    #[arg(long, default_value_t = 0.05, value_parser = parse_alpha)]
    alpha: f64,
    /// Degrees of freedom of the χ² test: residual (Σ edge dimensions − free
    /// pose parameters) or constraints (number of edges, as in the paper).
    #[arg(long, value_enum, default_value_t = DofArg::Residual)]
    dof: DofArg,
    /// Threads (0: all cores).
    #[arg(long, default_value_t = 0)]
    threads: usize,
    /// Print the JSON report on stdout.
    #[arg(long)]
    json: bool,
    /// Print nothing on stderr but errors.
    #[arg(short, long)]
    quiet: bool,
    /// Print every iteration on stderr.
    #[arg(short, long)]
    verbose: bool,
}

#[derive(Copy, Clone, Debug, ValueEnum)]
enum SolverArg {
    /// Levenberg–Marquardt.
    Lm,
    /// Gauss–Newton.
    Gn,
}

#[derive(Copy, Clone, Debug, ValueEnum)]
enum DegenerateArg {
    /// Keep every candidate.
    KeepAll,
    /// Drop every counted candidate: no wrong loop gets in silently.
    DropAll,
    /// Use the crossing anyway when there is one.
    Threshold,
}

#[derive(Copy, Clone, Debug, ValueEnum)]
enum DofArg {
    /// Σ edge dimensions − free pose parameters (the textbook value).
    Residual,
    /// The number of constraints (the paper's K).
    Constraints,
}

fn parse_gate(s: &str) -> Result<GateMode, String> {
    match s {
        "auto" => Ok(GateMode::Auto),
        "off" => Ok(GateMode::Off),
        n => n
            .parse::<u64>()
            .map(GateMode::Fixed)
            .map_err(|_| format!("expected auto, off or a non-negative integer, got '{n}'")),
    }
}

fn parse_alpha(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(a) if a > 0.0 && a < 1.0 => Ok(a),
        _ => Err(format!("expected a number in (0, 1), got '{s}'")),
    }
}

#[derive(Copy, Clone, Debug, ValueEnum)]
enum InitArg {
    /// The poses in the file (missing ones composed along a spanning tree).
    File,
    /// Odometry composed along a spanning tree from the gauge.
    Odometry,
    /// Chordal relaxation of rotations, then linear translations.
    Chordal,
}

fn main() -> ExitCode {
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) => {
            let _ = e.print();
            return ExitCode::from(if e.use_stderr() { 2 } else { 0 });
        }
    };
    match cli.command {
        Command::Optimize(args) => optimize(args),
        Command::Gate(args) => gate(args),
    }
}

fn gate(args: GateArgs) -> ExitCode {
    let counts = match read_counts(args.counts.as_deref()) {
        Ok(c) => c,
        Err(message) => {
            eprintln!("error: {message}");
            return ExitCode::from(2);
        }
    };
    let fit = pgo::gate::learn_threshold(&counts, &pgo::gate::MixtureOptions::default());
    if args.json {
        match serde_json::to_string_pretty(&fit) {
            Ok(text) => println!("{text}"),
            Err(e) => {
                eprintln!("error: cannot serialise the fit: {e}");
                return ExitCode::from(1);
            }
        }
    }
    match (&fit.degeneracy, &fit.threshold) {
        (None, Some(t)) => {
            if !args.json {
                println!("{}", t.count);
            }
            eprintln!(
                "T_GV = {:.3} inliers (v_T = {:.4} of max {}); {} counts, {} zero",
                t.count, t.normalized, t.max_count, fit.total_counts, fit.zero_counts
            );
            ExitCode::SUCCESS
        }
        (Some(reason), _) => {
            eprintln!("degenerate: {reason}");
            ExitCode::from(1)
        }
        (None, None) => {
            eprintln!("degenerate: no threshold");
            ExitCode::from(1)
        }
    }
}

/// Counts from a g2o file (its candidates), a CSV or plain list, or stdin.
fn read_counts(path: Option<&std::path::Path>) -> Result<Vec<u64>, String> {
    use pgo::graph::AnyPoseGraph;
    match path {
        None => {
            pgo::io::inliers::read_counts(std::io::stdin().lock(), std::path::Path::new("<stdin>"))
                .map_err(|e| e.to_string())
        }
        Some(p) if p.as_os_str() == "-" => {
            pgo::io::inliers::read_counts(std::io::stdin().lock(), std::path::Path::new("<stdin>"))
                .map_err(|e| e.to_string())
        }
        Some(p) if p.extension().is_some_and(|e| e == "g2o") => {
            let file = pgo::io::g2o::read(p, Default::default()).map_err(|e| e.to_string())?;
            let counts: Vec<u64> = match &file.graph {
                AnyPoseGraph::Planar(g) => g
                    .edges
                    .iter()
                    .filter_map(|e| e.candidate.and_then(|c| c.inliers))
                    .collect(),
                AnyPoseGraph::Spatial(g) => g
                    .edges
                    .iter()
                    .filter_map(|e| e.candidate.and_then(|c| c.inliers))
                    .collect(),
            };
            Ok(counts)
        }
        Some(p) => {
            let f = std::fs::File::open(p).map_err(|e| format!("{}: {e}", p.display()))?;
            pgo::io::inliers::read_counts(f, p).map_err(|e| e.to_string())
        }
    }
}

fn optimize(args: OptimizeArgs) -> ExitCode {
    if args.threads > 0 {
        let _ = rayon::ThreadPoolBuilder::new()
            .num_threads(args.threads)
            .build_global();
    }
    let mut config = OptimizeConfig::new(&args.input);
    config.output = if args.in_place {
        Some(args.input.clone())
    } else {
        args.output.clone()
    };
    config.inliers = args.inliers.clone();
    config.fix_information = args.fix_information;
    config.initialization = match args.init {
        InitArg::File => Initialization::File,
        InitArg::Odometry => Initialization::Odometry,
        InitArg::Chordal => Initialization::Chordal,
    };
    config.solver.method = match args.solver {
        SolverArg::Lm => Method::LevenbergMarquardt,
        SolverArg::Gn => Method::GaussNewton,
    };
    config.solver.max_iterations = args.max_iters;
    config.gate = args.gate;
    config.degenerate = match args.degenerate {
        DegenerateArg::KeepAll => DegeneratePolicy::KeepAll,
        DegenerateArg::DropAll => DegeneratePolicy::DropAll,
        DegenerateArg::Threshold => DegeneratePolicy::Threshold,
    };
    config.alpha = args.alpha;
    config.dof = match args.dof {
        DofArg::Residual => DofConvention::Residual,
        DofArg::Constraints => DofConvention::Constraints,
    };
    config.solver.threads = args.threads;
    if let Some(t) = args.time_limit {
        if !(t >= 0.0 && t.is_finite()) {
            eprintln!("error: --time-limit must be a non-negative number of seconds");
            return ExitCode::from(2);
        }
        config.solver.time_limit = Some(Duration::from_secs_f64(t));
    }
    let verbose = args.verbose && !args.quiet;
    let mut observer = |r: &IterationRecord| {
        if verbose {
            eprintln!(
                "iteration {:>3}: χ² {:.10e}  λ {:.1e}  rejected {}  |δ|∞ {:.2e}",
                r.iteration, r.objective, r.lambda, r.rejected, r.step_max
            );
        }
    };
    match pipeline::run(&config, &mut observer) {
        Ok(report) => {
            if !args.quiet {
                eprint!("{}", report.human_summary());
            }
            if args.json {
                match serde_json::to_string_pretty(&report) {
                    Ok(text) => println!("{text}"),
                    Err(e) => {
                        eprintln!("error: cannot serialise the report: {e}");
                        return ExitCode::from(1);
                    }
                }
            }
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::from(e.exit_code() as u8)
        }
    }
}
