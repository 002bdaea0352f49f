//! The line-preserving rewrite of a g2o file: the input's own text, byte for
//! byte, with new pose values in the vertex lines whose pose changed, and a
//! vertex line for each vertex that no line defined.
//!
//! * Every line that is not a vertex line of the file's pose type is copied
//!   as read: comments, blank lines, `FIX`, edges and mixture edges,
//!   landmarks (`VERTEX_XY`, `EDGE_SE2_XY`, …), `PARAMS_*`, any tag pgo
//!   skipped, a byte-order mark, CRLF line ends, a missing final newline.
//!   Edges keep their information matrices and inlier counts as written,
//!   even when `--fix-information` projected a matrix or `--inliers` gave a
//!   count: those change the optimisation, not the file.
//! * A vertex line whose numbers read back to the graph's pose (bit for bit)
//!   is copied as read. Otherwise its text up to the end of the id (spacing,
//!   tag, id) and its line end are kept, and the pose follows in the
//!   shortest form that reads back to the same bits, one space before each
//!   number.
//! * Vertices that no line defined (pgo composed their poses) get a vertex
//!   line each, in the order edges first named them, right after the last
//!   vertex line; in a file without vertex lines, right before its first
//!   edge or `FIX` line. They end like the file's lines (`\r\n` in a CRLF
//!   file); a last line without a newline gets one before them.
//! * The text is read a second time ([`crate::io::source`]) and must be the
//!   text that was parsed; if it is not (the file changed on disk while pgo
//!   ran), the rewrite fails, and a file output is not replaced.

use super::{FileText, G2oFile, G2oPose, MAX_LINE_BYTES, parse_id, parse_numbers};
use crate::graph::Graph;
use crate::io::source::Fingerprinter;
use crate::io::{LineError, LineReader, RawLine};
use std::io::{self, Read, Write};
use std::path::PathBuf;

/// Why the input could not be rewritten.
#[derive(Debug, thiserror::Error)]
pub enum RewriteError {
    /// The input's text is not available a second time.
    #[error("{}: its text cannot be read again for rewriting: {reason}", input.display())]
    NoText {
        /// The input.
        input: PathBuf,
        /// Why.
        reason: String,
    },
    /// The text read again is not the text that was parsed.
    #[error(
        "{}: changed while pgo ran{}; its text cannot be rewritten faithfully",
        input.display(),
        line.map_or(String::new(), |l| format!(" (line {l} is not what was read)"))
    )]
    Changed {
        /// The input.
        input: PathBuf,
        /// The first line found different, when known.
        line: Option<usize>,
    },
    /// Reading the input again failed.
    #[error("{}: cannot read it again: {source}", input.display())]
    Reread {
        /// The input.
        input: PathBuf,
        /// The cause.
        source: io::Error,
    },
    /// Writing the output failed.
    #[error(transparent)]
    Write(io::Error),
}

impl From<RewriteError> for io::Error {
    /// A write error as it was (its kind kept: a broken pipe stays one);
    /// the others as errors of their own.
    fn from(e: RewriteError) -> Self {
        match e {
            RewriteError::Write(e) => e,
            other => io::Error::other(other),
        }
    }
}

impl G2oFile {
    /// What the rewrite needs of the text, apart from the graph.
    pub fn text(&self) -> &FileText {
        &self.text
    }
}

/// The rewrite of a whole [`G2oFile`], for the tests and the fuzz targets
/// (the library rewrites through [`FileText::rewrite`]).
#[cfg(any(test, feature = "internals"))]
impl G2oFile {
    /// Writes the input's own text to `out` with the graph's current poses
    /// ([`FileText::rewrite`]).
    pub fn rewrite(&self, out: &mut impl Write) -> Result<(), RewriteError> {
        match &self.graph {
            crate::graph::AnyGraph::Planar(g) => self.text.rewrite(g, out),
            crate::graph::AnyGraph::Spatial(g) => self.text.rewrite(g, out),
        }
    }

    /// [`G2oFile::rewrite`] with the text given again as `text` (which must
    /// be the text this file was read from).
    pub fn rewrite_from<R: Read>(&self, text: R, out: &mut impl Write) -> Result<(), RewriteError> {
        match &self.graph {
            crate::graph::AnyGraph::Planar(g) => Rewriter::new(&self.text, g).run(text, out),
            crate::graph::AnyGraph::Spatial(g) => Rewriter::new(&self.text, g).run(text, out),
        }
    }
}

impl FileText {
    /// The input's name, as it was given to the reader (`<stdin>` for the
    /// standard input): the title of a solution's pictures.
    #[cfg(feature = "plot")]
    pub fn name(&self) -> &std::path::Path {
        &self.name
    }

    /// Writes the input's own text to `out` with the poses of `graph` (the
    /// graph read from it, optimised), by the rules of
    /// [`self`](crate::io::g2o::rewrite): every line kept byte for byte but
    /// the pose values of vertex lines whose pose changed, and vertex lines
    /// added for the vertices no line defined. Fails, before writing
    /// anything, when the text is not available (read from memory by
    /// [`super::read_from`], or a stream that could not be copied), and at
    /// the end when the text read again is not the text parsed.
    pub fn rewrite<P: G2oPose<D>, const D: usize>(
        &self,
        graph: &Graph<P, D>,
        out: &mut impl Write,
    ) -> Result<(), RewriteError> {
        let no_text = |reason: String| RewriteError::NoText {
            input: self.name.clone(),
            reason,
        };
        let original = self
            .original
            .as_ref()
            .ok_or_else(|| no_text("it was read from memory".into()))?;
        let text = original.reader().map_err(no_text)?;
        Rewriter::new(self, graph).run(text, out)
    }
}

