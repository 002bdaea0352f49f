//! `pgo optimize --covariances FILE`: every pose's covariance as CSV.
//!
//! A header, then one line per pose in the graph's order: its id and its
//! `D×D` covariance row by row, in the convention of [`super`] — columns
//! `id,x_x,x_y,x_theta,y_x,…,theta_theta` in 2D and `id,x_x,…,rz_rz` in 3D
//! (`a_b` is row `a`, column `b`; `rx ry rz` the rotation's tangent).
//! Fixed poses have zeros; a pose no edge in the map ties to the fixed
//! ones has no line (its covariance is unbounded) and is named in a
//! warning. Numbers are written to round-trip exactly.

use super::{Covariances, edges_in_map};
use crate::geometry::Pose;
use crate::graph::{Graph, VertexId};
use crate::solve::SolveError;
use std::io::{self, Write};
use std::path::Path;
use std::sync::Arc;

/// Why the covariances could not be written.
#[derive(Debug)]
pub(crate) enum CsvError {
    /// `H` could not be factorised ([`Covariances::new`]).
    Solve(SolveError),
    /// The file could not be written.
    Write(io::Error),
}

/// The names of the tangent's components, translation first.
fn components(d: usize) -> &'static [&'static str] {
    if d == 3 {
        &["x", "y", "theta"]
    } else {
        &["x", "y", "z", "rx", "ry", "rz"]
    }
}

/// Writes the covariances of the map `graph` (solved, with one `accepted`
/// flag per loop candidate) to `path` atomically (`-`: stdout), factorised
/// on `threads` threads. Returns the poses left out, whose covariance is
/// unbounded.
pub(crate) fn write_csv<P: Pose<D>, const D: usize>(
    graph: Graph<P, D>,
    accepted: impl IntoIterator<Item = bool>,
    threads: usize,
    path: &Path,
) -> Result<Vec<VertexId>, CsvError> {
    let in_map =
        edges_in_map(&graph, accepted).ok_or(CsvError::Solve(SolveError::WeightCount {
            weights: 0,
            edges: graph.edges.len(),
        }))?;
    let covariances =
        Covariances::new(Arc::new(graph), &in_map, threads).map_err(CsvError::Solve)?;
    let mut unbounded = Vec::new();
    crate::io::write_atomically(path, |w| {
        unbounded = write_lines(&covariances, w)?;
        Ok(())
    })
    .map_err(CsvError::Write)?;
    Ok(unbounded)
}

/// The header and one line per pose with a bounded covariance; returns the
/// others.
fn write_lines<P: Pose<D>, const D: usize>(
    covariances: &Covariances<P, D>,
    out: &mut impl Write,
) -> io::Result<Vec<VertexId>> {
    let names = components(D);
    let mut line = String::from("id");
    for r in names {
        for c in names {
            line += &format!(",{r}_{c}");
        }
    }
    writeln!(out, "{line}")?;
    let mut buffer = ryu::Buffer::new();
    let mut unbounded = Vec::new();
    for (id, covariance) in covariances.iter() {
        let Ok(m) = covariance else {
            unbounded.push(id);
            continue;
        };
        line.clear();
        line += &id.to_string();
        for r in 0..D {
            for c in 0..D {
                line.push(',');
                line += buffer.format(m[(r, c)]);
            }
        }
        writeln!(out, "{line}")?;
    }
    Ok(unbounded)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Se2;
    use nalgebra::Matrix3;

    #[test]
    fn one_line_per_bounded_pose_row_by_row() {
        let mut graph = Graph::<Se2, 3>::new();
        for k in 0..4 {
            graph
                .add_vertex(k + 10, Se2::new(k as f64, 0.0, 0.0))
                .unwrap();
        }
        let step = Se2::new(1.0, 0.0, 0.0);
        let info = Matrix3::from_diagonal(&[4.0, 4.0, 100.0].into());
        graph.add_edge(10, 11, step, info, None).unwrap();
        graph.add_edge(11, 12, step, info, None).unwrap();
        let candidate = Some(crate::graph::LoopCandidate { inliers: Some(3) });
        graph.add_edge(12, 13, step, info, candidate).unwrap();
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("cov.csv");
        let unbounded = write_csv(graph, [false], 1, &path).unwrap();
        assert_eq!(unbounded, [13]);
        let text = std::fs::read_to_string(&path).unwrap();
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(
            lines[0],
            "id,x_x,x_y,x_theta,y_x,y_y,y_theta,theta_x,theta_y,theta_theta"
        );
        let row =
            |k: usize| -> Vec<f64> { lines[k].split(',').map(|v| v.parse().unwrap()).collect() };
        let close = |got: Vec<f64>, want: [f64; 10]| {
            assert!(
                got.iter().zip(want).all(|(g, w)| (g - w).abs() < 1e-15),
                "{got:?}"
            );
        };
        close(row(1), [10.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
        close(
            row(2),
            [11.0, 0.25, 0.0, 0.0, 0.0, 0.25, 0.0, 0.0, 0.0, 0.01],
        );
        // Two steps: y also inherits the first step's heading, 1 m back.
        close(
            row(3),
            [12.0, 0.5, 0.0, 0.0, 0.0, 0.51, 0.01, 0.0, 0.01, 0.02],
        );
        assert_eq!(lines.len(), 4);
        // A candidate flag short: refused, nothing written.
        let graph = Graph::<Se2, 3>::new();
        assert!(write_csv(graph, [true], 1, &dir.path().join("no.csv")).is_err());
        assert!(!dir.path().join("no.csv").exists());
    }
}
