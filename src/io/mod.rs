//! Reading and writing pose graphs: the g2o format (with the inlier-count
//! annotation of loop candidates), inlier counts kept in a CSV beside it, and
//! atomic file replacement.

pub mod g2o;
pub mod inliers;
#[cfg(test)]
mod roundtrip_tests;

use std::fs::{self, File};
use std::io::{self, BufRead, BufReader, BufWriter, Read, Write};
use std::path::{Path, PathBuf};

/// Why a line of text could not be had.
#[derive(Debug)]
pub(crate) enum LineError {
    /// Reading failed.
    Io(io::Error),
    /// The line is longer than the limit (it was not read whole).
    TooLong,
    /// The line is not UTF-8.
    NotText,
}

/// Reads text one line at a time, holding at most one line (of at most
/// `limit` bytes) in memory: memory stays bounded whatever the input, and a
/// line that is too long or not UTF-8 is reported with its number. A UTF-8
/// byte-order mark at the start of the first line is dropped; the line end
/// (`\n` or `\r\n`) is part of the returned text.
pub(crate) struct LineReader<R> {
    reader: BufReader<R>,
    buf: Vec<u8>,
    line: usize,
    limit: usize,
}

impl<R: Read> LineReader<R> {
    pub(crate) fn new(reader: R, limit: usize) -> Self {
        Self {
            reader: BufReader::with_capacity(1 << 16, reader),
            buf: Vec::with_capacity(256),
            line: 0,
            limit,
        }
    }

    /// The next line and its 1-based number, `None` at the end of the input.
    pub(crate) fn next_line(&mut self) -> Option<(usize, Result<&str, LineError>)> {
        self.buf.clear();
        self.line += 1;
        let read = (&mut self.reader)
            .take(self.limit as u64 + 1)
            .read_until(b'\n', &mut self.buf);
        match read {
            Err(e) => return Some((self.line, Err(LineError::Io(e)))),
            Ok(0) => return None,
            Ok(_) => {}
        }
        if self.buf.len() > self.limit && self.buf.last() != Some(&b'\n') {
            return Some((self.line, Err(LineError::TooLong)));
        }
        let bytes = match (self.line, self.buf.strip_prefix(b"\xEF\xBB\xBF")) {
            (1, Some(rest)) => rest,
            _ => &self.buf[..],
        };
        Some((
            self.line,
            std::str::from_utf8(bytes).map_err(|_| LineError::NotText),
        ))
    }
}

/// Whether `a` and `b` name the same existing file (through links, `.` and
/// `..` too). False when either does not exist.
pub fn same_file(a: &Path, b: &Path) -> bool {
    match (fs::canonicalize(a), fs::canonicalize(b)) {
        (Ok(x), Ok(y)) => x == y,
        _ => false,
    }
}

/// Writes a file atomically: the content goes to a temporary file in the
/// same directory (`.NAME.pgo-tmp-PID`), which is flushed, synced to disk
/// (`fsync`) and then renamed over `path`; the directory is synced after the
/// rename so that the rename itself survives a crash. A failure at any point
/// leaves `path` as it was (and removes the temporary file), so a reader sees
/// either the old file or the complete new one, never a half-written one.
///
/// A process killed before the rename cannot remove its temporary file; the
/// next write to the same `path` removes such leftovers of processes that no
/// longer exist (on systems with `/proc`). An existing `path` keeps its
/// permissions.
///
/// ```ignore
/// let dir = std::env::temp_dir().join(format!("pgo-doc-{}", std::process::id()));
/// std::fs::create_dir_all(&dir).unwrap();
/// let path = dir.join("out.txt");
/// pgo::io::write_atomically(&path, |w| {
///     use std::io::Write;
///     writeln!(w, "hello")
/// })
/// .unwrap();
/// assert_eq!(std::fs::read_to_string(&path).unwrap(), "hello\n");
/// # std::fs::remove_dir_all(&dir).unwrap();
/// ```
pub fn write_atomically<F>(path: &Path, write: F) -> io::Result<()>
where
    F: FnOnce(&mut BufWriter<File>) -> io::Result<()>,
{
    let temp = temporary_path(path);
    remove_stale_temporaries(path);
    let result = (|| {
        let file = File::create(&temp)?;
        if let Ok(old) = fs::metadata(path) {
            file.set_permissions(old.permissions())?;
        }
        let mut writer = BufWriter::with_capacity(1 << 20, file);
        write(&mut writer)?;
        writer.flush()?;
        let file = writer.into_inner().map_err(|e| e.into_error())?;
        file.sync_all()?;
        drop(file);
        fs::rename(&temp, path)?;
        // Make the rename itself durable.
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            if let Ok(d) = File::open(dir) {
                let _ = d.sync_all();
            }
        }
        Ok(())
    })();
    if result.is_err() {
        let _ = fs::remove_file(&temp);
    }
    result
}

/// The prefix of the temporary files of `path`: `.NAME.pgo-tmp-`.
fn temporary_prefix(path: &Path) -> String {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "out".into());
    format!(".{name}.pgo-tmp-")
}

/// `dir/.NAME.pgo-tmp-PID` beside `path`.
fn temporary_path(path: &Path) -> PathBuf {
    path.with_file_name(format!("{}{}", temporary_prefix(path), std::process::id()))
}

