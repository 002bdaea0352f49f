//! Numerical faults and limits through the binary: a step with a
//! non-finite χ² is never taken, overflowing or singular problems are
//! named errors, and `--max-iters` / `--time-limit` stop the whole
//! optimisation (robust rounds included) with the best estimate so far
//! written and the stop reason in the report. I/O faults: a reader that goes
//! away (exit 141, quietly), a full or closed stdout or stderr, a full disk
//! (the old output kept, the error naming it): never a panic. (That LM
//! never returns NaN or infinite poses is a unit test of the solver,
//! src/solve/tests.rs.)

use crate::common::{pgo, sample, stderr, temp_dir, verdict_status, write};
use std::path::Path;

/// Runs `pgo optimize INPUT --json -q -o OUT ARGS…`; returns the report.
fn run_json(input: &str, out: &Path, args: &[&str]) -> serde_json::Value {
    let mut all = vec![
        "optimize",
        input,
        "--json",
        "-q",
        "-o",
        out.to_str().expect("utf-8"),
    ];
    all.extend_from_slice(args);
    let o = pgo(&all);
    let report: serde_json::Value = serde_json::from_slice(&o.stdout).expect("JSON report");
    assert_eq!(
        o.status.code(),
        Some(verdict_status(&report)),
        "{}",
        stderr(&o)
    );
    report
}

/// χ² of the poses written to `out` (read back as the file's own guess).
fn written_chi2(out: &Path) -> f64 {
    let back = pgo(&[
        "optimize",
        out.to_str().expect("utf-8"),
        "--init",
        "file",
        "--max-iters",
        "0",
        "--json",
        "-q",
    ]);
    let r: serde_json::Value = serde_json::from_slice(&back.stdout).expect("JSON");
    assert_eq!(
        back.status.code(),
        Some(verdict_status(&r)),
        "{}",
        stderr(&back)
    );
    r["input_chi2"].as_f64().expect("finite χ²")
}

fn close(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-9 * a.abs().max(b.abs())
}

#[test]
fn max_iters_bounds_robust_rounds_too_and_the_best_estimate_is_written() {
    let dir = temp_dir("faults-max-iters");
    let out = dir.join("out.g2o");
    // grid2d.g2o has loop candidates: EM reweighting runs several rounds.
    for n in [0usize, 1, 2, 5] {
        let r = run_json(
            &sample("grid2d.g2o"),
            &out,
            &["--max-iters", &n.to_string()],
        );
        let o = &r["optimizer"];
        assert_eq!(o["iterations"], n, "--max-iters {n}: {o}");
        assert_eq!(o["stop_reason"], "max_iterations", "--max-iters {n}");
        assert_eq!(o["converged"], false);
        assert!(
            o["final_objective"].as_f64().expect("finite")
                <= o["initial_objective"].as_f64().expect("finite")
        );
        let final_chi2 = o["final_chi2"].as_f64().expect("finite");
        assert!(close(written_chi2(&out), final_chi2), "--max-iters {n}");
    }
}

#[test]
fn time_limit_stops_the_optimisation_and_writes_the_best_so_far() {
    let dir = temp_dir("faults-time-limit");
    let graph = dir.join("g.g2o");
    let sim = pgo(&[
        "simulate",
        "--poses",
        "20000",
        "--loops",
        "2000",
        "--wrong",
        "200",
        "--inliers",
        "-o",
        graph.to_str().expect("utf-8"),
    ]);
    assert_eq!(sim.status.code(), Some(0), "{}", stderr(&sim));
    let out = dir.join("out.g2o");
    let input = graph.to_str().expect("utf-8");
    // No time at all: the initial guess is written.
    let r = run_json(input, &out, &["--time-limit", "0"]);
    assert_eq!(r["optimizer"]["iterations"], 0);
    assert_eq!(r["optimizer"]["stop_reason"], "time_limit");
    assert!(close(
        written_chi2(&out),
        r["initialization"]["chi2"].as_f64().expect("χ²")
    ));
    // A fraction of a second: the limit is checked between iterations, so
    // the run overshoots by at most one iteration. Least squares over every
    // candidate (1.6 s here: the wrong loops make LM crawl) stops with its
    // objective lowered; EM (0.6 s) stops within its decisions, whose sets
    // each have an objective of their own, so only its written map is
    // compared with its report.
    let (limit, limit_arg) = (0.3, "0.3");
    for flags in [&["--robust", "none", "--gate", "off"][..], &[]] {
        let mut args = vec!["--time-limit", limit_arg];
        args.extend_from_slice(flags);
        let r = run_json(input, &out, &args);
        let o = &r["optimizer"];
        assert_eq!(o["stop_reason"], "time_limit", "{flags:?}: {o}");
        // (EM's annealing counts against the limit too: it may pass before
        // the first iteration.)
        assert!(o["time_s"].as_f64().expect("t") < limit + 30.0);
        if !flags.is_empty() {
            let (initial, last) = (&o["initial_objective"], &o["final_objective"]);
            assert!(
                last.as_f64().expect("f") < initial.as_f64().expect("f"),
                "{o}"
            );
        }
        assert!(close(
            written_chi2(&out),
            o["final_chi2"].as_f64().expect("χ²")
        ));
    }
    // Nonsense limits are usage errors.
    for bad in ["-1", "nan", "inf"] {
        let o = pgo(&["optimize", input, &format!("--time-limit={bad}")]);
        assert_eq!(o.status.code(), Some(2), "--time-limit {bad}");
        assert!(stderr(&o).contains("--time-limit"), "{}", stderr(&o));
    }
}

