//! `pgo optimize`: the library's job on a g2o file — read it (and an
//! inlier CSV), optimise it, write the map, the covariances and the
//! pictures, print the report — with the command line's exit statuses.

use crate::console;
use crate::inliers::{self, InlierCsvError};
use pgo::output::{CheckError, check_files};
use pgo::plot::PlotError;
use pgo::report::Report;
use pgo::{AnyPoseGraph, AnySolution, Error, IterationRecord, Observer, Setting};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

#[derive(clap::Args, Debug)]
pub struct OptimizeArgs {
    /// Input g2o file (VERTEX_SE2/EDGE_SE2 or VERTEX_SE3:QUAT/EDGE_SE3:QUAT;
    /// `-` reads stdin).
    pub input: PathBuf,
    /// Write the optimised graph here (atomically: temporary file, then
    /// rename; `-` writes stdout).
    #[arg(short, long, value_name = "OUT.g2o")]
    pub output: Option<PathBuf>,
    /// Write the optimised graph over the input file (every line it does not
    /// change kept as it was).
    #[arg(long, conflicts_with = "output")]
    pub in_place: bool,
    /// Inlier counts of loop candidates from a CSV file (from,to,inliers).
    #[arg(long, value_name = "FILE")]
    pub inliers: Option<PathBuf>,
    /// Project information matrices that are not positive definite to the
    /// nearest positive-definite ones instead of failing.
    #[arg(long)]
    pub fix_information: bool,
    /// Write SVG pictures into this directory: counts.svg (histogram of the
    /// normalised inlier counts with the fitted mixture and T_GV), loops.svg
    /// (each candidate's innovation and prior against the loop model, with
    /// the line where its posterior is ½) and trajectory.svg (before and
    /// after, loops coloured by final weight).
    #[arg(long, value_name = "DIR")]
    pub plot: Option<PathBuf>,
    /// Write every pose's marginal covariance here as CSV (atomically; `-`
    /// writes stdout): a header, then per pose its id and its D×D
    /// covariance row by row, D = 3 (x, y, theta) or 6 (x, y, z, rx, ry,
    /// rz), perturbed on the right (in the pose's frame), from the map's
    /// edges at the optimum with the fixed poses as the gauge (zeros). A
    /// pose no edge in the map ties to them is left out, with a warning.
    #[arg(long, value_name = "FILE.csv")]
    pub covariances: Option<PathBuf>,
    /// Write the optimised trajectory here in the TUM format, as evo reads
    /// it (atomically; `-` writes stdout): per pose in the graph's order,
    /// `timestamp tx ty tz qx qy qz qw`, the timestamp its vertex id; a 2D
    /// pose as z = 0 and a rotation about z.
    #[arg(long, value_name = "FILE")]
    pub tum: Option<PathBuf>,
    /// Write the optimised trajectory here in the KITTI format, as evo
    /// reads it (atomically; `-` writes stdout): per pose in the graph's
    /// order (KITTI has no ids), the 3×4 matrix [R t] row by row.
    #[arg(long, value_name = "FILE")]
    pub kitti: Option<PathBuf>,
    /// Everything the job itself can be told (the library's `Options`).
    #[command(flatten)]
    pub options: pgo::Options,
    /// Print the JSON report on stdout.
    #[arg(long)]
    pub json: bool,
    /// Certify the map: prove it the global optimum of SE-Sync's isotropic
    /// problem over its edges (the report's "certificate"), or say why not.
    #[arg(long)]
    pub certify: bool,
    /// Print nothing on stderr but errors.
    #[arg(short, long)]
    pub quiet: bool,
    /// Print every iteration on stderr.
    #[arg(short, long)]
    pub verbose: bool,
}

/// The exit status of `pgo optimize` when the result fails its χ² test
/// (the outputs are still written).
const CHI2_FAILED_STATUS: u8 = 3;

/// The exit status of `pgo optimize` stopped by Ctrl-C (128 + SIGINT, as
/// shells report it; the outputs are still written).
const INTERRUPTED_STATUS: u8 = 130;

