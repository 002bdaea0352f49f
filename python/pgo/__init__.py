"""pgo: pose-graph SLAM back end with unsupervised loop-closure gating.

Build a :class:`PoseGraph` call by call (or read one with :func:`read_g2o`),
then :meth:`PoseGraph.optimize` it: the whole job of ``pgo optimize`` — the
geometric-verification gate learned from the loop candidates' inlier
counts, the robust weighting of the loops, and the χ² test of the result —
returning a :class:`Result` with the optimised poses, one decision per loop
candidate and the report ``pgo optimize --json`` prints. A mapping front
end that wants the map as the graph grows calls :meth:`PoseGraph.update`
instead: the same map, reached from the last update's, solving only what
the additions need (:attr:`Result.incremental` says how). A :class:`Cancel`
token, or Ctrl-C, stops a running job.

Bad input raises the :class:`Error` subclass of its kind (every one a
``ValueError``): :class:`DuplicateVertexError`, :class:`ParseError`,
:class:`UnconstrainedError`, ...; an argument of the wrong type is also a
``TypeError`` (:class:`ArgumentTypeError`), a file that cannot be read or
written an ``OSError`` (:class:`FileError`), a missing one a
``FileNotFoundError`` (:class:`MissingFileError`).

The library's warnings go to the :mod:`logging` logger ``pgo`` (which,
as a library's should, has only a ``NullHandler`` of its own: configure
logging to see them; ``Result.report["warnings"]`` holds them too).
"""

import logging as _logging

from ._pgo import (
    ArgumentTypeError,
    Cancel,
    DimensionError,
    DuplicateVertexError,
    EmptyGraphError,
    Error,
    FileError,
    InternalError,
    InvalidArgumentError,
    InvalidInformationError,
    InvalidOptionError,
    InvalidPoseError,
    LengthError,
    MissingFileError,
    NumericalError,
    ParseError,
    PoseGraph,
    Result,
    SelfLoopError,
    UnconstrainedError,
    UnknownOptionError,
    UnknownVertexError,
    UnsupportedError,
    __version__,
    option_names,
    read_g2o,
)

_logging.getLogger("pgo").addHandler(_logging.NullHandler())

__all__ = [
    "ArgumentTypeError",
    "Cancel",
    "DimensionError",
    "DuplicateVertexError",
    "EmptyGraphError",
    "Error",
    "FileError",
    "InternalError",
    "InvalidArgumentError",
    "InvalidInformationError",
    "InvalidOptionError",
    "InvalidPoseError",
    "LengthError",
    "MissingFileError",
    "NumericalError",
    "ParseError",
    "PoseGraph",
    "Result",
    "SelfLoopError",
    "UnconstrainedError",
    "UnknownOptionError",
    "UnknownVertexError",
    "UnsupportedError",
    "__version__",
    "option_names",
    "read_g2o",
]
