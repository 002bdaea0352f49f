//! `pgo`: the command-line interface, a thin clap layer over the library.

#![cfg_attr(not(test), deny(clippy::unwrap_used, clippy::expect_used))]

use clap::{Parser, Subcommand, ValueEnum};
use pgo::gate::{DegeneratePolicy, GateMode};
use pgo::pipeline::{self, CandidateRule, OptimizeConfig};
use pgo::robust::RobustMethod;
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
    /// Make a synthetic pose graph with ground truth (and, on request, wrong
    /// loop candidates and inlier counts).
    Simulate(SimulateArgs),
    /// Corrupt an existing pose graph with wrong loop candidates (the
    /// outlier policies of `simulate`) and give every loop candidate an
    /// inlier count; for benchmarks.
    Corrupt(CorruptArgs),
}

#[derive(clap::Args, Debug)]
struct CorruptArgs {
    /// The clean g2o file (vertices that no line defines are composed along
    /// a spanning tree first; mixture edges become plain edges).
    input: PathBuf,
    /// Wrong loop candidates to add.
    #[arg(
        long,
        visible_alias = "outliers",
        value_name = "N",
        default_value_t = 100
    )]
    wrong: usize,
    #[command(flatten)]
    placement: WrongLoopArgs,
    /// The last N non-sequential edges of the input are known to be wrong (the
    /// max-mixture outlier files: the last 1000 mixture edges): they are
    /// labelled wrong and get wrong-loop counts.
    #[arg(long, value_name = "N", default_value_t = 0)]
    known_wrong_last: usize,
    /// Random seed.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Where to write the corrupted graph.
    #[arg(short, long, value_name = "OUT.g2o")]
    output: PathBuf,
    /// Where to write which edges are wrong (CSV: edge,from,to,wrong).
    #[arg(long, value_name = "LABELS.csv")]
    labels: Option<PathBuf>,
}

#[derive(clap::Args, Debug)]
struct SimulateArgs {
    /// Shape of the trajectory.
    #[arg(long, value_enum, default_value_t = WorldArg::Grid2d)]
    world: WorldArg,
    /// Number of poses.
    #[arg(long, default_value_t = 1000)]
    poses: usize,
    /// Standard deviation of the translation noise per axis (metres).
    #[arg(long, default_value_t = 0.05)]
    noise: f64,
    /// Standard deviation of the rotation noise per axis (radians).
    #[arg(long, default_value_t = 0.01)]
    rotation_noise: f64,
    /// Most true loop closures.
    #[arg(long, default_value_t = 300)]
    loops: usize,
    /// Wrong loop candidates to plant.
    #[arg(
        long,
        visible_alias = "outliers",
        value_name = "N",
        default_value_t = 0
    )]
    wrong: usize,
    #[command(flatten)]
    placement: WrongLoopArgs,
    /// Give every loop candidate an inlier count, log-normal: true loops
    /// with median 150 and σ 0.5 (of ln count), wrong ones with median 25
    /// and σ 0.5, unless --true-inliers/--wrong-inliers say otherwise (either
    /// implies --inliers).
    #[arg(long)]
    inliers: bool,
    /// Random seed.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Where to write the noisy graph (with the dead-reckoning guess).
    #[arg(short, long, value_name = "OUT.g2o")]
    output: PathBuf,
    /// Where to write the ground truth (true poses, noise-free measurements
    /// of the edges that are not wrong).
    #[arg(long, value_name = "TRUTH.g2o")]
    truth: Option<PathBuf>,
    /// Where to write which edges are wrong (CSV: edge,from,to,wrong).
    #[arg(long, value_name = "LABELS.csv")]
    labels: Option<PathBuf>,
}

#[derive(Copy, Clone, Debug, ValueEnum)]
enum WorldArg {
    /// Manhattan-style grid walk (2D).
    Grid2d,
    /// Rings climbing a sphere (3D).
    Sphere3d,
    /// Rings around a torus (3D).
    Torus3d,
}

#[derive(Copy, Clone, Debug, ValueEnum)]
enum PolicyArg {
    /// Random pairs of poses.
    Random,
    /// Pairs close in time.
    Local,
    /// Groups of consecutive pairs sharing one wrong transform.
    Grouped,
}

