//! The g2o text format for SE(2) and SE(3) pose graphs, with the inlier
//! count of loop-closure candidates as one trailing integer on the edge line.
//!
//! | tag | tokens |
//! |---|---|
//! | `VERTEX_SE2 id x y θ` | 5 |
//! | `EDGE_SE2 i j dx dy dθ I₁₁ I₁₂ I₁₃ I₂₂ I₂₃ I₃₃ [inliers]` | 12 (13) |
//! | `VERTEX_SE3:QUAT id x y z qx qy qz qw` | 9 |
//! | `EDGE_SE3:QUAT i j x y z qx qy qz qw I₁₁ … I₆₆ [inliers]` | 31 (32) |
//! | `EDGE_SE2_MIXTURE i j n {EDGE_SE2 w i j dx dy dθ I×6}×n [inliers]` | 4 + 13n (+1) |
//! | `EDGE_SE3:QUAT_MIXTURE i j n {EDGE_SE3:QUAT w i j x y z qx qy qz qw I×21}×n [inliers]` | 4 + 32n (+1) |
//! | `FIX id …` | ≥ 2 |
//!
//! * The information matrix is the upper triangle, row by row, over the
//!   error coordinates (x, y, θ) or (x, y, z, qx, qy, qz).
//! * Quaternions are normalised on read.
//! * An edge with a trailing inlier count is a loop-closure candidate; an
//!   edge without one is trusted. (g2o and GTSAM read such files unchanged:
//!   they ignore the extra token.)
//! * Max-mixture edges (from the Vertigo / max-mixture outlier datasets) are
//!   read as their first component, the measurement; the rewrite keeps the
//!   line unchanged.
//! * Tokens are separated by any whitespace (CRLF line ends and tabs work);
//!   blank lines and lines starting with `#` are skipped; lines with any
//!   other tag are skipped with one warning per tag.
//! * Vertices and edges may come in any order. Ids that edges name but no
//!   vertex line defines are reported in [`G2oFile::missing`] so that the
//!   caller can initialise them (see [`crate::solve::init`]).
//! * Lines longer than [`MAX_LINE_BYTES`] are rejected, and the file is read
//!   line by line, never whole.
//! * Two writers: [`FileText::rewrite`] writes the input's own text back
//!   with the new poses (every other byte kept: comments, unknown tags,
//!   landmark lines, line ends; see [`rewrite`]), which is what
//!   `Solution::write_g2o` does for a graph read from a file;
//!   [`write_graph`] writes the model alone, in pgo's own layout.

mod rewrite;

#[cfg(feature = "internals")]
pub use rewrite::RewriteError;

use super::source::{Fingerprint, Fingerprinter, Input, Original};
use super::{LineError, LineReader};
use crate::geometry::{Pose, Se2, Se3};
use crate::graph::{
    AnyGraph, Graph, GraphError, LoopCandidate, VertexId, is_positive_definite, min_eigenvalue,
    nearest_positive_definite,
};
use nalgebra::SMatrix;
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::io::{self, Read, Write};
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// The longest line the reader accepts, in bytes.
pub const MAX_LINE_BYTES: usize = 1 << 16;

/// Distinct unknown tags counted one by one in [`ReadSummary::skipped_tags`];
/// lines with further tags are counted together under [`OTHER_TAGS`], so that
/// a file of garbage cannot make the summary (and the report) grow with it.
pub const MAX_SKIPPED_TAGS: usize = 32;

/// The key of [`ReadSummary::skipped_tags`] that counts the lines of tags
/// beyond the first [`MAX_SKIPPED_TAGS`].
pub const OTHER_TAGS: &str = "(other tags)";

/// A tag as shown in messages: at most 40 characters, control and other
/// non-printable characters escaped (garbage input stays readable).
fn shown_tag(tag: &str) -> String {
    let mut shown: String = tag.chars().take(40).flat_map(char::escape_debug).collect();
    if tag.chars().nth(40).is_some() {
        shown.push('…');
    }
    shown
}

/// The tags the reader knows.
const KNOWN_TAGS: [&str; 7] = [
    "VERTEX_SE2",
    "EDGE_SE2",
    "EDGE_SE2_MIXTURE",
    "VERTEX_SE3:QUAT",
    "EDGE_SE3:QUAT",
    "EDGE_SE3:QUAT_MIXTURE",
    "FIX",
];

/// The known tag an unknown `tag` is a slip of, if any: at most two
/// letters inserted, deleted, replaced or swapped (case ignored), so that
/// `EGDE_SE2` or `edge_se2` is named, and `EDGE_SE3` (a tag of g2o's other
/// formats) is matched to its nearest.
fn known_tag_like(tag: &str) -> Option<&'static str> {
    let tag = tag.to_ascii_uppercase();
    (KNOWN_TAGS.iter().copied())
        .map(|known| (edit_distance(&tag, known), known))
        .filter(|&(d, _)| d <= 2)
        .min_by_key(|&(d, _)| d)
        .map(|(_, known)| known)
}

/// The optimal-string-alignment distance of `a` and `b` (insertions,
/// deletions, replacements and swaps of neighbours), of their bytes.
fn edit_distance(a: &str, b: &str) -> usize {
    let (a, b) = (a.as_bytes(), b.as_bytes());
    if a.len().abs_diff(b.len()) > 2 || a.len() > 64 {
        return usize::MAX;
    }
    let mut d = vec![vec![0usize; b.len() + 1]; a.len() + 1];
    (0..=a.len()).for_each(|i| d[i][0] = i);
    (0..=b.len()).for_each(|j| d[0][j] = j);
    for i in 1..=a.len() {
        for j in 1..=b.len() {
            let cost = usize::from(a[i - 1] != b[j - 1]);
            d[i][j] = (d[i - 1][j] + 1)
                .min(d[i][j - 1] + 1)
                .min(d[i - 1][j - 1] + cost);
            if i > 1 && j > 1 && a[i - 1] == b[j - 2] && a[i - 2] == b[j - 1] {
                d[i][j] = d[i][j].min(d[i - 2][j - 2] + 1);
            }
        }
    }
    d[a.len()][b.len()]
}

