//! `pgo.Result`: what `PoseGraph.optimize` and `PoseGraph.update` return —
//! the optimised poses, one decision per loop candidate, the χ² test, the
//! report and, for an update, what it did — read from the library's
//! [`AnySolution`].

use crate::convert::{self, error};
use crate::covariance;
use numpy::{PyArray1, PyArray2, PyArrayMethods};
use pgo::{AnySolution, DecisionChange, LoopDecision};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList, PyTuple};

/// `(ids, poses)` as numpy arrays.
type PosesArrays<'py> = (Bound<'py, PyArray1<u64>>, Bound<'py, PyArray2<f64>>);

/// The result of `PoseGraph.optimize` or `PoseGraph.update`: the optimised
/// poses by id, one decision per loop candidate, χ², the χ² test of the
/// map, the report `pgo optimize --json` prints, and (an update's) what
/// the update did.
#[pyclass(name = "Result", module = "pgo", frozen)]
pub struct Solution {
    solution: AnySolution,
    /// The map's covariances, computed at the first request.
    covariances: covariance::Cache,
}

impl Solution {
    /// The result holding `solution`.
    pub fn new(solution: AnySolution) -> Self {
        Self {
            solution,
            covariances: covariance::Cache::default(),
        }
    }

    /// The optimised pose `id`'s numbers (every id of the graph has one).
    fn numbers(&self, id: u64) -> PyResult<Vec<f64>> {
        self.solution
            .pose(id)
            .ok_or_else(|| error(pgo::Error::UnknownVertex { id }))
    }
}

