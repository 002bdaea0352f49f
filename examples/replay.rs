//! Replays a g2o file as a mapping front end would feed it: poses in file
//! order, each edge added once both its ends exist, [`pgo::AnyPoseGraph::update`]
//! every N poses; then checks the last map against a batch solve.
//!
//! ```text
//! cargo run --release --example replay -- g2o_samples/grid2d.g2o 10
//! cargo run --release --example replay -- g2o_samples/grid2d.g2o 10 --update-iters 1
//! ```
//!
//! With `--update-iters K` each update solves for at most K iterations
//! (`update-iters`), and a closing update with nothing added finishes the
//! convergence; its time counts in the total. `--set NAME=VALUE` sets any
//! other option by its name (`Options::set`), e.g. `--set threads=1`.
//! `--gap-every M` compares every M-th update's map with a batch solve of
//! the graph at that point (untimed): how far its χ² is above the batch
//! job's, and its positions (as a share of the map's size) and rotations
//! from the batch job's, each update's with `-v`, with the loops only one
//! of the two accepts. `--hash` prints, after every update, a hash of
//! the bits of its poses and χ²: two builds (of one toolchain) that print
//! the same lines gave the same map at every update.
//!
//! Prints one line per update (poses, how it was solved, milliseconds) and
//! the earlier decisions it changed (and, for a whole job, why) with `-v`,
//! and a summary: updates, total and p99 time, how many of each kind, the
//! gaps, and the final χ² and decisions against the batch ones (with `-v`,
//! each decision that differs).

use pgo::{AnyPoseGraph, AnySolution, Options, UpdateSolve};
use std::collections::HashMap;
use std::io::Write;
use std::time::Instant;

/// One edge of the file: its ends, measurement, information (full, row by
/// row) and inlier count.
struct Edge {
    from: u64,
    to: u64,
    measurement: Vec<f64>,
    information: Vec<f64>,
    inliers: Option<u64>,
}

/// The full `n × n` matrix from g2o's upper triangle, row by row.
fn full(upper: &[f64], n: usize) -> Vec<f64> {
    let mut m = vec![0.0; n * n];
    let mut k = 0;
    for r in 0..n {
        for c in r..n {
            m[r * n + c] = upper[k];
            m[c * n + r] = upper[k];
            k += 1;
        }
    }
    m
}

/// A vertex of the file: its id and g2o numbers.
type Vertex = (u64, Vec<f64>);

/// Vertices and edges in file order, and the dimension.
fn read(path: &str) -> Result<(usize, Vec<Vertex>, Vec<Edge>), String> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("{path}: {e}"))?;
    let (mut vertices, mut edges, mut dim) = (Vec::new(), Vec::new(), 2);
    for (n, line) in text.lines().enumerate() {
        let t: Vec<&str> = line.split_whitespace().collect();
        let num = |s: &str| {
            s.parse::<f64>()
                .map_err(|_| format!("{path}:{}: bad number {s:?}", n + 1))
        };
        let (size, info) = match t.first().copied() {
            Some("VERTEX_SE2") | Some("EDGE_SE2") => (3, 6),
            Some("VERTEX_SE3:QUAT") | Some("EDGE_SE3:QUAT") => (7, 21),
            _ => continue,
        };
        dim = if size == 3 { 2 } else { 3 };
        let id = |s: &str| {
            s.parse::<u64>()
                .map_err(|_| format!("{path}:{}: bad id {s:?}", n + 1))
        };
        if t[0].starts_with("VERTEX") {
            let x: Result<Vec<f64>, _> = t[2..2 + size].iter().map(|s| num(s)).collect();
            vertices.push((id(t[1])?, x?));
        } else {
            let x: Result<Vec<f64>, _> = t[3..3 + size + info].iter().map(|s| num(s)).collect();
            let x = x?;
            let d = if size == 3 { 3 } else { 6 };
            edges.push(Edge {
                from: id(t[1])?,
                to: id(t[2])?,
                measurement: x[..size].to_vec(),
                information: full(&x[size..], d),
                inliers: t.get(3 + size + info).map(|s| id(s)).transpose()?,
            });
        }
    }
    Ok((dim, vertices, edges))
}

/// The command line.
struct Args {
    path: String,
    /// Update every this many poses.
    every: usize,
    options: Options,
    verbose: bool,
    /// Print a hash of each update's map.
    hash: bool,
    /// Measure every this many updates' gap to the batch optimum (0: none).
    gap_every: usize,
}