/// What is wrong with one line of a g2o file.
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
pub enum LineProblem {
    /// The line has the wrong number of tokens for its tag.
    #[error("{tag} needs {expected}, found {found}")]
    TokenCount {
        /// The tag.
        tag: String,
        /// What the tag needs, e.g. `"12 tokens (13 with an inlier count)"`.
        expected: String,
        /// How many tokens the line has.
        found: usize,
    },
    /// A token that should be a number is not.
    #[error("'{token}' is not a number")]
    NotANumber {
        /// The token.
        token: String,
    },
    /// A number that is NaN or infinite.
    #[error("'{token}' is not finite")]
    NotFinite {
        /// The token.
        token: String,
    },
    /// A vertex id that is not a non-negative integer below 2⁶⁴.
    #[error("'{token}' is not a vertex id (a non-negative integer below 2^64)")]
    BadId {
        /// The token.
        token: String,
    },
    /// An inlier count that is not a non-negative integer below 2⁶⁴.
    #[error("inlier count '{token}' is not a non-negative integer below 2^64")]
    BadInlierCount {
        /// The token.
        token: String,
    },
    /// A second vertex line for the same id.
    #[error("vertex {id} is defined twice (first on line {first_line})")]
    DuplicateVertex {
        /// The id.
        id: VertexId,
        /// Where it was defined first.
        first_line: usize,
    },
    /// An edge from a vertex to itself.
    #[error("edge from vertex {id} to itself")]
    SelfLoop {
        /// The id.
        id: VertexId,
    },
    /// An information matrix that is not symmetric positive definite.
    #[error(
        "information matrix is not positive definite (smallest eigenvalue {min_eigenvalue:e}); \
         --fix-information projects such matrices to the nearest positive-definite one"
    )]
    InformationNotPositiveDefinite {
        /// Its smallest eigenvalue.
        min_eigenvalue: f64,
    },
    /// An information matrix that cannot be repaired (all eigenvalues zero).
    #[error("information matrix is zero and cannot be made positive definite")]
    InformationZero,
    /// An information matrix whose projection fails (entries so large that
    /// the eigen-decomposition overflows).
    #[error(
        "information matrix cannot be made positive definite (its entries are too large to decompose)"
    )]
    InformationNotRepairable,
    /// A quaternion of zero norm.
    #[error("quaternion has zero norm")]
    ZeroQuaternion,
    /// An SE(2) line in an SE(3) file or the other way round.
    #[error("{tag} in a file of {dimension}D poses")]
    MixedDimensions {
        /// The tag.
        tag: String,
        /// The dimension the file started with.
        dimension: usize,
    },
    /// A mixture edge whose components are malformed.
    #[error("malformed mixture edge: {0}")]
    BadMixture(String),
    /// `FIX` names a vertex that no line defines or uses.
    #[error("FIX names vertex {id}, which no vertex or edge line mentions")]
    FixUnknownVertex {
        /// The id.
        id: VertexId,
    },
    /// A line longer than [`MAX_LINE_BYTES`].
    #[error("line is longer than {limit} bytes")]
    LineTooLong {
        /// The limit.
        limit: usize,
    },
    /// Bytes that are not UTF-8 text.
    #[error("not UTF-8 text (is this a binary file?)")]
    NotText,
}

/// An error reading a g2o file. Every variant names the file; line problems
/// also name the line (1-based).
#[derive(Debug, thiserror::Error)]
pub enum ReadError {
    /// The file could not be opened or read.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: io::Error,
    },
    /// A line is malformed.
    #[error("{path}:{line}: {problem}")]
    Line {
        /// The file.
        path: PathBuf,
        /// 1-based line number.
        line: usize,
        /// What is wrong.
        problem: LineProblem,
    },
    /// The file holds no pose graph.
    #[error(
        "{path}: no VERTEX_SE2, EDGE_SE2, VERTEX_SE3:QUAT or EDGE_SE3:QUAT lines in {lines} lines{skipped}"
    )]
    NoPoseGraph {
        /// The file.
        path: PathBuf,
        /// How many lines the file has (0: it is empty).
        lines: usize,
        /// A note on the tags that were skipped, if any.
        skipped: String,
    },
}

impl ReadError {
    /// The line number, for line problems.
    pub fn line(&self) -> Option<usize> {
        match self {
            Self::Line { line, .. } => Some(*line),
            _ => None,
        }
    }
}

/// Options for reading.
#[derive(Clone, Copy, Debug, Default)]
pub struct ReadOptions {
    /// Project information matrices that are not positive definite to the
    /// nearest positive-definite matrix (eigenvalues clamped at
    /// `1e-6·max|λ|`) instead of failing.
    pub fix_information: bool,
}

/// What the reader noticed besides the graph.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ReadSummary {
    /// Lines with unknown tags, by tag, in tag order.
    pub skipped_tags: BTreeMap<String, usize>,
    /// Information matrices projected to positive definite (with
    /// [`ReadOptions::fix_information`]).
    pub information_fixed: usize,
    /// Human-readable warnings (one per skipped tag, one for projected
    /// information matrices).
    pub warnings: Vec<String>,
}

/// A g2o file as read: the graph, what the rewrite needs of its text, and
/// what was noticed.
#[derive(Clone, Debug)]
pub struct G2oFile {
    /// The pose graph.
    pub graph: AnyGraph,
    /// Indices of the vertices that edges name but no vertex line defines;
    /// their poses are placeholders (identity) until initialised.
    pub missing: Vec<usize>,
    /// Notes and warnings.
    pub summary: ReadSummary,
    /// What the rewrite needs of the text.
    text: FileText,
}

/// What the line-preserving rewrite ([`FileText::rewrite`]) needs of the
/// file a graph was read from: its name, a fingerprint of the text that was
/// parsed, the text itself (to be read again), and which vertices no line
/// defined.
#[derive(Clone, Debug, Default)]
pub struct FileText {
    /// The input's name in messages.
    name: PathBuf,
    /// What the text that was parsed looked like.
    fingerprint: Fingerprint,
    /// The text, to be read again (`None` when it was read from memory by
    /// [`read_from`]).
    original: Option<Arc<Original>>,
    /// Indices of the vertices that no line defined.
    missing: Vec<usize>,
}

