//! `pgo optimize --covariances FILE`: every pose's covariance as CSV.
//!
//! A header, then one line per pose in the graph's order: its id and its
//! `D×D` covariance row by row, in the convention of [`super`] — columns
//! `id,x_x,x_y,x_theta,y_x,…,theta_theta` in 2D and `id,x_x,…,rz_rz` in 3D
//! (`a_b` is row `a`, column `b`; `rx ry rz` the rotation's tangent).
//! Fixed poses have zeros; a pose no edge in the map ties to the fixed
//! ones has no line (its covariance is unbounded) and is named in a
//! warning. Numbers are written to round-trip exactly.

use super::{AnyCovariances, Covariances};
use crate::geometry::Pose;
use crate::graph::VertexId;
use std::io::{self, Write};

/// The names of the tangent's components, translation first.
fn components(d: usize) -> &'static [&'static str] {
    if d == 3 {
        &["x", "y", "theta"]
    } else {
        &["x", "y", "z", "rx", "ry", "rz"]
    }
}

impl<P: Pose<D>, const D: usize> Covariances<P, D> {
    /// Writes every pose's covariance as CSV to `out` (`pgo optimize
    /// --covariances`): a header, then one line per pose in the graph's
    /// order, its id and its `D×D` covariance row by row (columns
    /// `id,x_x,x_y,x_theta,…` in 2D, `id,x_x,…,rz_rz` in 3D), numbers that
    /// read back to the same bits. Returns the ids of the poses left out:
    /// those no edge in the map ties to the fixed ones (their covariance
    /// is unbounded).
    pub fn write_csv(&self, out: &mut impl Write) -> io::Result<Vec<VertexId>> {
        write_lines(self, out)
    }
}

impl AnyCovariances {
    /// See [`Covariances::write_csv`].
    pub fn write_csv(&self, out: &mut impl Write) -> io::Result<Vec<VertexId>> {
        match self {
            Self::Planar(c) => c.write_csv(out),
            Self::Spatial(c) => c.write_csv(out),
        }
    }
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
    use crate::covariance::edges_in_map;
    use crate::geometry::Se2;
    use crate::graph::Graph;
    use nalgebra::Matrix3;
    use std::sync::Arc;

    /// The CSV of the covariances of `graph` with one `accepted` flag per
    /// loop candidate, and the poses left out.
    fn csv(graph: Graph<Se2, 3>, accepted: &[bool]) -> (String, Vec<VertexId>) {
        let in_map = edges_in_map(&graph, accepted.iter().copied()).unwrap();
        let covariances = Covariances::new(Arc::new(graph), &in_map, 1).unwrap();
        let mut out = Vec::new();
        let unbounded = covariances.write_csv(&mut out).unwrap();
        (String::from_utf8(out).unwrap(), unbounded)
    }

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
        let (text, unbounded) = csv(graph, &[false]);
        assert_eq!(unbounded, [13]);
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
    }
}
