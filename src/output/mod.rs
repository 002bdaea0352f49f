//! Output files: the one place that opens them. Every file pgo writes (the
//! optimised graph, `simulate`'s and `corrupt`'s graphs and label CSVs, the
//! plots) goes through [`write()`], by these rules.
//!
//! * **Atomic replacement.** The content goes to a new temporary file in the
//!   target's directory, created exclusively (`O_EXCL`) under a short random
//!   name (`.pgo-XXXXXXXX.tmp`: any target name up to the file system's
//!   limit works), flushed and `fsync`ed, then renamed over the target; the
//!   directory is synced after the rename. A failure at any point (a full
//!   disk, a write error, a killed run) leaves the target as it was: a
//!   reader sees the old file or the complete new one, never a part.
//! * **Regular files only.** An existing target must be a regular file: a
//!   directory, FIFO, character or block device (`/dev/null`, `/dev/full`)
//!   or socket is refused with a message naming the path, before anything
//!   is written. (To discard an output, leave out `-o`; to stream it, `-o -`.)
//! * **Symbolic links are followed.** A target that is a symbolic link to a
//!   regular file is written through: the file the link leads to is replaced
//!   atomically, in its own directory, and the link stays (as `cp` and
//!   `sed -i --follow-symlinks` do). A link to a missing file, or to anything
//!   but a regular file, is refused.
//! * **Owner and mode are kept.** A replaced file keeps its mode (set-id
//!   bits included) and, where the process may set them, its owner and
//!   group; a new file gets `0666` less the umask, as the shell's `>` gives.
//!   The temporary is never more permissive than the final file. A file with
//!   several hard links gets a new inode: its other names keep the old text
//!   (as with `sed -i`).
//! * **`-` is stdout** (and `-` as an input is stdin). Stdout is a stream,
//!   written as it goes, not atomically; a reader that stops reading (a
//!   broken pipe, `| head`) ends the run quietly with exit status 141
//!   (the command line).
//! * **No output is an input.** The command line refuses, before reading
//!   anything, an output that is one of its inputs (through links, `..` and
//!   hard links too) unless `--in-place`, and two outputs that are the same
//!   file or both stdout ([`check_files`]).
//! * **Interrupted runs.** A killed run can leave its temporary beside the
//!   target; it is never read. A run holds an `flock` on its temporary while
//!   it writes; each write into a directory first removes the temporaries
//!   there that nobody holds (pgo's exact name pattern, regular files of the
//!   same user, never through a link), so leftovers do not pile up, and a
//!   temporary still being written, by any process in any PID namespace, is
//!   never removed.
//! * **Unmodelled lines** are kept by the g2o rewrite
//!   ([`crate::Solution::write_g2o`]): `optimize -o` and `--in-place`
//!   write the input's text back byte for byte, changing only the pose
//!   values of the vertex lines whose pose changed, and add the vertices no
//!   line defined after the last vertex line. When the input's text cannot
//!   be had again unchanged, nothing is replaced.

mod check;
mod temporary;
#[cfg(test)]
mod tests;

pub use check::{CheckError, check_files};

use std::fmt;
use std::fs::{self, File};
use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};

/// What a path that is not a regular file is, for messages.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FileKind {
    /// A directory.
    Directory,
    /// A FIFO (named pipe).
    Fifo,
    /// A character device (`/dev/null`, `/dev/full`, a terminal).
    CharDevice,
    /// A block device (a disk).
    BlockDevice,
    /// A Unix socket.
    Socket,
    /// Anything else that is not a regular file.
    Other,
}

impl FileKind {
    /// The kind of `meta`, `None` for a regular file.
    fn of(meta: &fs::Metadata) -> Option<Self> {
        let t = meta.file_type();
        if t.is_file() {
            return None;
        }
        if t.is_dir() {
            return Some(Self::Directory);
        }
        #[cfg(unix)]
        {
            use std::os::unix::fs::FileTypeExt;
            if t.is_fifo() {
                return Some(Self::Fifo);
            }
            if t.is_char_device() {
                return Some(Self::CharDevice);
            }
            if t.is_block_device() {
                return Some(Self::BlockDevice);
            }
            if t.is_socket() {
                return Some(Self::Socket);
            }
        }
        Some(Self::Other)
    }
}