/// The g2o tags and pose syntax of one pose type.
pub trait G2oPose<const D: usize>: Pose<D> {
    /// Vertex tag.
    const VERTEX_TAG: &'static str;
    /// Edge tag.
    const EDGE_TAG: &'static str;
    /// Max-mixture edge tag.
    const MIXTURE_TAG: &'static str;
    /// Numbers in a pose (3 or 7).
    const POSE_NUMBERS: usize;
    /// A pose from its numbers.
    fn from_numbers(v: &[f64]) -> Result<Self, LineProblem>;
    /// The pose's numbers as a g2o line has them (`x y θ` or `x y z qx qy
    /// qz qw`).
    fn numbers(&self) -> Vec<f64>;
    /// Appends the pose's numbers, space-separated, shortest round-trip form.
    fn write_numbers(&self, out: &mut String) {
        push_numbers(out, &self.numbers());
    }
    /// Wraps the graph into [`AnyGraph`].
    fn wrap(graph: Graph<Self, D>) -> AnyGraph;
}

impl G2oPose<3> for Se2 {
    const VERTEX_TAG: &'static str = "VERTEX_SE2";
    const EDGE_TAG: &'static str = "EDGE_SE2";
    const MIXTURE_TAG: &'static str = "EDGE_SE2_MIXTURE";
    const POSE_NUMBERS: usize = 3;
    fn from_numbers(v: &[f64]) -> Result<Self, LineProblem> {
        Ok(Se2::new(v[0], v[1], v[2]))
    }
    fn numbers(&self) -> Vec<f64> {
        vec![self.x, self.y, self.theta]
    }
    fn wrap(graph: Graph<Self, 3>) -> AnyGraph {
        AnyGraph::Planar(graph)
    }
}

impl G2oPose<6> for Se3 {
    const VERTEX_TAG: &'static str = "VERTEX_SE3:QUAT";
    const EDGE_TAG: &'static str = "EDGE_SE3:QUAT";
    const MIXTURE_TAG: &'static str = "EDGE_SE3:QUAT_MIXTURE";
    const POSE_NUMBERS: usize = 7;
    fn from_numbers(v: &[f64]) -> Result<Self, LineProblem> {
        Se3::from_translation_quaternion([v[0], v[1], v[2]], [v[3], v[4], v[5], v[6]])
            .ok_or(LineProblem::ZeroQuaternion)
    }
    fn numbers(&self) -> Vec<f64> {
        let t = self.translation;
        let q = self.quaternion_xyzw();
        vec![t.x, t.y, t.z, q[0], q[1], q[2], q[3]]
    }
    fn wrap(graph: Graph<Self, 6>) -> AnyGraph {
        AnyGraph::Spatial(graph)
    }
}

/// Appends numbers in their shortest round-trip form, each preceded by a space.
fn push_numbers(out: &mut String, values: &[f64]) {
    let mut buf = ryu::Buffer::new();
    for &v in values {
        out.push(' ');
        out.push_str(buf.format(v));
    }
}

/// Reads a g2o file; `-` reads stdin (named `<stdin>` in messages). The
/// text stays available to [`FileText::rewrite`] (see [`super::source`]):
/// a regular file stays open, anything else is copied as it is read.
pub fn read(path: &Path, options: ReadOptions) -> Result<G2oFile, ReadError> {
    let input = Input::open(path).map_err(|source| ReadError::Io {
        path: path.to_owned(),
        source,
    })?;
    let name = input.name().to_owned();
    let mut lines = LineReader::new(input, MAX_LINE_BYTES);
    let mut file = parse(&mut lines, &name, options)?;
    file.text.original = Some(Arc::new(lines.into_inner().into_original()));
    Ok(file)
}

/// Reads g2o text from any reader; `path` is only used in messages. The
/// text is not kept: write the result with [`G2oFile::rewrite_from`] (given
/// the same text again) or [`write_graph`]. (For the tests and the fuzz
/// targets.)
#[cfg(any(test, feature = "internals"))]
pub fn read_from<R: Read>(
    reader: R,
    path: &Path,
    options: ReadOptions,
) -> Result<G2oFile, ReadError> {
    parse(&mut LineReader::new(reader, MAX_LINE_BYTES), path, options)
}

/// Parses the lines of `lines` to the end, fingerprinting them.
fn parse<R: Read>(
    lines: &mut LineReader<R>,
    path: &Path,
    options: ReadOptions,
) -> Result<G2oFile, ReadError> {
    let mut parser = Parser {
        path,
        options,
        state: State::Undecided { fixes: Vec::new() },
        summary: ReadSummary::default(),
        lines: 0,
        skipped_first: BTreeMap::new(),
    };
    let mut fingerprint = Fingerprinter::default();
    while let Some((line_no, line)) = lines.next_raw() {
        let line = line.map_err(|e| match e {
            LineError::Io(source) => ReadError::Io {
                path: path.to_owned(),
                source,
            },
            LineError::TooLong => parser.error(
                line_no,
                LineProblem::LineTooLong {
                    limit: MAX_LINE_BYTES,
                },
            ),
            LineError::NotText => parser.error(line_no, LineProblem::NotText),
        })?;
        fingerprint.add(line.raw);
        parser.lines = line_no;
        parser.line(line_no, line.text)?;
    }
    let mut file = parser.finish()?;
    file.text.name = path.to_owned();
    file.text.fingerprint = fingerprint.finish();
    Ok(file)
}

enum State {
    Undecided { fixes: Vec<(usize, Vec<VertexId>)> },
    Planar(Builder<Se2, 3>),
    Spatial(Builder<Se3, 6>),
}

struct Parser<'a> {
    path: &'a Path,
    options: ReadOptions,
    state: State,
    summary: ReadSummary,
    /// Lines read so far.
    lines: usize,
    /// The first line of each skipped tag (as counted in `skipped_tags`).
    skipped_first: BTreeMap<String, usize>,
}

