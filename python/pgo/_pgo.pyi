"""Type stubs of the extension module ``pgo._pgo`` (re-exported by ``pgo``)."""

import os
from typing import Any, Callable, Dict, Iterable, List, Literal, Optional, Sequence, Tuple, TypedDict, Union

import numpy as np
import numpy.typing as npt

__version__: str

#: A vertex id: an integer in 0 ..= 2**64 - 1 (a bool is none).
VertexId = int
#: A pose or measurement: (x, y, θ) in 2D, (x, y, z, qx, qy, qz, qw) in 3D,
#: as a sequence or array of real numbers (ints or floats). Refused, with a
#: pgo.ArgumentTypeError: text, bytes (a memoryview of them too), bools,
#: complex numbers, objects, masked arrays (also as items of a list).
Numbers = Union[Sequence[float], npt.ArrayLike]
#: An information matrix: 3×3 (2D) or 6×6 (3D), nested or an array.
Matrix = Union[Sequence[Sequence[float]], npt.ArrayLike]
#: A pose as returned: 3 floats in 2D, 7 in 3D.
PoseTuple = Tuple[float, ...]
#: An option value, converted to the text the command line takes.
OptionValue = Union[bool, int, float, str, None]

class Error(ValueError):
    """Bad input to pgo or a failed optimisation, with the library's message.

    Each kind of failure is a subclass; every one is a ValueError."""

class InvalidArgumentError(Error):
    """An argument no call can take: an id or count out of range, an array of the wrong shape."""

class ArgumentTypeError(InvalidArgumentError, TypeError):
    """An argument of the wrong type: a bool as an id or count, text, complex or masked arrays as numbers, a path that is no str or os.PathLike."""

class DuplicateVertexError(Error):
    """A pose was added twice under the same id."""

class UnknownVertexError(Error, LookupError):
    """An edge, fix or look-up names a vertex id the graph does not have."""

class SelfLoopError(Error):
    """An edge from a vertex to itself."""

class InvalidPoseError(Error):
    """A pose or measurement that is not one: a NaN or infinite number, a zero quaternion."""

class InvalidInformationError(Error):
    """An information matrix that is not finite, symmetric, positive definite and within range."""

class LengthError(Error):
    """Numbers of the wrong count for the graph's dimension."""

class DimensionError(Error):
    """A dimension other than 2 or 3, or a file of the other dimension."""

class UnknownOptionError(Error):
    """A name that is no option (option_names() lists them)."""

class InvalidOptionError(Error):
    """An option's value that does not parse or is out of range."""

class FileError(OSError, Error):
    """A file that cannot be opened, read or written (errno, strerror, filename as OSError's)."""

class MissingFileError(FileNotFoundError, FileError):
    """A file (or directory) that does not exist."""

class ParseError(Error):
    """A malformed g2o file; the message names the file and line."""

class EmptyGraphError(Error):
    """A graph without poses cannot be optimised."""

class UnconstrainedError(Error):
    """Poses tied to the fixed ones by no chain of edges."""

class NumericalError(Error):
    """A problem floating point cannot solve: a pose its edges do not determine, numbers too large."""

class InternalError(Error):
    """A failure of pgo's own (threads, memory, a bug), not the input's."""

class UnsupportedError(Error):
    """A request pgo does not serve for this graph: a certificate of a map with several fixed poses."""

class Cancel:
    """A token another thread cancels to stop a running optimize or update."""

    def __init__(self) -> None: ...
    def cancel(self) -> None:
        """Stops every job that holds this token, at its next iteration."""
    @property
    def cancelled(self) -> bool:
        """Whether cancel() was called."""
    def __repr__(self) -> str: ...

