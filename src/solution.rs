//! What the job returns: the optimised poses by id, one decision per loop
//! candidate, the χ² test's verdict, and the report `pgo optimize` prints.

use crate::certify::{self, Certificate};
use crate::covariance::{self, AnyCovariances, Covariances};
use crate::error::Error;
use crate::geometry::{Pose, Se2, Se3};
use crate::graph::{self, VertexId};
use crate::io::g2o::{self, FileText, G2oPose};
use crate::report::{IncrementalReport, MapStatus, Report};
pub use crate::robust::Reason;
use crate::solve::StopReason;
use crate::stats::Chi2Test;
use std::any::Any;
use std::collections::HashMap;
use std::io::{self, Write};
use std::path::Path;
#[cfg(feature = "plot")]
use std::path::PathBuf;
use std::sync::Arc;

#[cfg(feature = "plot")]
mod plots;
mod trajectory;

/// The result of [`crate::PoseGraph::optimize`].
#[derive(Clone, Debug)]
pub struct Solution<P> {
    ids: Vec<VertexId>,
    poses: Vec<P>,
    /// Where each id is, when the ids are not increasing (found by binary
    /// search when they are, as a front end's usually are).
    index: Option<HashMap<VertexId, usize>>,
    loops: Vec<LoopDecision>,
    report: Report,
    /// The graph as solved (its edges, which are candidates, the gauge), a
    /// `graph::Graph<P, D>`, for [`Solution::covariances`]; clones share
    /// it. `None` only for a solution made without it.
    solved: Option<Arc<dyn Any + Send + Sync>>,
    /// The job's `--threads`, for the covariances' factorisation.
    threads: usize,
    /// The poses the solve started from, when the whole job ran.
    initial: Option<Vec<P>>,
    /// The text of the file the graph was read from, for
    /// [`Solution::write_g2o`].
    text: Option<Arc<FileText>>,
}

/// How the job decided one loop candidate. Serialised (with the `json`
/// feature's `serde_json`, say) under its field names, `reason` as
/// [`Reason::as_str`] names it.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct LoopDecision {
    /// Its index, as [`crate::PoseGraph::add_loop_candidate`] returned it
    /// (edges and candidates are numbered together; with
    /// `--candidates non-sequential` a trusted edge between non-consecutive
    /// ids is a candidate too, under its edge index).
    pub index: usize,
    /// Its first vertex id.
    pub from: VertexId,
    /// Its second vertex id.
    pub to: VertexId,
    /// Its inlier count, if it has one.
    pub inliers: Option<u64>,
    /// Whether the gate kept it.
    pub kept: bool,
    /// Its final weight in the optimisation, in [0, 1].
    pub weight: f64,
    /// Whether it is in the map: weight ≥ ½.
    pub accepted: bool,
    /// EM: its posterior probability of being a true loop.
    pub posterior: Option<f64>,
    /// EM: its squared innovation `ν²` against the map without it and its
    /// cluster (`None` when nothing else checks it).
    pub innovation: Option<f64>,
    /// Why it ended where it did.
    pub reason: Reason,
}

impl Reason {
    /// Its name as the JSON report spells it (snake case): `consistent`,
    /// `inconsistent`, `outlying`, `unchecked`, `explains_chi2`,
    /// `unsettled`, `kernel`, `dropped` or `trusted` (for bindings).
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Consistent => "consistent",
            Self::Inconsistent => "inconsistent",
            Self::Outlying => "outlying",
            Self::Unchecked => "unchecked",
            Self::ExplainsChi2 => "explains_chi2",
            Self::Unsettled => "unsettled",
            Self::Kernel => "kernel",
            Self::Dropped => "dropped",
            Self::Trusted => "trusted",
        }
    }
}

