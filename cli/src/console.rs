//! Printing for the command line, where printing can fail: a reader that
//! went away (`pgo … --json | head -1`), a full device (`> /dev/full`).
//! (`println!` panics then, with exit status 101.)
//!
//! * **stdout** carries results (the JSON report, `gate`'s threshold, the
//!   graph with `-o -`). A failure is returned; the command then ends with
//!   [`stdout_failure`]'s status: [`BROKEN_PIPE_STATUS`] (141 = 128 +
//!   SIGPIPE, what a shell shows for a classic Unix tool ended by a broken
//!   pipe), quietly, when the reader went away — the reader chose to stop,
//!   as with `yes | head -1`; 1, with a message on stderr, for any other
//!   failure (a full disk).
//! * **stderr** carries messages (the summary, warnings, errors). Writing
//!   them is best effort: a failure is ignored, since there is nowhere to
//!   report it, and the exit status still tells success from failure.
//! * A standard descriptor closed at start (`2>&-`, `>&-`) is reopened on
//!   `/dev/null` by the Rust runtime (on Linux and the BSDs) before `main`,
//!   so no file pgo opens can take its place and receive its messages.

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use std::cell::Cell;
use std::fmt;
use std::io::{self, Write};
use std::time::Duration;

/// The exit status after a broken pipe on stdout: 128 + SIGPIPE (13).
pub const BROKEN_PIPE_STATUS: u8 = 141;

/// Writes `text` and a newline to stdout and flushes them.
pub fn out_line(text: &str) -> io::Result<()> {
    let mut stdout = io::stdout().lock();
    stdout.write_all(text.as_bytes())?;
    stdout.write_all(b"\n")?;
    stdout.flush()
}

/// Writes `args` to stderr, best effort (a failure is ignored).
pub fn err(args: fmt::Arguments<'_>) {
    let _ = io::stderr().lock().write_fmt(args);
}

/// Writes `args` and a newline to stderr, best effort.
pub fn err_line(args: fmt::Arguments<'_>) {
    let mut stderr = io::stderr().lock();
    let _ = stderr.write_fmt(args).and_then(|_| stderr.write_all(b"\n"));
}

/// The exit status after writing to stdout failed with `e`:
/// [`BROKEN_PIPE_STATUS`], quietly, for a broken pipe; else 1, after saying
/// so on stderr.
pub fn stdout_failure(e: &io::Error) -> u8 {
    if e.kind() == io::ErrorKind::BrokenPipe {
        BROKEN_PIPE_STATUS
    } else {
        err_line(format_args!("error: stdout: {e}"));
        1
    }
}

/// A line on stderr that shows a long job is alive: the time, the solver's
/// iterations so far (over every solve of the job) and the last objective.
/// Drawn only on a terminal (nothing in a pipe, a file or CI logs), and
/// not at all when `hidden` (`-q`, or `-v` printing every iteration).
pub struct Spinner {
    bar: ProgressBar,
    iterations: Cell<usize>,
}

impl Spinner {
    /// A spinner on stderr, drawn from the first iteration on.
    pub fn new(hidden: bool) -> Self {
        let target = if hidden {
            ProgressDrawTarget::hidden()
        } else {
            ProgressDrawTarget::stderr()
        };
        let bar = ProgressBar::with_draw_target(None, target);
        if let Ok(style) = ProgressStyle::with_template("{spinner} {elapsed:>4} {msg}") {
            bar.set_style(style);
        }
        Self {
            bar,
            iterations: Cell::new(0),
        }
    }

    /// One more solver iteration, ending at `objective`.
    pub fn iteration(&self, objective: f64) {
        let n = self.iterations.get() + 1;
        self.iterations.set(n);
        if n == 1 {
            self.bar.enable_steady_tick(Duration::from_millis(200));
        }
        self.bar
            .set_message(format!("solver iteration {n}, objective {objective:.6e}"));
    }

    /// Takes the line away, before the summary is printed.
    pub fn clear(&self) {
        self.bar.finish_and_clear();
    }
}
