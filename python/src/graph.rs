//! `pgo.PoseGraph`: the library's [`AnyPoseGraph`] — poses, edges and loop
//! candidates added call by call or read from a g2o file — and its
//! optimisation with options named as `pgo optimize`'s flags, as one batch
//! job or incrementally (`update`).

use crate::cancel::{Cancel, Stop};
use crate::convert::{self, error};
use crate::solution::Solution;
use pgo::{AnyPoseGraph, AnySolution, Options};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyTuple};
use std::panic::{self, AssertUnwindSafe};

/// A pose graph in 2D (SE(2), poses `(x, y, θ)`) or 3D (SE(3), poses
/// `(x, y, z, qx, qy, qz, qw)`, g2o's order): poses with integer ids,
/// trusted edges (odometry), loop-closure candidates with their inlier
/// counts, and the poses held fixed.
///
/// Every addition is checked (finite numbers, known and distinct ids, no
/// edge from a pose to itself, symmetric positive-definite information)
/// and refused with a `pgo.Error` subclass naming what is wrong. With `repair_information=True`,
/// information matrices that are not positive definite are projected to
/// the nearest ones instead (counted in the report's `information_fixed`).
#[pyclass(name = "PoseGraph", module = "pgo")]
pub struct PoseGraph {
    graph: AnyPoseGraph,
}

impl PoseGraph {
    /// The graph a file was read into.
    pub fn from_graph(graph: AnyPoseGraph) -> Self {
        Self { graph }
    }

    /// Adds an edge or a loop candidate (`candidate` holds its count).
    fn add(
        &mut self,
        edge: [&Bound<'_, PyAny>; 4],
        candidate: Option<Option<u64>>,
    ) -> PyResult<usize> {
        let [from, to, measurement, information] = edge;
        let (from, to) = (convert::vertex_id(from)?, convert::vertex_id(to)?);
        let measurement = convert::vector("measurement", measurement)?;
        let information = convert::matrix(information, self.graph.information_width())?;
        match candidate {
            None => self.graph.add_edge(from, to, &measurement, &information),
            Some(inliers) => {
                self.graph
                    .add_loop_candidate(from, to, &measurement, &information, inliers)
            }
        }
        .map_err(error)
    }
}

#[pymethods]
impl PoseGraph {
    /// An empty pose graph of poses in `dim` (2 or 3) dimensions.
    #[new]
    #[pyo3(signature = (dim, *, repair_information = false))]
    fn new(dim: &Bound<'_, PyAny>, repair_information: bool) -> PyResult<Self> {
        let mut graph = AnyPoseGraph::new(convert::dimension(dim)?).map_err(error)?;
        graph.set_repair_information(repair_information);
        Ok(Self { graph })
    }

    /// Adds a pose: `(x, y, θ)` in 2D, `(x, y, z, qx, qy, qz, qw)` in 3D
    /// (any sequence of numbers or array; the quaternion is normalised).
    /// The first pose added is held fixed unless `fix` names others.
    fn add_pose(&mut self, id: &Bound<'_, PyAny>, pose: &Bound<'_, PyAny>) -> PyResult<()> {
        let id = convert::vertex_id(id)?;
        let pose = convert::vector("pose", pose)?;
        self.graph.add_pose(id, &pose).map_err(error)
    }

    /// Adds a trusted edge (odometry) from pose `i` to pose `j`: the
    /// measurement of `j` in the frame of `i` (laid out as a pose) and its
    /// information matrix (3×3 in 2D, 6×6 in 3D; symmetric positive
    /// definite). Returns its edge index.
    fn add_edge(
        &mut self,
        i: &Bound<'_, PyAny>,
        j: &Bound<'_, PyAny>,
        meas: &Bound<'_, PyAny>,
        info: &Bound<'_, PyAny>,
    ) -> PyResult<usize> {
        self.add([i, j, meas, info], None)
    }