impl From<PolicyArg> for pgo::simulate::OutlierPolicy {
    fn from(p: PolicyArg) -> Self {
        match p {
            PolicyArg::Random => Self::Random,
            PolicyArg::Local => Self::Local,
            PolicyArg::Grouped => Self::Grouped,
        }
    }
}

/// A log-normal inlier-count model from the command line: `MEDIAN[,SIGMA]`.
#[derive(Copy, Clone, Debug)]
struct CountModel {
    median: f64,
    sigma: Option<f64>,
}

/// How wrong loop candidates are placed and what inlier counts candidates
/// get: shared by `pgo simulate` and `pgo corrupt`.
#[derive(clap::Args, Debug)]
struct WrongLoopArgs {
    /// How wrong candidates are placed: any two poses, poses within 20 of
    /// each other, or groups of consecutive mutually consistent wrong loops.
    #[arg(long, visible_alias = "outlier-policy", value_enum, default_value_t = PolicyArg::Random)]
    wrong_mode: PolicyArg,
    /// Size of the groups of grouped wrong candidates.
    #[arg(long, default_value_t = 10)]
    group_size: usize,
    /// Inlier counts of true loops: median and σ of ln count [default:
    /// 150,0.5].
    #[arg(long, visible_alias = "true-median", value_name = "MEDIAN[,SIGMA]", value_parser = parse_count_model)]
    true_inliers: Option<CountModel>,
    /// Inlier counts of wrong candidates: median and σ of ln count
    /// [default: 25,0.5].
    #[arg(long, visible_alias = "wrong-median", value_name = "MEDIAN[,SIGMA]", value_parser = parse_count_model)]
    wrong_inliers: Option<CountModel>,
}

impl WrongLoopArgs {
    /// Whether either count model was given.
    fn counts_given(&self) -> bool {
        self.true_inliers.is_some() || self.wrong_inliers.is_some()
    }

    /// The inlier model, [`pgo::simulate::InlierModel`]'s defaults where a
    /// part is not given.
    fn inlier_model(&self) -> pgo::simulate::InlierModel {
        let d = pgo::simulate::InlierModel::default();
        let (t, w) = (self.true_inliers, self.wrong_inliers);
        pgo::simulate::InlierModel {
            true_median: t.map_or(d.true_median, |m| m.median),
            true_sigma: t.and_then(|m| m.sigma).unwrap_or(d.true_sigma),
            wrong_median: w.map_or(d.wrong_median, |m| m.median),
            wrong_sigma: w.and_then(|m| m.sigma).unwrap_or(d.wrong_sigma),
        }
    }
}