#[test]
fn overflowing_and_singular_problems_are_named_errors_and_write_nothing() {
    let dir = temp_dir("faults-overflow");
    let out = dir.join("out.g2o");
    let v = "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nVERTEX_SE2 2 2 0 0\n";
    let cases = [
        // Measurements near the largest double: χ² overflows at any guess.
        (
            "huge-measurement.g2o",
            format!("{v}EDGE_SE2 0 1 1e300 0 0 1 0 0 1 0 1\nEDGE_SE2 1 2 1e300 0 0 1 0 0 1 0 1\n"),
            vec![],
            "edge 0 (vertex 0 → 1) has a non-finite χ² at the chordal initial guess",
        ),
        // A pose near the largest double, kept by --init file.
        (
            "huge-pose.g2o",
            "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1e300 0 0\nVERTEX_SE2 2 2 0 0\n\
             EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\nEDGE_SE2 1 2 1 0 0 1 0 0 1 0 1\n"
                .to_string(),
            vec!["--init", "file"],
            "edge 0 (vertex 0 → 1) has a non-finite χ² at the file initial guess",
        ),
        // Information spanning 600 orders of magnitude (the normal
        // equations would be numerically singular at vertex 1): refused
        // as out of the range the job computes with.
        (
            "singular.g2o",
            format!(
                "{v}EDGE_SE2 0 1 1 0 0 1e300 0 0 1e300 0 1e300\n\
                 EDGE_SE2 1 2 1 0 0 1e-300 0 0 1e-300 0 1e-300\n\
                 EDGE_SE2 0 2 5 3 2 1e300 0 0 1e300 0 1e300\n"
            ),
            vec![],
            "edge 0 → 1: information matrix has diagonal entry (0, 0) = 1e300, outside the range \
             pgo computes with (1e-100 to 1e100",
        ),
        // Information beyond the cube root of the float range, uniformly:
        // this used to be "not positive definite at vertex 3" (the chordal
        // guess's 3×3 inverse) or every loop rejected (EM's).
        (
            "tiny-information.g2o",
            format!(
                "{v}EDGE_SE2 0 1 1 0 0 1e-120 0 0 1e-120 0 1e-120\n\
                 EDGE_SE2 1 2 1 0 0 1e-120 0 0 1e-120 0 1e-120\n"
            ),
            vec![],
            "edge 0 → 1: information matrix has diagonal entry (0, 0) = 1e-120, outside",
        ),
    ];
    for (name, text, args, message) in cases {
        let input = write(&dir, name, &text);
        let mut all = vec![
            "optimize",
            input.to_str().expect("utf-8"),
            "-o",
            out.to_str().expect("utf-8"),
        ];
        all.extend(args);
        let o = pgo(&all);
        let err = stderr(&o);
        assert_eq!(o.status.code(), Some(2), "{name}: {err}");
        assert!(
            err.contains(&format!("{name}: ")) && err.contains(message),
            "{name}: {err}"
        );
        assert!(!err.contains("panicked"));
        assert!(!out.exists(), "{name}: output written");
    }
    // The file's own guess overflowing is only reported (the chordal guess
    // replaces it): a warning, and the optimum is found.
    let input = write(
        &dir,
        "huge-guess.g2o",
        "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1e300 0 0\nVERTEX_SE2 2 2 0 0\n\
         EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\nEDGE_SE2 1 2 1 0 0 1 0 0 1 0 1\n",
    );
    let r = run_json(input.to_str().expect("utf-8"), &out, &[]);
    assert!(r["input_chi2"].is_null());
    assert!(
        r["warnings"].to_string().contains("non-finite χ²"),
        "{}",
        r["warnings"]
    );
    assert!(r["optimizer"]["final_chi2"].as_f64().expect("finite") < 1e-12);
}

