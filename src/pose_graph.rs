//! The pose graph a caller builds and optimises: [`PoseGraph`] (SE(2) or
//! SE(3) chosen at compile time) and [`AnyPoseGraph`] (chosen at run time,
//! numbers in slices, for bindings). Every addition is checked; a graph
//! that was built is a graph the job can run on.

use crate::error::{Error, InformationProblem, PoseProblem};
use crate::geometry::{Pose, Se2, Se3, dimension};
use crate::graph::{self, LoopCandidate, VertexId};
use crate::io::g2o::G2oPose;
use crate::io::g2o::{self, FileText, ReadOptions, ReadSummary};
use crate::job::{self, Settings, Warm};
use crate::options::Options;
use crate::report::Report;
use crate::solution::{AnySolution, Solution};
use crate::solve::{IterationRecord, Observer, StopReason};
use nalgebra::SMatrix;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

mod edges;
pub use edges::Edge;

/// What [`Report::input`] says of a graph that was not read from a file.
pub(crate) const IN_MEMORY: &str = "(in memory)";

/// Entries `(i, j)` and `(j, i)` of an information matrix may differ by
/// this much of its largest entry (round-off of the caller's inversion);
/// the upper triangle is what is kept, as a g2o file keeps it.
const SYMMETRY_TOLERANCE: f64 = 1e-9;

pub(crate) mod sealed {
    /// What the library needs of a pose type beyond [`crate::Pose`]:
    /// reading and writing it as g2o does, the chordal initial guess, and
    /// checking a caller's pose.
    pub trait Sealed<const D: usize>:
        crate::io::g2o::G2oPose<D> + crate::solve::init::ChordalInit<D>
    {
        /// The pose as the library keeps it, or what is wrong with it.
        /// Quaternions are normalised as the g2o reader does, so a graph
        /// built in memory and the same graph read from its file hold the
        /// same numbers.
        fn checked(&self) -> Result<Self, crate::error::PoseProblem>;
        /// The pose from its g2o numbers (`x y θ` or `x y z qx qy qz qw`).
        fn from_numbers_checked(numbers: &[f64]) -> Result<Self, crate::error::PoseProblem>;
        /// The reader's graph, if it is of this pose type.
        fn unwrap(graph: crate::graph::AnyGraph) -> Option<crate::graph::Graph<Self, D>>;
    }
}

/// A pose type a [`PoseGraph`] holds: [`Se2`] (`D` = 3) or [`Se3`]
/// (`D` = 6). Sealed: the library implements it for these two only.
pub trait GraphPose<const D: usize>: Pose<D> + sealed::Sealed<D> {}

impl GraphPose<3> for Se2 {}
impl GraphPose<6> for Se3 {}

impl sealed::Sealed<3> for Se2 {
    fn checked(&self) -> Result<Self, PoseProblem> {
        if self.is_finite() {
            Ok(*self)
        } else {
            Err(PoseProblem::NotFinite)
        }
    }
    fn from_numbers_checked(v: &[f64]) -> Result<Self, PoseProblem> {
        Se2::new(v[0], v[1], v[2]).checked()
    }
    fn unwrap(graph: graph::AnyGraph) -> Option<graph::Graph<Self, 3>> {
        match graph {
            graph::AnyGraph::Planar(g) => Some(g),
            graph::AnyGraph::Spatial(_) => None,
        }
    }
}

impl sealed::Sealed<6> for Se3 {
    fn checked(&self) -> Result<Self, PoseProblem> {
        let t = self.translation;
        Self::from_numbers_checked(&[&[t.x, t.y, t.z][..], &self.quaternion_xyzw()].concat())
    }
    fn from_numbers_checked(v: &[f64]) -> Result<Self, PoseProblem> {
        if !v.iter().all(|x| x.is_finite()) {
            return Err(PoseProblem::NotFinite);
        }
        Se3::from_translation_quaternion([v[0], v[1], v[2]], [v[3], v[4], v[5], v[6]])
            .ok_or(PoseProblem::ZeroQuaternion)
    }
    fn unwrap(graph: graph::AnyGraph) -> Option<graph::Graph<Self, 6>> {
        match graph {
            graph::AnyGraph::Spatial(g) => Some(g),
            graph::AnyGraph::Planar(_) => None,
        }
    }
}