impl<P> Solution<P> {
    /// The solution in the optimised `graph`, with the job's `report`.
    pub(crate) fn new<const D: usize>(graph: &graph::Graph<P, D>, report: Report) -> Self
    where
        P: Pose<D>,
    {
        let candidates = (0..graph.edges.len()).filter(|&k| graph.edges[k].is_candidate());
        let loops = candidates
            .zip(&report.loops)
            .map(|(index, l)| LoopDecision {
                index,
                from: l.from,
                to: l.to,
                inliers: l.inliers,
                kept: l.kept,
                weight: l.weight,
                accepted: l.accepted,
                posterior: l.posterior,
                innovation: l.innovation,
                reason: l.reason,
            })
            .collect();
        let ids = graph.ids().to_vec();
        let increasing = ids.windows(2).all(|w| w[0] < w[1]);
        let index = (!increasing).then(|| ids.iter().enumerate().map(|(k, &id)| (id, k)).collect());
        Self {
            ids,
            poses: graph.poses.clone(),
            index,
            loops,
            report,
            solved: None,
            threads: 0,
            initial: None,
            text: None,
        }
    }

    /// The graph as solved.
    fn solved_graph<const D: usize>(&self) -> Result<Arc<graph::Graph<P, D>>, Error>
    where
        P: Pose<D>,
    {
        (self.solved.clone())
            .and_then(|g| g.downcast::<graph::Graph<P, D>>().ok())
            .ok_or_else(|| Error::Internal("the solution holds no graph".into()))
    }

    /// The map's edges with their isotropic weights, which
    /// [`Solution::certificate`] certifies.
    pub(crate) fn certificate_problem<const D: usize>(&self) -> Result<certify::Problem<P>, Error>
    where
        P: Pose<D>,
    {
        Ok(certify::Problem::of_graph(
            &*self.solved_graph::<D>()?,
            &self.report,
        ))
    }

    /// This solution, written back into the text of the file its graph was
    /// read from (when there is one) by [`Solution::write_g2o`].
    pub(crate) fn with_text(mut self, text: Option<Arc<FileText>>) -> Self {
        self.text = text;
        self
    }

    /// The optimised map as g2o text on `out`: the file's own text with
    /// the new poses, or the graph's lines ([`Solution::write_g2o`]).
    fn write_lines<const D: usize>(&self, out: &mut impl Write) -> io::Result<()>
    where
        P: G2oPose<D>,
    {
        let graph = self.solved_graph::<D>().map_err(io::Error::other)?;
        match &self.text {
            Some(text) => Ok(text.rewrite(&graph, out)?),
            None => g2o::write_graph(&graph, &[], out),
        }
    }

    /// [`Solution::write_g2o`] for either pose type.
    fn write_file<const D: usize>(&self, path: &Path) -> Result<(), Error>
    where
        P: G2oPose<D>,
    {
        crate::io::write_atomically(path, |w| self.write_lines(w)).map_err(|source| Error::Write {
            path: path.to_owned(),
            source,
        })
    }

    /// [`Solution::write_tum`] and [`Solution::write_kitti`] for either
    /// pose type.
    fn write_trajectory(&self, path: &Path, format: trajectory::Format) -> Result<(), Error>
    where
        P: trajectory::Embed,
    {
        crate::output::write_atomically(path, |w| trajectory::write(self.poses(), format, w))
            .map_err(|source| Error::Write {
                path: path.to_owned(),
                source,
            })
    }

    /// This solution, with the poses its solve started from (`initial`,
    /// in the graph's order).
    pub(crate) fn starting_from(mut self, initial: Vec<P>) -> Self {
        self.initial = Some(initial);
        self
    }

    /// This solution, keeping the solved `graph` (moved, not copied) for
    /// [`Solution::covariances`], to be factorised on `threads` threads.
    pub(crate) fn keeping<const D: usize>(
        mut self,
        graph: graph::Graph<P, D>,
        threads: usize,
    ) -> Self
    where
        P: Pose<D>,
    {
        self.solved = Some(Arc::new(graph));
        self.threads = threads;
        self
    }