#[pymethods]
impl Solution {
    /// The optimised poses: a dict from id to pose, laid out as
    /// `PoseGraph.add_pose` takes it, in the graph's order.
    #[getter]
    fn poses<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let poses = PyDict::new(py);
        let width = self.solution.pose_width();
        let flat = self.solution.poses_flat();
        for (&id, pose) in self.solution.ids().iter().zip(flat.chunks_exact(width)) {
            poses.set_item(id, PyTuple::new(py, pose)?)?;
        }
        Ok(poses)
    }

    /// The optimised pose `id` as a tuple.
    fn pose<'py>(&self, py: Python<'py>, id: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyTuple>> {
        PyTuple::new(py, self.numbers(convert::vertex_id(id)?)?)
    }

    /// The optimised poses for numpy: `(ids, poses)`, ids a uint64 array
    /// of N and poses a float64 array N×3 (2D) or N×7 (3D), row k the pose
    /// of ids[k], in the graph's order.
    fn poses_array<'py>(&self, py: Python<'py>) -> PyResult<PosesArrays<'py>> {
        let ids = self.solution.ids();
        let poses = PyArray1::from_vec(py, self.solution.poses_flat())
            .reshape([ids.len(), self.solution.pose_width()])?;
        Ok((PyArray1::from_slice(py, ids), poses))
    }

    /// One dict per loop candidate, in the order they were added: `index`
    /// (as `add_loop_candidate` returned it), `from`, `to`, `inliers` (int
    /// or None), `kept` (the gate kept it), `weight` (its final weight in
    /// [0, 1]), `accepted` (weight ≥ ½: it is in the map), `posterior`
    /// (EM's probability that it is a true loop) and `innovation` (its ν²
    /// against the map without its cluster), each None where the method
    /// gives none, and `reason` (why it ended where it did: "consistent",
    /// "inconsistent", "outlying", "unchecked", "explains_chi2", "unsettled",
    /// "kernel", "dropped" or "trusted").
    #[getter]
    fn loops<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyList>> {
        let loops = PyList::empty(py);
        for decision in self.solution.loops() {
            loops.append(loop_dict(py, decision)?)?;
        }
        Ok(loops)
    }

    /// The report `pgo optimize --json` prints, as a dict (its JSON
    /// parsed by `json.loads`).
    #[getter]
    fn report<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let text = self.solution.report().to_json().map_err(error)?;
        py.import("json")?.call_method1("loads", (text,))
    }

    /// What `PoseGraph.update` did, as a dict; `None` for `optimize`'s
    /// result. `solve` is how it reached the map: "batch" (the whole job:
    /// the first update, other options, after `fix` or `forget`), "none"
    /// (nothing was added: the last map stands), "extended" (only new
    /// poses hung by one trusted edge each: composed, nothing solved),
    /// "warm" (EM's decisions from the last ones) or "full" (every
    /// candidate weighed again by the kernel); `reason` says why in a few
    /// words; `new_poses`, `new_edges` (loop candidates included) and
    /// `new_candidates` count the additions since the last update; and
    /// `changed` lists the earlier candidates whose decision this update
    /// changed, one dict each: `index`, `from`, `to`, `accepted` (now)
    /// and `reason` (named as in `loops`). The same as
    /// `report["incremental"]`.
    #[getter]
    fn incremental<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyDict>>> {
        let Some(update) = self.solution.incremental() else {
            return Ok(None);
        };
        let dict = PyDict::new(py);
        dict.set_item("solve", update.solve.as_str())?;
        dict.set_item("reason", &update.reason)?;
        dict.set_item("new_poses", update.new_poses)?;
        dict.set_item("new_edges", update.new_edges)?;
        dict.set_item("new_candidates", update.new_candidates)?;
        let changed = PyList::empty(py);
        for change in &update.changed {
            changed.append(change_dict(py, change)?)?;
        }
        dict.set_item("changed", changed)?;
        Ok(Some(dict))
    }

    /// `Σ eᵀΩe` over all edges at the optimised poses (g2o's χ², the
    /// candidates left out of the map included).
    #[getter]
    fn chi2(&self) -> f64 {
        self.solution.chi2()
    }

    /// D², the χ² of the edges in the map that the χ² test tests; `None`
    /// when the test could not be computed (`report["warnings"]` says why).
    #[getter]
    fn d2(&self) -> Option<f64> {
        self.solution.d2()
    }

    /// Whether the map passes the χ² test (D² within the critical value
    /// at significance `alpha`); `None` when there is no test.
    #[getter]
    fn passed(&self) -> Option<bool> {
        self.solution.passed()
    }

    /// The χ² test's verdict: "passed", "failed", or `None` when the test
    /// could not be computed.
    #[getter]
    fn verdict(&self) -> Option<&'static str> {
        self.solution
            .passed()
            .map(|p| if p { "passed" } else { "failed" })
    }

    /// Whether a `pgo.Cancel` token stopped the job: the poses are the
    /// best found until then, and an update left the graph's kept state as
    /// it was.
    #[getter]
    fn cancelled(&self) -> bool {
        self.solution.cancelled()
    }

    /// How far the map can be taken as it is, as `pgo optimize`'s exit
    /// status says it: "ok" (nothing questions it, exit 0), "chi2_failed"
    /// (3), "unfinished" (an iteration or time limit stopped the job, 4),
    /// "unsettled" (the loop decisions did not settle, 4), "questioned"
    /// (a doubtful cluster, loops held back by their counts or outlying
    /// accepted loops, 5) or
    /// "cancelled" (130); the first that applies, in that order from
    /// "cancelled" back to "questioned".
    #[getter]
    fn status(&self) -> &'static str {
        self.solution.status().name()
    }

    /// The job's warnings (`report["warnings"]`), e.g. that the loop
    /// decisions did not settle (loops with reason "unsettled"), that an
    /// accepted cluster is doubtful (`report["robust"]["doubtful"]`), that
    /// rejected loops were kept out by their counts alone
    /// (`report["robust"]["held_back"]`), that accepted loops err beyond
    /// the true loops' reach (`report["robust"]["outlying"]`), that no
    /// candidate was accepted,
    /// or why there is no χ² test.
    #[getter]
    fn warnings(&self) -> Vec<String> {
        self.solution.report().warnings.clone()
    }

    /// A certificate of global optimality of the map over its edges, as a
    /// dict (the report's "certificate" of `pgo optimize --certify`):
    /// `certified`, `eta`, `cost` (isotropic cost of the certified map),
    /// `map_cost`, `gap_bound`, `max_translation_change`,
    /// `max_rotation_change`, and where not certified `lambda_min`,
    /// `lambda_min_bounds` and `eigenvector_poses` (`id`, `share`).
    /// Computed on each call, without the GIL.
    fn certificate<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let certificate = py.detach(|| self.solution.certificate()).map_err(error)?;
        let text = certificate.to_json().map_err(error)?;
        py.import("json")?.call_method1("loads", (text,))
    }

    /// The marginal covariance of pose `id`: a float64 array 3×3 in 2D
    /// (x, y, θ), 6×6 in 3D (x, y, z, rx, ry, rz) — perturbations on the
    /// right (in the pose's own frame), translation first, in the graph's
    /// units and radians — from the normal matrix of the map's edges
    /// (trusted edges and accepted loops) at the optimised poses, with the
    /// fixed poses as the gauge (their covariance is zero). The first of
    /// the covariance methods factorises that matrix (about three
    /// factorisations' time, with the GIL released); the result keeps it
    /// for the others. Raises `pgo.Error` for an unknown id, or a pose no
    /// edge in the map ties to the fixed ones (unbounded).
    fn covariance<'py>(
        &self,
        py: Python<'py>,
        id: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyAny>> {
        covariance::pose(py, &self.covariances, &self.solution, id)
    }

    /// The covariances of the poses `ids` (an iterable of ids; `None`:
    /// every pose, in the graph's order) as `(ids, covariances)`: a uint64
    /// array of N and a float64 array N×D×D, `covariances[k]` that of
    /// `ids[k]` (as `covariance`).
    #[pyo3(signature = (ids = None))]
    fn covariances<'py>(
        &self,
        py: Python<'py>,
        ids: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<(Bound<'py, PyArray1<u64>>, Bound<'py, PyAny>)> {
        covariance::poses(py, &self.covariances, &self.solution, ids)
    }

    /// The joint covariance of poses `a` and `b`: a float64 array 2D×2D,
    /// `[[Σ_aa, Σ_ab], [Σ_ba, Σ_bb]]` (as `covariance`).
    fn joint_covariance<'py>(
        &self,
        py: Python<'py>,
        a: &Bound<'py, PyAny>,
        b: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyAny>> {
        covariance::joint(py, &self.covariances, &self.solution, (a, b))
    }

    /// The covariance of pose `b` relative to pose `a` (of `Xa⁻¹·Xb`, in
    /// its own tangent space as `covariance`): `b`'s uncertainty as seen
    /// from `a`, whichever poses are fixed. A float64 array D×D.
    fn relative_covariance<'py>(
        &self,
        py: Python<'py>,
        a: &Bound<'py, PyAny>,
        b: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyAny>> {
        covariance::relative(py, &self.covariances, &self.solution, (a, b))
    }

    /// Writes the optimised map as a g2o file at `path` (`str` or
    /// path-like), atomically (a temporary file renamed over it; `"-"` is
    /// the process's standard output): a graph read from a file as that
    /// file's own text with the new poses, any other graph as
    /// `PoseGraph.write_g2o` writes it, with the optimised poses. Raises
    /// `pgo.FileError` (an `OSError`) when it cannot be written; nothing
    /// is replaced then.
    fn write_g2o(&self, py: Python<'_>, path: &Bound<'_, PyAny>) -> PyResult<()> {
        let path = convert::path(path)?;
        py.detach(|| self.solution.write_g2o(&path)).map_err(error)
    }

    /// Writes the optimised trajectory in the TUM format at `path`, as
    /// evo reads it (atomically, as `write_g2o`): one line per pose in the
    /// graph's order, `timestamp tx ty tz qx qy qz qw`, the timestamp the
    /// vertex id (poses have no time); a 2D pose as z = 0 and a rotation
    /// about z. Raises `pgo.FileError`.
    fn write_tum(&self, py: Python<'_>, path: &Bound<'_, PyAny>) -> PyResult<()> {
        let path = convert::path(path)?;
        py.detach(|| self.solution.write_tum(&path)).map_err(error)
    }

    /// Writes the optimised trajectory in the KITTI format at `path`, as
    /// evo reads it (atomically, as `write_g2o`): one line per pose in the
    /// graph's order (the format has no ids), the 3×4 matrix `[R t]` row
    /// by row; a 2D pose as z = 0 and a rotation about z. Raises
    /// `pgo.FileError`.
    fn write_kitti(&self, py: Python<'_>, path: &Bound<'_, PyAny>) -> PyResult<()> {
        let path = convert::path(path)?;
        py.detach(|| self.solution.write_kitti(&path))
            .map_err(error)
    }

    /// Writes the job's pictures as SVG files into the directory `dir`
    /// (`str` or path-like; made if missing), what `pgo optimize --plot
    /// DIR` writes: `counts.svg` (when the candidates have inlier counts
    /// and the gate fitted them), `loops.svg` (when EM's loop model
    /// decided) and `trajectory.svg` (before and after, loops coloured by
    /// their final weight), each atomically. Returns the paths written, as
    /// `str`, in that order. Raises `pgo.FileError` when the directory or
    /// a picture cannot be written.
    fn write_plots(&self, py: Python<'_>, dir: &Bound<'_, PyAny>) -> PyResult<Vec<String>> {
        let dir = convert::path(dir)?;
        let written = py
            .detach(|| self.solution.write_plots(&dir))
            .map_err(|e| error(e.into()))?;
        Ok(written
            .iter()
            .map(|p| p.to_string_lossy().into_owned())
            .collect())
    }

    /// `Result(poses=…, loops=…, accepted=…, chi2=…, verdict=…)`.
    fn __repr__(&self) -> String {
        let loops = self.solution.loops();
        let accepted = loops.iter().filter(|d| d.accepted).count();
        let verdict = self
            .verdict()
            .map_or("None".to_owned(), |v| format!("'{v}'"));
        format!(
            "Result(poses={}, loops={}, accepted={accepted}, chi2={}, verdict={verdict}, \
             status='{}')",
            self.solution.ids().len(),
            loops.len(),
            self.solution.chi2(),
            self.status()
        )
    }
}

/// One loop decision as a dict.
fn loop_dict<'py>(py: Python<'py>, d: &LoopDecision) -> PyResult<Bound<'py, PyDict>> {
    let dict = PyDict::new(py);
    dict.set_item("index", d.index)?;
    dict.set_item("from", d.from)?;
    dict.set_item("to", d.to)?;
    dict.set_item("inliers", d.inliers)?;
    dict.set_item("kept", d.kept)?;
    dict.set_item("weight", d.weight)?;
    dict.set_item("accepted", d.accepted)?;
    dict.set_item("posterior", d.posterior)?;
    dict.set_item("innovation", d.innovation)?;
    dict.set_item("reason", d.reason.as_str())?;
    Ok(dict)
}

/// An earlier decision an update changed, as a dict.
fn change_dict<'py>(py: Python<'py>, c: &DecisionChange) -> PyResult<Bound<'py, PyDict>> {
    let dict = PyDict::new(py);
    dict.set_item("index", c.index)?;
    dict.set_item("from", c.from)?;
    dict.set_item("to", c.to)?;
    dict.set_item("accepted", c.accepted)?;
    dict.set_item("reason", c.reason.as_str())?;
    Ok(dict)
}
