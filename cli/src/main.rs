//! `pgo`: the command-line interface, a thin clap layer over the library.

#![cfg_attr(not(test), deny(clippy::unwrap_used, clippy::expect_used))]

use clap::{Parser, Subcommand, ValueEnum};
use optimize::OptimizeArgs;
use pgo::output::{OutputError, check_files};
use std::path::PathBuf;
use std::process::ExitCode;

/// A line on stderr, best effort: printing never panics (see
/// [`console`]).
macro_rules! say {
    ($($arg:tt)*) => {
        $crate::console::err_line(format_args!($($arg)*))
    };
}

mod console;
mod inliers;
mod optimize;

/// Pose-graph optimisation with unsupervised loop-closure gating.
#[derive(Parser, Debug)]
#[command(name = "pgo", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Optimise a pose graph read from a g2o file (exit status 3 when the
    /// result fails its χ² test; the outputs are still written).
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
    /// Project information matrices that are not positive definite to the
    /// nearest positive-definite ones instead of failing (the corrupted
    /// graph carries the projected matrices).
    #[arg(long)]
    fix_information: bool,
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
    /// Perceptual aliasing: pairs i–j measuring the pose of j+s from i, in
    /// groups of consecutive pairs sharing the offset s.
    Aliased,
}

impl From<PolicyArg> for pgo_sim::OutlierPolicy {
    fn from(p: PolicyArg) -> Self {
        match p {
            PolicyArg::Random => Self::Random,
            PolicyArg::Local => Self::Local,
            PolicyArg::Grouped => Self::Grouped,
            PolicyArg::Aliased => Self::Aliased,
        }
    }
}

#[derive(Copy, Clone, Debug, ValueEnum)]
enum AliasPlaceArg {
    /// At places the trajectory revisited, a few poses off a true loop.
    Revisited,
    /// Between any two places, most never revisited.
    Anywhere,
}