fn parse_count_model(s: &str) -> Result<CountModel, String> {
    let number = |t: &str| {
        t.trim()
            .parse::<f64>()
            .ok()
            .filter(|x| x.is_finite())
            .ok_or_else(|| format!("expected MEDIAN[,SIGMA] with finite numbers, got '{s}'"))
    };
    let (median, sigma) = match s.split_once(',') {
        Some((m, sd)) => (number(m)?, Some(number(sd)?)),
        None => (number(s)?, None),
    };
    if median <= 0.0 || sigma.is_some_and(|sd| sd < 0.0) {
        return Err(format!(
            "the median must be positive and σ non-negative, got '{s}'"
        ));
    }
    Ok(CountModel { median, sigma })
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
    /// Most LM/GN iterations in all, robust reweighting rounds included.
    /// Without it, each solve stops after 100 and the robust rounds are
    /// bounded by their own limits.
    #[arg(long, value_name = "N")]
    max_iters: Option<usize>,
    /// Stop optimising after this many seconds (checked between iterations;
    /// reading, initialisation and writing not counted) and write the best
    /// estimate so far.
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
    /// Loop-candidate gate: `auto` learns T_GV from the inlier counts and drops
    /// candidates below it; `soft` drops nothing but gives each candidate its
    /// posterior P(true loop | count) as the robust prior; `off` keeps every
    /// candidate; a number N keeps candidates with count ≥ N.
    #[arg(long, value_name = "auto|soft|off|N", default_value = "auto", value_parser = parse_gate)]
    gate: GateMode,
    /// What the learned gate does when the counts do not show two components.
    #[arg(long, value_enum, default_value_t = DegenerateArg::KeepAll)]
    degenerate: DegenerateArg,
    /// Significance level of the χ² test of the result.
    #[arg(long, default_value_t = 0.05, value_parser = parse_alpha)]
    alpha: f64,
    /// Degrees of freedom of the χ² test: residual (Σ edge dimensions − free
    /// pose parameters) or constraints (number of edges, as in the paper).
    #[arg(long, value_enum, default_value_t = DofArg::Residual)]
    dof: DofArg,
    /// Robust weighting of the loop candidates that pass the gate.
    #[arg(long, value_enum, default_value_t = RobustArg::Em)]
    robust: RobustArg,
    /// Kernel width c on the whitened residual norm. Defaults: em
    /// √χ²_D(1 − 10⁻⁶) (5.54 in 2D, 6.19 in 3D); gnc √χ²_D(0.99) (3.368 /
    /// 4.100); huber and cauchy √χ²_D(0.95) (2.796 / 3.548); dcs 1 (Φ = 1).
    #[arg(long, value_name = "C")]
    robust_c: Option<f64>,
    /// EM: do not rescue the candidates the gate dropped. By default each is
    /// held out of the weighting and accepted if its residual at the map made
    /// from the kept candidates is that of an inlier (r²/s² ≤ c², or below
    /// the learned width narrowed by its count's odds), or its innovation is
    /// (see --no-innovation); a wrong loop never shapes the map it is judged
    /// by.
    #[arg(long)]
    no_rescue: bool,
    /// EM: decide on plain residuals only. By default the candidates the
    /// decided map was solved without (dropped by the gate, rejected by EM)
    /// are judged again by their innovation ν² = eᵀ(Ω⁻¹ + J·H⁻¹·Jᵀ)⁻¹e (the
    /// map's uncertainty between the two poses added to the edge's):
    /// accepted when the prior odds (a dropped candidate's count posterior,
    /// a kept one's ½) times the likelihood ratio of ln(ν²/s²) — consistent
    /// loops (the residual mixture) against the density of the dropped
    /// candidates left out (a kernel estimate, each weighted by 1 − p) —
    /// are ≥ 1.
    #[arg(long)]
    no_innovation: bool,
    /// EM: report in the JSON each loop candidate's innovation ν²/s²
    /// against the final map without it (loops[].innovation): for a loop
    /// the map was solved with, its deleted residual eᵀ(Ω⁻¹ − J·H⁻¹·Jᵀ)⁻¹e,
    /// large where the other loops contradict it; for one left out, its
    /// innovation. Off by default: it takes a selected inversion of the
    /// normal matrix (about one more factorisation, and its memory).
    #[arg(long)]
    innovations: bool,
    /// EM: decide at c instead of at the width learned from the residuals.
    /// By default, once the decisions at c settle, two normals are fitted to
    /// ln(r²/s²) of the candidates (consistent and inconsistent loops, with
    /// the gate's EM) and the candidates are decided again at the larger of
    /// the consistent component's 1 − 10⁻⁶ quantile and the crossing of the
    /// weighted densities, never below c (JSON: robust.decision_c,
    /// robust.residual_mixture).
    #[arg(long)]
    no_learn_width: bool,
    /// EM: keep deciding at the file's scale (s² = χ²/dof ≤ 1) even when a
    /// decided map does not fit the information. By default such a map
    /// (χ² > 1.4·χ²_dof(1 − 10⁻⁶)), which wrong loops bent, makes EM search the
    /// scale: decisions at trial scales 1.4× apart until a decided map fits
    /// its own; undone when a trial would keep fewer than half the loops
    /// (JSON: robust.scale_search, robust.scale_trials).
    #[arg(long)]
    no_scale_search: bool,
    /// Which edges are loop candidates: those with an inlier count, or also
    /// every edge between non-consecutive ids.
    #[arg(long, value_enum, default_value_t = CandidatesArg::Counted)]
    candidates: CandidatesArg,
    /// Write SVG pictures into this directory: counts.svg (histogram of the
    /// normalised inlier counts with the fitted mixture and T_GV) and
    /// trajectory.svg (before and after, loops coloured by final weight).
    #[arg(long, value_name = "DIR")]
    plot: Option<PathBuf>,
    /// Threads: 0 (the default) and 1 optimise in one thread, which was the
    /// fastest on a 2-core machine shared with other work; N > 1 uses N.
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
enum RobustArg {
    /// Plain least squares.
    None,
    /// EM-weighted loop edges (Lee et al., IROS 2013).
    Em,
    /// Huber kernel.
    Huber,
    /// Cauchy kernel.
    Cauchy,
    /// Dynamic covariance scaling.
    Dcs,
    /// Graduated non-convexity (truncated least squares).
    Gnc,
}

#[derive(Copy, Clone, Debug, ValueEnum)]
enum CandidatesArg {
    /// Edges with an inlier count.
    Counted,
    /// Also every edge with |i − j| ≠ 1.
    NonSequential,
}

#[derive(Copy, Clone, Debug, ValueEnum)]
enum DegenerateArg {
    /// Keep every candidate: the robust back end decides them by geometry.
    KeepAll,
    /// Drop every counted candidate: no wrong loop gets in (the choice with
    /// --robust none).
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
        "soft" => Ok(GateMode::Soft),
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
        Command::Simulate(args) => simulate(args),
        Command::Corrupt(args) => corrupt(args),
    }
}

