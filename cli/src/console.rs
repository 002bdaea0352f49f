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

use std::fmt;
use std::io::{self, Write};

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
