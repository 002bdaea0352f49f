//! Inlier counts kept apart from the g2o file: a CSV of `from,to,inliers`
//! rows (a header line is optional). Each row turns the matching edge into a
//! loop-closure candidate with that count.
//!
//! Rows match edges by their vertex ids in the given direction, or else in
//! the reverse direction. When a vertex pair has several edges, the k-th row
//! for the pair goes to the k-th such edge in file order.

use super::g2o::MAX_LINE_BYTES;
use super::{LineError, LineReader};
use crate::geometry::Pose;
use crate::graph::{Graph, LoopCandidate, VertexId};
use std::collections::HashMap;
use std::io;
use std::path::{Path, PathBuf};

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

/// The error for a line that could not be read.
fn line_error(path: &Path, line: usize, e: LineError) -> InlierCsvError {
    let problem = match e {
        LineError::Io(source) => {
            return InlierCsvError::Io {
                path: path.to_owned(),
                source,
            };
        }
        LineError::TooLong => format!("line is longer than {MAX_LINE_BYTES} bytes"),
        LineError::NotText => "not UTF-8 text (is this a binary file?)".to_owned(),
    };
    InlierCsvError::Row {
        path: path.to_owned(),
        line,
        problem,
    }
}

/// Reads `from,to,inliers` rows from the file `path` (`-`: stdin, named
/// `<stdin>` in messages). Blank lines and `#` lines are skipped; a first
/// line that does not start with a number is taken as a header.
pub fn read_csv(path: &Path) -> Result<Vec<InlierRow>, InlierCsvError> {
    if path.as_os_str() == "-" {
        return read_csv_from(io::stdin().lock(), Path::new(super::source::STDIN_NAME));
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
    let mut lines = LineReader::new(reader, MAX_LINE_BYTES);
    let mut rows = Vec::new();
    while let Some((line_no, line)) = lines.next_line() {
        let text = line.map_err(|e| line_error(path, line_no, e))?.trim();
        if text.is_empty() || text.starts_with('#') {
            continue;
        }
        let fields: Vec<&str> = text.split(',').map(str::trim).collect();
        let starts_numeric = fields
            .first()
            .is_some_and(|f| f.chars().next().is_some_and(|c| c.is_ascii_digit()));
        if line_no == 1 && !starts_numeric {
            continue;
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
    }
    Ok(rows)
}

/// Reads bare inlier counts, for `pgo gate`: one count per line, or CSV
/// rows whose last field is the count (e.g. `from,to,inliers`). Blank lines
/// and `#` lines are skipped; a first line whose last field is not a number
/// is taken as a header.
pub fn read_counts<R: std::io::Read>(reader: R, path: &Path) -> Result<Vec<u64>, InlierCsvError> {
    let mut counts = Vec::new();
    let mut lines = LineReader::new(reader, MAX_LINE_BYTES);
    while let Some((line_no, line)) = lines.next_line() {
        let text = line.map_err(|e| line_error(path, line_no, e))?.trim();
        if text.is_empty() || text.starts_with('#') {
            continue;
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
    }
    Ok(counts)
}

/// Gives each row's count to its edge (see the module documentation).
/// Returns how many edges already had a count that the CSV replaced.
pub fn apply<P: Pose<D>, const D: usize>(
    graph: &mut Graph<P, D>,
    rows: &[InlierRow],
    path: &Path,
) -> Result<usize, InlierCsvError> {
    let mut by_pair: HashMap<(VertexId, VertexId), Vec<usize>> = HashMap::new();
    for (k, e) in graph.edges.iter().enumerate() {
        by_pair
            .entry((graph.id(e.from), graph.id(e.to)))
            .or_default()
            .push(k);
    }
    // Consume matches in file order.
    for list in by_pair.values_mut() {
        list.reverse();
    }
    let mut replaced = 0;
    for row in rows {
        let edge = by_pair
            .get_mut(&(row.from, row.to))
            .and_then(Vec::pop)
            .or_else(|| by_pair.get_mut(&(row.to, row.from)).and_then(Vec::pop))
            .ok_or_else(|| InlierCsvError::Row {
                path: path.to_owned(),
                line: row.line,
                problem: format!(
                    "no (further) edge between vertices {} and {}",
                    row.from, row.to
                ),
            })?;
        let e = &mut graph.edges[edge];
        if e.candidate.is_some_and(|c| c.inliers.is_some()) {
            replaced += 1;
        }
        e.candidate = Some(LoopCandidate {
            inliers: Some(row.inliers),
        });
    }
    Ok(replaced)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Se2;
    use nalgebra::Matrix3;

    fn temp_csv(name: &str, text: &str) -> PathBuf {
        let p = std::env::temp_dir().join(format!("pgo-inliers-{}-{name}.csv", std::process::id()));
        std::fs::write(&p, text).unwrap();
        p
    }

    fn graph() -> Graph<Se2, 3> {
        let mut g = Graph::new();
        for k in 0..4 {
            g.add_vertex(k, Se2::identity()).unwrap();
        }
        let i = Matrix3::identity();
        g.add_edge(0, 1, Se2::identity(), i, None).unwrap();
        g.add_edge(3, 0, Se2::identity(), i, None).unwrap();
        g.add_edge(3, 0, Se2::identity(), i, None).unwrap();
        g
    }

    #[test]
    fn header_is_optional_and_rows_match_in_either_direction() {
        let p = temp_csv("ok", "from,to,inliers\n0,3,61\n3,0,7\n\n# note\n");
        let rows = read_csv(&p).unwrap();
        assert_eq!(rows.len(), 2);
        let mut g = graph();
        assert_eq!(apply(&mut g, &rows, &p).unwrap(), 0);
        assert_eq!(g.edges[0].candidate, None);
        // The k-th row of a pair goes to the k-th edge of that pair.
        assert_eq!(
            g.edges[1].candidate,
            Some(LoopCandidate { inliers: Some(61) })
        );
        assert_eq!(
            g.edges[2].candidate,
            Some(LoopCandidate { inliers: Some(7) })
        );
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
        let p = temp_csv("bad", "0,1,5\n1,2,5\n");
        let rows = read_csv(&p).unwrap();
        let err = apply(&mut graph(), &rows, &p).unwrap_err().to_string();
        assert!(
            err.contains(":2:") && err.contains("vertices 1 and 2"),
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