/// The output must not be the input (through links or `..` too): only
/// `--in-place` overwrites the input.
fn refuse_to_overwrite_input(
    input: &std::path::Path,
    output: &std::path::Path,
) -> Result<(), String> {
    if pgo::io::same_file(input, output) {
        Err(format!(
            "{}: the output is the input file {}; pgo overwrites its input only with --in-place",
            output.display(),
            input.display()
        ))
    } else {
        Ok(())
    }
}

fn corrupt(args: CorruptArgs) -> ExitCode {
    use pgo::graph::AnyPoseGraph;
    use pgo::simulate::CorruptionOptions;
    if let Err(message) = refuse_to_overwrite_input(&args.input, &args.output) {
        eprintln!("error: {message}");
        return ExitCode::from(2);
    }
    let mut file = match pgo::io::g2o::read(&args.input, Default::default()) {
        Ok(f) => f,
        Err(e) => {
            eprintln!("error: {e}");
            return ExitCode::from(2);
        }
    };
    let options = CorruptionOptions {
        outliers: args.wrong,
        policy: args.placement.wrong_mode.into(),
        group_size: args.placement.group_size,
        known_wrong_last: args.known_wrong_last,
        inliers: Some(args.placement.inlier_model()),
        ..CorruptionOptions::default()
    };
    let result = match &mut file.graph {
        AnyPoseGraph::Planar(g) => corrupt_graph(g, &file.missing, &options, &args),
        AnyPoseGraph::Spatial(g) => corrupt_graph(g, &file.missing, &options, &args),
    };
    match result {
        Ok(message) => {
            eprintln!("{message}");
            ExitCode::SUCCESS
        }
        Err((code, message)) => {
            eprintln!("error: {message}");
            ExitCode::from(code)
        }
    }
}

fn corrupt_graph<P, const D: usize>(
    g: &mut pgo::graph::PoseGraph<P, D>,
    missing: &[usize],
    options: &pgo::simulate::CorruptionOptions,
    args: &CorruptArgs,
) -> Result<String, (u8, String)>
where
    P: pgo::io::g2o::G2oPose<D> + pgo::solve::init::ChordalInit<D>,
{
    use pgo::io::{g2o::write_graph, write_atomically};
    use rand::SeedableRng;
    pgo::solve::init::initialize(g, missing, Initialization::File, None)
        .map_err(|e| (2, format!("{}: {e}", args.input.display())))?;
    let mut rng = rand::rngs::StdRng::seed_from_u64(args.seed);
    let corruption =
        pgo::simulate::corrupt(g, options, &mut rng).map_err(|e| (2, e.to_string()))?;
    write_atomically(&args.output, |w| write_graph(g, w))
        .map_err(|e| (1, format!("{}: {e}", args.output.display())))?;
    if let Some(l) = &args.labels {
        write_atomically(l, |w| pgo::simulate::write_labels(g, &corruption.wrong, w))
            .map_err(|e| (1, format!("{}: {e}", l.display())))?;
    }
    Ok(format!(
        "wrote {}: {} true loop candidates with counts, {} wrong candidates",
        args.output.display(),
        corruption.marked,
        corruption.wrong.iter().filter(|w| **w).count()
    ))
}

