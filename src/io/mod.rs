//! Reading and writing pose graphs: the g2o format (with the inlier-count
//! annotation of loop candidates), inlier counts kept in a CSV beside it,
//! the input's text kept for rewriting ([`source`]); output files are
//! opened by [`crate::output`].

pub mod g2o;
#[cfg(test)]
mod roundtrip_tests;
pub mod source;

use std::io::{self, BufRead, BufReader, Read};

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

/// One line as read: its bytes exactly as in the input (a byte-order mark
/// and the line end included), and its text (without the byte-order mark).
pub(crate) struct RawLine<'a> {
    /// The bytes of the line, as in the input.
    pub raw: &'a [u8],
    /// The line as text: `raw` without a leading byte-order mark.
    pub text: &'a str,
}

/// Reads text one line at a time, holding at most one line (of at most
/// `limit` bytes) in memory: memory stays bounded whatever the input, and a
/// line that is too long or not UTF-8 is reported with its number. A UTF-8
/// byte-order mark at the start of the first line is dropped from the text
/// (kept in the raw bytes); the line end (`\n` or `\r\n`) is part of both.
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

    /// The next line, its bytes and its text, with its 1-based number;
    /// `None` at the end of the input.
    pub(crate) fn next_raw(&mut self) -> Option<(usize, Result<RawLine<'_>, LineError>)> {
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
        let line = std::str::from_utf8(bytes)
            .map(|text| RawLine {
                raw: &self.buf,
                text,
            })
            .map_err(|_| LineError::NotText);
        Some((self.line, line))
    }

    /// The reader underneath (what it had buffered but not returned is
    /// lost: call this at the end of the input).
    pub(crate) fn into_inner(self) -> R {
        self.reader.into_inner()
    }
}

pub use crate::output::write_atomically;

#[cfg(test)]
mod tests {
    use super::*;

    /// The next line's text and its 1-based number ([`LineReader::next_raw`]
    /// without the bytes).
    fn next_line<R: Read>(r: &mut LineReader<R>) -> Option<(usize, Result<&str, LineError>)> {
        r.next_raw().map(|(n, line)| (n, line.map(|l| l.text)))
    }

    #[test]
    fn raw_lines_keep_the_byte_order_mark_and_the_line_end() {
        let text: &[u8] = b"\xEF\xBB\xBFa b\r\n\xEF\xBB\xBFc";
        let mut r = LineReader::new(text, 16);
        let (n, line) = r.next_raw().unwrap();
        let line = line.unwrap();
        assert_eq!((n, line.raw, line.text), (1, &text[..8], "a b\r\n"));
        // Only the first line's mark is one: later it is text.
        let (n, line) = r.next_raw().unwrap();
        let line = line.unwrap();
        assert_eq!((n, line.raw, line.text), (2, &text[8..], "\u{feff}c"));
        assert!(r.next_raw().is_none());
    }

    #[test]
    fn line_reader_bounds_lines_and_names_them() {
        let text: &[u8] = b"\xEF\xBB\xBFfirst\r\nsecond\n\xff\nlast";
        let mut r = LineReader::new(text, 16);
        assert_eq!(
            next_line(&mut r).map(|(n, l)| (n, l.unwrap().to_owned())),
            Some((1, "first\r\n".into()))
        );
        assert_eq!(
            next_line(&mut r).map(|(n, l)| (n, l.unwrap().to_owned())),
            Some((2, "second\n".into()))
        );
        assert!(matches!(
            next_line(&mut r),
            Some((3, Err(LineError::NotText)))
        ));
        assert_eq!(
            next_line(&mut r).map(|(n, l)| (n, l.unwrap().to_owned())),
            Some((4, "last".into()))
        );
        assert!(next_line(&mut r).is_none());
        let long = vec![b'x'; 100];
        let mut r = LineReader::new(long.as_slice(), 16);
        assert!(matches!(
            next_line(&mut r),
            Some((1, Err(LineError::TooLong)))
        ));
        // Exactly the limit, plus the newline, is fine.
        let ok = [vec![b'y'; 16], vec![b'\n']].concat();
        let mut r = LineReader::new(ok.as_slice(), 16);
        assert_eq!(
            next_line(&mut r).map(|(n, l)| (n, l.unwrap().len())),
            Some((1, 17))
        );
    }
}
