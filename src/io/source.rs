//! The input: a path, or `-` for stdin, read once, line by line, and had
//! again for the line-preserving rewrite ([`super::g2o::G2oFile::rewrite`]).
//!
//! * A regular file stays open and is read again from its start through the
//!   same handle (a rename over its path in the meantime, as `--in-place`
//!   does at the end, changes nothing).
//! * Anything else (stdin, a FIFO, a pipe such as `<(…)`, a character
//!   device) is read once and only once: it is never opened a second time,
//!   so a FIFO is not waited on again. Its bytes are copied as they are read
//!   into an unnamed temporary file (in `$TMPDIR`, removed by the system on
//!   exit), which takes disk space, not memory. If that copy fails (no
//!   space), reading goes on and only the rewrite refuses.
//! * Both readings are fingerprinted (`Fingerprint`): the rewrite refuses
//!   if the text it reads again is not the text that was parsed.

use std::fs::File;
use std::hash::{DefaultHasher, Hasher};
use std::io::{self, Read, Write};
use std::path::{Path, PathBuf};

/// How the input is shown in messages when it is stdin.
pub const STDIN_NAME: &str = "<stdin>";

/// The input as opened for the first reading.
pub(crate) struct Input {
    name: PathBuf,
    file: File,
    /// For a stream: the copy of what was read (or why there is none).
    copy: Option<Result<File, String>>,
}

impl Input {
    /// Opens `path` (`-`: stdin) for reading. Opening a FIFO waits for a
    /// writer, as any reader does; it is opened once only.
    pub(crate) fn open(path: &Path) -> io::Result<Self> {
        let (name, file) = if path.as_os_str() == "-" {
            (PathBuf::from(STDIN_NAME), stdin_file()?)
        } else {
            (path.to_owned(), File::open(path)?)
        };
        let copy = if file.metadata()?.is_file() {
            None
        } else {
            Some(
                tempfile::tempfile()
                    .map_err(|e| format!("cannot make a copy of it to read again: {e}")),
            )
        };
        Ok(Self { name, file, copy })
    }

    /// The input's name for messages: the path, or [`STDIN_NAME`].
    pub(crate) fn name(&self) -> &Path {
        &self.name
    }

    /// The input's text, to be had again once read to the end.
    pub(crate) fn into_original(self) -> Original {
        let text = match self.copy {
            None => Ok(self.file),
            Some(copy) => copy.and_then(|mut c| {
                c.flush()
                    .map(|_| c)
                    .map_err(|e| format!("cannot make a copy of it to read again: {e}"))
            }),
        };
        Original { text }
    }
}

/// A handle of its own on stdin (file descriptor 0), read without `Stdin`'s
/// buffer.
#[cfg(unix)]
fn stdin_file() -> io::Result<File> {
    use std::os::fd::AsFd;
    Ok(File::from(io::stdin().as_fd().try_clone_to_owned()?))
}

#[cfg(windows)]
fn stdin_file() -> io::Result<File> {
    use std::os::windows::io::AsHandle;
    Ok(File::from(io::stdin().as_handle().try_clone_to_owned()?))
}

impl Read for Input {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        let n = self.file.read(buf)?;
        if let Some(Ok(copy)) = &mut self.copy {
            if let Err(e) = copy.write_all(&buf[..n]) {
                self.copy = Some(Err(format!("cannot make a copy of it to read again: {e}")));
            }
        }
        Ok(n)
    }
}

/// The text of an input that was read, to be read again.
#[derive(Debug)]
pub struct Original {
    /// The file to read from its start (the input itself, or the copy of a
    /// stream), or why there is none.
    text: Result<File, String>,
}

impl Original {
    /// A reader of the text from its start, or why there is none.
    pub(crate) fn reader(&self) -> Result<impl Read + '_, String> {
        match &self.text {
            Ok(file) => Ok(ReadAt { file, offset: 0 }),
            Err(why) => Err(why.clone()),
        }
    }
}

/// Reads a file from an offset without moving the file's own position.
struct ReadAt<'a> {
    file: &'a File,
    offset: u64,
}