class PoseGraph:
    """A pose graph in 2D (SE(2)) or 3D (SE(3)).

    Poses with integer ids, trusted edges (odometry), loop-closure
    candidates with their inlier counts, and the poses held fixed. Every
    addition is checked and refused with the :class:`Error` subclass of
    its kind.
    """

    def __init__(self, dim: int, *, repair_information: bool = False) -> None:
        """An empty graph of poses in ``dim`` (2 or 3) dimensions; with ``repair_information``, matrices that are not positive definite are projected to the nearest ones."""
    def add_pose(self, id: VertexId, pose: Numbers) -> None:
        """Adds a pose: (x, y, θ) or (x, y, z, qx, qy, qz, qw)."""
    def add_edge(self, i: VertexId, j: VertexId, meas: Numbers, info: Matrix) -> int:
        """Adds a trusted edge from pose i to pose j; returns its edge index."""
    def add_loop_candidate(
        self,
        i: VertexId,
        j: VertexId,
        meas: Numbers,
        info: Matrix,
        inliers: Optional[int] = None,
    ) -> int:
        """Adds a loop-closure candidate with its inlier count; returns its index."""
    def fix(self, id: VertexId) -> None:
        """Holds the pose ``id`` fixed (the first pose added is, without any)."""
    def len(self) -> int:
        """Number of poses."""
    def __len__(self) -> int:
        """Number of poses."""
    def __contains__(self, id: object) -> bool:
        """Whether a pose has this id."""
    @property
    def dim(self) -> int:
        """The dimension: 2 or 3."""
    @property
    def ids(self) -> List[VertexId]:
        """The ids of the poses, in the order they were added (or read)."""
    @property
    def num_edges(self) -> int:
        """Number of edges, loop candidates included."""
    @property
    def num_loop_candidates(self) -> int:
        """Number of loop-closure candidates."""
    def pose(self, id: VertexId) -> Optional[PoseTuple]:
        """The pose as given; None for a vertex a file named only in edges."""
    def write_g2o(self, path: Union[str, os.PathLike[str]]) -> None:
        """Writes the graph as a g2o file, atomically."""
    def optimize(self, *, cancel: Optional[Cancel] = None, progress: Optional[Callable[[int, float], object]] = None, **options: OptionValue) -> Result:
        """Runs the job of ``pgo optimize``; options are its flags, ``_`` for ``-`` (option_names() lists them); ``cancel`` stops it; ``progress(iterations, objective)`` is called at every solver iteration (an exception it raises stops the job and is raised)."""
    def update(self, *, cancel: Optional[Cancel] = None, progress: Optional[Callable[[int, float], object]] = None, **options: OptionValue) -> Result:
        """The job again after additions, from the last update's map; options, cancel and progress as optimize's, plus update_iters=K (at most K iterations per solve; the map may then be short of the optimum, and a later update goes on from it)."""
    def forget(self) -> None:
        """Drops what update keeps: the next update runs the whole job."""
    def __repr__(self) -> str: ...

#: An earlier loop candidate whose decision an update changed.
DecisionChange = TypedDict(
    "DecisionChange",
    {"index": int, "from": VertexId, "to": VertexId, "accepted": bool, "reason": str},
)

class Incremental(TypedDict):
    """What :meth:`PoseGraph.update` did (:attr:`Result.incremental`)."""

    solve: Literal["batch", "none", "extended", "warm", "full"]
    reason: str
    new_poses: int
    new_edges: int
    new_candidates: int
    changed: List[DecisionChange]