const USAGE: &str = "usage: replay FILE.g2o [EVERY_N_POSES] [--update-iters K] \
                     [--set NAME=VALUE]… [--gap-every M] [--hash] [-v]";

fn parse_args() -> Result<Args, Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let verbose = args.iter().any(|a| a == "-v");
    let hash = args.iter().any(|a| a == "--hash");
    let (mut options, mut gap_every, mut rest) = (Options::default(), 0, Vec::new());
    let mut it = args.iter().filter(|a| *a != "-v" && *a != "--hash");
    while let Some(a) = it.next() {
        let mut value = || it.next().ok_or(format!("{a} needs a value"));
        match a.as_str() {
            "--update-iters" => options.set("update-iters", value()?)?,
            "--set" => {
                let (name, v) = value()?.split_once('=').ok_or("--set needs NAME=VALUE")?;
                options.set(name, v)?;
            }
            "--gap-every" => gap_every = value()?.parse()?,
            _ => rest.push(a.clone()),
        }
    }
    let (Some(path), every) = (rest.first(), rest.get(1)) else {
        return Err(USAGE.into());
    };
    Ok(Args {
        path: path.clone(),
        every: every.map_or(Ok(1), |s| s.parse())?,
        options,
        verbose,
        hash,
        gap_every,
    })
}

/// What the updates did: each one's milliseconds, how many of each kind,
/// the earlier decisions they changed, and the measured gaps.
#[derive(Default)]
struct Tally {
    times: Vec<f64>,
    kinds: HashMap<&'static str, usize>,
    changed: usize,
    gaps: Vec<f64>,
    /// At the same updates: how far the positions are from the batch
    /// job's, as a share of the map's size.
    apart: Vec<f64>,
    /// At the same updates: the largest angle from the batch job's
    /// rotations, in radians.
    turned: Vec<f64>,
}

/// `options` without the bound on an update's iterations.
fn unbounded(options: &Options) -> Options {
    let mut plain = options.clone();
    plain.solver.update_iterations = None;
    plain
}

/// Adds one edge of the file to `graph`.
fn add(graph: &mut AnyPoseGraph, e: &Edge) -> Result<(), pgo::Error> {
    match e.inliers {
        Some(n) => graph.add_loop_candidate(e.from, e.to, &e.measurement, &e.information, Some(n)),
        None => graph.add_edge(e.from, e.to, &e.measurement, &e.information),
    }
    .map(|_| ())
}