    /// The marginal covariances of the map ([`Covariances`]: the
    /// convention, the gauge, what `H` holds): factorises the normal matrix
    /// of the edges in the map (trusted edges and accepted loops) at the
    /// returned poses, undamped, and computes its selected inverse, on the
    /// job's threads — about three factorisations' time, once per call:
    /// keep the result for many queries. The solution holds the solved
    /// graph for this (its memory: 128 bytes per edge in 2D and 376 in 3D,
    /// and the poses and ids again). Errors: [`Error::Undetermined`] (the edges at a pose do not
    /// determine it, to rounding), [`Error::Threads`], [`Error::Internal`].
    pub fn covariances<const D: usize>(&self) -> Result<Covariances<P, D>, Error>
    where
        P: Pose<D>,
    {
        let graph = self.solved_graph::<D>()?;
        let in_map = covariance::edges_in_map(&graph, self.loops.iter().map(|l| l.accepted))
            .ok_or_else(|| Error::Internal("loop decisions do not match the graph".into()))?;
        Covariances::new(graph, &in_map, self.threads).map_err(|e| match e {
            crate::solve::SolveError::Linear(crate::linear::LinearError::ThreadPool(message)) => {
                Error::Threads {
                    threads: self.threads,
                    message,
                }
            }
            other => other.into(),
        })
    }
}

impl<P> Solution<P> {
    /// What an incremental update ([`crate::PoseGraph::update`]) did:
    /// how it reached the map and which earlier decisions it changed
    /// (`None` for [`crate::PoseGraph::optimize`]).
    pub fn incremental(&self) -> Option<&IncrementalReport> {
        self.report.incremental.as_ref()
    }

    /// The optimised pose with this id.
    pub fn pose(&self, id: VertexId) -> Option<&P> {
        let k = match &self.index {
            Some(index) => index.get(&id).copied(),
            None => self.ids.binary_search(&id).ok(),
        };
        k.map(|k| &self.poses[k])
    }

    /// Every optimised pose with its id, in the graph's order.
    pub fn poses(&self) -> impl ExactSizeIterator<Item = (VertexId, &P)> {
        self.ids.iter().copied().zip(&self.poses)
    }

    /// One decision per loop candidate, in the order they were added.
    pub fn loops(&self) -> &[LoopDecision] {
        &self.loops
    }

    /// `Σ eᵀΩe` over all edges at the optimised poses (g2o's χ²; dropped
    /// candidates included).
    pub fn chi2(&self) -> f64 {
        self.report.optimizer.final_chi2
    }

    /// The χ² test of the result, over the edges in the map (weight ≥ ½);
    /// `None` when it cannot be computed (the report's warnings say why).
    pub fn chi2_test(&self) -> Option<&Chi2Test> {
        self.report.chi2_test.as_ref()
    }

    /// `D²`, the χ² of the edges in the map that the test tests.
    pub fn d2(&self) -> Option<f64> {
        self.chi2_test().map(|t| t.d2)
    }

    /// The test's verdict: whether `D²` is within the critical value.
    pub fn passed(&self) -> Option<bool> {
        self.chi2_test().map(|t| t.passed)
    }

    /// Whether a [`crate::Cancel`] token (or another [`crate::Observer`])
    /// stopped the job: the poses are the best found until then, and an
    /// update kept the graph's earlier state.
    pub fn cancelled(&self) -> bool {
        self.report.optimizer.stop_reason == StopReason::Cancelled
    }

    /// How far the map can be taken as it is — what `pgo optimize`'s exit
    /// status says ([`MapStatus`]): [`MapStatus::Ok`] when nothing
    /// questions it.
    ///
    /// ```
    /// use pgo::{MapStatus, Options, PoseGraph2, Se2};
    /// let mut graph = PoseGraph2::new();
    /// let step = Se2::new(1.0, 0.0, 0.0);
    /// for k in 0..4 {
    ///     graph.add_pose(k, Se2::new(k as f64, 0.1, 0.0))?;
    /// }
    /// for k in 1..4 {
    ///     graph.add_edge(k - 1, k, step, pgo::nalgebra::Matrix3::identity())?;
    /// }
    /// let solution = graph.optimize(&Options::default())?;
    /// // A chain has no χ² test (no redundancy), and nothing questions it.
    /// assert_eq!(solution.passed(), None);
    /// assert_eq!(solution.status(), MapStatus::Ok);
    /// # Ok::<(), pgo::Error>(())
    /// ```
    pub fn status(&self) -> MapStatus {
        self.report.status()
    }