/// The exit status of `pgo optimize` when its budget (`--max-iters`,
/// `--time-limit`) ran out before the job finished: the map written is the
/// best so far, its decisions and χ² verdict those of an unfinished job.
const BUDGET_STATUS: u8 = 4;

/// The exit status of `pgo optimize` when the map passed its χ² test with
/// settled decisions but the evidence questions some of them: an accepted
/// cluster is doubtful (`robust.doubtful`), rejected loops were held back
/// by their counts alone (`robust.held_back`) or accepted loops err beyond
/// the true loops' reach (`robust.outlying`), any of them moving the map by
/// over 1 % of its size. The map is written; a script can tell it from a
/// map nothing questions.
const QUESTIONED_STATUS: u8 = 5;

/// Why `pgo optimize` failed.
#[derive(Debug, thiserror::Error)]
pub enum Failure {
    /// The library refused the graph or the job failed on it.
    #[error("{}", library_message(.input, .error))]
    Job {
        /// The input file.
        input: PathBuf,
        /// The library's error.
        error: Error,
    },
    /// The inlier CSV is unreadable or malformed.
    #[error(transparent)]
    Inliers(#[from] InlierCsvError),
    /// A picture could not be drawn or written.
    #[error(transparent)]
    Plot(#[from] PlotError),
}

/// The library's message for the command line: its options by their flags,
/// and the input named where the message does not name a file itself.
fn library_message(input: &Path, error: &Error) -> String {
    let message = error.message_with(&|s| match s {
        Setting::RepairAdded | Setting::RepairRead => "--fix-information".into(),
        other => other.rust_name(),
    });
    if error.io_error().is_some() || matches!(error, Error::Read(_)) {
        message
    } else {
        format!("{}: {message}", input.display())
    }
}

impl Failure {
    /// The process exit status: 2 for input the job cannot take, 1 for
    /// other failures (an output that cannot be written among them).
    pub fn exit_code(&self) -> u8 {
        use pgo::ErrorKind as K;
        match self {
            Self::Inliers(_) => 2,
            // An output that cannot be written is a runtime error, not bad
            // input (the README's exit statuses).
            Self::Job {
                error: Error::Write { .. },
                ..
            } => 1,
            Self::Job { error, .. } => match error.kind() {
                K::Io | K::Parse | K::Dimension | K::InvalidInformation | K::InvalidPose => 2,
                K::Unconstrained | K::EmptyGraph | K::UnknownVertex | K::InvalidOption => 2,
                _ if matches!(
                    error,
                    Error::Undetermined { .. } | Error::NonFiniteEdge { .. }
                ) =>
                {
                    2
                }
                _ => 1,
            },
            Self::Plot(_) => 1,
        }
    }
}

/// Runs `pgo optimize`: returns the report after writing every output
/// asked for. `observer` sees every solver iteration. Unless `-q`, the
/// summary's header and what reading the file noticed are printed as soon
/// as the file is read (returned too, so that the summary does not repeat
/// them).
pub fn run(
    args: &OptimizeArgs,
    observer: &mut dyn Observer,
) -> Result<(Report, Vec<String>), Failure> {
    let start = Instant::now();
    let job = |error| Failure::Job {
        input: args.input.clone(),
        error,
    };
    let mut graph = if args.fix_information {
        AnyPoseGraph::read_g2o_repairing(&args.input)
    } else {
        AnyPoseGraph::read_g2o(&args.input)
    }
    .map_err(job)?;
    let read_s = start.elapsed().as_secs_f64();
    let said = graph.read_warnings().to_vec();
    if !args.quiet {
        let sizes = [graph.len(), graph.num_edges(), graph.num_loop_candidates()];
        let input = args.input.display().to_string();
        say!("{}", Report::header(&input, graph.dimension(), sizes));
        said.iter().for_each(|w| say!("warning: {w}"));
        if let Some(note) = candidates_hint(&graph, &args.options) {
            say!("note: {note}");
        }
    }
    let mut replaced = None;
    if let Some(csv) = &args.inliers {
        let rows = inliers::read_csv(csv)?;
        let n = inliers::apply(&mut graph, &rows, csv)?;
        replaced =
            (n > 0).then(|| format!("{}: replaced the inlier counts of {n} edges", csv.display()));
    }
    let solution = graph.optimize_with(&args.options, observer).map_err(job)?;
    // The solution holds the map and what writing it and its pictures needs.
    drop(graph);
    let mut report = solution.report().clone();
    report.time.read_s = read_s;
    report.warnings.splice(0..0, replaced);
    if let Some(dir) = &args.plot {
        let written = solution.write_plots(dir)?;
        (report.plots).extend(written.iter().map(|p| p.display().to_string()));
    }
    if args.certify {
        match solution.certificate() {
            Ok(c) => report.certificate = Some(c),
            Err(e) => report.warnings.push(format!("no certificate: {e}")),
        }
    }
    let output = if args.in_place {
        Some(&args.input)
    } else {
        args.output.as_ref()
    };
    if let Some(out) = output {
        let writing = Instant::now();
        solution.write_g2o(out).map_err(job)?;
        report.output = Some(out.display().to_string());
        report.time.write_s = writing.elapsed().as_secs_f64();
    }
    if let Some(path) = &args.covariances {
        write_covariances(&solution, path, &mut report).map_err(job)?;
    }
    if let Some(path) = &args.tum {
        solution.write_tum(path).map_err(job)?;
        report.trajectories.push(path.display().to_string());
    }
    if let Some(path) = &args.kitti {
        solution.write_kitti(path).map_err(job)?;
        report.trajectories.push(path.display().to_string());
    }
    report.time.total_s = start.elapsed().as_secs_f64();
    Ok((report, said))
}

/// A hint for a file whose loops the job will all trust: no edge has an
/// inlier count (as in the public datasets), yet some join non-consecutive
/// poses, and `--candidates non-sequential` was not given.
fn candidates_hint(graph: &AnyPoseGraph, options: &pgo::Options) -> Option<String> {
    let counted = options.gate.candidates == pgo::CandidateRule::Counted;
    let loops = match graph {
        AnyPoseGraph::Planar(g) => g.edges().filter(|e| e.from.abs_diff(e.to) != 1).count(),
        AnyPoseGraph::Spatial(g) => g.edges().filter(|e| e.from.abs_diff(e.to) != 1).count(),
    };
    (counted && graph.num_loop_candidates() == 0 && loops > 0).then(|| {
        format!(
            "no edge has an inlier count, so all {loops} edges between non-consecutive poses are \
             trusted loops; --candidates non-sequential weighs them as loop candidates"
        )
    })
}

/// Writes the covariances of the map (`--covariances`): a warning names
/// the poses left out.
fn write_covariances(
    solution: &AnySolution,
    path: &Path,
    report: &mut Report,
) -> Result<(), Error> {
    let covariances = solution.covariances()?;
    let mut unbounded = Vec::new();
    pgo::output::write_atomically(path, |w| {
        unbounded = covariances.write_csv(w)?;
        Ok(())
    })
    .map_err(|source| Error::Write {
        path: path.to_owned(),
        source,
    })?;
    if let Some(first) = unbounded.first() {
        let warning = format!(
            "--covariances: {} poses left out (no trusted edge or accepted loop ties them to the \
             fixed poses: their covariance is unbounded), e.g. {first}",
            unbounded.len()
        );
        report.warnings.push(warning);
    }
    Ok(())
}

/// The decisions of a finished job the evidence questions (the accepted
/// loops of doubtful clusters, the rejected loops held back by their
/// counts, the outlying accepted loops), in words.
fn questioned(report: &Report) -> String {
    let robust = &report.robust;
    let doubtful: usize = robust.doubtful.iter().map(|d| d.loops.len()).sum();
    let held: usize = robust.held_back.iter().map(|h| h.loops.len()).sum();
    let outlying: usize = robust.outlying.iter().map(|o| o.loops.len()).sum();
    let parts: Vec<String> = [
        (doubtful, "accepted", "in doubtful clusters"),
        (held, "rejected", "held back by their counts"),
        (outlying, "accepted", "beyond the true loops' reach"),
    ]
    .into_iter()
    .filter(|&(n, _, _)| n > 0)
    .map(|(n, decided, what)| {
        let loops = if n == 1 { "loop" } else { "loops" };
        format!("{n} {decided} {loops} {what}")
    })
    .collect();
    parts.join(" and ")
}

/// `pgo optimize`: checks the files, runs the job with Ctrl-C as its
/// cancellation, prints the summary (and the JSON report), and ends with
/// the exit status: 3 when the χ² test failed, 4 when the job did not
/// finish, 5 when its decisions are questioned, 130 when interrupted.
pub fn command(args: OptimizeArgs) -> ExitCode {
    if let Err(message) = check_optimize_files(&args) {
        say!("error: {message}");
        return ExitCode::from(2);
    }
    let verbose = args.verbose && !args.quiet;
    // Ctrl-C stops the optimisation between iterations; the best map so far
    // is written and the exit status says it was interrupted.
    let cancel = pgo::Cancel::new();
    let on_interrupt = cancel.clone();
    let _ = ctrlc::set_handler(move || on_interrupt.cancel());
    let spinner = console::Spinner::new(args.quiet || verbose);
    let progress = |r: &IterationRecord| {
        if verbose {
            say!(
                "iteration {:>3}: objective {:.10e}  λ {:.1e}  rejected {}  |δ|∞ {:.2e}",
                r.iteration,
                r.objective,
                r.lambda,
                r.rejected,
                r.step_max
            );
        }
        spinner.iteration(r.objective);
    };
    let mut observer = pgo::Cancellable::new(cancel, progress);
    let outcome = run(&args, &mut observer);
    spinner.clear();
    match outcome {
        Ok((report, said)) => finish(&args, &report, &said),
        // `-o -`: a reader that went away (141, quietly), or a full stdout.
        Err(Failure::Job {
            error: Error::Write { path, source },
            ..
        }) if path.as_os_str() == "-" => ExitCode::from(console::stdout_failure(&source)),
        Err(e) => {
            say!("error: {e}");
            ExitCode::from(e.exit_code())
        }
    }
}

/// Prints the summary (but its header and the warnings `said` already)
/// and the report; the exit status of a job that ran.
fn finish(args: &OptimizeArgs, report: &Report, said: &[String]) -> ExitCode {
    if !args.quiet {
        let mut rest = report.clone();
        rest.warnings.retain(|w| !said.contains(w));
        console::err(format_args!("{}", rest.human_body()));
        // The solver's line counts its own time; where the rest went.
        console::err(format_args!("{}\n", report.time_summary()));
    }
    if args.json {
        match serde_json::to_string_pretty(report) {
            Ok(text) => {
                if let Err(e) = console::out_line(&text) {
                    return ExitCode::from(console::stdout_failure(&e));
                }
            }
            Err(e) => {
                say!("error: cannot serialise the report: {e}");
                return ExitCode::from(1);
            }
        }
    }
    match status_line(args, report) {
        None => ExitCode::SUCCESS,
        Some((status, line)) => {
            say!("{line} (exit status {status})");
            ExitCode::from(status)
        }
    }
}

/// The exit status of a job that ran and the line saying why, from its
/// report's [`pgo::MapStatus`]; `None` for success.
fn status_line(args: &OptimizeArgs, report: &Report) -> Option<(u8, String)> {
    let (status, line) = match report.status() {
        pgo::MapStatus::Ok => return None,
        pgo::MapStatus::Cancelled => (
            INTERRUPTED_STATUS,
            "pgo: interrupted: the best map so far was written".to_owned(),
        ),
        pgo::MapStatus::Chi2Failed => (
            CHI2_FAILED_STATUS,
            "pgo: the χ² test FAILED: the map does not fit its measurements".to_owned(),
        ),
        pgo::MapStatus::Unfinished => {
            // Without `--max-iters`, only a last solve that did not converge
            // within its own limit (ten times each solve's) stops at the
            // iteration limit.
            let what = match report.optimizer.stop_reason {
                pgo::StopReason::TimeLimit => "--time-limit stopped the job before it finished",
                _ if args.options.solver.max_iterations.is_some() => {
                    "--max-iters stopped the job before it finished"
                }
                _ => "the last solve did not converge within its iteration limit",
            };
            let line = format!(
                "pgo: {what}: the best map so far was written, its loop decisions and χ² verdict \
                 unfinished"
            );
            (BUDGET_STATUS, line)
        }
        pgo::MapStatus::Unsettled => {
            let unsettled = (report.loops.iter())
                .filter(|l| l.reason == pgo::Reason::Unsettled)
                .count();
            let line = format!(
                "pgo: the loop decisions did not settle ({unsettled} candidates `unsettled`): the \
                 map written rests on decisions its loop model does not confirm"
            );
            (BUDGET_STATUS, line)
        }
        pgo::MapStatus::Questioned => {
            let line = format!(
                "pgo: the map passed its χ² test, but the evidence questions {}: reversing those \
                 decisions would move the map by over 1 % of its size; see robust.doubtful, \
                 robust.held_back and robust.outlying in the JSON report",
                questioned(report)
            );
            (QUESTIONED_STATUS, line)
        }
    };
    Some((status, line))
}

/// [`check_files`] for `pgo optimize`: the input (`-`: stdin) and
/// `--inliers` are read; `-o` is written, or with `--in-place` the input
/// itself (which must then be a file), and `-o -` leaves stdout to the
/// graph (no `--json`).
pub fn check_optimize_files(args: &OptimizeArgs) -> Result<(), String> {
    let mut inputs = vec![args.input.as_path()];
    inputs.extend(args.inliers.as_deref());
    let checked: Result<(), CheckError> = if args.in_place {
        if args.input.as_os_str() == "-" {
            return Err("--in-place needs an input file, not stdin (-)".into());
        }
        check_files(&inputs[1..], &[("--in-place", &args.input)])
            .and_then(|_| check_files(&inputs, &[]))
    } else {
        match &args.output {
            Some(o) if args.json && o.as_os_str() == "-" => {
                return Err("-o - and --json both write to stdout: give -o a file".into());
            }
            Some(o) => check_files(&inputs, &[("-o", o)]),
            None => check_files(&inputs, &[]),
        }
    };
    checked.map_err(|e| e.to_string())?;
    check_plot_dir(args.plot.as_deref())?;
    check_extra_outputs(args, &inputs)
}

/// `--plot DIR` must be a directory or not exist yet (it is made): a file
/// there is refused before anything runs, so that no other output waits
/// on a job whose pictures cannot be written.
fn check_plot_dir(dir: Option<&std::path::Path>) -> Result<(), String> {
    match dir.map(std::fs::metadata) {
        Some(Ok(meta)) if !meta.is_dir() => Err(format!(
            "--plot {}: not a directory (the pictures go into a directory, made if missing)",
            dir.map_or_else(String::new, |d| d.display().to_string())
        )),
        _ => Ok(()),
    }
}

/// [`check_files`] for `--covariances`, `--tum` and `--kitti`: outputs of
/// their own, beside each other, `-o` (or the input, `--in-place`) and
/// `--json` on stdout: at most one of them all may be `-`.
fn check_extra_outputs(args: &OptimizeArgs, inputs: &[&std::path::Path]) -> Result<(), String> {
    let extra = [
        ("--covariances", &args.covariances),
        ("--tum", &args.tum),
        ("--kitti", &args.kitti),
    ];
    let mut outputs: Vec<(&str, &Path)> = (extra.iter())
        .filter_map(|(option, path)| Some((*option, path.as_deref()?)))
        .collect();
    if outputs.is_empty() {
        return Ok(());
    }
    outputs.extend(args.output.as_deref().map(|o| ("-o", o)));
    let inputs = if args.in_place {
        outputs.push(("--in-place", args.input.as_path()));
        &inputs[1..]
    } else {
        inputs
    };
    if args.json {
        outputs.push(("--json", std::path::Path::new("-")));
    }
    check_files(inputs, &outputs).map_err(|e| e.to_string())
}