/// A pose graph over poses `P` with `D` degrees of freedom: poses with ids,
/// trusted edges (odometry, priors), loop-closure candidates with their
/// inlier counts, and the poses held fixed. Use [`PoseGraph2`] or
/// [`PoseGraph3`].
///
/// Every addition is checked and refused with an [`Error`] naming the id:
/// finite numbers, known and distinct ids, no edge from a vertex to itself,
/// and symmetric positive-definite information (or its repair, when asked
/// for with [`PoseGraph::set_repair_information`]).
///
/// [`PoseGraph::optimize`] runs the whole job of `pgo optimize` on it.
///
/// ```
/// use pgo::nalgebra::Matrix3;
/// use pgo::{Options, PoseGraph2, Reason, Se2};
/// use std::f64::consts::FRAC_PI_2;
///
/// // A square driven twice: odometry 1 m forward and a quarter turn left.
/// let mut graph = PoseGraph2::new();
/// let step = Se2::new(1.0, 0.0, FRAC_PI_2);
/// let mut pose = Se2::new(0.0, 0.0, 0.0);
/// for k in 0..9 {
///     graph.add_pose(k, pose)?;
///     pose = pgo::Pose::compose(&pose, &step);
/// }
/// let odometry = Matrix3::from_diagonal(&[100.0, 100.0, 400.0].into());
/// for k in 1..9 {
///     graph.add_edge(k - 1, k, step, odometry)?;
/// }
/// // Place recognition: vertex 4 and 8 are where 0 was (many inliers);
/// // a look-alike claims 6 is 5 m from 2, where 2 was (few inliers).
/// let loop_info = Matrix3::from_diagonal(&[50.0, 50.0, 200.0].into());
/// let same = Se2::new(0.0, 0.0, 0.0);
/// let a = graph.add_loop_candidate(0, 4, same, loop_info, Some(140))?;
/// let b = graph.add_loop_candidate(0, 8, same, loop_info, Some(155))?;
/// let wrong = graph.add_loop_candidate(2, 6, Se2::new(4.0, -3.0, 2.0), loop_info, Some(9))?;
///
/// let solution = graph.optimize(&pgo::Options::default())?;
/// let decided = |index| solution.loops().iter().find(|d| d.index == index).unwrap();
/// assert!(decided(a).accepted && decided(b).accepted);
/// assert!(!decided(wrong).accepted);
/// assert_eq!(solution.passed(), Some(true)); // the χ² test of the map
/// assert_eq!(solution.status(), pgo::MapStatus::Ok); // and nothing questions it
/// let end = solution.pose(8).unwrap();
/// assert!(end.x.abs() < 1e-6 && end.y.abs() < 1e-6);
/// # Ok::<(), pgo::Error>(())
/// ```
#[derive(Clone, Debug)]
pub struct PoseGraph<P: GraphPose<D>, const D: usize> {
    graph: graph::Graph<P, D>,
    /// Indices of the vertices a file's edges named without a vertex line
    /// (their poses are placeholders until the job initialises them).
    missing: Vec<usize>,
    /// The file it was read from, and what the reader noticed.
    source: Option<(PathBuf, ReadSummary)>,
    /// The file's text, for writing the optimised map back line by line
    /// ([`Solution::write_g2o`]); dropped when a pose, an edge or a fixed
    /// pose is added.
    text: Option<Arc<FileText>>,
    repair_information: bool,
    /// Information matrices repaired when edges were added.
    repaired: usize,
    /// What [`PoseGraph::update`] keeps between calls: the options of the
    /// last one and its solution's state.
    state: Option<Box<(Options, Warm<P, D>)>>,
}

/// A planar pose graph (SE(2), 3 degrees of freedom).
pub type PoseGraph2 = PoseGraph<Se2, 3>;
/// A spatial pose graph (SE(3), 6 degrees of freedom).
pub type PoseGraph3 = PoseGraph<Se3, 6>;

impl<P: GraphPose<D>, const D: usize> Default for PoseGraph<P, D> {
    fn default() -> Self {
        Self::new()
    }
}

impl<P: GraphPose<D>, const D: usize> PoseGraph<P, D> {
    /// An empty graph that refuses information matrices that are not
    /// positive definite.
    pub fn new() -> Self {
        Self {
            graph: graph::Graph::new(),
            missing: Vec::new(),
            source: None,
            text: None,
            repair_information: false,
            repaired: 0,
            state: None,
        }
    }

    /// Reads a g2o file (the format, with loop candidates marked by a
    /// trailing inlier count, is described in the README). A vertex that
    /// edges name but no vertex line defines gets its pose from the job's
    /// initial guess. Errors: [`Error::Read`] naming the file and line,
    /// [`Error::Dimension`] for a file of the other dimension.
    pub fn read_g2o(path: impl AsRef<Path>) -> Result<Self, Error> {
        Self::read(path.as_ref(), false)
    }

    /// [`PoseGraph::read_g2o`], projecting information matrices that are
    /// not positive definite to the nearest positive-definite ones
    /// (eigenvalues raised to 10⁻⁶ of the largest; `pgo optimize
    /// --fix-information`), counted in the report's `information_fixed`.
    pub fn read_g2o_repairing(path: impl AsRef<Path>) -> Result<Self, Error> {
        Self::read(path.as_ref(), true)
    }

    fn read(path: &Path, fix_information: bool) -> Result<Self, Error> {
        let mut file = g2o::read(path, ReadOptions { fix_information })?;
        in_range(&file.graph)?;
        let found = file.graph.dimension();
        let graph = std::mem::replace(
            &mut file.graph,
            graph::AnyGraph::Planar(graph::Graph::new()),
        );
        let graph = P::unwrap(graph).ok_or(Error::Dimension {
            expected: dimension::<D>(),
            found,
        })?;
        Ok(Self::of_file(graph, file, path, fix_information))
    }