    /// The initial guess the solve started from ([`crate::Initialization`]),
    /// each pose with its id, in the order the poses were added. `None`
    /// for an update ([`crate::PoseGraph::update`]) that resumed from the
    /// last map instead of running the whole job.
    pub fn initial_guess(&self) -> Option<impl ExactSizeIterator<Item = (VertexId, &P)>> {
        let initial = self.initial.as_ref()?;
        Some(self.ids.iter().copied().zip(initial))
    }

    /// The report `pgo optimize --json` prints.
    pub fn report(&self) -> &Report {
        &self.report
    }

    /// The report, owned.
    pub fn into_report(self) -> Report {
        self.report
    }
}

impl Solution<Se2> {
    /// Writes the optimised map as a g2o file, atomically (a temporary file
    /// renamed over `path`; `-` is the standard output). A graph read from
    /// a file, with no pose, edge or fixed pose added since, is written as
    /// that file's own text with the new poses — every other line byte for
    /// byte, a vertex line added for each vertex no line defined: what
    /// `pgo optimize -o` writes. Any other graph is written as
    /// [`crate::PoseGraph::write_g2o`] writes it, with the optimised poses.
    /// Errors: [`Error::Write`] (the file cannot be written, or the input
    /// file changed on disk since it was read; nothing is replaced then).
    ///
    /// ```
    /// use pgo::nalgebra::Matrix3;
    /// use pgo::{Options, PoseGraph2, Se2};
    ///
    /// let mut graph = PoseGraph2::new();
    /// for k in 0..3 {
    ///     graph.add_pose(k, Se2::new(0.0, 0.0, 0.0))?;
    /// }
    /// for k in 1..3 {
    ///     graph.add_edge(k - 1, k, Se2::new(1.0, 0.0, 0.0), Matrix3::identity())?;
    /// }
    /// let solution = graph.optimize(&Options::default())?;
    /// let path = std::env::temp_dir().join(format!("pgo-doc-{}.g2o", std::process::id()));
    /// solution.write_g2o(&path)?;
    /// let map = PoseGraph2::read_g2o(&path)?;
    /// assert!((map.pose(2).unwrap().x - 2.0).abs() < 1e-9);
    /// # std::fs::remove_file(&path).unwrap();
    /// # Ok::<(), pgo::Error>(())
    /// ```
    pub fn write_g2o(&self, path: impl AsRef<Path>) -> Result<(), Error> {
        self.write_file(path.as_ref())
    }

    /// Writes the optimised trajectory in the TUM format, atomically as
    /// [`Solution::write_g2o`] writes (`-` is the standard output): one
    /// line per pose in the graph's order, `timestamp tx ty tz qx qy qz
    /// qw`, as evo (`evo_ape tum`) and the TUM RGB-D tools read it. pgo's
    /// poses have no time: the timestamp is the vertex id (to associate
    /// with a ground truth, give its poses the same ids, or map ids to
    /// times yourself). The pose is embedded in SE(3): `(x, y, 0)` and the
    /// rotation by θ about z, quaternion `(0, 0, sin θ/2, cos θ/2)` with
    /// `qw ≥ 0` (in 3D the pose's own quaternion; its sign is arbitrary).
    /// Numbers are in their shortest form that reads back to the same
    /// bits. Errors: [`Error::Write`] (nothing is replaced then).
    ///
    /// ```
    /// use pgo::nalgebra::Matrix3;
    /// use pgo::{Options, PoseGraph2, Se2};
    ///
    /// let mut graph = PoseGraph2::new();
    /// graph.add_pose(7, Se2::new(0.0, 0.0, 0.0))?;
    /// graph.add_pose(8, Se2::new(0.9, 0.0, 0.0))?;
    /// graph.add_edge(7, 8, Se2::new(1.0, 0.0, 0.0), Matrix3::identity())?;
    /// let solution = graph.optimize(&Options::default())?;
    /// let path = std::env::temp_dir().join(format!("pgo-doc-{}.tum", std::process::id()));
    /// solution.write_tum(&path)?;
    /// let text = std::fs::read_to_string(&path)?;
    /// assert_eq!(text.lines().next(), Some("7 0.0 0.0 0.0 0.0 0.0 0.0 1.0"));
    /// # std::fs::remove_file(&path).unwrap();
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
    pub fn write_tum(&self, path: impl AsRef<Path>) -> Result<(), Error> {
        self.write_trajectory(path.as_ref(), trajectory::Format::Tum)
    }