impl Parser<'_> {
    fn error(&self, line: usize, problem: LineProblem) -> ReadError {
        ReadError::Line {
            path: self.path.to_owned(),
            line,
            problem,
        }
    }

    fn line(&mut self, line_no: usize, text: &str) -> Result<(), ReadError> {
        let mut tokens = text.split_whitespace();
        let Some(tag) = tokens.next() else {
            return Ok(());
        };
        if tag.starts_with('#') {
            return Ok(());
        }
        let rest: Vec<&str> = tokens.collect();
        let result = match tag {
            "VERTEX_SE2" | "EDGE_SE2" | "EDGE_SE2_MIXTURE" => {
                self.planar(line_no, tag)?.line(tag, &rest, line_no)
            }
            "VERTEX_SE3:QUAT" | "EDGE_SE3:QUAT" | "EDGE_SE3:QUAT_MIXTURE" => {
                self.spatial(line_no, tag)?.line(tag, &rest, line_no)
            }
            "FIX" => self.fix(&rest, line_no),
            _ => {
                let tags = &mut self.summary.skipped_tags;
                let key = if tags.contains_key(tag) || tags.len() < MAX_SKIPPED_TAGS {
                    tag
                } else {
                    OTHER_TAGS
                };
                *tags.entry(key.to_owned()).or_insert(0) += 1;
                self.skipped_first.entry(key.to_owned()).or_insert(line_no);
                Ok(())
            }
        };
        result.map_err(|p| self.error(line_no, p))
    }

    fn fix(&mut self, rest: &[&str], line_no: usize) -> Result<(), LineProblem> {
        if rest.is_empty() {
            return Err(LineProblem::TokenCount {
                tag: "FIX".into(),
                expected: "at least 2 tokens".into(),
                found: 1,
            });
        }
        let ids = rest
            .iter()
            .map(|t| parse_id(t))
            .collect::<Result<Vec<_>, _>>()?;
        match &mut self.state {
            State::Undecided { fixes } => fixes.push((line_no, ids)),
            State::Planar(b) => b.fix(ids, line_no),
            State::Spatial(b) => b.fix(ids, line_no),
        }
        Ok(())
    }

    fn planar(&mut self, line_no: usize, tag: &str) -> Result<&mut Builder<Se2, 3>, ReadError> {
        if let State::Undecided { fixes } = &mut self.state {
            let fixes = std::mem::take(fixes);
            self.state = State::Planar(Builder::new(self.options, fixes));
        }
        match &mut self.state {
            State::Planar(b) => Ok(b),
            _ => Err(ReadError::Line {
                path: self.path.to_owned(),
                line: line_no,
                problem: LineProblem::MixedDimensions {
                    tag: tag.to_owned(),
                    dimension: 3,
                },
            }),
        }
    }

    fn spatial(&mut self, line_no: usize, tag: &str) -> Result<&mut Builder<Se3, 6>, ReadError> {
        if let State::Undecided { fixes } = &mut self.state {
            let fixes = std::mem::take(fixes);
            self.state = State::Spatial(Builder::new(self.options, fixes));
        }
        match &mut self.state {
            State::Spatial(b) => Ok(b),
            _ => Err(ReadError::Line {
                path: self.path.to_owned(),
                line: line_no,
                problem: LineProblem::MixedDimensions {
                    tag: tag.to_owned(),
                    dimension: 2,
                },
            }),
        }
    }

    fn finish(mut self) -> Result<G2oFile, ReadError> {
        let state = std::mem::replace(&mut self.state, State::Undecided { fixes: Vec::new() });
        let mut file = match state {
            State::Undecided { .. } => {
                let skipped = if self.summary.skipped_tags.is_empty() {
                    String::new()
                } else {
                    let mut by_count: Vec<(&String, &usize)> =
                        self.summary.skipped_tags.iter().collect();
                    by_count.sort_by(|a, b| b.1.cmp(a.1).then(a.0.cmp(b.0)));
                    let shown: Vec<String> = by_count
                        .iter()
                        .take(5)
                        .map(|(t, n)| format!("{} ×{n}", shown_tag(t)))
                        .collect();
                    let more = match by_count.len().saturating_sub(5) {
                        0 => String::new(),
                        k => format!(" and {k} other tags"),
                    };
                    format!(" (skipped: {}{more})", shown.join(", "))
                };
                return Err(ReadError::NoPoseGraph {
                    path: self.path.to_owned(),
                    lines: self.lines,
                    skipped,
                });
            }
            State::Planar(b) => b.finish().map_err(|(line, p)| self.error(line, p))?,
            State::Spatial(b) => b.finish().map_err(|(line, p)| self.error(line, p))?,
        };
        for (tag, count) in &self.summary.skipped_tags {
            let first = self.skipped_first.get(tag).copied().unwrap_or(0);
            let hint = known_tag_like(tag)
                .map(|known| format!(": did you mean {known}?"))
                .unwrap_or_default();
            self.summary.warnings.push(format!(
                "line {first}: skipped {count} line(s) with unsupported tag {}{hint}",
                shown_tag(tag)
            ));
        }
        file.summary.skipped_tags = std::mem::take(&mut self.summary.skipped_tags);
        file.summary.warnings.splice(0..0, self.summary.warnings);
        Ok(file)
    }
}

/// Builds the graph of one pose type, line by line.
struct Builder<P, const D: usize> {
    options: ReadOptions,
    graph: Graph<P, D>,
    /// The line that defined each vertex (by index), if any.
    defined_on: Vec<Option<usize>>,
    /// The line that named each vertex first (by index).
    named_on: Vec<usize>,
    /// The line being read.
    line_no: usize,
    fixes: Vec<(usize, Vec<VertexId>)>,
    information_fixed: usize,
}

impl<P: G2oPose<D>, const D: usize> Builder<P, D> {
    fn new(options: ReadOptions, fixes: Vec<(usize, Vec<VertexId>)>) -> Self {
        Self {
            options,
            graph: Graph::new(),
            defined_on: Vec::new(),
            named_on: Vec::new(),
            line_no: 0,
            fixes,
            information_fixed: 0,
        }
    }

    fn line(&mut self, tag: &str, rest: &[&str], line_no: usize) -> Result<(), LineProblem> {
        self.line_no = line_no;
        if tag == P::VERTEX_TAG {
            self.vertex(tag, rest, line_no)
        } else if tag == P::EDGE_TAG {
            self.edge(tag, rest)
        } else {
            self.mixture(tag, rest)
        }
    }

    /// The index of vertex `id`, creating a placeholder if it is new.
    fn vertex_index(&mut self, id: VertexId) -> usize {
        let (k, added) = self.graph.vertex_or_insert(id, P::identity());
        if added {
            self.defined_on.push(None);
            self.named_on.push(self.line_no);
        }
        k
    }