    /// The graph `graph` read from the file `path` (the rest of `file`:
    /// the vertices no line defined, what the reader noticed, the text).
    fn of_file(graph: graph::Graph<P, D>, file: g2o::G2oFile, path: &Path, repair: bool) -> Self {
        Self {
            graph,
            text: Some(Arc::new(file.text().clone())),
            missing: file.missing,
            source: Some((path.to_owned(), file.summary)),
            repair_information: repair,
            repaired: 0,
            state: None,
        }
    }

    /// Writes the graph as a g2o file, atomically (a temporary file renamed
    /// over `path`): vertices in the order they were added, then edges
    /// (loop candidates with their inlier counts), then a `FIX` line for
    /// the fixed vertices. Numbers read back to the same bits. A vertex
    /// without a pose of its own (see [`PoseGraph::read_g2o`]) gets no
    /// vertex line, and a max-mixture edge read from a file is written as
    /// the plain edge of its first component.
    pub fn write_g2o(&self, path: impl AsRef<Path>) -> Result<(), Error> {
        let path = path.as_ref();
        crate::io::write_atomically(path, |w| g2o::write_graph(&self.graph, &self.missing, w))
            .map_err(|source| Error::Write {
                path: path.to_owned(),
                source,
            })
    }

    /// Whether edges added from now on with an information matrix that is
    /// not positive definite have it projected to the nearest
    /// positive-definite one (eigenvalues raised to 10⁻⁶ of the largest)
    /// instead of being refused; each repair is counted
    /// ([`PoseGraph::information_repaired`]) and reported as a warning.
    /// Off by default. Non-finite or asymmetric matrices are refused
    /// either way.
    pub fn set_repair_information(&mut self, repair: bool) {
        self.repair_information = repair;
    }

    /// Information matrices repaired so far (by the reader of
    /// [`PoseGraph::read_g2o_repairing`] and by additions).
    pub fn information_repaired(&self) -> usize {
        self.repaired + self.source.as_ref().map_or(0, |(_, s)| s.information_fixed)
    }

    /// Adds a pose under a new id. The first pose added is held fixed
    /// unless [`PoseGraph::fix`] fixes others. Errors:
    /// [`Error::DuplicateVertex`], [`Error::InvalidPose`] (not finite; an
    /// SE(3) quaternion of zero norm — others are normalised).
    pub fn add_pose(&mut self, id: VertexId, pose: P) -> Result<(), Error> {
        let pose = pose
            .checked()
            .map_err(|problem| Error::InvalidPose { id, problem })?;
        self.graph
            .add_vertex(id, pose)
            .map_err(|_| Error::DuplicateVertex { id })?;
        self.text = None;
        Ok(())
    }

    /// Adds a trusted edge (odometry, a prior, a verified loop): the pose of
    /// `to` in the frame of `from` is `measurement`, with `information`
    /// (inverse covariance) over the error `(x, y, θ)` or `(x, y, z, qx, qy,
    /// qz)`. Returns the edge's index (edges and loop candidates are
    /// numbered together, from 0, in the order they are added). Errors:
    /// [`Error::SelfLoop`], [`Error::UnknownVertex`],
    /// [`Error::InvalidMeasurement`], [`Error::InvalidInformation`].
    pub fn add_edge(
        &mut self,
        from: VertexId,
        to: VertexId,
        measurement: P,
        information: SMatrix<f64, D, D>,
    ) -> Result<usize, Error> {
        self.push_edge(from, to, measurement, information, None)
    }

    /// Adds a loop-closure candidate: an edge as [`PoseGraph::add_edge`]
    /// adds one, whose correctness the job decides — by its `inliers` (the
    /// RANSAC inlier count of its geometric verification, if the front end
    /// has one) against the gate learned from all the counts, then by its
    /// consistency with the map. Returns its index, which its
    /// [`crate::LoopDecision`] carries. Errors as [`PoseGraph::add_edge`].
    pub fn add_loop_candidate(
        &mut self,
        from: VertexId,
        to: VertexId,
        measurement: P,
        information: SMatrix<f64, D, D>,
        inliers: Option<u64>,
    ) -> Result<usize, Error> {
        let candidate = Some(LoopCandidate { inliers });
        self.push_edge(from, to, measurement, information, candidate)
    }

    fn push_edge(
        &mut self,
        from: VertexId,
        to: VertexId,
        measurement: P,
        information: SMatrix<f64, D, D>,
        candidate: Option<LoopCandidate>,
    ) -> Result<usize, Error> {
        if from == to {
            return Err(Error::SelfLoop { id: from });
        }
        for id in [from, to] {
            if self.graph.index_of(id).is_none() {
                return Err(Error::UnknownVertex { id });
            }
        }
        let measurement = measurement
            .checked()
            .map_err(|problem| Error::InvalidMeasurement { from, to, problem })?;
        let (information, repaired) = checked_information(&information, self.repair_information)
            .map_err(|problem| Error::InvalidInformation { from, to, problem })?;
        self.repaired += usize::from(repaired);
        let index = (self.graph)
            .add_edge(from, to, measurement, information, candidate)
            .map_err(|_| Error::UnknownVertex { id: from })?;
        self.text = None;
        Ok(index)
    }