    /// Writes the optimised trajectory in the KITTI odometry format,
    /// atomically as [`Solution::write_g2o`] writes (`-` is the standard
    /// output): one line per pose, the first three rows of its 4 × 4 matrix
    /// `[R t; 0 0 0 1]` row by row, `r11 r12 r13 tx r21 r22 r23 ty r31 r32
    /// r33 tz`, as evo (`evo_ape kitti`) reads it. The format has no ids or
    /// times: line k is the k-th pose in the graph's order (as the poses
    /// were added, or as the file had them). The pose is embedded in SE(3)
    /// as for [`Solution::write_tum`]. Errors: [`Error::Write`].
    pub fn write_kitti(&self, path: impl AsRef<Path>) -> Result<(), Error> {
        self.write_trajectory(path.as_ref(), trajectory::Format::Kitti)
    }

    /// Writes the job's pictures as SVG files into `dir` (made if
    /// missing), what `pgo optimize --plot DIR` writes, and returns the
    /// paths written, in this order:
    ///
    /// * `counts.svg`, when the candidates have inlier counts and the gate
    ///   fitted them: their histogram with the mixture and `T_GV`
    ///   ([`crate::plot::plot_counts`]);
    /// * `loops.svg`, when EM's loop model decided the loops: each
    ///   candidate's innovation and prior against the model
    ///   ([`crate::plot::plot_loops`]);
    /// * `trajectory.svg`: the initial guess and the map side by side, the
    ///   loops coloured by their final weight
    ///   ([`crate::plot::plot_trajectory`]; a 3D map seen from above),
    ///   titled with the input file's name for a graph read from a file.
    ///
    /// Each file is written atomically (a temporary file renamed over it).
    /// Errors: [`crate::plot::PlotError`] naming the file (or `dir`);
    /// `pgo::Error::from` turns it into [`Error::Write`] for a file that
    /// cannot be written. Needs the `plot` feature.
    ///
    /// ```
    /// use pgo::nalgebra::Matrix3;
    /// use pgo::{Options, PoseGraph2, Se2};
    ///
    /// let mut graph = PoseGraph2::new();
    /// for k in 0..4 {
    ///     graph.add_pose(k, Se2::new(k as f64, 0.1 * k as f64, 0.0))?;
    /// }
    /// for k in 1..4 {
    ///     graph.add_edge(k - 1, k, Se2::new(1.0, 0.0, 0.0), Matrix3::identity())?;
    /// }
    /// graph.add_loop_candidate(0, 3, Se2::new(3.0, 0.0, 0.0), Matrix3::identity(), Some(120))?;
    /// let solution = graph.optimize(&Options::default())?;
    /// let dir = std::env::temp_dir().join(format!("pgo-doc-plots-{}", std::process::id()));
    /// let written = solution.write_plots(&dir)?;
    /// assert_eq!(written.last(), Some(&dir.join("trajectory.svg")));
    /// assert!(std::fs::read_to_string(&written[0])?.starts_with("<svg"));
    /// # std::fs::remove_dir_all(&dir)?;
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
    #[cfg(feature = "plot")]
    pub fn write_plots(
        &self,
        dir: impl AsRef<Path>,
    ) -> Result<Vec<PathBuf>, crate::plot::PlotError> {
        self.plots::<3>(dir.as_ref())
    }