class Result:
    """What :meth:`PoseGraph.optimize` and :meth:`PoseGraph.update` return."""

    @property
    def poses(self) -> Dict[VertexId, PoseTuple]:
        """The optimised poses by id, in the graph's order."""
    def pose(self, id: VertexId) -> PoseTuple:
        """The optimised pose ``id``."""
    def poses_array(
        self,
    ) -> Tuple[npt.NDArray[np.uint64], npt.NDArray[np.float64]]:
        """(ids, poses): ids of N poses and an N×3 (2D) or N×7 (3D) array."""
    @property
    def loops(self) -> List[Dict[str, Any]]:
        """One dict per loop candidate: index, from, to, inliers, kept, weight, accepted, posterior, innovation, reason."""
    @property
    def report(self) -> Dict[str, Any]:
        """The report ``pgo optimize --json`` prints."""
    @property
    def incremental(self) -> Optional[Incremental]:
        """What update did (solve, reason, new_poses, new_edges, new_candidates, changed); None for optimize."""
    @property
    def chi2(self) -> float:
        """Σ eᵀΩe over all edges at the optimised poses."""
    @property
    def d2(self) -> Optional[float]:
        """D² of the χ² test; None when there is no test."""
    @property
    def passed(self) -> Optional[bool]:
        """Whether the map passes the χ² test; None when there is no test."""
    @property
    def verdict(self) -> Optional[str]:
        """"passed", "failed", or None when there is no test."""
    @property
    def cancelled(self) -> bool:
        """Whether a Cancel token stopped the job (the best map so far)."""
    @property
    def status(self) -> str:
        """How far the map can be taken as it is, as `pgo optimize`'s exit status says: "ok" (0), "chi2_failed" (3), "unfinished" (4), "unsettled" (4), "questioned" (a doubtful cluster, loops held back or outlying accepted loops, 5) or "cancelled" (130)."""
    @property
    def warnings(self) -> List[str]:
        """The job's warnings (report["warnings"]): e.g. that the loop decisions did not settle (loops with reason "unsettled"), an accepted cluster the map cannot vouch for (report["robust"]["doubtful"]), rejected loops kept out by their counts alone that would move the map (report["robust"]["held_back"]), or accepted loops beyond the true loops' reach that move it (report["robust"]["outlying"])."""
    def certificate(self) -> Dict[str, Any]:
        """Certificate of global optimality of the map (certified, eta, cost, map_cost, gap_bound, max_translation_change, max_rotation_change, lambda_min, lambda_min_bounds, eigenvector_poses, time)."""
    def write_g2o(self, path: Union[str, os.PathLike[str]]) -> None:
        """Writes the optimised map as a g2o file, atomically (``"-"``: stdout): a file's own text with the new poses, else the graph's lines; raises FileError."""
    def write_tum(self, path: Union[str, os.PathLike[str]]) -> None:
        """Writes the optimised trajectory as TUM (evo): per pose in the graph's order ``id tx ty tz qx qy qz qw``, the vertex id as timestamp; 2D as z = 0 and a rotation about z; raises FileError."""
    def write_kitti(self, path: Union[str, os.PathLike[str]]) -> None:
        """Writes the optimised trajectory as KITTI (evo): per pose in the graph's order (no ids), the 3×4 matrix [R t] row by row; 2D as z = 0 and a rotation about z; raises FileError."""
    def write_plots(self, dir: Union[str, os.PathLike[str]]) -> List[str]:
        """Writes the job's SVG pictures into ``dir`` (made if missing), as ``pgo optimize --plot``: counts.svg (counts and a gate fit), loops.svg (EM's loop model), trajectory.svg; returns the paths written; raises FileError."""
    def covariance(self, id: VertexId) -> npt.NDArray[np.float64]:
        """Pose ``id``'s marginal covariance, D×D (3: x y θ; 6: x y z rx ry rz; right perturbation)."""
    def covariances(
        self, ids: Optional[Iterable[VertexId]] = None
    ) -> Tuple[npt.NDArray[np.uint64], npt.NDArray[np.float64]]:
        """(ids, covariances): N ids (all poses for None) and an N×D×D array."""
    def joint_covariance(self, a: VertexId, b: VertexId) -> npt.NDArray[np.float64]:
        """The joint covariance of poses ``a`` and ``b``, 2D×2D."""
    def relative_covariance(self, a: VertexId, b: VertexId) -> npt.NDArray[np.float64]:
        """The covariance of ``b`` relative to ``a`` (of Xa⁻¹·Xb), D×D."""
    def __repr__(self) -> str: ...

def read_g2o(
    path: Union[str, os.PathLike[str]], *, repair_information: bool = False
) -> PoseGraph:
    """Reads a g2o file of either dimension (MissingFileError if there is none, ParseError naming the line if it is malformed)."""

def option_names() -> List[str]:
    """The option names :meth:`PoseGraph.optimize` takes (``-`` or ``_``)."""