    /// Gives loop candidates their inlier counts from a list kept apart
    /// from the graph (`pgo optimize --inliers`): each `(from, to, count)`
    /// goes to the next edge between `from` and `to` — in that direction,
    /// else the other — in the order edges were added, which becomes a loop
    /// candidate with that count. Returns how many of those edges already
    /// had a count. A graph read from a file still writes the file's own
    /// counts ([`Solution::write_g2o`]): the counts change the job, not the
    /// file. Errors: [`Error::NoEdge`] naming the first entry without a
    /// (further) edge, before any count is given.
    pub fn set_inlier_counts(
        &mut self,
        counts: &[(VertexId, VertexId, u64)],
    ) -> Result<usize, Error> {
        let edges = self
            .graph
            .edges_of_pairs(counts.iter().map(|&(a, b, _)| (a, b)));
        let edges = edges.map_err(|entry| Error::NoEdge {
            from: counts[entry].0,
            to: counts[entry].1,
            entry,
        })?;
        let mut replaced = 0;
        for (&k, &(_, _, inliers)) in edges.iter().zip(counts) {
            let e = &mut self.graph.edges[k];
            replaced += usize::from(e.candidate.is_some_and(|c| c.inliers.is_some()));
            e.candidate = Some(LoopCandidate {
                inliers: Some(inliers),
            });
        }
        // Another job: the last solution is no start for the next.
        self.state = None;
        Ok(replaced)
    }

    /// Holds a pose fixed (part of the gauge). Without any, the first pose
    /// added is. Errors: [`Error::UnknownVertex`].
    pub fn fix(&mut self, id: VertexId) -> Result<(), Error> {
        self.graph
            .fix(id)
            .map_err(|_| Error::UnknownVertex { id })?;
        self.text = None;
        // Another gauge: the last solution is no start for the next.
        self.state = None;
        Ok(())
    }

    /// Number of poses.
    pub fn len(&self) -> usize {
        self.graph.num_vertices()
    }

    /// Whether there are no poses.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Number of edges, loop candidates included.
    pub fn num_edges(&self) -> usize {
        self.graph.edges.len()
    }

    /// What reading its file noticed, one line each, with the line of the
    /// file it concerns: skipped tags (and the tag a misspelled one is a
    /// slip of), vertices only edges name, repaired information matrices.
    /// Empty for a graph built call by call. The job's report starts its
    /// warnings with these.
    pub fn read_warnings(&self) -> &[String] {
        self.source.as_ref().map_or(&[], |(_, s)| &s.warnings)
    }

    /// Number of loop-closure candidates.
    pub fn num_loop_candidates(&self) -> usize {
        self.graph.num_candidates()
    }

    /// The ids of the poses, in the order they were added (read).
    pub fn ids(&self) -> &[VertexId] {
        self.graph.ids()
    }

    /// Whether a pose has this id.
    pub fn contains(&self, id: VertexId) -> bool {
        self.graph.index_of(id).is_some()
    }

    /// The pose with this id as given; `None` for an unknown id or a
    /// vertex a file's edges named without a vertex line.
    pub fn pose(&self, id: VertexId) -> Option<&P> {
        let k = self.graph.index_of(id)?;
        (!self.missing.contains(&k)).then(|| &self.graph.poses[k])
    }

    /// Runs the whole job of `pgo optimize` on the graph (which is left as
    /// it is): the gate learned from the loop candidates' inlier counts,
    /// the initial guess, the robust optimisation of the loops the gate
    /// passes, and the χ² test of the result. The same graph read from a
    /// g2o file with the same options gives the same poses, bit for bit,
    /// and the same decisions. Warnings go to the report and to
    /// `log::warn!`.
    ///
    /// Errors: [`Error::InvalidOption`] ([`Options::validate`]),
    /// [`Error::EmptyGraph`], [`Error::Unconstrained`] (poses no chain of
    /// trusted edges or kept loops ties to the fixed ones),
    /// [`Error::Undetermined`], [`Error::NonFiniteEdge`],
    /// [`Error::NonFinite`], [`Error::Threads`], [`Error::Internal`].
    pub fn optimize(&self, options: &Options) -> Result<Solution<P>, Error> {
        self.optimize_with(options, &mut trace)
    }

