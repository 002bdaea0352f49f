//! [`AnyCovariances`]: the covariances of a map of either dimension, as
//! flat arrays of numbers, for bindings.

use super::Covariances;
use crate::error::Error;
use crate::geometry::{Se2, Se3};
use crate::graph::VertexId;
use nalgebra::{Dim, Matrix, RawStorage};

/// The covariances of an [`crate::AnySolution`]'s map
/// ([`crate::AnySolution::covariances`]), each matrix as its numbers row by
/// row: `D×D` per pose, `D` = 3 in 2D (`x y θ`) and 6 in 3D (`x y z rx ry
/// rz`), in the convention of [`Covariances`].
///
/// ```
/// let mut graph = pgo::AnyPoseGraph::new(2)?;
/// let info = [100.0, 0.0, 0.0, 0.0, 100.0, 0.0, 0.0, 0.0, 1e4];
/// graph.add_pose(0, &[0.0, 0.0, 0.0])?;
/// graph.add_pose(1, &[1.0, 0.0, 0.0])?;
/// graph.add_edge(0, 1, &[1.0, 0.0, 0.0], &info)?;
/// let covariances = graph.optimize(&pgo::Options::default())?.covariances()?;
/// assert_eq!(covariances.size(), 3);
/// let c = covariances.pose(1)?;
/// assert!((c[0] - 0.01).abs() < 1e-12 && (c[8] - 1e-4).abs() < 1e-12);
/// assert_eq!(covariances.joint(0, 1)?.len(), 36);
/// # Ok::<(), pgo::Error>(())
/// ```
#[derive(Debug)]
pub enum AnyCovariances {
    /// SE(2).
    Planar(Covariances<Se2, 3>),
    /// SE(3).
    Spatial(Covariances<Se3, 6>),
}

/// Runs `$body` with `$c` bound to the covariances of either dimension.
macro_rules! either {
    ($self:expr, |$c:ident| $body:expr) => {
        match $self {
            AnyCovariances::Planar($c) => $body,
            AnyCovariances::Spatial($c) => $body,
        }
    };
}

/// A matrix's numbers row by row.
fn row_major<R: Dim, C: Dim, S: RawStorage<f64, R, C>>(m: &Matrix<f64, R, C, S>) -> Vec<f64> {
    let mut out = Vec::with_capacity(m.nrows() * m.ncols());
    for r in 0..m.nrows() {
        out.extend((0..m.ncols()).map(|c| m[(r, c)]));
    }
    out
}

impl AnyCovariances {
    /// `D`, the rows of a pose's covariance: 3 (2D) or 6 (3D).
    pub fn size(&self) -> usize {
        match self {
            Self::Planar(_) => 3,
            Self::Spatial(_) => 6,
        }
    }

    /// The ids of the poses, in the graph's order.
    pub fn ids(&self) -> &[VertexId] {
        either!(self, |c| c.ids())
    }

    /// The `D·D` numbers of pose `id`'s covariance
    /// ([`Covariances::pose`]).
    pub fn pose(&self, id: VertexId) -> Result<Vec<f64>, Error> {
        either!(self, |c| c.pose(id).map(|m| row_major(&m)))
    }

    /// The covariances of the poses `ids`, one after the other: `D·D`
    /// numbers each. Errors: those of [`Covariances::pose`], for the first
    /// id that has none.
    pub fn poses(&self, ids: &[VertexId]) -> Result<Vec<f64>, Error> {
        let mut out = Vec::with_capacity(ids.len() * self.size() * self.size());
        for &id in ids {
            out.extend(self.pose(id)?);
        }
        Ok(out)
    }

    /// The `2D·2D` numbers of the joint covariance of `a` and `b`
    /// ([`Covariances::joint`]).
    pub fn joint(&self, a: VertexId, b: VertexId) -> Result<Vec<f64>, Error> {
        either!(self, |c| c.joint(a, b).map(|m| row_major(&m)))
    }

    /// The `D·D` numbers of the covariance of `b` relative to `a`
    /// ([`Covariances::relative`]).
    pub fn relative(&self, a: VertexId, b: VertexId) -> Result<Vec<f64>, Error> {
        either!(self, |c| c.relative(a, b).map(|m| row_major(&m)))
    }

    /// See [`Covariances::factor_values`].
    pub fn factor_values(&self) -> usize {
        either!(self, |c| c.factor_values())
    }
}