impl From<AliasPlaceArg> for pgo_sim::AliasPlace {
    fn from(p: AliasPlaceArg) -> Self {
        match p {
            AliasPlaceArg::Revisited => Self::Revisited,
            AliasPlaceArg::Anywhere => Self::Anywhere,
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
    /// each other, groups of consecutive mutually consistent wrong loops,
    /// or aliases (i–j measuring the pose of j+s from i).
    #[arg(long, visible_alias = "outlier-policy", value_enum, default_value_t = PolicyArg::Random)]
    wrong_mode: PolicyArg,
    /// Size of the groups of grouped and aliased wrong candidates (1:
    /// scattered aliases).
    #[arg(long, default_value_t = 10)]
    group_size: usize,
    /// Where aliased groups fall: at places the trajectory revisited (a
    /// true loop beside every group), or between any two places (the
    /// stretch from j said to be the stretch from i+s, moved rigidly).
    #[arg(long, value_enum, default_value_t = AliasPlaceArg::Revisited)]
    alias_place: AliasPlaceArg,
    /// Range of |s|, the offset in steps of aliased candidates (either
    /// sign), 1 ≤ MIN ≤ MAX [default: 5,40].
    #[arg(long, value_name = "MIN,MAX", value_parser = parse_alias_offsets)]
    alias_offset: Option<pgo_sim::AliasOffsets>,
    /// Share of the wrong candidates whose inlier counts are drawn from the
    /// true-loop model (each with this probability), 0 ≤ SHARE ≤ 1; in
    /// `simulate`, a positive share implies --inliers.
    #[arg(long, value_name = "SHARE", default_value_t = 0.0)]
    true_like_counts: f64,
    /// A grouped or aliased group draws --true-like-counts once for all its
    /// members (verification fooled by a repeated place is fooled along
    /// all of it) instead of once per candidate.
    #[arg(long)]
    true_like_by_group: bool,
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
    /// Whether either count model or a share of true-like counts was given.
    fn counts_given(&self) -> bool {
        self.true_inliers.is_some() || self.wrong_inliers.is_some() || self.true_like_counts > 0.0
    }

    /// The alias offsets, the library's defaults unless given.
    fn alias_offsets(&self) -> pgo_sim::AliasOffsets {
        self.alias_offset.unwrap_or_default()
    }

    /// The inlier model, [`pgo_sim::InlierModel`]'s defaults where a
    /// part is not given.
    fn inlier_model(&self) -> pgo_sim::InlierModel {
        let d = pgo_sim::InlierModel::default();
        let (t, w) = (self.true_inliers, self.wrong_inliers);
        pgo_sim::InlierModel {
            true_median: t.map_or(d.true_median, |m| m.median),
            true_sigma: t.and_then(|m| m.sigma).unwrap_or(d.true_sigma),
            wrong_median: w.map_or(d.wrong_median, |m| m.median),
            wrong_sigma: w.and_then(|m| m.sigma).unwrap_or(d.wrong_sigma),
        }
    }
}

fn parse_alias_offsets(s: &str) -> Result<pgo_sim::AliasOffsets, String> {
    let bad = || format!("expected MIN,MAX with whole numbers of steps, got '{s}'");
    let (min, max) = s.split_once(',').ok_or_else(bad)?;
    let number = |t: &str| t.trim().parse::<usize>().map_err(|_| bad());
    Ok(pgo_sim::AliasOffsets {
        min: number(min)?,
        max: number(max)?,
    })
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

fn main() -> ExitCode {
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) => {
            return match e.print() {
                Err(p) if p.kind() == std::io::ErrorKind::BrokenPipe => {
                    ExitCode::from(console::BROKEN_PIPE_STATUS)
                }
                _ => ExitCode::from(if e.use_stderr() { 2 } else { 0 }),
            };
        }
    };
    match cli.command {
        Command::Optimize(args) => optimize::command(args),
        Command::Gate(args) => gate(args),
        Command::Simulate(args) => simulate(args),
        Command::Corrupt(args) => corrupt(args),
    }
}

/// The exit status after an output could not be written: 141, quietly, if
/// it was stdout and its reader went away; else 1, with the message.
fn output_failure(e: &OutputError) -> ExitCode {
    if e.is_broken_pipe() {
        return ExitCode::from(console::BROKEN_PIPE_STATUS);
    }
    say!("error: {e}");
    ExitCode::from(1)
}

/// Prints `text` and a newline on stdout; on failure, the exit status to
/// end with (see [`console::stdout_failure`]).
fn print_result(text: &str) -> Result<(), ExitCode> {
    console::out_line(text).map_err(|e| ExitCode::from(console::stdout_failure(&e)))
}

fn corrupt(args: CorruptArgs) -> ExitCode {
    use pgo::AnyPoseGraph;
    use pgo_sim::CorruptionOptions;
    let mut outputs = vec![("-o", args.output.as_path())];
    outputs.extend(args.labels.as_deref().map(|l| ("--labels", l)));
    if let Err(message) = check_files(&[&args.input], &outputs) {
        say!("error: {message}");
        return ExitCode::from(2);
    }
    let read = if args.fix_information {
        AnyPoseGraph::read_g2o_repairing(&args.input)
    } else {
        AnyPoseGraph::read_g2o(&args.input)
    };
    let graph = match read {
        Ok(g) => g,
        Err(pgo::Error::Read(e)) => {
            say!("error: {e}");
            return ExitCode::from(2);
        }
        Err(e) => {
            say!("error: {}: {e}", args.input.display());
            return ExitCode::from(2);
        }
    };
    graph
        .read_warnings()
        .iter()
        .for_each(|w| say!("warning: {w}"));
    let options = CorruptionOptions {
        outliers: args.wrong,
        policy: args.placement.wrong_mode.into(),
        group_size: args.placement.group_size,
        alias_offsets: args.placement.alias_offsets(),
        alias_place: args.placement.alias_place.into(),
        known_wrong_last: args.known_wrong_last,
        inliers: Some(args.placement.inlier_model()),
        true_like_share: args.placement.true_like_counts,
        true_like_by_group: args.placement.true_like_by_group,
        ..CorruptionOptions::default()
    };
    let result = match graph {
        AnyPoseGraph::Planar(g) => corrupt_graph(g, &options, &args),
        AnyPoseGraph::Spatial(g) => corrupt_graph(g, &options, &args),
    };
    match result {
        Ok(message) => {
            say!("{message}");
            ExitCode::SUCCESS
        }
        Err(CorruptFailure::Output(e)) => e.exit(),
        Err(CorruptFailure::Input(message)) => {
            say!("error: {message}");
            ExitCode::from(2)
        }
    }
}

/// Why `pgo corrupt` failed: its input (exit status 2) or an output.
enum CorruptFailure {
    Input(String),
    Output(SimulatedOutputError),
}

/// A graph or labels CSV of `pgo simulate` or `pgo corrupt` that could not
/// be written.
enum SimulatedOutputError {
    /// The g2o file ([`pgo::PoseGraph::write_g2o`]).
    Graph(pgo::Error),
    /// The labels CSV.
    Labels(OutputError),
}

impl SimulatedOutputError {
    /// The exit status, as for any output: 141 quietly for a reader of
    /// stdout that went away, else 1 with the message.
    fn exit(&self) -> ExitCode {
        let e = match self {
            Self::Labels(e) => return output_failure(e),
            Self::Graph(e) => e,
        };
        match e.io_error() {
            Some((_, source)) if source.kind() == std::io::ErrorKind::BrokenPipe => {
                ExitCode::from(console::BROKEN_PIPE_STATUS)
            }
            Some((path, source)) => {
                let shown = if path.as_os_str() == "-" {
                    "stdout".into()
                } else {
                    path.display().to_string()
                };
                say!("error: {shown}: {source}");
                ExitCode::from(1)
            }
            None => {
                say!("error: {e}");
                ExitCode::from(1)
            }
        }
    }
}

fn corrupt_graph<P: pgo_sim::ErrorCoordinates<D>, const D: usize>(
    mut g: pgo::PoseGraph<P, D>,
    options: &pgo_sim::CorruptionOptions,
    args: &CorruptArgs,
) -> Result<String, CorruptFailure> {
    use rand::SeedableRng;
    g.compose_missing_poses();
    let mut rng = rand::rngs::StdRng::seed_from_u64(args.seed);
    let corruption = pgo_sim::corrupt(&g, options, &mut rng)
        .map_err(|e| CorruptFailure::Input(e.to_string()))?;
    write_graph_and_labels(
        &corruption.graph,
        None,
        &corruption.wrong,
        &args.output,
        args.labels.as_deref(),
    )
    .map_err(CorruptFailure::Output)?;
    Ok(format!(
        "wrote {}: {} true loop candidates with counts, {} wrong candidates",
        args.output.display(),
        corruption.marked,
        corruption.wrong.iter().filter(|w| **w).count()
    ))
}

/// Writes a simulated or corrupted graph, its truth if any, and its labels
/// CSV if asked for.
fn write_graph_and_labels<P: pgo::GraphPose<D>, const D: usize>(
    graph: &pgo::PoseGraph<P, D>,
    truth: Option<(&pgo::PoseGraph<P, D>, &std::path::Path)>,
    wrong: &[bool],
    output: &std::path::Path,
    labels: Option<&std::path::Path>,
) -> Result<(), SimulatedOutputError> {
    graph
        .write_g2o(output)
        .map_err(SimulatedOutputError::Graph)?;
    if let Some((truth, path)) = truth {
        truth.write_g2o(path).map_err(SimulatedOutputError::Graph)?;
    }
    if let Some(l) = labels {
        pgo::output::write(l, |w| pgo_sim::write_labels(graph, wrong, w))
            .map_err(SimulatedOutputError::Labels)?;
    }
    Ok(())
}

fn simulate(args: SimulateArgs) -> ExitCode {
    use pgo_sim::{AnySimulation, SimulationOptions, World};
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
        alias_offsets: args.placement.alias_offsets(),
        alias_place: args.placement.alias_place.into(),
        true_like_share: args.placement.true_like_counts,
        true_like_by_group: args.placement.true_like_by_group,
        inliers: (args.inliers || args.placement.counts_given())
            .then(|| args.placement.inlier_model()),
    };
    let mut outputs = vec![("-o", args.output.as_path())];
    outputs.extend(args.truth.as_deref().map(|t| ("--truth", t)));
    outputs.extend(args.labels.as_deref().map(|l| ("--labels", l)));
    if let Err(message) = check_files(&[], &outputs) {
        say!("error: {message}");
        return ExitCode::from(2);
    }
    let result = match pgo_sim::simulate(&options) {
        Ok(AnySimulation::Planar(s)) => write_simulation(&s, &args),
        Ok(AnySimulation::Spatial(s)) => write_simulation(&s, &args),
        Err(e) => {
            say!("error: {e}");
            return ExitCode::from(2);
        }
    };
    match result {
        Ok(summary) => {
            say!("{summary}");
            ExitCode::SUCCESS
        }
        Err(e) => e.exit(),
    }
}