    /// [`PoseGraph::optimize`] reporting every solver iteration (χ², time)
    /// to `observer`, which can also stop the job: a [`crate::Cancel`] token (set
    /// from another thread) or a [`crate::Cancellable`] progress callback. A
    /// stopped job returns the best map so far, its report's stop reason
    /// `cancelled` ([`Solution::cancelled`]).
    ///
    /// ```
    /// use pgo::{Cancel, Options, PoseGraph2, Se2};
    /// use pgo::nalgebra::Matrix3;
    ///
    /// let mut graph = PoseGraph2::new();
    /// for k in 0..3 {
    ///     graph.add_pose(k, Se2::new(k as f64, 0.1, 0.0))?;
    /// }
    /// for k in 1..3 {
    ///     graph.add_edge(k - 1, k, Se2::new(1.0, 0.0, 0.0), Matrix3::identity())?;
    /// }
    /// let cancel = Cancel::new();
    /// cancel.cancel(); // e.g. from a Ctrl-C handler
    /// let solution = graph.optimize_with(&Options::default(), &mut cancel.clone())?;
    /// assert_eq!(solution.report().optimizer.iterations, 0);
    /// assert!(solution.cancelled());
    /// # Ok::<(), pgo::Error>(())
    /// ```
    pub fn optimize_with(
        &self,
        options: &Options,
        observer: &mut dyn Observer,
    ) -> Result<Solution<P>, Error> {
        let start = Instant::now();
        options.validate()?;
        let mut report = self.start()?;
        let config = Settings::new(options);
        let mut graph = self.graph.clone();
        let initial = job::run(&mut graph, &self.missing, &config, &mut report, observer)?;
        for w in &report.warnings {
            log::warn!("{w}");
        }
        report.time.total_s = start.elapsed().as_secs_f64();
        Ok(Solution::new(&graph, report)
            .with_text(self.text.clone())
            .starting_from(initial)
            .keeping(graph, options.solver.threads))
    }

    /// The job again after poses, edges or loop candidates were added, for
    /// a mapping front end that asks for the map every keyframe: the same
    /// map and decisions as [`PoseGraph::optimize`] of the graph as it now
    /// is, reached from the last update's. The graph keeps that update's
    /// poses, decisions, report (with the gate's fit, the start of the
    /// next one), elimination order and linear system's layout, the last
    /// factorisation's allocation and the prepared poses and measurements
    /// (its memory: the poses, a byte per edge, 4 bytes per pose, the
    /// layout's 16 bytes per edge, 8 per pose and per pair of poses an
    /// edge joins and 4 per block row of the factor's supernodes, about
    /// 100 bytes per loop candidate, the factor's values, which the next
    /// factorisation fills instead of fresh memory, and 64 bytes per pose
    /// and 40 per edge in SE(2), 184 and 128 in SE(3)); a new pose is
    /// composed along trusted edges from them. Only as much is solved as
    /// the additions need: nothing when nothing was added, no factorisation when the new
    /// poses hang on the map by one trusted edge each (odometry), else
    /// EM's decisions from the last ones ([`crate::UpdateSolve`]). The report's
    /// `incremental` part says which, and which earlier decisions changed.
    ///
    /// The first update, one with other options than the last, one
    /// after [`PoseGraph::fix`] or [`PoseGraph::forget`], one whose last
    /// decisions are no start to resume from (a kernel method, fewer
    /// candidates than EM's model needs, no last loop model or no accepted
    /// loop), and one whose EM decisions swing from the last ones (the new
    /// evidence overturned them, `docs/method.md` §7b) run the whole job
    /// ([`crate::UpdateSolve::Batch`], the reason saying which). After
    /// every call without an `update_iterations` bound the solution is
    /// [`PoseGraph::optimize`]'s: the same accepted set and verdict, χ²
    /// within 10⁻⁶ relative, poses within 10⁻⁶ of the map's size
    /// (`tests/update_equals_optimize.rs`). A cancelled update keeps the earlier state;
    /// one cut short by `options.solver.time_limit` or
    /// `options.solver.update_iterations` (bounds on an update's latency;
    /// the report then says not converged) leaves its map as the start of
    /// the next, and an update with nothing added goes on converging (with
    /// no such bound, to the batch map).
    /// Errors: those of [`PoseGraph::optimize`].
    ///
    /// ```
    /// use pgo::nalgebra::Matrix3;
    /// use pgo::{Options, PoseGraph2, Se2, UpdateSolve};
    ///
    /// let (step, info) = (Se2::new(1.0, 0.0, 0.0), Matrix3::identity());
    /// let mut graph = PoseGraph2::new();
    /// graph.add_pose(0, Se2::new(0.0, 0.0, 0.0))?;
    /// let options = Options::default();
    /// for k in 1..5 {
    ///     graph.add_pose(k, Se2::new(0.0, 0.0, 0.0))?; // composed by update
    ///     graph.add_edge(k - 1, k, step, info)?;
    ///     let solution = graph.update(&options)?;
    ///     let how = solution.incremental().unwrap().solve;
    ///     assert_eq!(how, if k == 1 { UpdateSolve::Batch } else { UpdateSolve::Extended });
    ///     assert!((solution.pose(k).unwrap().x - k as f64).abs() < 1e-12);
    /// }
    /// # Ok::<(), pgo::Error>(())
    /// ```
    pub fn update(&mut self, options: &Options) -> Result<Solution<P>, Error> {
        self.update_with(options, &mut trace)
    }