    fn vertex(&mut self, tag: &str, rest: &[&str], line_no: usize) -> Result<(), LineProblem> {
        let n = 1 + P::POSE_NUMBERS;
        if rest.len() != n {
            return Err(token_count(tag, &format!("{} tokens", n + 1), rest.len()));
        }
        let id = parse_id(rest[0])?;
        let numbers = parse_numbers(&rest[1..])?;
        let pose = P::from_numbers(&numbers)?;
        let k = self.vertex_index(id);
        if let Some(first_line) = self.defined_on[k] {
            return Err(LineProblem::DuplicateVertex { id, first_line });
        }
        self.defined_on[k] = Some(line_no);
        self.graph.poses[k] = pose;
        Ok(())
    }

    fn edge(&mut self, tag: &str, rest: &[&str]) -> Result<(), LineProblem> {
        let n = 2 + P::POSE_NUMBERS + D * (D + 1) / 2;
        if rest.len() != n && rest.len() != n + 1 {
            return Err(token_count(
                tag,
                &format!("{} tokens ({} with an inlier count)", n + 1, n + 2),
                rest.len(),
            ));
        }
        let from = parse_id(rest[0])?;
        let to = parse_id(rest[1])?;
        let inliers = rest.get(n).map(|t| parse_count(t)).transpose()?;
        let numbers = parse_numbers(&rest[2..n])?;
        self.push_edge(from, to, &numbers, inliers)
    }

    /// `TAG i j n {EDGE_TAG w i j pose info}×n [inliers]`: the first
    /// component is the measurement.
    fn mixture(&mut self, tag: &str, rest: &[&str]) -> Result<(), LineProblem> {
        let per = 4 + P::POSE_NUMBERS + D * (D + 1) / 2;
        let expected = format!("4 + {per}·n tokens (+1 with an inlier count)");
        if rest.len() < 3 {
            return Err(token_count(tag, &expected, rest.len()));
        }
        let from = parse_id(rest[0])?;
        let to = parse_id(rest[1])?;
        let components: usize = rest[2].parse().map_err(|_| {
            LineProblem::BadMixture(format!("'{}' is not a component count", rest[2]))
        })?;
        // A component count too large for the line (even one whose token
        // count overflows) is a token-count error, not an overflow.
        let body = match components.checked_mul(per).and_then(|b| b.checked_add(3)) {
            Some(body) if components > 0 && (rest.len() == body || rest.len() == body + 1) => body,
            _ => return Err(token_count(tag, &expected, rest.len())),
        };
        // Every component must be well formed (its numbers finite), though
        // only the first is used: the line is written back as read.
        let mut first = None;
        for component in rest[3..body].chunks(per) {
            if component[0] != P::EDGE_TAG {
                return Err(LineProblem::BadMixture(format!(
                    "component starts with '{}', expected {}",
                    component[0],
                    P::EDGE_TAG
                )));
            }
            parse_numbers(&component[1..2])?;
            parse_id(component[2])?;
            parse_id(component[3])?;
            let numbers = parse_numbers(&component[4..])?;
            P::from_numbers(&numbers[..P::POSE_NUMBERS])?;
            first.get_or_insert(numbers);
        }
        let numbers = first.ok_or_else(|| LineProblem::BadMixture("no components".into()))?;
        let inliers = rest.get(body).map(|t| parse_count(t)).transpose()?;
        self.push_edge(from, to, &numbers, inliers)
    }

    /// Adds an edge from `numbers` = pose numbers followed by the upper
    /// triangle of the information matrix.
    fn push_edge(
        &mut self,
        from: VertexId,
        to: VertexId,
        numbers: &[f64],
        inliers: Option<u64>,
    ) -> Result<(), LineProblem> {
        if from == to {
            return Err(LineProblem::SelfLoop { id: from });
        }
        let measurement = P::from_numbers(&numbers[..P::POSE_NUMBERS])?;
        let mut information = upper_triangle_to_matrix::<D>(&numbers[P::POSE_NUMBERS..]);
        if !is_positive_definite(&information) {
            if !self.options.fix_information {
                return Err(LineProblem::InformationNotPositiveDefinite {
                    min_eigenvalue: min_eigenvalue(&information),
                });
            }
            information = nearest_positive_definite(&information).ok_or(
                if information.iter().all(|v| *v == 0.0) {
                    LineProblem::InformationZero
                } else {
                    LineProblem::InformationNotRepairable
                },
            )?;
            self.information_fixed += 1;
        }
        self.vertex_index(from);
        self.vertex_index(to);
        let candidate = inliers.map(|n| LoopCandidate { inliers: Some(n) });
        self.graph
            .add_edge(from, to, measurement, information, candidate)
            .map_err(|e| match e {
                // Both vertices exist by now, so a self-loop is all add_edge can report.
                GraphError::SelfLoop(id)
                | GraphError::DuplicateVertex(id)
                | GraphError::UnknownVertex(id) => LineProblem::SelfLoop { id },
            })?;
        Ok(())
    }

    fn fix(&mut self, ids: Vec<VertexId>, line_no: usize) {
        self.fixes.push((line_no, ids));
    }

    /// Applies FIX lines, puts vertices defined by a vertex line first (in
    /// line order) so that "the first vertex" means the first vertex line,
    /// and lists the vertices no line defined.
    fn finish(mut self) -> Result<G2oFile, (usize, LineProblem)> {
        for (line_no, ids) in std::mem::take(&mut self.fixes) {
            for id in ids {
                if self.graph.fix(id).is_err() {
                    return Err((line_no, LineProblem::FixUnknownVertex { id }));
                }
            }
        }
        let mut order: Vec<usize> = (0..self.graph.num_vertices())
            .filter(|&k| self.defined_on[k].is_some())
            .collect();
        order.sort_by_key(|&k| self.defined_on[k]);
        let defined = order.len();
        order.extend((0..self.graph.num_vertices()).filter(|&k| self.defined_on[k].is_none()));
        // Vertices only edges name, in a file that defines others: a
        // VERTEX line missing, or an id mistyped.
        let undefined = (defined > 0)
            .then(|| {
                (order[defined..].iter())
                    .min_by_key(|&&k| self.named_on[k])
                    .map(|&k| (self.graph.id(k), self.named_on[k]))
            })
            .flatten();
        self.graph.reorder_vertices(&order);
        let mut summary = ReadSummary {
            information_fixed: self.information_fixed,
            ..Default::default()
        };
        if self.information_fixed > 0 {
            summary.warnings.push(format!(
                "projected {} information matrices that were not positive definite to the nearest positive-definite ones",
                self.information_fixed
            ));
        }
        let missing: Vec<usize> = (defined..self.graph.num_vertices()).collect();
        if let Some((id, line)) = undefined {
            summary.warnings.push(format!(
                "line {line}: vertex {id} has no VERTEX line ({} such vertices): their poses are \
                 composed along the edges from the defined ones",
                missing.len()
            ));
        }
        // The vectors grew by doubling: give back the unused capacity (up
        // to half of the graph's memory) before the optimiser needs its own.
        self.graph.edges.shrink_to_fit();
        Ok(G2oFile {
            graph: P::wrap(self.graph),
            text: FileText {
                missing: missing.clone(),
                ..FileText::default()
            },
            missing,
            summary,
        })
    }
}