    /// Adds a loop-closure candidate from pose `i` to pose `j`, as
    /// `add_edge`, with the inlier count of its geometric verification
    /// (`None`: no count). Returns its index, as `Result.loops` reports it.
    #[pyo3(signature = (i, j, meas, info, inliers = None))]
    fn add_loop_candidate(
        &mut self,
        i: &Bound<'_, PyAny>,
        j: &Bound<'_, PyAny>,
        meas: &Bound<'_, PyAny>,
        info: &Bound<'_, PyAny>,
        inliers: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<usize> {
        let inliers = convert::inlier_count(inliers)?;
        self.add([i, j, meas, info], Some(inliers))
    }

    /// Holds the pose `id` fixed (part of the gauge).
    fn fix(&mut self, id: &Bound<'_, PyAny>) -> PyResult<()> {
        let id = convert::vertex_id(id)?;
        self.graph.fix(id).map_err(error)
    }

    /// Number of poses.
    fn len(&self) -> usize {
        self.graph.len()
    }

    /// Number of poses.
    fn __len__(&self) -> usize {
        self.graph.len()
    }

    /// Whether a pose has this id (False for what is no id, a bool
    /// included).
    fn __contains__(&self, id: &Bound<'_, PyAny>) -> bool {
        convert::maybe_vertex_id(id).is_some_and(|id| self.graph.ids().contains(&id))
    }

    /// The dimension: 2 or 3.
    #[getter]
    fn dim(&self) -> usize {
        self.graph.dimension()
    }

    /// The ids of the poses, in the order they were added (or read).
    #[getter]
    fn ids(&self) -> Vec<u64> {
        self.graph.ids().to_vec()
    }

    /// Number of edges, loop candidates included.
    #[getter]
    fn num_edges(&self) -> usize {
        self.graph.num_edges()
    }

    /// Number of loop-closure candidates.
    #[getter]
    fn num_loop_candidates(&self) -> usize {
        self.graph.num_loop_candidates()
    }

    /// The pose `id` as given, laid out as `add_pose` takes it; `None` for
    /// a pose a file's edges named without a vertex line (the
    /// optimisation's initial guess places it). Unknown ids raise.
    fn pose<'py>(
        &self,
        py: Python<'py>,
        id: &Bound<'py, PyAny>,
    ) -> PyResult<Option<Bound<'py, PyTuple>>> {
        let id = convert::vertex_id(id)?;
        if !self.graph.ids().contains(&id) {
            return Err(error(pgo::Error::UnknownVertex { id }));
        }
        self.graph
            .pose(id)
            .map(|numbers| PyTuple::new(py, numbers))
            .transpose()
    }

    /// Writes the graph as a g2o file (`str` or path-like), atomically.
    fn write_g2o(&self, path: &Bound<'_, PyAny>) -> PyResult<()> {
        self.graph.write_g2o(convert::path(path)?).map_err(error)
    }

    /// Runs the job of `pgo optimize` on the graph (left unchanged): the
    /// gate learned from the inlier counts, the robust weighting of the
    /// loops, the χ² test. Options are `pgo optimize`'s flags with `_` for
    /// `-` (`gate="off"`, `robust="none"`, `max_iters=50`, `alpha=0.01`,
    /// `expert="no-search"`; see `pgo.option_names()`); `None` leaves one
    /// at its default. The GIL is released while it runs. `cancel`, a
    /// `pgo.Cancel`, stops it from another thread; Ctrl-C stops it too and
    /// raises `KeyboardInterrupt`. `progress`, a callable, is called as
    /// `progress(iterations, objective)` at every solver iteration (the
    /// iterations of every solve of the job so far, the objective the
    /// solver just reached), with the GIL held: to show a long job alive
    /// (a tqdm bar, a log line); an exception it raises stops the job and
    /// is raised here.
    #[pyo3(signature = (*, cancel = None, progress = None, **options))]
    fn optimize(
        &self,
        py: Python<'_>,
        cancel: Option<&Bound<'_, Cancel>>,
        progress: Option<Py<PyAny>>,
        options: Option<&Bound<'_, PyDict>>,
    ) -> PyResult<Solution> {
        let options = parse_options(options)?;
        let graph = &self.graph;
        let mut stop = Stop::new(cancel).reporting_to(progress);
        let solution = detached(py, &mut stop, |stop| graph.optimize_with(&options, stop))?;
        Ok(Solution::new(solution))
    }