    /// [`PoseGraph::update`] reporting every solver iteration to
    /// `observer`, which can stop it (as in [`PoseGraph::optimize_with`]).
    pub fn update_with(
        &mut self,
        options: &Options,
        observer: &mut dyn Observer,
    ) -> Result<Solution<P>, Error> {
        let start = Instant::now();
        options.validate()?;
        let report = self.start()?;
        let config = Settings::new(options);
        let last = match self.state.as_deref_mut() {
            Some((last, warm)) if last.same_job(options) => Ok(warm),
            Some(_) => Err("options changed"),
            None => Err("no earlier solution"),
        };
        let job::Updated {
            graph,
            mut report,
            warm,
            initial,
        } = job::update(&self.graph, &self.missing, last, &config, report, observer)?;
        if report.optimizer.stop_reason != StopReason::Cancelled {
            self.state = Some(Box::new((options.clone(), warm)));
        }
        for w in &report.warnings {
            log::warn!("{w}");
        }
        report.time.total_s = start.elapsed().as_secs_f64();
        let mut solution = Solution::new(&graph, report).with_text(self.text.clone());
        if let Some(initial) = initial {
            solution = solution.starting_from(initial);
        }
        Ok(solution.keeping(graph, options.solver.threads))
    }

    /// Drops what [`PoseGraph::update`] keeps: the next update runs the
    /// whole job.
    pub fn forget(&mut self) {
        self.state = None;
    }

    /// The report before the job.
    fn start(&self) -> Result<Report, Error> {
        if self.is_empty() {
            return Err(Error::EmptyGraph);
        }
        let (input, summary) = match &self.source {
            Some((path, summary)) => (path.clone(), summary.clone()),
            None => (PathBuf::from(IN_MEMORY), ReadSummary::default()),
        };
        let mut report = Report::for_graph(&input, &self.graph, &summary);
        if self.repaired > 0 {
            report.information_fixed += self.repaired;
            report.warnings.push(format!(
                "projected {} information matrices that were not positive definite to the nearest positive-definite ones",
                self.repaired
            ));
        }
        Ok(report)
    }
}

/// The observer of `optimize` and `update`: every iteration to
/// `log::trace!`.
fn trace(r: &IterationRecord) {
    log::trace!(
        "iteration {}: χ² {:e}, λ {:e}, |δ|∞ {:e}",
        r.iteration,
        r.objective,
        r.lambda,
        r.step_max
    )
}

/// Refuses a graph read from a file whose information matrices leave
/// [`graph::INFORMATION_RANGE`] (the reader takes any finite scale).
fn in_range(graph: &graph::AnyGraph) -> Result<(), Error> {
    let found = match graph {
        graph::AnyGraph::Planar(g) => g.information_out_of_range(),
        graph::AnyGraph::Spatial(g) => g.information_out_of_range(),
    };
    match found {
        Some((from, to, index, value)) => Err(Error::InvalidInformation {
            from,
            to,
            problem: InformationProblem::OutOfRange { index, value },
        }),
        None => Ok(()),
    }
}

/// The information matrix as the graph keeps it — the upper triangle
/// mirrored, as a g2o file stores it — and whether it was repaired.
fn checked_information<const D: usize>(
    m: &SMatrix<f64, D, D>,
    repair: bool,
) -> Result<(SMatrix<f64, D, D>, bool), InformationProblem> {
    if let Some(k) = m.iter().position(|v| !v.is_finite()) {
        return Err(InformationProblem::NotFinite {
            row: k % D,
            col: k / D,
        });
    }
    let largest = m.iter().fold(0.0f64, |a, v| a.max(v.abs()));
    let mut kept = *m;
    for r in 0..D {
        for c in r + 1..D {
            let (upper, lower) = (m[(r, c)], m[(c, r)]);
            if (upper - lower).abs() > SYMMETRY_TOLERANCE * largest {
                return Err(InformationProblem::NotSymmetric {
                    row: r,
                    col: c,
                    upper,
                    lower,
                });
            }
            kept[(c, r)] = upper;
        }
    }
    let (kept, repaired) = if graph::is_positive_definite(&kept) {
        (kept, false)
    } else if !repair {
        return Err(InformationProblem::NotPositiveDefinite {
            min_eigenvalue: graph::min_eigenvalue(&kept),
        });
    } else {
        let repaired =
            graph::nearest_positive_definite(&kept).ok_or(InformationProblem::NotRepairable)?;
        (repaired, true)
    };
    match graph::information_out_of_range(&kept) {
        Some((index, value)) => Err(InformationProblem::OutOfRange { index, value }),
        None => Ok((kept, repaired)),
    }
}