fn token_count(tag: &str, expected: &str, found_after_tag: usize) -> LineProblem {
    LineProblem::TokenCount {
        tag: tag.to_owned(),
        expected: expected.to_owned(),
        found: found_after_tag + 1,
    }
}

fn parse_id(token: &str) -> Result<VertexId, LineProblem> {
    token.parse::<u64>().map_err(|_| LineProblem::BadId {
        token: token.to_owned(),
    })
}

fn parse_count(token: &str) -> Result<u64, LineProblem> {
    token
        .parse::<u64>()
        .map_err(|_| LineProblem::BadInlierCount {
            token: token.to_owned(),
        })
}

fn parse_numbers(tokens: &[&str]) -> Result<Vec<f64>, LineProblem> {
    tokens
        .iter()
        .map(|t| match t.parse::<f64>() {
            Ok(v) if v.is_finite() => Ok(v),
            Ok(_) => Err(LineProblem::NotFinite {
                token: (*t).to_owned(),
            }),
            Err(_) => Err(LineProblem::NotANumber {
                token: (*t).to_owned(),
            }),
        })
        .collect()
}

/// The symmetric matrix whose upper triangle, row by row, is `v`.
fn upper_triangle_to_matrix<const D: usize>(v: &[f64]) -> SMatrix<f64, D, D> {
    let mut m = SMatrix::<f64, D, D>::zeros();
    let mut k = 0;
    for r in 0..D {
        for c in r..D {
            m[(r, c)] = v[k];
            m[(c, r)] = v[k];
            k += 1;
        }
    }
    m
}

fn vertex_line<P: G2oPose<D>, const D: usize>(g: &Graph<P, D>, k: usize, line: &mut String) {
    let _ = write!(line, "{} {}", P::VERTEX_TAG, g.id(k));
    g.poses[k].write_numbers(line);
    line.push('\n');
}

fn edge_line<P: G2oPose<D>, const D: usize>(g: &Graph<P, D>, k: usize, line: &mut String) {
    let e = &g.edges[k];
    let _ = write!(line, "{} {} {}", P::EDGE_TAG, g.id(e.from), g.id(e.to));
    e.measurement.write_numbers(line);
    let mut upper = Vec::with_capacity(D * (D + 1) / 2);
    for r in 0..D {
        for c in r..D {
            upper.push(e.information[(r, c)]);
        }
    }
    push_numbers(line, &upper);
    if let Some(n) = e.candidate.and_then(|c| c.inliers) {
        let _ = write!(line, " {n}");
    }
    line.push('\n');
}