fn simulate(args: SimulateArgs) -> ExitCode {
    use pgo::simulate::{self, AnySimulation, SimulationOptions, World};
    let options = SimulationOptions {
        world: match args.world {
            WorldArg::Grid2d => World::Grid2d,
            WorldArg::Sphere3d => World::Sphere3d,
            WorldArg::Torus3d => World::Torus3d,
        },
        poses: args.poses,
        translation_noise: args.noise,
        rotation_noise: args.rotation_noise,
        loops: args.loops,
        seed: args.seed,
        outliers: args.wrong,
        outlier_policy: args.placement.wrong_mode.into(),
        group_size: args.placement.group_size,
        inliers: (args.inliers || args.placement.counts_given())
            .then(|| args.placement.inlier_model()),
    };
    let result = match simulate::simulate(&options) {
        Ok(AnySimulation::Planar(s)) => write_simulation(&s, &args),
        Ok(AnySimulation::Spatial(s)) => write_simulation(&s, &args),
        Err(e) => {
            eprintln!("error: {e}");
            return ExitCode::from(2);
        }
    };
    match result {
        Ok(summary) => {
            eprintln!("{summary}");
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::from(1)
        }
    }
}

fn write_simulation<P: pgo::io::g2o::G2oPose<D>, const D: usize>(
    sim: &pgo::simulate::Simulation<P, D>,
    args: &SimulateArgs,
) -> Result<String, String> {
    use pgo::io::{g2o::write_graph, write_atomically};
    let write = |path: &PathBuf, g: &pgo::graph::PoseGraph<P, D>| {
        write_atomically(path, |w| write_graph(g, w))
            .map_err(|e| format!("{}: {e}", path.display()))
    };
    write(&args.output, &sim.noisy)?;
    if let Some(t) = &args.truth {
        write(t, &sim.truth)?;
    }
    if let Some(l) = &args.labels {
        write_atomically(l, |w| {
            pgo::simulate::write_labels(&sim.noisy, &sim.wrong, w)
        })
        .map_err(|e| format!("{}: {e}", l.display()))?;
    }
    Ok(format!(
        "wrote {}: {} poses, {} edges, {} loop candidates ({} wrong)",
        args.output.display(),
        sim.noisy.num_vertices(),
        sim.noisy.edges.len(),
        sim.noisy.num_candidates(),
        sim.num_wrong()
    ))
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
    if let Some(out) = &args.output {
        if let Err(message) = refuse_to_overwrite_input(&args.input, out) {
            eprintln!("error: {message}");
            return ExitCode::from(2);
        }
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
    if let Some(n) = args.max_iters {
        config.solver.max_iterations = n;
    }
    config.iteration_budget = args.max_iters;
    config.gate = args.gate;
    config.degenerate = match args.degenerate {
        DegenerateArg::KeepAll => DegeneratePolicy::KeepAll,
        DegenerateArg::DropAll => DegeneratePolicy::DropAll,
        DegenerateArg::Threshold => DegeneratePolicy::Threshold,
    };
    config.alpha = args.alpha;
    config.robust = match args.robust {
        RobustArg::None => RobustMethod::None,
        RobustArg::Em => RobustMethod::Em,
        RobustArg::Huber => RobustMethod::Huber,
        RobustArg::Cauchy => RobustMethod::Cauchy,
        RobustArg::Dcs => RobustMethod::Dcs,
        RobustArg::Gnc => RobustMethod::Gnc,
    };
    config.robust_c = args.robust_c;
    config.rescue = !args.no_rescue;
    config.innovation = !args.no_innovation;
    config.loop_innovations = args.innovations;
    config.learn_width = !args.no_learn_width;
    config.scale_search = !args.no_scale_search;
    config.plot = args.plot.clone();
    config.candidates = match args.candidates {
        CandidatesArg::Counted => CandidateRule::Counted,
        CandidatesArg::NonSequential => CandidateRule::NonSequential,
    };
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
