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
//!
//! Prints one line per update (poses, how it was solved, milliseconds) and
//! the earlier decisions it changed with `-v`, and a summary: updates,
//! total and p99 time, how many of each kind, and the final χ² and
//! decisions against the batch ones (with `-v`, each decision that
//! differs).

use pgo::{AnyPoseGraph, Options, UpdateSolve};
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

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let verbose = args.iter().any(|a| a == "-v");
    // A closed stdout (`| head`) ends the replay with an error, not a panic.
    let mut out = std::io::stdout().lock();
    let mut options = Options::default();
    let mut rest = Vec::new();
    let mut it = args.iter().filter(|a| *a != "-v");
    while let Some(a) = it.next() {
        if a == "--update-iters" {
            options.set("update-iters", it.next().ok_or("--update-iters needs K")?)?;
        } else if a == "--set" {
            let setting = it.next().ok_or("--set needs NAME=VALUE")?;
            let (name, value) = setting.split_once('=').ok_or("--set needs NAME=VALUE")?;
            options.set(name, value)?;
        } else {
            rest.push(a);
        }
    }
    let (Some(path), every) = (rest.first(), rest.get(1)) else {
        return Err(
            "usage: replay FILE.g2o [EVERY_N_POSES] [--update-iters K] [--set NAME=VALUE]… [-v]"
                .into(),
        );
    };
    let every: usize = every.map_or(Ok(1), |s| s.parse())?;
    let (dim, vertices, edges) = read(path)?;
    let mut at: HashMap<u64, usize> = HashMap::new();
    for (k, (id, _)) in vertices.iter().enumerate() {
        at.insert(*id, k);
    }
    // Each edge is added once its later end is.
    let mut due: Vec<Vec<&Edge>> = vec![Vec::new(); vertices.len()];
    for e in &edges {
        if let (Some(&a), Some(&b)) = (at.get(&e.from), at.get(&e.to)) {
            due[a.max(b)].push(e);
        }
    }
    let mut graph = AnyPoseGraph::new(dim)?;
    let (mut times, mut kinds) = (Vec::new(), HashMap::<&str, usize>::new());
    let (mut last, mut changed) = (None, 0);
    for (k, (id, pose)) in vertices.iter().enumerate() {
        graph.add_pose(*id, pose)?;
        for e in &due[k] {
            match e.inliers {
                Some(n) => graph.add_loop_candidate(
                    e.from,
                    e.to,
                    &e.measurement,
                    &e.information,
                    Some(n),
                )?,
                None => graph.add_edge(e.from, e.to, &e.measurement, &e.information)?,
            };
        }
        if (k + 1) % every != 0 && k + 1 != vertices.len() {
            continue;
        }
        let t = Instant::now();
        let solution = graph.update(&options)?;
        let ms = t.elapsed().as_secs_f64() * 1e3;
        times.push(ms);
        let how = solution
            .incremental()
            .map_or(UpdateSolve::Batch, |i| i.solve);
        let name = match how {
            UpdateSolve::Batch => "batch",
            UpdateSolve::None => "none",
            UpdateSolve::Extended => "extended",
            UpdateSolve::Warm => "warm",
            UpdateSolve::Full => "full",
        };
        *kinds.entry(name).or_default() += 1;
        let changes = solution.incremental().map_or(&[][..], |i| &i.changed[..]);
        changed += changes.len();
        if verbose {
            let r = solution.report();
            let o = &r.optimizer;
            writeln!(
                out,
                "{:>7} poses  {name:<8} {ms:8.2} ms  {} iterations, {} factorisations ({:.2} ms), optimiser {:.2} ms; {} EM decisions ({:.2} ms judging), {} earlier decisions changed",
                k + 1,
                o.iterations,
                o.factorizations,
                o.timing.factorize_s * 1e3,
                o.time_s * 1e3,
                r.robust.decisions,
                r.time.evaluation_s * 1e3,
                changes.len(),
            )?;
            for c in changes {
                let verb = if c.accepted { "accepted" } else { "rejected" };
                writeln!(
                    out,
                    "          {verb} loop {}–{} ({:?})",
                    c.from, c.to, c.reason
                )?;
            }
        }
        last = Some(solution);
    }
    let mut last = last.ok_or("no vertex in the file")?;
    // Without the bound: the same job, to the batch tolerance.
    let plain = Options::default();
    if options.solver.update_iterations.is_some() {
        // The closing update: nothing added, the convergence finished.
        let t = Instant::now();
        last = graph.update(&plain)?;
        let ms = t.elapsed().as_secs_f64() * 1e3;
        times.push(ms);
        writeln!(out, "closing update: {ms:.2} ms")?;
    }
    let t = Instant::now();
    let batch = graph.optimize(&plain)?;
    let batch_ms = t.elapsed().as_secs_f64() * 1e3;
    times.sort_by(f64::total_cmp);
    let total: f64 = times.iter().sum();
    let p99 = times[((times.len() as f64 * 0.99).ceil() as usize).clamp(1, times.len()) - 1];
    let accepted = |s: &pgo::AnySolution| -> Vec<usize> {
        s.loops()
            .iter()
            .filter(|d| d.accepted)
            .map(|d| d.index)
            .collect()
    };
    writeln!(
        out,
        "{} updates every {every} poses: {total:.1} ms in all, median {:.2} ms, p99 {p99:.2} ms, max {:.2} ms; {kinds:?}; {changed} earlier decisions changed",
        times.len(),
        times[times.len() / 2],
        times[times.len() - 1],
    )?;
    writeln!(
        out,
        "final χ² {:.10e}, batch {:.10e} ({batch_ms:.1} ms): relative difference {:.1e}; accepted sets {}",
        last.chi2(),
        batch.chi2(),
        (last.chi2() / batch.chi2() - 1.0).abs(),
        if accepted(&last) == accepted(&batch) {
            "identical"
        } else {
            "DIFFER"
        }
    )?;
    if verbose {
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