    /// The job again after poses, edges or loop candidates were added,
    /// for a mapping front end that asks for the map every keyframe: the
    /// map and decisions `optimize` would give the graph as it now is,
    /// reached from the last update's. The graph keeps that update's
    /// poses, decisions and report; only as much is solved as the
    /// additions need (nothing when nothing was added, a composition when
    /// only odometry was). `Result.incremental` says how and which
    /// earlier decisions changed. The first update, one with other options
    /// than the last, and one after `fix` or `forget` run the whole job
    /// ("batch"); a failed or cancelled one leaves the kept state as it
    /// was. Options, `cancel`, `progress` and Ctrl-C as `optimize`'s. The
    /// GIL is released while it runs; meanwhile another thread's use of
    /// the graph raises `RuntimeError`.
    #[pyo3(signature = (*, cancel = None, progress = None, **options))]
    fn update(
        &mut self,
        py: Python<'_>,
        cancel: Option<&Bound<'_, Cancel>>,
        progress: Option<Py<PyAny>>,
        options: Option<&Bound<'_, PyDict>>,
    ) -> PyResult<Solution> {
        let options = parse_options(options)?;
        let graph = &mut self.graph;
        let mut stop = Stop::new(cancel).reporting_to(progress);
        let solution = detached(py, &mut stop, |stop| graph.update_with(&options, stop))?;
        Ok(Solution::new(solution))
    }

    /// Drops what `update` keeps (the last update's poses, decisions and
    /// report): the next update runs the whole job.
    fn forget(&mut self) {
        self.graph.forget();
    }

    /// `PoseGraph(dim=…, poses=…, edges=…, loop_candidates=…)`.
    fn __repr__(&self) -> String {
        format!(
            "PoseGraph(dim={}, poses={}, edges={}, loop_candidates={})",
            self.graph.dimension(),
            self.graph.len(),
            self.graph.num_edges(),
            self.graph.num_loop_candidates()
        )
    }
}

/// The library's options from keyword arguments, each set by its name
/// through `Options::set` (which reports unknown names and bad values).
fn parse_options(kwargs: Option<&Bound<'_, PyDict>>) -> PyResult<Options> {
    let mut options = Options::default();
    for (name, value) in kwargs.into_iter().flatten() {
        if value.is_none() {
            continue;
        }
        let name: String = name.extract()?;
        let text = convert::option_text(&name, &value)?;
        options.set(&name, &text).map_err(error)?;
    }
    Ok(options)
}

/// Runs a job of the library with the GIL released, stopped by `stop`;
/// its error as the `pgo.Error` of its kind, a panic (a bug) as a
/// `pgo.InternalError`, and the signal's error (`KeyboardInterrupt`) if
/// one stopped it.
fn detached(
    py: Python<'_>,
    stop: &mut Stop,
    job: impl Send + FnOnce(&mut Stop) -> Result<AnySolution, pgo::Error>,
) -> PyResult<AnySolution> {
    let solution = py
        .detach(|| panic::catch_unwind(AssertUnwindSafe(|| job(&mut *stop))))
        .map_err(|panic| {
            crate::errors::internal(format!("internal failure: {}", panic_text(&panic)))
        })?
        .map_err(error)?;
    match stop.interrupted.take() {
        Some(signal) => Err(signal),
        None => Ok(solution),
    }
}

/// A panic's message.
fn panic_text(panic: &(dyn std::any::Any + Send)) -> String {
    panic
        .downcast_ref::<&str>()
        .map(|s| (*s).to_owned())
        .or_else(|| panic.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "panic".to_owned())
}