    /// A certificate of global optimality of the map over its edges
    /// (trusted edges and accepted loops): the map refined on SE-Sync's
    /// isotropic problem (one rotation and one translation weight per edge
    /// from its information matrix) and a proof, by one sparse Cholesky
    /// factorisation, that the refined map is that problem's global
    /// optimum — or, where it is not, the smallest eigenvalue of the
    /// certificate matrix and the poses where its vector is largest.
    /// `docs/method.md` §10 says what exactly is certified.
    /// Errors: [`crate::CertifyError`] (several fixed poses; non-finite
    /// map).
    ///
    /// ```
    /// use pgo::nalgebra::Matrix3;
    /// use pgo::{Options, PoseGraph2, Se2};
    ///
    /// let mut graph = PoseGraph2::new();
    /// for k in 0..4 {
    ///     graph.add_pose(k, Se2::new(k as f64, 0.0, 0.0))?;
    /// }
    /// for k in 1..4 {
    ///     graph.add_edge(k - 1, k, Se2::new(1.0, 0.1, 0.05), Matrix3::identity())?;
    /// }
    /// graph.add_edge(0, 3, Se2::new(3.0, 0.0, 0.0), Matrix3::identity())?;
    /// let certificate = graph.optimize(&Options::default())?.certificate()?;
    /// assert!(certificate.certified);
    /// assert!(certificate.gap_bound.unwrap() < 1e-4);
    /// # Ok::<(), pgo::Error>(())
    /// ```
    pub fn certificate(&self) -> Result<Certificate, Error> {
        let problem = self.certificate_problem::<3>()?;
        Ok(certify::certify::<Se2, 2, 3, 3>(
            &problem,
            &self.poses,
            &self.ids,
        )?)
    }
}

impl Solution<Se3> {
    /// Writes the optimised map as a g2o file; see
    /// [`Solution::<Se2>::write_g2o`](Solution#method.write_g2o).
    pub fn write_g2o(&self, path: impl AsRef<Path>) -> Result<(), Error> {
        self.write_file(path.as_ref())
    }

    /// Writes the optimised trajectory in the TUM format; see
    /// [`Solution::<Se2>::write_tum`](Solution#method.write_tum).
    pub fn write_tum(&self, path: impl AsRef<Path>) -> Result<(), Error> {
        self.write_trajectory(path.as_ref(), trajectory::Format::Tum)
    }

    /// Writes the optimised trajectory in the KITTI format; see
    /// [`Solution::<Se2>::write_kitti`](Solution#method.write_kitti).
    pub fn write_kitti(&self, path: impl AsRef<Path>) -> Result<(), Error> {
        self.write_trajectory(path.as_ref(), trajectory::Format::Kitti)
    }

    /// Writes the job's pictures as SVG files into `dir`; see
    /// [`Solution::<Se2>::write_plots`](Solution#method.write_plots). The
    /// trajectory is seen from above (x and y).
    #[cfg(feature = "plot")]
    pub fn write_plots(
        &self,
        dir: impl AsRef<Path>,
    ) -> Result<Vec<PathBuf>, crate::plot::PlotError> {
        self.plots::<6>(dir.as_ref())
    }

    /// A certificate of global optimality of the map over its edges; see
    /// [`Solution::<Se2>::certificate`](Solution#method.certificate).
    pub fn certificate(&self) -> Result<Certificate, Error> {
        let problem = self.certificate_problem::<6>()?;
        Ok(certify::certify::<Se3, 3, 4, 6>(
            &problem,
            &self.poses,
            &self.ids,
        )?)
    }
}

/// The result of [`crate::AnyPoseGraph::optimize`].
#[derive(Clone, Debug)]
pub enum AnySolution {
    /// SE(2).
    Planar(Solution<crate::Se2>),
    /// SE(3).
    Spatial(Solution<crate::Se3>),
}

/// Runs `$body` with `$s` bound to the solution of either dimension.
macro_rules! either {
    ($self:expr, |$s:ident| $body:expr) => {
        match $self {
            AnySolution::Planar($s) => $body,
            AnySolution::Spatial($s) => $body,
        }
    };
}

impl AnySolution {
    /// The g2o numbers of the optimised pose with this id (`x y θ` or
    /// `x y z qx qy qz qw`).
    pub fn pose(&self, id: VertexId) -> Option<Vec<f64>> {
        either!(self, |s| s.pose(id).map(G2oPose::numbers))
    }

    /// 2 or 3.
    pub fn dimension(&self) -> usize {
        match self {
            Self::Planar(_) => 2,
            Self::Spatial(_) => 3,
        }
    }

    /// The numbers of a pose: 3 (`x y θ`) in 2D, 7 (`x y z qx qy qz qw`)
    /// in 3D.
    pub fn pose_width(&self) -> usize {
        match self {
            Self::Planar(_) => 3,
            Self::Spatial(_) => 7,
        }
    }