/// Runs `pgo ARGS` with stdout and stderr as given; stdin empty.
fn run_with(
    args: &[&str],
    stdout: std::process::Stdio,
    stderr: std::process::Stdio,
) -> std::process::Child {
    std::process::Command::new(env!("CARGO_BIN_EXE_pgo"))
        .args(args)
        .stdin(std::process::Stdio::null())
        .stdout(stdout)
        .stderr(stderr)
        .spawn()
        .expect("start pgo")
}

fn no_panic(err: &str, status: Option<i32>, what: &str) {
    assert_ne!(status, Some(101), "{what}: {err}");
    assert!(!err.contains("panicked"), "{what}: {err}");
}

#[cfg(unix)]
#[test]
fn a_reader_that_goes_away_ends_the_run_quietly_with_status_141() {
    use std::process::Stdio;
    let dir = temp_dir("faults-broken-pipe");
    let out = dir.join("out.g2o");
    let graph = sample("grid2d.g2o");
    let o = out.to_str().expect("utf-8");
    for args in [
        vec!["optimize", graph.as_str(), "--json", "-o", o],
        vec!["optimize", graph.as_str(), "-o", "-"],
        vec!["gate", graph.as_str()],
        vec!["gate", graph.as_str(), "--json"],
        vec!["simulate", "--poses", "200", "--loops", "20", "-o", "-"],
        vec!["--help"],
    ] {
        let _ = std::fs::remove_file(&out);
        // The reader is gone before pgo starts (closing it after the spawn
        // would race with pgo's first write: `--help` can fill the pipe
        // before the reader closes). A socket pair, one end closed, makes
        // every write fail with EPIPE as a pipe would.
        let (reader, writer) = std::os::unix::net::UnixStream::pair().expect("socket pair");
        drop(reader);
        let writer = std::os::fd::OwnedFd::from(writer);
        let child = run_with(&args, Stdio::from(writer), Stdio::piped());
        let done = child.wait_with_output().expect("wait");
        let err = String::from_utf8_lossy(&done.stderr).into_owned();
        no_panic(&err, done.status.code(), &format!("{args:?}"));
        assert_eq!(done.status.code(), Some(141), "{args:?}: {err}");
        assert!(!err.contains("error"), "{args:?}: not quiet: {err}");
        if args.contains(&"--json") && args[0] == "optimize" {
            // The report came last: the graph was written before it.
            assert!(out.is_file(), "{args:?}");
        }
    }
}

#[test]
#[cfg(target_os = "linux")]
fn a_full_stdout_is_an_error_naming_stdout_and_a_full_stderr_is_ignored() {
    use std::process::Stdio;
    let full = || std::fs::OpenOptions::new().write(true).open("/dev/full");
    if full().is_err() {
        eprintln!("skipped: no /dev/full");
        return;
    }
    let dir = temp_dir("faults-dev-full");
    let out = dir.join("out.g2o");
    let o = out.to_str().expect("utf-8");
    let graph = sample("grid2d.g2o");
    // stdout full: exit status 1 and a message; the output file is complete.
    for args in [
        vec!["optimize", graph.as_str(), "--json", "-o", o],
        vec!["gate", graph.as_str()],
        vec!["optimize", graph.as_str(), "-o", "-"],
    ] {
        let child = run_with(&args, Stdio::from(full().expect("full")), Stdio::piped());
        let done = child.wait_with_output().expect("wait");
        let err = String::from_utf8_lossy(&done.stderr).into_owned();
        no_panic(&err, done.status.code(), &format!("{args:?}"));
        assert_eq!(done.status.code(), Some(1), "{args:?}: {err}");
        assert!(
            err.contains("stdout: No space left on device"),
            "{args:?}: {err}"
        );
    }
    assert!(out.is_file());
    // stderr full (the summary, -v's iterations): ignored, the run succeeds.
    let _ = std::fs::remove_file(&out);
    let child = run_with(
        &["optimize", graph.as_str(), "-v", "-o", o],
        Stdio::null(),
        Stdio::from(full().expect("full")),
    );
    let done = child.wait_with_output().expect("wait");
    assert_eq!(done.status.code(), Some(0));
    assert!(out.is_file());
    // A failing run with stderr full still fails with its status.
    let child = run_with(
        &["optimize", "/nonexistent.g2o"],
        Stdio::null(),
        Stdio::from(full().expect("full")),
    );
    assert_eq!(
        child.wait_with_output().expect("wait").status.code(),
        Some(2)
    );
}