impl Read for ReadAt<'_> {
    #[cfg(unix)]
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        use std::os::unix::fs::FileExt;
        let n = self.file.read_at(buf, self.offset)?;
        self.offset += n as u64;
        Ok(n)
    }

    #[cfg(windows)]
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        use std::os::windows::fs::FileExt;
        let n = self.file.seek_read(buf, self.offset)?;
        self.offset += n as u64;
        Ok(n)
    }
}

/// What identifies a text: its number of lines and bytes and a hash of its
/// lines (SipHash, fed line by line, so that the two readings, cut into the
/// same lines, agree exactly when their bytes do, up to hash collisions).
/// It guards against a file changed on disk between two readings, not
/// against an adversary.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(crate) struct Fingerprint {
    lines: u64,
    bytes: u64,
    hash: u64,
}

/// Computes a [`Fingerprint`] line by line.
#[derive(Clone, Debug, Default)]
pub(crate) struct Fingerprinter {
    lines: u64,
    bytes: u64,
    hasher: DefaultHasher,
}

impl Fingerprinter {
    /// Adds one line, its bytes as in the input.
    pub(crate) fn add(&mut self, raw: &[u8]) {
        self.lines += 1;
        self.bytes += raw.len() as u64;
        self.hasher.write(raw);
    }

    /// The fingerprint of the lines added.
    pub(crate) fn finish(&self) -> Fingerprint {
        Fingerprint {
            lines: self.lines,
            bytes: self.bytes,
            hash: self.hasher.finish(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_stream_is_copied_as_read_and_a_file_is_read_again_in_place() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("in.txt");
        std::fs::write(&path, "one\ntwo\n").unwrap();
        let mut input = Input::open(&path).unwrap();
        assert!(input.copy.is_none(), "a regular file is not copied");
        let mut first = String::new();
        input.read_to_string(&mut first).unwrap();
        let original = input.into_original();
        let mut again = String::new();
        original
            .reader()
            .unwrap()
            .read_to_string(&mut again)
            .unwrap();
        assert_eq!(
            (first.as_str(), again.as_str()),
            ("one\ntwo\n", "one\ntwo\n")
        );
        // Twice: each reader starts at the beginning.
        let mut third = String::new();
        original
            .reader()
            .unwrap()
            .read_to_string(&mut third)
            .unwrap();
        assert_eq!(third, again);
    }

    #[test]
    #[cfg(unix)]
    fn a_fifo_is_opened_once_and_read_again_from_its_copy() {
        let dir = tempfile::tempdir().unwrap();
        let fifo = dir.path().join("fifo");
        let made = std::process::Command::new("mkfifo").arg(&fifo).status();
        if !made.is_ok_and(|s| s.success()) {
            eprintln!("skipped: mkfifo unavailable");
            return;
        }
        let writer = {
            let fifo = fifo.clone();
            std::thread::spawn(move || std::fs::write(fifo, "a b\r\nc\n"))
        };
        let mut input = Input::open(&fifo).unwrap();
        let mut first = Vec::new();
        input.read_to_end(&mut first).unwrap();
        writer.join().unwrap().unwrap();
        let original = input.into_original();
        let mut again = Vec::new();
        original.reader().unwrap().read_to_end(&mut again).unwrap();
        assert_eq!(
            (first.as_slice(), again.as_slice()),
            (&b"a b\r\nc\n"[..], &b"a b\r\nc\n"[..])
        );
    }

    #[test]
    fn fingerprints_tell_texts_apart() {
        let print = |lines: &[&[u8]]| {
            let mut f = Fingerprinter::default();
            lines.iter().for_each(|l| f.add(l));
            f.finish()
        };
        assert_eq!(print(&[b"a\n", b"b\n"]), print(&[b"a\n", b"b\n"]));
        assert_ne!(print(&[b"a\n", b"b\n"]), print(&[b"a\n", b"c\n"]));
        assert_ne!(print(&[b"a\n"]), print(&[b"a\n", b""]));
        assert_ne!(print(&[b"a\n", b"b\n"]), print(&[b"a\r\n", b"b\n"]));
    }
}