    /// The ids of the poses, in the graph's order.
    pub fn ids(&self) -> &[VertexId] {
        either!(self, |s| &s.ids)
    }

    /// Every optimised pose's numbers, one pose after the other in the
    /// order of [`AnySolution::ids`]: [`AnySolution::pose_width`] numbers
    /// each, an N × width row-major array.
    ///
    /// ```
    /// let mut graph = pgo::AnyPoseGraph::new(2)?;
    /// graph.add_pose(7, &[0.0, 0.0, 0.0])?;
    /// graph.add_pose(3, &[0.9, 0.0, 0.0])?;
    /// graph.add_edge(7, 3, &[1.0, 0.0, 0.0], &[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0])?;
    /// let solution = graph.optimize(&pgo::Options::default())?;
    /// assert_eq!(solution.ids(), &[7, 3]);
    /// let flat = solution.poses_flat();
    /// assert_eq!(flat.len(), 2 * solution.pose_width());
    /// assert!((flat[3] - 1.0).abs() < 1e-9); // x of pose 3
    /// # Ok::<(), pgo::Error>(())
    /// ```
    pub fn poses_flat(&self) -> Vec<f64> {
        either!(self, |s| s
            .poses
            .iter()
            .flat_map(G2oPose::numbers)
            .collect())
    }

    /// See [`Solution::loops`].
    pub fn loops(&self) -> &[LoopDecision] {
        either!(self, |s| s.loops())
    }

    /// See [`Solution::chi2`].
    pub fn chi2(&self) -> f64 {
        either!(self, |s| s.chi2())
    }

    /// See [`Solution::chi2_test`].
    pub fn chi2_test(&self) -> Option<&Chi2Test> {
        either!(self, |s| s.chi2_test())
    }

    /// See [`Solution::d2`].
    pub fn d2(&self) -> Option<f64> {
        either!(self, |s| s.d2())
    }

    /// See [`Solution::passed`].
    pub fn passed(&self) -> Option<bool> {
        either!(self, |s| s.passed())
    }

    /// See [`Solution::cancelled`].
    pub fn cancelled(&self) -> bool {
        either!(self, |s| s.cancelled())
    }

    /// See [`Solution::status`].
    pub fn status(&self) -> MapStatus {
        either!(self, |s| s.status())
    }

    /// See [`Solution::report`].
    pub fn report(&self) -> &Report {
        either!(self, |s| s.report())
    }

    /// See [`Solution::certificate`](Solution#method.certificate).
    pub fn certificate(&self) -> Result<Certificate, Error> {
        either!(self, |s| s.certificate())
    }

    /// Writes the optimised map as a g2o file ([`Solution::write_g2o`]).
    pub fn write_g2o(&self, path: impl AsRef<Path>) -> Result<(), Error> {
        either!(self, |s| s.write_g2o(path))
    }

    /// Writes the optimised trajectory in the TUM format
    /// ([`Solution::write_tum`]).
    pub fn write_tum(&self, path: impl AsRef<Path>) -> Result<(), Error> {
        either!(self, |s| s.write_tum(path))
    }

    /// Writes the optimised trajectory in the KITTI format
    /// ([`Solution::write_kitti`]).
    pub fn write_kitti(&self, path: impl AsRef<Path>) -> Result<(), Error> {
        either!(self, |s| s.write_kitti(path))
    }

    /// Writes the job's pictures as SVG files into `dir` and returns the
    /// paths written ([`Solution::write_plots`](Solution#method.write_plots)).
    #[cfg(feature = "plot")]
    pub fn write_plots(
        &self,
        dir: impl AsRef<Path>,
    ) -> Result<Vec<PathBuf>, crate::plot::PlotError> {
        either!(self, |s| s.write_plots(dir))
    }

    /// See [`Solution::incremental`].
    pub fn incremental(&self) -> Option<&IncrementalReport> {
        either!(self, |s| s.incremental())
    }

    /// See [`Solution::covariances`]; the covariances as numbers.
    pub fn covariances(&self) -> Result<AnyCovariances, Error> {
        Ok(match self {
            Self::Planar(s) => AnyCovariances::Planar(s.covariances()?),
            Self::Spatial(s) => AnyCovariances::Spatial(s.covariances()?),
        })
    }
}