/// A pose graph whose dimension is chosen at run time, numbers passed in
/// slices: for bindings (Python, C). Poses are their g2o numbers — `x y θ`
/// in 2D, `x y z qx qy qz qw` in 3D (the quaternion normalised) —
/// and information matrices are `D × D` (9 or 36 numbers), row by row.
///
/// ```
/// let mut graph = pgo::AnyPoseGraph::new(2)?;
/// graph.add_pose(0, &[0.0, 0.0, 0.0])?;
/// graph.add_pose(1, &[1.1, 0.0, 0.0])?;
/// let identity = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
/// graph.add_edge(0, 1, &[1.0, 0.0, 0.0], &identity)?;
/// let err = graph.add_edge(0, 1, &[1.0, 0.0], &identity).unwrap_err();
/// assert_eq!(err.to_string(), "measurement: expected 3 numbers for a 2D graph, got 2");
/// let solution = graph.optimize(&pgo::Options::default())?;
/// let x1 = solution.pose(1).unwrap();
/// assert!((x1[0] - 1.0).abs() < 1e-9);
/// # Ok::<(), pgo::Error>(())
/// ```
#[derive(Clone, Debug)]
pub enum AnyPoseGraph {
    /// SE(2).
    Planar(PoseGraph2),
    /// SE(3).
    Spatial(PoseGraph3),
}

/// Runs `$body` with `$g` bound to the graph of either dimension.
macro_rules! either {
    ($self:expr, |$g:ident| $body:expr) => {
        match $self {
            AnyPoseGraph::Planar($g) => $body,
            AnyPoseGraph::Spatial($g) => $body,
        }
    };
}

impl AnyPoseGraph {
    /// An empty graph of poses in `dimension` (2 or 3) dimensions. Errors:
    /// [`Error::UnsupportedDimension`].
    pub fn new(dimension: usize) -> Result<Self, Error> {
        match dimension {
            2 => Ok(Self::Planar(PoseGraph2::new())),
            3 => Ok(Self::Spatial(PoseGraph3::new())),
            _ => Err(Error::UnsupportedDimension { dimension }),
        }
    }

    /// Reads a g2o file of either dimension ([`PoseGraph::read_g2o`]).
    pub fn read_g2o(path: impl AsRef<Path>) -> Result<Self, Error> {
        Self::read(path.as_ref(), false)
    }

    /// Reads a g2o file of either dimension, repairing information
    /// matrices ([`PoseGraph::read_g2o_repairing`]).
    pub fn read_g2o_repairing(path: impl AsRef<Path>) -> Result<Self, Error> {
        Self::read(path.as_ref(), true)
    }

    fn read(path: &Path, fix: bool) -> Result<Self, Error> {
        let mut file = g2o::read(
            path,
            ReadOptions {
                fix_information: fix,
            },
        )?;
        in_range(&file.graph)?;
        let graph = std::mem::replace(
            &mut file.graph,
            graph::AnyGraph::Planar(graph::Graph::new()),
        );
        Ok(match graph {
            graph::AnyGraph::Planar(g) => Self::Planar(PoseGraph::of_file(g, file, path, fix)),
            graph::AnyGraph::Spatial(g) => Self::Spatial(PoseGraph::of_file(g, file, path, fix)),
        })
    }

    /// Writes the graph as a g2o file ([`PoseGraph::write_g2o`]).
    pub fn write_g2o(&self, path: impl AsRef<Path>) -> Result<(), Error> {
        either!(self, |g| g.write_g2o(path))
    }

    /// See [`PoseGraph::read_warnings`].
    pub fn read_warnings(&self) -> &[String] {
        either!(self, |g| g.read_warnings())
    }

    /// 2 or 3.
    pub fn dimension(&self) -> usize {
        match self {
            Self::Planar(_) => 2,
            Self::Spatial(_) => 3,
        }
    }

    /// The numbers of a pose or measurement: 3 (`x y θ`) in 2D, 7
    /// (`x y z qx qy qz qw`) in 3D.
    pub fn pose_width(&self) -> usize {
        match self {
            Self::Planar(_) => 3,
            Self::Spatial(_) => 7,
        }
    }

    /// The side of an information matrix, the degrees of freedom of a
    /// pose: 3 in 2D, 6 in 3D (it takes the square's numbers).
    pub fn information_width(&self) -> usize {
        match self {
            Self::Planar(_) => 3,
            Self::Spatial(_) => 6,
        }
    }

    /// See [`PoseGraph::set_repair_information`].
    pub fn set_repair_information(&mut self, repair: bool) {
        either!(self, |g| g.set_repair_information(repair))
    }

    /// Adds a pose from its numbers ([`PoseGraph::add_pose`]); errors also
    /// [`Error::Length`].
    pub fn add_pose(&mut self, id: VertexId, pose: &[f64]) -> Result<(), Error> {
        either!(self, |g| {
            let pose = from_numbers(g, pose, "pose")
                .map_err(|e| e.unwrap_or_else(|problem| Error::InvalidPose { id, problem }))?;
            g.add_pose(id, pose)
        })
    }

    /// Adds a trusted edge from numbers ([`PoseGraph::add_edge`]); errors
    /// also [`Error::Length`].
    pub fn add_edge(
        &mut self,
        from: VertexId,
        to: VertexId,
        measurement: &[f64],
        information: &[f64],
    ) -> Result<usize, Error> {
        self.add(from, to, measurement, information, None)
    }