fn write_simulation<P: pgo::GraphPose<D>, const D: usize>(
    sim: &pgo_sim::Simulation<P, D>,
    args: &SimulateArgs,
) -> Result<String, SimulatedOutputError> {
    let truth = args.truth.as_deref().map(|t| (&sim.truth, t));
    write_graph_and_labels(
        &sim.noisy,
        truth,
        &sim.wrong,
        &args.output,
        args.labels.as_deref(),
    )?;
    Ok(format!(
        "wrote {}: {} poses, {} edges, {} loop candidates ({} wrong)",
        args.output.display(),
        sim.noisy.len(),
        sim.noisy.num_edges(),
        sim.noisy.num_loop_candidates(),
        sim.num_wrong()
    ))
}

fn gate(args: GateArgs) -> ExitCode {
    let counts = match read_counts(args.counts.as_deref()) {
        Ok(c) => c,
        Err(message) => {
            say!("error: {message}");
            return ExitCode::from(2);
        }
    };
    let fit = pgo::learn_threshold(&counts, &pgo::MixtureOptions::default());
    if args.json {
        match serde_json::to_string_pretty(&fit) {
            Ok(text) => {
                if let Err(code) = print_result(&text) {
                    return code;
                }
            }
            Err(e) => {
                say!("error: cannot serialise the fit: {e}");
                return ExitCode::from(1);
            }
        }
    }
    match (&fit.degeneracy, &fit.threshold) {
        (None, Some(t)) => {
            if !args.json {
                if let Err(code) = print_result(&t.count.to_string()) {
                    return code;
                }
            }
            say!(
                "T_GV = {:.3} inliers (v_T = {:.4} of max {}); {} counts, {} zero",
                t.count,
                t.normalized,
                t.max_count,
                fit.total_counts,
                fit.zero_counts
            );
            ExitCode::SUCCESS
        }
        (Some(reason), _) => {
            say!("degenerate: {reason}");
            ExitCode::from(1)
        }
        (None, None) => {
            say!("degenerate: no threshold");
            ExitCode::from(1)
        }
    }
}

/// Counts from a g2o file (its candidates), a CSV or plain list, or stdin.
fn read_counts(path: Option<&std::path::Path>) -> Result<Vec<u64>, String> {
    let stdin = || {
        inliers::read_counts(std::io::stdin().lock(), std::path::Path::new("<stdin>"))
            .map_err(|e| e.to_string())
    };
    match path {
        None => stdin(),
        Some(p) if p.as_os_str() == "-" => stdin(),
        Some(p) if p.extension().is_some_and(|e| e == "g2o") => {
            let graph = pgo::AnyPoseGraph::read_g2o(p).map_err(|e| e.to_string())?;
            Ok(match &graph {
                pgo::AnyPoseGraph::Planar(g) => g.edges().filter_map(|e| e.inliers).collect(),
                pgo::AnyPoseGraph::Spatial(g) => g.edges().filter_map(|e| e.inliers).collect(),
            })
        }
        Some(p) => {
            let f = std::fs::File::open(p).map_err(|e| format!("{}: {e}", p.display()))?;
            inliers::read_counts(f, p).map_err(|e| e.to_string())
        }
    }
}
