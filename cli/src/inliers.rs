//! Inlier counts kept apart from the g2o file: a CSV of `from,to,inliers`
//! rows (a header line is optional). Each row turns the matching edge into a
//! loop-closure candidate with that count.
//!
//! Rows match edges by their vertex ids in the given direction, or else in
//! the reverse direction. When a vertex pair has several edges, the k-th row
//! for the pair goes to the k-th such edge in file order.

use pgo::VertexId;
use std::io::{self, BufRead, BufReader, Read};
use std::path::{Path, PathBuf};

/// The longest line read, in bytes (as the g2o reader's).
const MAX_LINE_BYTES: usize = 1 << 16;

/// How messages name stdin.
const STDIN_NAME: &str = "<stdin>";

/// One row of the CSV.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct InlierRow {
    /// First vertex id.
    pub from: VertexId,
    /// Second vertex id.
    pub to: VertexId,
    /// The inlier count.
    pub inliers: u64,
    /// 1-based line number in the CSV.
    pub line: usize,
}

/// An error reading or applying an inlier CSV; each names the file and line.
#[derive(Debug, thiserror::Error)]
pub enum InlierCsvError {
    /// The file could not be read.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: io::Error,
    },
    /// A row is malformed.
    #[error("{path}:{line}: {problem}")]
    Row {
        /// The file.
        path: PathBuf,
        /// 1-based line number.
        line: usize,
        /// What is wrong.
        problem: String,
    },
}

/// Reads text one line at a time, each of at most [`MAX_LINE_BYTES`]
/// (memory stays bounded whatever the input), calling `each` with the
/// line's 1-based number and its text, trimmed; a UTF-8 byte-order mark
/// opening the first line is dropped. A line that cannot be read, is too
/// long or is not UTF-8 is an error naming `path` and the line.
fn for_each_line<R: Read>(
    reader: R,
    path: &Path,
    mut each: impl FnMut(usize, &str) -> Result<(), InlierCsvError>,
) -> Result<(), InlierCsvError> {
    let mut reader = BufReader::new(reader);
    let mut buf = Vec::new();
    for line in 1.. {
        buf.clear();
        let read = (&mut reader)
            .take(MAX_LINE_BYTES as u64 + 1)
            .read_until(b'\n', &mut buf)
            .map_err(|source| InlierCsvError::Io {
                path: path.to_owned(),
                source,
            })?;
        if read == 0 {
            break;
        }
        let problem = |problem: String| InlierCsvError::Row {
            path: path.to_owned(),
            line,
            problem,
        };
        if buf.len() > MAX_LINE_BYTES && buf.last() != Some(&b'\n') {
            return Err(problem(format!(
                "line is longer than {MAX_LINE_BYTES} bytes"
            )));
        }
        let bytes = match (line, buf.strip_prefix(b"\xEF\xBB\xBF")) {
            (1, Some(rest)) => rest,
            _ => &buf[..],
        };
        let text = std::str::from_utf8(bytes)
            .map_err(|_| problem("not UTF-8 text (is this a binary file?)".into()))?;
        each(line, text.trim())?;
    }
    Ok(())
}

/// Reads `from,to,inliers` rows from the file `path` (`-`: stdin, named
/// `<stdin>` in messages). Blank lines and `#` lines are skipped; a first
/// line that does not start with a number is taken as a header.
pub fn read_csv(path: &Path) -> Result<Vec<InlierRow>, InlierCsvError> {
    if path.as_os_str() == "-" {
        return read_csv_from(io::stdin().lock(), Path::new(STDIN_NAME));
    }
    let file = std::fs::File::open(path).map_err(|source| InlierCsvError::Io {
        path: path.to_owned(),
        source,
    })?;
    read_csv_from(file, path)
}

/// [`read_csv`] from any reader; `path` is only used in messages.
pub fn read_csv_from<R: io::Read>(
    reader: R,
    path: &Path,
) -> Result<Vec<InlierRow>, InlierCsvError> {
    let mut rows = Vec::new();
    for_each_line(reader, path, |line_no, text| {
        if text.is_empty() || text.starts_with('#') {
            return Ok(());
        }
        let fields: Vec<&str> = text.split(',').map(str::trim).collect();
        let starts_numeric = fields
            .first()
            .is_some_and(|f| f.chars().next().is_some_and(|c| c.is_ascii_digit()));
        if line_no == 1 && !starts_numeric {
            return Ok(());
        }
        let row_err = |problem: String| InlierCsvError::Row {
            path: path.to_owned(),
            line: line_no,
            problem,
        };
        if fields.len() != 3 {
            return Err(row_err(format!(
                "expected 3 fields (from,to,inliers), found {}",
                fields.len()
            )));
        }
        let int = |f: &str, what: &str| {
            f.parse::<u64>().map_err(|_| {
                row_err(format!(
                    "{what} '{f}' is not a non-negative integer below 2^64"
                ))
            })
        };
        rows.push(InlierRow {
            from: int(fields[0], "vertex id")?,
            to: int(fields[1], "vertex id")?,
            inliers: int(fields[2], "inlier count")?,
            line: line_no,
        });
        Ok(())
    })?;
    Ok(rows)
}