/// Writes a graph that is not rewritten over its file (a graph built in
/// memory, a simulated or corrupted one): vertices in index order but for
/// those in `without` (vertices a file named without a vertex line, whose
/// poses are placeholders), then edges (loop candidates with their inlier
/// counts), then a `FIX` line for explicitly fixed vertices. The one g2o
/// writer of [`crate::PoseGraph::write_g2o`] and `pgo simulate`/`pgo
/// corrupt`.
pub fn write_graph<P: G2oPose<D>, const D: usize>(
    g: &Graph<P, D>,
    without: &[usize],
    out: &mut impl Write,
) -> io::Result<()> {
    let mut written = vec![true; g.num_vertices()];
    for &k in without {
        written[k] = false;
    }
    let mut line = String::with_capacity(512);
    for k in (0..g.num_vertices()).filter(|&k| written[k]) {
        line.clear();
        vertex_line(g, k, &mut line);
        out.write_all(line.as_bytes())?;
    }
    for k in 0..g.edges.len() {
        line.clear();
        edge_line(g, k, &mut line);
        out.write_all(line.as_bytes())?;
    }
    let fixed: Vec<String> = (0..g.num_vertices())
        .filter(|&k| g.is_fixed(k))
        .map(|k| g.id(k).to_string())
        .collect();
    if !fixed.is_empty() {
        writeln!(out, "FIX {}", fixed.join(" "))?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<G2oFile, ReadError> {
        read_from(
            text.as_bytes(),
            Path::new("test.g2o"),
            ReadOptions::default(),
        )
    }

    /// The graph of `f` as [`write_graph`] writes it.
    fn written(f: &G2oFile) -> Vec<u8> {
        let mut out = Vec::new();
        match &f.graph {
            AnyGraph::Planar(g) => write_graph(g, &[], &mut out).unwrap(),
            AnyGraph::Spatial(g) => write_graph(g, &[], &mut out).unwrap(),
        }
        out
    }

    fn planar(f: &G2oFile) -> &Graph<Se2, 3> {
        match &f.graph {
            AnyGraph::Planar(g) => g,
            AnyGraph::Spatial(_) => panic!("expected SE(2)"),
        }
    }

    fn line_error(text: &str) -> (usize, LineProblem) {
        match parse(text) {
            Err(ReadError::Line { line, problem, .. }) => (line, problem),
            other => panic!("expected a line error, got {other:?}"),
        }
    }

    const SE2: &str = "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nVERTEX_SE2 2 2 0 0\n\
        EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\nEDGE_SE2 1 2 1 0 0 1 0 0 1 0 1\nEDGE_SE2 0 2 2 0 0 1 0 0 1 0 1 61\n";

    #[test]
    fn reads_vertices_edges_and_inlier_counts() {
        let f = parse(SE2).unwrap();
        let g = planar(&f);
        assert_eq!(
            (g.num_vertices(), g.edges.len(), g.num_candidates()),
            (3, 3, 1)
        );
        assert_eq!(
            g.edges[2].candidate,
            Some(LoopCandidate { inliers: Some(61) })
        );
        assert!(f.missing.is_empty());
        assert_eq!(g.chi2(), 0.0);
    }

    #[test]
    fn information_is_the_upper_triangle_row_by_row() {
        let f =
            parse("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 0 0 0\nEDGE_SE2 0 1 0 0 0 10 1 2 20 3 30\n")
                .unwrap();
        let i = planar(&f).edges[0].information;
        assert_eq!(
            i,
            nalgebra::Matrix3::new(10.0, 1.0, 2.0, 1.0, 20.0, 3.0, 2.0, 3.0, 30.0)
        );
    }

    #[test]
    fn round_trip_is_exact() {
        let text = "VERTEX_SE3:QUAT 0 0.1 0.2 0.3 0 0 0 1\n\
            VERTEX_SE3:QUAT 5 1.000000001 2 3 0.1 0.2 0.3 0.9\n\
            EDGE_SE3:QUAT 0 5 1 2 3 0.1 0.2 0.3 0.9 1 0 0 0 0 0 1 0 0 0 0 1 0 0 0 4 0 0 4 0 4 17\n\
            FIX 0\n";
        let a = parse(text).unwrap();
        let out = written(&a);
        let b = parse(std::str::from_utf8(&out).unwrap()).unwrap();
        assert_eq!(out, written(&b));
        match (&a.graph, &b.graph) {
            (AnyGraph::Spatial(x), AnyGraph::Spatial(y)) => {
                assert_eq!(x.poses, y.poses);
                assert_eq!(x.edges, y.edges);
                assert_eq!(x.gauge(), y.gauge());
            }
            _ => panic!("expected SE(3)"),
        }
    }

    #[test]
    fn comments_blank_lines_crlf_tabs_and_no_final_newline() {
        let text = "# header\r\n\r\nVERTEX_SE2\t0 0 0 0\r\n  VERTEX_SE2 1  1 0 0  \r\n\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 1";
        let f = parse(text).unwrap();
        assert_eq!(planar(&f).edges.len(), 1);
    }

    #[test]
    fn mixture_component_counts_that_overflow_are_token_count_errors() {
        // Found by the parse fuzz target: `body + 1` overflowed (a panic in
        // builds with overflow checks).
        for count in [
            "11111111111222222222",
            "18446744073709551615",
            "1418129833677085",
        ] {
            let (line, p) = line_error(&format!(
                "VERTEX_SE2 4 0 0 0\nEDGE_SE2_MIXTURE 4 16111 {count}\n"
            ));
            assert_eq!(line, 2);
            assert!(
                matches!(p, LineProblem::TokenCount { found: 4, .. }),
                "{count}: {p:?}"
            );
        }
    }

    #[test]
    fn distinct_unknown_tags_are_capped() {
        let garbage: String = (0..100).map(|k| format!("TAG{k} 1 2\n")).collect();
        let f = parse(&format!("{SE2}{garbage}TAG0 again\n")).unwrap();
        let tags = &f.summary.skipped_tags;
        assert_eq!(tags.len(), MAX_SKIPPED_TAGS + 1);
        assert_eq!(tags.get("TAG0"), Some(&2));
        assert_eq!(tags.get(OTHER_TAGS), Some(&(100 - MAX_SKIPPED_TAGS)));
        assert_eq!(tags.values().sum::<usize>(), 101);
    }

    #[test]
    fn unknown_tags_are_skipped_with_one_warning_per_tag() {
        let f = parse(&format!("{SE2}EQUIV 0 1\nEQUIV 1 2\nBR 0 1 2 3 4 5\n")).unwrap();
        assert_eq!(f.summary.skipped_tags.get("EQUIV"), Some(&2));
        assert_eq!(f.summary.skipped_tags.get("BR"), Some(&1));
        assert_eq!(f.summary.warnings.len(), 2);
    }

    /// A misspelled tag is named with the line it is first on and the tag
    /// it is likely a slip of; a foreign one only with its line.
    #[test]
    fn a_misspelled_tag_is_named_with_its_line_and_the_tag_meant() {
        let f = parse(&format!(
            "{SE2}EGDE_SE2 0 1 1 0 0 1 0 0 1 0 1\nPARAMS_SE2OFFSET 0\n"
        ))
        .unwrap();
        let first = SE2.lines().count() + 1;
        assert_eq!(
            f.summary.warnings,
            [
                format!(
                    "line {first}: skipped 1 line(s) with unsupported tag EGDE_SE2: did you mean EDGE_SE2?"
                ),
                format!(
                    "line {}: skipped 1 line(s) with unsupported tag PARAMS_SE2OFFSET",
                    first + 1
                ),
            ]
        );
        assert_eq!(known_tag_like("edge_se3:quat"), Some("EDGE_SE3:QUAT"));
        assert_eq!(known_tag_like("EDGE_SE2_XY"), None);
    }

    /// In a file that defines its vertices, an edge naming one it does not
    /// define is worth a warning: a VERTEX line is missing or an id
    /// mistyped. Edge-only files (every vertex composed) get none.
    #[test]
    fn an_edge_to_an_undefined_vertex_is_named_with_its_line() {
        let f = parse(&format!("{SE2}EDGE_SE2 2 7 1 0 0 1 0 0 1 0 1\n")).unwrap();
        let line = SE2.lines().count() + 1;
        assert_eq!(f.summary.warnings.len(), 1, "{:?}", f.summary.warnings);
        assert!(
            f.summary.warnings[0]
                .starts_with(&format!("line {line}: vertex 7 has no VERTEX line (1 such")),
            "{:?}",
            f.summary.warnings
        );
        let edges_only = parse("EDGE_SE2 4 5 1 0 0 1 0 0 1 0 1\n").unwrap();
        assert!(edges_only.summary.warnings.is_empty());
    }

    #[test]
    fn edges_without_vertices_leave_missing_vertices_in_first_mention_order() {
        let f = parse("EDGE_SE2 4 5 1 0 0 1 0 0 1 0 1\nEDGE_SE2 5 6 1 0 0 1 0 0 1 0 1\n").unwrap();
        let g = planar(&f);
        assert_eq!(g.ids(), &[4, 5, 6]);
        assert_eq!(f.missing, vec![0, 1, 2]);
        assert_eq!(g.gauge(), vec![0]);
    }

    #[test]
    fn interleaved_lines_put_vertex_lines_first() {
        let text = "EDGE_SE2 2 1 1 0 0 1 0 0 1 0 1\nVERTEX_SE2 1 0 0 0\nVERTEX_SE2 2 1 0 0\nEDGE_SE2 2 3 1 0 0 1 0 0 1 0 1\n";
        let f = parse(text).unwrap();
        let g = planar(&f);
        assert_eq!(g.ids(), &[1, 2, 3]);
        assert_eq!(f.missing, vec![2]);
        assert_eq!((g.id(g.edges[0].from), g.id(g.edges[0].to)), (2, 1));
    }

    #[test]
    fn fix_lines_set_the_gauge_even_before_any_pose_line() {
        let f = parse(&format!("FIX 2\n{SE2}")).unwrap();
        assert_eq!(planar(&f).gauge(), vec![2]);
        let (line, p) = line_error(&format!("{SE2}FIX 9\n"));
        assert_eq!((line, p), (7, LineProblem::FixUnknownVertex { id: 9 }));
    }

    #[test]
    fn mixture_edges_read_their_first_component_and_write_back_unchanged() {
        let mix = "EDGE_SE2_MIXTURE 0 2 2 EDGE_SE2 1 0 2 2 0 0 1 0 0 1 0 1 EDGE_SE2 0.01 0 2 2 0 0 1e-11 0 0 1e-11 0 1e-11";
        let text = format!("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nVERTEX_SE2 2 2 0 0\n{mix}\n");
        let f = parse(&text).unwrap();
        let g = planar(&f);
        assert_eq!(g.edges[0].measurement, Se2::new(2.0, 0.0, 0.0));
        assert_eq!(g.edges[0].information, nalgebra::Matrix3::identity());
        let mut out = Vec::new();
        f.rewrite_from(text.as_bytes(), &mut out).unwrap();
        assert!(std::str::from_utf8(&out).unwrap().contains(mix));
    }

    #[test]
    fn errors_name_the_line_and_the_problem() {
        let v = "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\n";
        let cases: Vec<(String, usize, &str)> = vec![
            (
                format!("{v}EDGE_SE2 0 1 1 0 0 1 0 0 1 0\n"),
                3,
                "EDGE_SE2 needs 12 tokens (13 with an inlier count), found 11",
            ),
            (
                format!("{v}EDGE_SE2 0 1 1 x 0 1 0 0 1 0 1\n"),
                3,
                "'x' is not a number",
            ),
            (
                format!("{v}EDGE_SE2 0 1 1 nan 0 1 0 0 1 0 1\n"),
                3,
                "'nan' is not finite",
            ),
            (
                format!("{v}EDGE_SE2 0 1 1 0 inf 1 0 0 1 0 1\n"),
                3,
                "'inf' is not finite",
            ),
            (
                format!("{v}EDGE_SE2 0 -1 1 0 0 1 0 0 1 0 1\n"),
                3,
                "'-1' is not a vertex id",
            ),
            (
                format!("{v}EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1 6.5\n"),
                3,
                "inlier count '6.5'",
            ),
            (
                format!("{v}EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1 18446744073709551616\n"),
                3,
                "inlier count '18446744073709551616'",
            ),
            (
                format!("{v}EDGE_SE2 1 1 1 0 0 1 0 0 1 0 1\n"),
                3,
                "edge from vertex 1 to itself",
            ),
            (
                format!("{v}EDGE_SE2 0 1 1 0 0 -1 0 0 1 0 1\n"),
                3,
                "not positive definite",
            ),
            (
                format!("{v}VERTEX_SE2 1 5 5 5\n"),
                3,
                "vertex 1 is defined twice (first on line 2)",
            ),
            (
                format!("{v}VERTEX_SE3:QUAT 2 0 0 0 0 0 0 1\n"),
                3,
                "VERTEX_SE3:QUAT in a file of 2D poses",
            ),
            (
                "VERTEX_SE3:QUAT 2 0 0 0 0 0 0 0\n".to_string(),
                1,
                "quaternion has zero norm",
            ),
            (
                "VERTEX_SE2 0 0 0 0 7\n".to_string(),
                1,
                "VERTEX_SE2 needs 5 tokens, found 6",
            ),
            (
                "FIX\n".to_string(),
                1,
                "FIX needs at least 2 tokens, found 1",
            ),
        ];
        for (text, line, message) in cases {
            let err = parse(&text).unwrap_err();
            assert_eq!(err.line(), Some(line), "{text}");
            let shown = err.to_string();
            assert!(shown.starts_with(&format!("test.g2o:{line}: ")), "{shown}");
            assert!(
                shown.contains(message),
                "{shown} does not contain {message}"
            );
        }
    }

    #[test]
    fn indefinite_information_is_projected_on_request_and_counted() {
        let text =
            "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nEDGE_SE2 0 1 1 0 0 10 0 84022 10 0 10\n";
        assert!(parse(text).is_err());
        let f = read_from(
            text.as_bytes(),
            Path::new("t"),
            ReadOptions {
                fix_information: true,
            },
        )
        .unwrap();
        assert_eq!(f.summary.information_fixed, 1);
        assert!(is_positive_definite(&planar(&f).edges[0].information));
        assert_eq!(f.summary.warnings.len(), 1);
    }

    #[test]
    fn empty_comment_only_and_binary_inputs_are_errors() {
        for text in ["", "# nothing\n\n", "EQUIV 0 1\n"] {
            assert!(
                matches!(parse(text), Err(ReadError::NoPoseGraph { .. })),
                "{text:?}"
            );
        }
        let garbage: &[u8] = &[0x56, 0xff, 0xfe, 0x00, 0x0a];
        let err = read_from(garbage, Path::new("bin"), ReadOptions::default()).unwrap_err();
        assert!(err.to_string().contains("not UTF-8"), "{err}");
    }

    #[test]
    fn over_long_lines_are_rejected_without_reading_them_whole() {
        let long = format!("# {}\n", "x".repeat(MAX_LINE_BYTES + 10));
        let (line, p) = line_error(&long);
        assert_eq!(
            (line, p),
            (
                1,
                LineProblem::LineTooLong {
                    limit: MAX_LINE_BYTES
                }
            )
        );
    }
}