/// One timed update at `poses` poses, tallied (and printed with `-v`).
fn update(
    graph: &mut AnyPoseGraph,
    args: &Args,
    poses: usize,
    tally: &mut Tally,
    out: &mut impl Write,
) -> Result<AnySolution, Box<dyn std::error::Error>> {
    let t = Instant::now();
    let solution = graph.update(&args.options)?;
    let ms = t.elapsed().as_secs_f64() * 1e3;
    tally.times.push(ms);
    if args.hash {
        writeln!(out, "hash {poses} {:016x}", map_hash(&solution))?;
    }
    let inc = solution.incremental();
    let name = match inc.map_or(UpdateSolve::Batch, |i| i.solve) {
        UpdateSolve::Batch => "batch",
        UpdateSolve::None => "none",
        UpdateSolve::Extended => "extended",
        UpdateSolve::Warm => "warm",
        UpdateSolve::Full => "full",
    };
    *tally.kinds.entry(name).or_default() += 1;
    let changes = inc.map_or(&[][..], |i| &i.changed[..]);
    tally.changed += changes.len();
    if args.gap_every > 0 && tally.times.len() % args.gap_every == 0 {
        let batch = graph.optimize(&unbounded(&args.options))?;
        let gap = solution.chi2() / batch.chi2() - 1.0;
        let (apart, size, turned) = poses_apart(&solution, &batch);
        tally.gaps.push(gap);
        tally.apart.push(apart / size);
        tally.turned.push(turned);
        if args.verbose {
            writeln!(
                out,
                "          gap: χ² {gap:.1e} above, positions {:.1e} of the size, rotations {turned:.1e} rad",
                apart / size
            )?;
            let (only_update, only_batch) = accepted_apart(&solution, &batch);
            if !only_update.is_empty() || !only_batch.is_empty() {
                writeln!(
                    out,
                    "          accepted by the update only: {only_update:?}; by the batch job only: {only_batch:?}"
                )?;
            }
        }
    }
    if args.verbose {
        let r = solution.report();
        let o = &r.optimizer;
        writeln!(
            out,
            "{poses:>7} poses  {name:<8} {ms:8.2} ms  {} iterations, {} factorisations ({:.2} ms), optimiser {:.2} ms; {} EM decisions ({:.2} ms judging, {:.2} ms of it the loop model), {} earlier decisions changed",
            o.iterations,
            o.factorizations,
            o.timing.factorize_s * 1e3,
            o.time_s * 1e3,
            r.robust.decisions,
            r.time.evaluation_s * 1e3,
            r.time.loop_model_s * 1e3,
            changes.len(),
        )?;
        if let Some(i) = inc.filter(|i| i.solve == UpdateSolve::Batch) {
            writeln!(out, "          why: {}", i.reason)?;
        }
        for c in changes {
            let verb = if c.accepted { "accepted" } else { "rejected" };
            writeln!(
                out,
                "          {verb} loop {}–{} ({:?})",
                c.from, c.to, c.reason
            )?;
        }
    }
    Ok(solution)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args = parse_args()?;
    // A closed stdout (`| head`) ends the replay with an error, not a panic.
    let mut out = std::io::stdout().lock();
    let (dim, vertices, edges) = read(&args.path)?;
    let at: HashMap<u64, usize> = (vertices.iter().enumerate())
        .map(|(k, (id, _))| (*id, k))
        .collect();
    // Each edge is added once its later end is.
    let mut due: Vec<Vec<&Edge>> = vec![Vec::new(); vertices.len()];
    for e in &edges {
        if let (Some(&a), Some(&b)) = (at.get(&e.from), at.get(&e.to)) {
            due[a.max(b)].push(e);
        }
    }
    let mut graph = AnyPoseGraph::new(dim)?;
    let (mut tally, mut last) = (Tally::default(), None);
    for (k, (id, pose)) in vertices.iter().enumerate() {
        graph.add_pose(*id, pose)?;
        for e in &due[k] {
            add(&mut graph, e)?;
        }
        if (k + 1) % args.every == 0 || k + 1 == vertices.len() {
            last = Some(update(&mut graph, &args, k + 1, &mut tally, &mut out)?);
        }
    }
    let mut last = last.ok_or("no vertex in the file")?;
    // Without the bound: the same job, to the batch tolerance.
    let plain = unbounded(&args.options);
    if args.options.solver.update_iterations.is_some() {
        // The closing update: nothing added, the convergence finished.
        let t = Instant::now();
        last = graph.update(&plain)?;
        let ms = t.elapsed().as_secs_f64() * 1e3;
        tally.times.push(ms);
        writeln!(out, "closing update: {ms:.2} ms")?;
    }
    let t = Instant::now();
    let batch = graph.optimize(&plain)?;
    let batch_ms = t.elapsed().as_secs_f64() * 1e3;
    summary(&mut out, &args, tally, (&last, &batch, batch_ms))
}

/// The summary lines: times, kinds, gaps, and the last map against batch.
fn summary(
    out: &mut impl Write,
    args: &Args,
    mut tally: Tally,
    (last, batch, batch_ms): (&AnySolution, &AnySolution, f64),
) -> Result<(), Box<dyn std::error::Error>> {
    let times = &mut tally.times;
    times.sort_by(f64::total_cmp);
    let total: f64 = times.iter().sum();
    let p99 = times[((times.len() as f64 * 0.99).ceil() as usize).clamp(1, times.len()) - 1];
    writeln!(
        out,
        "{} updates every {} poses: {total:.1} ms in all, median {:.2} ms, p99 {p99:.2} ms, max {:.2} ms; {:?}; {} earlier decisions changed",
        times.len(),
        args.every,
        times[times.len() / 2],
        times[times.len() - 1],
        tally.kinds,
        tally.changed,
    )?;
    if !tally.gaps.is_empty() {
        let gaps = &mut tally.gaps;
        gaps.sort_by(f64::total_cmp);
        writeln!(
            out,
            "χ² above the batch optimum at every {}th update: median {:.1e}, max {:.1e} ({} checks)",
            args.gap_every,
            gaps[gaps.len() / 2],
            gaps[gaps.len() - 1],
            gaps.len(),
        )?;
        spread(
            out,
            "positions apart from the batch job's at the same updates, as a share of the map's size",
            &mut tally.apart,
        )?;
        spread(
            out,
            "rotations apart from the batch job's at the same updates, in radians",
            &mut tally.turned,
        )?;
    }
    let accepted = |s: &AnySolution| -> Vec<usize> {
        (s.loops().iter().filter(|d| d.accepted))
            .map(|d| d.index)
            .collect()
    };
    let same = accepted(last) == accepted(batch);
    writeln!(
        out,
        "final χ² {:.10e}, batch {:.10e} ({batch_ms:.1} ms): relative difference {:.1e}; accepted sets {}",
        last.chi2(),
        batch.chi2(),
        (last.chi2() / batch.chi2() - 1.0).abs(),
        if same { "identical" } else { "DIFFER" }
    )?;
    let (apart, size, turned) = poses_apart(last, batch);
    writeln!(
        out,
        "positions up to {apart:.2e} apart, {:.2e} of the map's size {size:.1} (the diagonal of its bounding box); rotations up to {turned:.2e} rad",
        apart / size
    )?;
    if args.verbose {
        for (u, b) in last.loops().iter().zip(batch.loops()) {
            if u.accepted != b.accepted {
                writeln!(
                    out,
                    "  differs: loop {}–{} ({} inliers): update {} ({:?}, posterior {:.3?}, ν² {:.3?}), batch {} ({:?}, posterior {:.3?}, ν² {:.3?})",
                    u.from,
                    u.to,
                    u.inliers.map_or("no".into(), |n| n.to_string()),
                    if u.accepted { "accepts" } else { "rejects" },
                    u.reason,
                    u.posterior,
                    u.innovation,
                    if b.accepted { "accepts" } else { "rejects" },
                    b.reason,
                    b.posterior,
                    b.innovation,
                )?;
            }
        }
    }
    Ok(())
}