/// Reads bare inlier counts, for `pgo gate`: one count per line, or CSV
/// rows whose last field is the count (e.g. `from,to,inliers`). Blank lines
/// and `#` lines are skipped; a first line whose last field is not a number
/// is taken as a header.
pub fn read_counts<R: Read>(reader: R, path: &Path) -> Result<Vec<u64>, InlierCsvError> {
    let mut counts = Vec::new();
    for_each_line(reader, path, |line_no, text| {
        if text.is_empty() || text.starts_with('#') {
            return Ok(());
        }
        let field = text
            .rsplit([',', ' ', '\t', ';'])
            .next()
            .unwrap_or(text)
            .trim();
        match field.parse::<u64>() {
            Ok(n) => counts.push(n),
            Err(_)
                if line_no == 1
                    && !field.starts_with(|c: char| c.is_ascii_digit() || c == '-' || c == '+') => {
            }
            Err(_) => {
                return Err(InlierCsvError::Row {
                    path: path.to_owned(),
                    line: line_no,
                    problem: format!(
                        "inlier count '{field}' is not a non-negative integer below 2^64"
                    ),
                });
            }
        }
        Ok(())
    })?;
    Ok(counts)
}

/// Gives each row's count to its edge ([`pgo::AnyPoseGraph::set_inlier_counts`]:
/// the k-th row of a vertex pair to the k-th edge between them). Returns
/// how many edges already had a count that the CSV replaced; a row without
/// a (further) edge is an error naming `path` and its line.
pub fn apply(
    graph: &mut pgo::AnyPoseGraph,
    rows: &[InlierRow],
    path: &Path,
) -> Result<usize, InlierCsvError> {
    let counts: Vec<(VertexId, VertexId, u64)> =
        rows.iter().map(|r| (r.from, r.to, r.inliers)).collect();
    graph.set_inlier_counts(&counts).map_err(|e| match e {
        pgo::Error::NoEdge { from, to, entry } => InlierCsvError::Row {
            path: path.to_owned(),
            line: rows[entry].line,
            problem: format!("no (further) edge between vertices {from} and {to}"),
        },
        other => InlierCsvError::Row {
            path: path.to_owned(),
            line: 0,
            problem: other.to_string(),
        },
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use pgo::nalgebra::Matrix3;
    use pgo::{Pose, PoseGraph2, Se2};

    fn temp_csv(name: &str, text: &str) -> PathBuf {
        let p = std::env::temp_dir().join(format!("pgo-inliers-{}-{name}.csv", std::process::id()));
        std::fs::write(&p, text).unwrap();
        p
    }

    fn graph() -> pgo::AnyPoseGraph {
        let mut g = PoseGraph2::new();
        for k in 0..4 {
            g.add_pose(k, Se2::identity()).unwrap();
        }
        let i = Matrix3::identity();
        for (a, b) in [(0, 1), (1, 2), (2, 3), (3, 0), (3, 0)] {
            g.add_edge(a, b, Se2::identity(), i).unwrap();
        }
        pgo::AnyPoseGraph::Planar(g)
    }

    /// The loop candidates of `g` as the job sees them: edge index and count.
    fn candidates(g: &pgo::AnyPoseGraph) -> Vec<(usize, Option<u64>)> {
        let solution = g.optimize(&pgo::Options::default()).unwrap();
        solution
            .loops()
            .iter()
            .map(|l| (l.index, l.inliers))
            .collect()
    }

    #[test]
    fn header_is_optional_and_rows_match_in_either_direction() {
        let p = temp_csv("ok", "from,to,inliers\n0,3,61\n3,0,7\n\n# note\n");
        let rows = read_csv(&p).unwrap();
        assert_eq!(rows.len(), 2);
        let mut g = graph();
        assert_eq!(apply(&mut g, &rows, &p).unwrap(), 0);
        // The k-th row of a pair goes to the k-th edge of that pair.
        assert_eq!(candidates(&g), [(3, Some(61)), (4, Some(7))]);
        // Given again, the counts replace those.
        assert_eq!(apply(&mut g, &rows, &p).unwrap(), 2);
        std::fs::remove_file(p).unwrap();
    }

    #[test]
    fn bare_counts_one_per_line_or_as_the_last_csv_field() {
        let p = Path::new("stdin");
        assert_eq!(
            read_counts("12\n\n# c\n7\n0\n".as_bytes(), p).unwrap(),
            vec![12, 7, 0]
        );
        assert_eq!(
            read_counts("from,to,inliers\n1,5,30\n2,9,4\n".as_bytes(), p).unwrap(),
            vec![30, 4]
        );
        let err = read_counts("5\n-3\n".as_bytes(), p)
            .unwrap_err()
            .to_string();
        assert!(err.contains("stdin:2:") && err.contains("'-3'"), "{err}");
        let err = read_counts("5\n1e3\n".as_bytes(), p)
            .unwrap_err()
            .to_string();
        assert!(err.contains("stdin:2:"), "{err}");
    }

    #[test]
    fn unmatched_rows_and_bad_fields_name_the_line() {
        let p = temp_csv("bad", "0,1,5\n1,0,5\n");
        let rows = read_csv(&p).unwrap();
        let err = apply(&mut graph(), &rows, &p).unwrap_err().to_string();
        assert!(
            err.contains(":2:") && err.contains("vertices 1 and 0"),
            "{err}"
        );
        let p2 = temp_csv("bad2", "0,1,-5\n");
        let err = read_csv(&p2).unwrap_err().to_string();
        assert!(
            err.contains(":1:") && err.contains("inlier count '-5'"),
            "{err}"
        );
        std::fs::remove_file(p).unwrap();
        std::fs::remove_file(p2).unwrap();
    }
}