#[test]
#[cfg(unix)]
fn closed_stdout_and_stderr_do_not_panic_or_catch_other_files() {
    let dir = temp_dir("faults-closed");
    let out = dir.join("out.g2o");
    let graph = sample("grid2d.g2o");
    let script = format!(
        "exec \"$0\" optimize '{}' --json -v -o '{}' >&- 2>&-",
        graph,
        out.display()
    );
    let done = std::process::Command::new("sh")
        .args(["-c", &script, env!("CARGO_BIN_EXE_pgo")])
        .output()
        .expect("sh");
    assert_eq!(done.status.code(), Some(0), "{done:?}");
    // The output is a graph, not messages that found their way into it.
    let text = std::fs::read_to_string(&out).expect("written");
    assert!(
        text.lines().all(|l| l.starts_with("VERTEX_SE2")
            || l.starts_with("EDGE_SE2")
            || l.starts_with("FIX"))
    );
}

#[test]
#[cfg(unix)]
fn a_full_disk_names_the_output_and_leaves_the_old_file() {
    // The file size limit (ulimit -f, with SIGXFSZ ignored) makes writes past
    // 4 KiB fail as a full disk does, without needing root.
    let dir = temp_dir("faults-full-disk");
    let out = dir.join("out.g2o");
    std::fs::write(&out, "old\n").expect("old");
    let graph = sample("grid2d.g2o");
    let script = format!(
        "trap '' XFSZ; ulimit -f 8; exec \"$0\" optimize '{}' -q -o '{}'",
        graph,
        out.display()
    );
    let done = std::process::Command::new("sh")
        .args(["-c", &script, env!("CARGO_BIN_EXE_pgo")])
        .output()
        .expect("sh");
    let err = String::from_utf8_lossy(&done.stderr).into_owned();
    no_panic(&err, done.status.code(), "ulimit");
    assert_eq!(done.status.code(), Some(1), "{err}");
    assert!(
        err.contains(&format!("{}: cannot write: ", out.display())),
        "{err}"
    );
    assert!(err.contains("the file is left as it was"), "{err}");
    assert_eq!(std::fs::read_to_string(&out).expect("old"), "old\n");
    let names: Vec<_> = std::fs::read_dir(&dir).expect("dir").collect();
    assert_eq!(names.len(), 1, "a temporary was left");
    // A real full file system where we may make one (root, tmpfs).
    full_tmpfs(&graph);
}

/// The same on a 64 KiB tmpfs, where root may mount one; skipped otherwise.
#[cfg(unix)]
fn full_tmpfs(graph: &str) {
    let dir = temp_dir("faults-tmpfs");
    let mounted = std::process::Command::new("mount")
        .args([
            "-t",
            "tmpfs",
            "-o",
            "size=64k",
            "tmpfs",
            dir.to_str().expect("utf-8"),
        ])
        .stderr(std::process::Stdio::null())
        .status()
        .is_ok_and(|s| s.success());
    if !mounted {
        eprintln!("note: no tmpfs (needs root): the ENOSPC case is skipped");
        return;
    }
    let out = dir.join("out.g2o");
    std::fs::write(&out, "old\n").expect("old");
    let done = pgo(&["optimize", graph, "-q", "-o", out.to_str().expect("utf-8")]);
    let err = stderr(&done);
    let left = std::fs::read_to_string(&out);
    let names = std::fs::read_dir(&dir).map(|d| d.count()).unwrap_or(0);
    let _ = std::process::Command::new("umount").arg(&*dir).status();
    assert_eq!(done.status.code(), Some(1), "{err}");
    assert!(err.contains("No space left on device"), "{err}");
    assert_eq!(left.expect("old"), "old\n");
    assert_eq!(names, 1, "a temporary was left");
}