/// One summary line of `values` (sorted here): median, largest, and how
/// many are above the update's promise of 10⁻⁶.
fn spread(out: &mut impl Write, what: &str, values: &mut [f64]) -> std::io::Result<()> {
    values.sort_by(f64::total_cmp);
    writeln!(
        out,
        "{what}: median {:.1e}, max {:.1e}; {} above 10⁻⁶",
        values[values.len() / 2],
        values[values.len() - 1],
        values.iter().filter(|&&v| v > 1e-6).count(),
    )
}

/// A loop by its ends (from, to).
type Ends = (u64, u64);

/// The loops `a` accepts and `b` does not, and the reverse.
fn accepted_apart(a: &AnySolution, b: &AnySolution) -> (Vec<Ends>, Vec<Ends>) {
    let accepted = |s: &AnySolution| -> Vec<Ends> {
        let loops = s.report().loops.iter().filter(|l| l.accepted);
        loops.map(|l| (l.from, l.to)).collect()
    };
    let (a, b) = (accepted(a), accepted(b));
    let only =
        |x: &[(u64, u64)], y: &[(u64, u64)]| x.iter().filter(|l| !y.contains(l)).copied().collect();
    (only(&a, &b), only(&b, &a))
}

/// The largest distance between a position of `a` and the same pose's of
/// `b`, the diagonal of `b`'s positions' bounding box, and the largest
/// angle between a rotation of `a` and the same pose's of `b`.
/// A hash of the bits of `solution`'s poses and χ².
fn map_hash(solution: &AnySolution) -> u64 {
    use std::hash::{Hash, Hasher};
    let mut h = std::collections::hash_map::DefaultHasher::new();
    for x in solution.poses_flat() {
        x.to_bits().hash(&mut h);
    }
    solution.chi2().to_bits().hash(&mut h);
    h.finish()
}

fn poses_apart(a: &AnySolution, b: &AnySolution) -> (f64, f64, f64) {
    let (width, dims) = (b.pose_width(), if b.pose_width() == 3 { 2 } else { 3 });
    let (pa, pb) = (a.poses_flat(), b.poses_flat());
    let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
    let (mut apart, mut turned) = (0.0f64, 0.0f64);
    for (x, y) in pa.chunks_exact(width).zip(pb.chunks_exact(width)) {
        let mut d2 = 0.0;
        for i in 0..dims {
            (lo[i], hi[i]) = (lo[i].min(y[i]), hi[i].max(y[i]));
            d2 += (x[i] - y[i]).powi(2);
        }
        apart = apart.max(d2.sqrt());
        let angle = if dims == 2 {
            let d = x[2] - y[2];
            d.sin().atan2(d.cos()).abs()
        } else {
            // The angle between unit quaternions q and r: 2·acos|q·r|.
            let dot: f64 = (3..7).map(|i| x[i] * y[i]).sum();
            2.0 * dot.abs().min(1.0).acos()
        };
        turned = turned.max(angle);
    }
    let size = (0..dims)
        .map(|i| (hi[i] - lo[i]).powi(2))
        .sum::<f64>()
        .sqrt();
    (apart, size, turned)
}