/// The state of one rewrite.
struct Rewriter<'a, P, const D: usize> {
    file: &'a FileText,
    graph: &'a Graph<P, D>,
    /// Vertices defined by a line: indices `0..defined`, in line order.
    defined: usize,
    /// Vertex lines seen so far.
    vertex_lines: usize,
    /// Whether the vertices without a line have been written.
    added: bool,
    /// The line end of the last line that had one.
    ending: &'static [u8],
    numbers: String,
}

impl<'a, P: G2oPose<D>, const D: usize> Rewriter<'a, P, D> {
    fn new(file: &'a FileText, graph: &'a Graph<P, D>) -> Self {
        Self {
            file,
            graph,
            defined: graph.num_vertices().saturating_sub(file.missing.len()),
            vertex_lines: 0,
            added: file.missing.is_empty(),
            ending: b"\n",
            numbers: String::with_capacity(128),
        }
    }

    fn changed(&self, line: Option<usize>) -> RewriteError {
        RewriteError::Changed {
            input: self.file.name.clone(),
            line,
        }
    }

    fn run<R: Read>(mut self, text: R, out: &mut impl Write) -> Result<(), RewriteError> {
        let mut lines = LineReader::new(text, MAX_LINE_BYTES);
        let mut fingerprint = Fingerprinter::default();
        while let Some((no, line)) = lines.next_raw() {
            let line = line.map_err(|e| match e {
                LineError::Io(source) => RewriteError::Reread {
                    input: self.file.name.clone(),
                    source,
                },
                LineError::TooLong | LineError::NotText => self.changed(Some(no)),
            })?;
            fingerprint.add(line.raw);
            self.line(no, &line, out)?;
        }
        if self.vertex_lines != self.defined
            || !self.added
            || fingerprint.finish() != self.file.fingerprint
        {
            return Err(self.changed(None));
        }
        Ok(())
    }

    fn line(
        &mut self,
        no: usize,
        line: &RawLine<'_>,
        out: &mut impl Write,
    ) -> Result<(), RewriteError> {
        let end = line_end(line.raw);
        if !end.is_empty() {
            self.ending = end;
        }
        let tag = line.text.split_whitespace().next();
        if tag == Some(P::VERTEX_TAG) {
            self.vertex(no, line, out)?;
            if self.vertex_lines == self.defined && !self.added {
                if end.is_empty() {
                    out.write_all(self.ending).map_err(RewriteError::Write)?;
                }
                self.add_missing(out)?;
            }
            return Ok(());
        }
        let names_vertices =
            tag.is_some_and(|t| t == P::EDGE_TAG || t == P::MIXTURE_TAG || t == "FIX");
        if self.defined == 0 && !self.added && names_vertices {
            self.add_missing(out)?;
        }
        out.write_all(line.raw).map_err(RewriteError::Write)
    }

    /// Vertex line `vertex_lines`: as read if its pose is unchanged, else
    /// with the pose's numbers after its id.
    fn vertex(
        &mut self,
        no: usize,
        line: &RawLine<'_>,
        out: &mut impl Write,
    ) -> Result<(), RewriteError> {
        let k = self.vertex_lines;
        self.vertex_lines += 1;
        let tokens: Vec<&str> = line.text.split_whitespace().collect();
        let read = (k < self.defined && tokens.len() == 2 + P::POSE_NUMBERS)
            .then(|| {
                let id = parse_id(tokens[1]).ok()?;
                let numbers = parse_numbers(&tokens[2..]).ok()?;
                Some((id, P::from_numbers(&numbers).ok()?))
            })
            .flatten();
        let pose = match read {
            Some((id, pose)) if id == self.graph.id(k) => pose,
            _ => return Err(self.changed(Some(no))),
        };
        let now = &self.graph.poses[k];
        if pose == *now {
            return out.write_all(line.raw).map_err(RewriteError::Write);
        }
        let bom = line.raw.len() - line.text.len();
        let keep = bom + token_end(line.text, 2);
        self.numbers.clear();
        now.write_numbers(&mut self.numbers);
        out.write_all(&line.raw[..keep])
            .and_then(|_| out.write_all(self.numbers.as_bytes()))
            .and_then(|_| out.write_all(line_end(line.raw)))
            .map_err(RewriteError::Write)
    }

    /// A vertex line for each vertex no line defined, ended like the file's
    /// lines.
    fn add_missing(&mut self, out: &mut impl Write) -> Result<(), RewriteError> {
        self.added = true;
        for &k in &self.file.missing {
            self.numbers.clear();
            self.numbers.push_str(P::VERTEX_TAG);
            self.numbers.push(' ');
            self.numbers.push_str(&self.graph.id(k).to_string());
            self.graph.poses[k].write_numbers(&mut self.numbers);
            out.write_all(self.numbers.as_bytes())
                .and_then(|_| out.write_all(self.ending))
                .map_err(RewriteError::Write)?;
        }
        Ok(())
    }
}

/// The line end of `raw`: `\r\n`, `\n`, or nothing (the last line).
fn line_end(raw: &[u8]) -> &'static [u8] {
    if raw.ends_with(b"\r\n") {
        b"\r\n"
    } else if raw.ends_with(b"\n") {
        b"\n"
    } else {
        b""
    }
}

/// The byte offset just after the `n`-th whitespace-separated token of
/// `text` (the end of `text` if it has fewer).
fn token_end(text: &str, n: usize) -> usize {
    let mut seen = 0;
    let mut inside = false;
    for (i, c) in text.char_indices() {
        if c.is_whitespace() {
            if inside {
                seen += 1;
                if seen == n {
                    return i;
                }
            }
            inside = false;
        } else {
            inside = true;
        }
    }
    text.len()
}

#[cfg(test)]
mod tests;
