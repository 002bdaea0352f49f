//! `pgo`: the command-line interface, a thin clap layer over the library.

use clap::{Parser, Subcommand, ValueEnum};
use pgo::pipeline::{self, OptimizeConfig};
use pgo::solve::init::Initialization;
use pgo::solve::{IterationRecord, Method};
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