impl fmt::Display for FileKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::Directory => "a directory",
            Self::Fifo => "a FIFO (named pipe)",
            Self::CharDevice => "a character device",
            Self::BlockDevice => "a block device",
            Self::Socket => "a socket",
            Self::Other => "not a regular file",
        })
    }
}

/// What is wrong with an output (the path is in [`OutputError`]).
#[derive(Debug, thiserror::Error)]
pub enum OutputProblem {
    /// The target exists and is not a regular file (or is a link to one that
    /// is not).
    #[error(
        "{}{kind}; pgo writes only regular files (use - for stdout)",
        link_prefix(.link.as_deref())
    )]
    NotRegular {
        /// What it is.
        kind: FileKind,
        /// The file a symbolic link led to, if the target is one.
        link: Option<PathBuf>,
    },
    /// The target is a symbolic link to a file that does not exist.
    #[error(
        "is a symbolic link to {}, which does not exist; pgo writes through a link only to an existing regular file",
        .0.display()
    )]
    DanglingLink(PathBuf),
    /// The path names no file (empty, `/`, ending in `..`).
    #[error("names no file")]
    NoFileName,
    /// The path cannot be looked at (permissions, a loop of links, a file
    /// used as a directory).
    #[error("cannot look at it: {0}")]
    Resolve(#[source] io::Error),
    /// The temporary file cannot be created beside the target.
    #[error("cannot create a file in {}: {source}", dir.display())]
    Temporary {
        /// The directory.
        dir: PathBuf,
        /// The cause.
        source: io::Error,
    },
    /// Writing the content failed (a full disk, an error of the writer);
    /// the target is as it was.
    #[error("{0} (the file is left as it was)")]
    Write(#[source] io::Error),
    /// The finished temporary could not be renamed over the target; the
    /// target is as it was.
    #[error("cannot replace it: {0} (the file is left as it was)")]
    Replace(#[source] io::Error),
    /// Writing to stdout failed.
    #[error("{0}")]
    Stdout(#[source] io::Error),
}

fn link_prefix(link: Option<&Path>) -> String {
    link.map_or(String::from("is "), |l| {
        format!("is a symbolic link to {}, which is ", l.display())
    })
}

impl OutputProblem {
    /// The [`io::ErrorKind`] that stands for this problem.
    pub fn kind(&self) -> io::ErrorKind {
        match self {
            Self::NotRegular { .. } | Self::NoFileName => io::ErrorKind::InvalidInput,
            Self::DanglingLink(_) => io::ErrorKind::NotFound,
            Self::Resolve(e)
            | Self::Temporary { source: e, .. }
            | Self::Write(e)
            | Self::Replace(e)
            | Self::Stdout(e) => e.kind(),
        }
    }
}

/// An output that could not be written: the path (as given; `-` is shown as
/// `stdout`) and the problem. The target is never left half-written.
#[derive(Debug, thiserror::Error)]
#[error("{}: {problem}", shown(path))]
pub struct OutputError {
    /// The output path as given.
    pub path: PathBuf,
    /// What went wrong.
    pub problem: OutputProblem,
}

/// `stdout` for `-`, else the path.
fn shown(path: &Path) -> String {
    if is_dash(path) {
        "stdout".into()
    } else {
        path.display().to_string()
    }
}

fn is_dash(path: &Path) -> bool {
    path.as_os_str() == "-"
}

impl OutputError {
    fn new(path: &Path, problem: OutputProblem) -> Self {
        Self {
            path: path.to_owned(),
            problem,
        }
    }

    /// Whether the output was stdout and its reader went away (`| head`).
    pub fn is_broken_pipe(&self) -> bool {
        self.problem.kind() == io::ErrorKind::BrokenPipe
    }

    /// The problem as an [`io::Error`] of the same kind whose message does
    /// not repeat the path (for callers that name it themselves).
    pub fn into_io(self) -> io::Error {
        io::Error::new(self.problem.kind(), self.problem)
    }
}

/// Where an output goes, resolved by the rules of this module.
#[derive(Debug)]
pub enum Target {
    /// `-`: the standard output.
    Stdout,
    /// A regular file, existing or to be created.
    File(Box<FileTarget>),
}

/// A regular file to be written atomically.
#[derive(Debug)]
pub struct FileTarget {
    /// The path as given.
    requested: PathBuf,
    /// The file that is replaced: `requested`, or where its link leads.
    file: PathBuf,
    /// The directory of `file`, where the temporary is made.
    dir: PathBuf,
    /// The existing file, `None` when it is to be created.
    existing: Option<fs::Metadata>,
}

impl Target {
    /// Resolves `path` by the rules of this module: `-` is stdout; links
    /// are followed to an existing regular file; a missing file is to be
    /// created; anything else is refused. Looks only: opens nothing (a FIFO
    /// is not waited on).
    pub fn resolve(path: &Path) -> Result<Self, OutputError> {
        if is_dash(path) {
            return Ok(Self::Stdout);
        }
        let err = |problem| OutputError::new(path, problem);
        if path.file_name().is_none() {
            return Err(err(OutputProblem::NoFileName));
        }
        let (file, existing) = match fs::symlink_metadata(path) {
            Err(e) if e.kind() == io::ErrorKind::NotFound => (path.to_owned(), None),
            Err(e) => return Err(err(OutputProblem::Resolve(e))),
            Ok(meta) if meta.file_type().is_symlink() => {
                let (file, meta) = follow_link(path).map_err(err)?;
                (file, Some(meta))
            }
            Ok(meta) => match FileKind::of(&meta) {
                None => (path.to_owned(), Some(meta)),
                Some(kind) => return Err(err(OutputProblem::NotRegular { kind, link: None })),
            },
        };
        let dir = match file.parent() {
            Some(d) if !d.as_os_str().is_empty() => d.to_owned(),
            _ => PathBuf::from("."),
        };
        Ok(Self::File(Box::new(FileTarget {
            requested: path.to_owned(),
            file,
            dir,
            existing,
        })))
    }

    /// Whether writing this target and writing `other` would write the
    /// same thing: both stdout, or the same file (the same inode when both
    /// exist; the same directory and name when neither does).
    pub fn same_as(&self, other: &Target) -> bool {
        match (self, other) {
            (Self::Stdout, Self::Stdout) => true,
            (Self::File(a), Self::File(b)) => match (&a.existing, &b.existing) {
                (Some(x), Some(y)) => same_inode(x, y),
                (None, None) => {
                    a.file.file_name() == b.file.file_name()
                        && canonical(&a.dir) == canonical(&b.dir)
                }
                _ => false,
            },
            _ => false,
        }
    }

    /// Whether writing this target would replace the existing file `input`
    /// (through links, `..` and hard links too). `-` (stdin) is no file.
    pub fn is_file(&self, input: &Path) -> bool {
        if is_dash(input) {
            return false;
        }
        match (self, fs::metadata(input)) {
            (Self::File(target), Ok(inp)) => target
                .existing
                .as_ref()
                .is_some_and(|out| same_inode(out, &inp)),
            _ => false,
        }
    }
}

/// The regular file that the link `path` leads to, and its metadata.
fn follow_link(path: &Path) -> Result<(PathBuf, fs::Metadata), OutputProblem> {
    match fs::canonicalize(path) {
        Ok(file) => {
            let meta = fs::metadata(&file).map_err(OutputProblem::Resolve)?;
            match FileKind::of(&meta) {
                None => Ok((file, meta)),
                Some(kind) => Err(OutputProblem::NotRegular {
                    kind,
                    link: Some(file),
                }),
            }
        }
        Err(e) if e.kind() == io::ErrorKind::NotFound => {
            let to = fs::read_link(path).map_err(OutputProblem::Resolve)?;
            Err(OutputProblem::DanglingLink(to))
        }
        Err(e) => Err(OutputProblem::Resolve(e)),
    }
}

fn canonical(dir: &Path) -> PathBuf {
    fs::canonicalize(dir).unwrap_or_else(|_| dir.to_owned())
}

#[cfg(unix)]
fn same_inode(a: &fs::Metadata, b: &fs::Metadata) -> bool {
    use std::os::unix::fs::MetadataExt;
    (a.dev(), a.ino()) == (b.dev(), b.ino())
}

#[cfg(not(unix))]
fn same_inode(_: &fs::Metadata, _: &fs::Metadata) -> bool {
    false
}

/// Where [`write()`]'s closure writes: the temporary file of a regular
/// target, or stdout; buffered.
pub struct Sink<'a>(SinkInner<'a>);

enum SinkInner<'a> {
    File(BufWriter<&'a File>),
    Stdout(BufWriter<io::StdoutLock<'static>>),
}

impl Write for Sink<'_> {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        match &mut self.0 {
            SinkInner::File(w) => w.write(buf),
            SinkInner::Stdout(w) => w.write(buf),
        }
    }

    fn write_all(&mut self, buf: &[u8]) -> io::Result<()> {
        match &mut self.0 {
            SinkInner::File(w) => w.write_all(buf),
            SinkInner::Stdout(w) => w.write_all(buf),
        }
    }

    fn flush(&mut self) -> io::Result<()> {
        match &mut self.0 {
            SinkInner::File(w) => w.flush(),
            SinkInner::Stdout(w) => w.flush(),
        }
    }
}