/// Removes the temporary files of `path` left by killed processes: those
/// whose process id no longer exists. Only where `/proc` tells which
/// processes exist; errors are ignored (a leftover is harmless: it is never
/// read).
fn remove_stale_temporaries(path: &Path) {
    let proc = Path::new("/proc");
    if !proc.join("self").exists() {
        return;
    }
    let prefix = temporary_prefix(path);
    let dir = match path.parent().filter(|d| !d.as_os_str().is_empty()) {
        Some(d) => d.to_owned(),
        None => PathBuf::from("."),
    };
    let Ok(entries) = fs::read_dir(&dir) else {
        return;
    };
    for entry in entries.flatten() {
        let name = entry.file_name();
        let Some(pid) = name
            .to_str()
            .and_then(|n| n.strip_prefix(prefix.as_str()))
            .and_then(|p| p.parse::<u32>().ok())
        else {
            continue;
        };
        if pid != std::process::id() && !proc.join(pid.to_string()).exists() {
            let _ = fs::remove_file(entry.path());
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn failed_write_leaves_the_old_file_and_no_temporary() {
        let dir = std::env::temp_dir().join(format!("pgo-atomic-{}", std::process::id()));
        fs::create_dir_all(&dir).unwrap();
        let path = dir.join("graph.g2o");
        fs::write(&path, "old").unwrap();
        let err = write_atomically(&path, |w| {
            w.write_all(b"partial")?;
            Err(io::Error::other("interrupted"))
        });
        assert!(err.is_err());
        assert_eq!(fs::read_to_string(&path).unwrap(), "old");
        let leftovers: Vec<_> = fs::read_dir(&dir).unwrap().collect();
        assert_eq!(leftovers.len(), 1, "temporary file left behind");
        write_atomically(&path, |w| w.write_all(b"new")).unwrap();
        assert_eq!(fs::read_to_string(&path).unwrap(), "new");
        fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    #[cfg(target_os = "linux")]
    fn leftovers_of_dead_processes_are_removed_and_permissions_kept() {
        use std::os::unix::fs::PermissionsExt;
        let dir = std::env::temp_dir().join(format!("pgo-stale-{}", std::process::id()));
        fs::create_dir_all(&dir).unwrap();
        let path = dir.join("graph.g2o");
        fs::write(&path, "old").unwrap();
        fs::set_permissions(&path, fs::Permissions::from_mode(0o640)).unwrap();
        // A process id above the kernel's maximum (4194304) never exists.
        let dead = dir.join(".graph.g2o.pgo-tmp-4294967");
        // Our own parent is alive: its leftover-looking file stays.
        let alive = dir.join(format!(
            ".graph.g2o.pgo-tmp-{}",
            std::os::unix::process::parent_id()
        ));
        let other = dir.join(".other.g2o.pgo-tmp-4294967");
        for p in [&dead, &alive, &other] {
            fs::write(p, "partial").unwrap();
        }
        write_atomically(&path, |w| w.write_all(b"new")).unwrap();
        assert_eq!(fs::read_to_string(&path).unwrap(), "new");
        assert_eq!(
            fs::metadata(&path).unwrap().permissions().mode() & 0o777,
            0o640
        );
        assert!(!dead.exists());
        assert!(alive.exists() && other.exists());
        fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn line_reader_bounds_lines_and_names_them() {
        let text: &[u8] = b"\xEF\xBB\xBFfirst\r\nsecond\n\xff\nlast";
        let mut r = LineReader::new(text, 16);
        assert_eq!(
            r.next_line().map(|(n, l)| (n, l.unwrap().to_owned())),
            Some((1, "first\r\n".into()))
        );
        assert_eq!(
            r.next_line().map(|(n, l)| (n, l.unwrap().to_owned())),
            Some((2, "second\n".into()))
        );
        assert!(matches!(r.next_line(), Some((3, Err(LineError::NotText)))));
        assert_eq!(
            r.next_line().map(|(n, l)| (n, l.unwrap().to_owned())),
            Some((4, "last".into()))
        );
        assert!(r.next_line().is_none());
        let long = vec![b'x'; 100];
        let mut r = LineReader::new(long.as_slice(), 16);
        assert!(matches!(r.next_line(), Some((1, Err(LineError::TooLong)))));
        // Exactly the limit, plus the newline, is fine.
        let ok = [vec![b'y'; 16], vec![b'\n']].concat();
        let mut r = LineReader::new(ok.as_slice(), 16);
        assert_eq!(
            r.next_line().map(|(n, l)| (n, l.unwrap().len())),
            Some((1, 17))
        );
    }

    #[test]
    #[cfg(unix)]
    fn same_file_sees_through_dot_dot_and_links() {
        let dir = std::env::temp_dir().join(format!("pgo-same-{}", std::process::id()));
        fs::create_dir_all(dir.join("sub")).unwrap();
        let a = dir.join("a.g2o");
        fs::write(&a, "x").unwrap();
        assert!(same_file(&a, &dir.join("sub/../a.g2o")));
        std::os::unix::fs::symlink(&a, dir.join("link.g2o")).unwrap();
        assert!(same_file(&a, &dir.join("link.g2o")));
        assert!(!same_file(&a, &dir.join("missing.g2o")));
        fs::remove_dir_all(&dir).unwrap();
    }
}