    /// Adds a loop-closure candidate from numbers
    /// ([`PoseGraph::add_loop_candidate`]); errors also [`Error::Length`].
    pub fn add_loop_candidate(
        &mut self,
        from: VertexId,
        to: VertexId,
        measurement: &[f64],
        information: &[f64],
        inliers: Option<u64>,
    ) -> Result<usize, Error> {
        self.add(
            from,
            to,
            measurement,
            information,
            Some(LoopCandidate { inliers }),
        )
    }

    fn add(
        &mut self,
        from: VertexId,
        to: VertexId,
        measurement: &[f64],
        information: &[f64],
        candidate: Option<LoopCandidate>,
    ) -> Result<usize, Error> {
        either!(self, |g| {
            let z = from_numbers(g, measurement, "measurement").map_err(|e| {
                e.unwrap_or_else(|problem| Error::InvalidMeasurement { from, to, problem })
            })?;
            let omega = matrix(g, information)?;
            g.push_edge(from, to, z, omega, candidate)
        })
    }

    /// See [`PoseGraph::fix`].
    pub fn fix(&mut self, id: VertexId) -> Result<(), Error> {
        either!(self, |g| g.fix(id))
    }

    /// Number of poses.
    pub fn len(&self) -> usize {
        either!(self, |g| g.len())
    }

    /// Whether there are no poses.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Number of edges, loop candidates included.
    pub fn num_edges(&self) -> usize {
        either!(self, |g| g.num_edges())
    }

    /// Number of loop-closure candidates.
    pub fn num_loop_candidates(&self) -> usize {
        either!(self, |g| g.num_loop_candidates())
    }

    /// The ids of the poses, in the order they were added (read).
    pub fn ids(&self) -> &[VertexId] {
        either!(self, |g| g.ids())
    }

    /// The numbers of the pose with this id ([`PoseGraph::pose`]).
    pub fn pose(&self, id: VertexId) -> Option<Vec<f64>> {
        either!(self, |g| g.pose(id).map(|p| p.numbers()))
    }

    /// Runs the job ([`PoseGraph::optimize`]).
    pub fn optimize(&self, options: &Options) -> Result<AnySolution, Error> {
        match self {
            Self::Planar(g) => g.optimize(options).map(AnySolution::Planar),
            Self::Spatial(g) => g.optimize(options).map(AnySolution::Spatial),
        }
    }

    /// See [`PoseGraph::optimize_with`].
    pub fn optimize_with(
        &self,
        options: &Options,
        observer: &mut dyn Observer,
    ) -> Result<AnySolution, Error> {
        match self {
            Self::Planar(g) => g.optimize_with(options, observer).map(AnySolution::Planar),
            Self::Spatial(g) => g.optimize_with(options, observer).map(AnySolution::Spatial),
        }
    }

    /// See [`PoseGraph::update`].
    pub fn update(&mut self, options: &Options) -> Result<AnySolution, Error> {
        self.update_with(options, &mut trace)
    }

    /// See [`PoseGraph::update_with`].
    pub fn update_with(
        &mut self,
        options: &Options,
        observer: &mut dyn Observer,
    ) -> Result<AnySolution, Error> {
        match self {
            Self::Planar(g) => g.update_with(options, observer).map(AnySolution::Planar),
            Self::Spatial(g) => g.update_with(options, observer).map(AnySolution::Spatial),
        }
    }

    /// See [`PoseGraph::forget`].
    pub fn forget(&mut self) {
        either!(self, |g| g.forget())
    }

    /// See [`PoseGraph::set_inlier_counts`].
    pub fn set_inlier_counts(
        &mut self,
        counts: &[(VertexId, VertexId, u64)],
    ) -> Result<usize, Error> {
        either!(self, |g| g.set_inlier_counts(counts))
    }
}

/// A pose from its g2o numbers: `Err(Ok(_))` for the wrong count,
/// `Err(Err(problem))` for numbers that are no pose.
fn from_numbers<P: GraphPose<D>, const D: usize>(
    _graph: &PoseGraph<P, D>,
    numbers: &[f64],
    what: &'static str,
) -> Result<P, Result<Error, PoseProblem>> {
    if numbers.len() != P::POSE_NUMBERS {
        return Err(Ok(Error::Length {
            what,
            dimension: dimension::<D>(),
            expected: P::POSE_NUMBERS,
            found: numbers.len(),
        }));
    }
    P::from_numbers_checked(numbers).map_err(Err)
}

/// A `D × D` matrix from its numbers, row by row.
fn matrix<P: GraphPose<D>, const D: usize>(
    _graph: &PoseGraph<P, D>,
    numbers: &[f64],
) -> Result<SMatrix<f64, D, D>, Error> {
    if numbers.len() != D * D {
        return Err(Error::Length {
            what: "information",
            dimension: dimension::<D>(),
            expected: D * D,
            found: numbers.len(),
        });
    }
    Ok(SMatrix::<f64, D, D>::from_row_slice(numbers))
}