/// Writes the output `path` by the rules of this module: `write` fills a
/// [`Sink`]; for a regular file the result replaces the target atomically
/// only if `write`, flushing and syncing all succeed (else the target is as
/// it was and the temporary is removed); for `-` it goes to stdout.
///
/// ```
/// let dir = tempfile::tempdir().unwrap();
/// let path = dir.path().join("out.txt");
/// pgo::output::write(&path, |w| {
///     use std::io::Write;
///     writeln!(w, "hello")
/// })
/// .unwrap();
/// assert_eq!(std::fs::read_to_string(&path).unwrap(), "hello\n");
/// // A directory is no output.
/// let err = pgo::output::write(dir.path(), |_| Ok(())).unwrap_err();
/// assert!(err.to_string().ends_with("is a directory; pgo writes only regular files (use - for stdout)"));
/// ```
pub fn write<F>(path: &Path, write: F) -> Result<(), OutputError>
where
    F: FnOnce(&mut Sink<'_>) -> io::Result<()>,
{
    match Target::resolve(path)? {
        Target::Stdout => {
            write_stdout(write).map_err(|e| OutputError::new(path, OutputProblem::Stdout(e)))
        }
        Target::File(target) => target.replace(write),
    }
}

fn write_stdout<F>(write: F) -> io::Result<()>
where
    F: FnOnce(&mut Sink<'_>) -> io::Result<()>,
{
    let mut sink = Sink(SinkInner::Stdout(BufWriter::with_capacity(
        1 << 16,
        io::stdout().lock(),
    )));
    write(&mut sink)?;
    sink.flush()
}

impl FileTarget {
    fn error(&self, problem: OutputProblem) -> OutputError {
        OutputError::new(&self.requested, problem)
    }

    /// Writes a temporary beside the file and renames it over the file.
    fn replace<F>(&self, write: F) -> Result<(), OutputError>
    where
        F: FnOnce(&mut Sink<'_>) -> io::Result<()>,
    {
        temporary::remove_stale(&self.dir);
        let temp = temporary::create(&self.dir, self.existing.as_ref()).map_err(|source| {
            self.error(OutputProblem::Temporary {
                dir: self.dir.clone(),
                source,
            })
        })?;
        let written = (|| {
            let mut sink = Sink(SinkInner::File(BufWriter::with_capacity(
                1 << 20,
                temp.as_file(),
            )));
            write(&mut sink)?;
            sink.flush()?;
            drop(sink);
            temp.as_file().sync_all()
        })();
        // On failure, dropping `temp` removes it.
        written.map_err(|e| self.error(OutputProblem::Write(e)))?;
        temp.persist(&self.file)
            .map_err(|e| self.error(OutputProblem::Replace(e.error)))?;
        // Make the rename itself durable (best effort: the data is synced).
        if let Ok(d) = File::open(&self.dir) {
            let _ = d.sync_all();
        }
        Ok(())
    }
}

/// Writes an output file by the rules of [this module](self) (atomic replacement of
/// a regular file, `-` for stdout, links followed, devices refused): the
/// same as [`write()`], with the problem as an [`io::Error`] of the
/// same kind that does not repeat the path (callers that name the path
/// themselves use this one).
///
/// ```
/// let dir = tempfile::tempdir().unwrap();
/// let path = dir.path().join("out.txt");
/// pgo::output::write_atomically(&path, |w| {
///     use std::io::Write;
///     writeln!(w, "hello")
/// })
/// .unwrap();
/// assert_eq!(std::fs::read_to_string(&path).unwrap(), "hello\n");
/// ```
pub fn write_atomically<F>(path: &Path, write: F) -> io::Result<()>
where
    F: FnOnce(&mut Sink<'_>) -> io::Result<()>,
{
    self::write(path, write).map_err(OutputError::into_io)
}
