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
token, or Ctrl-C, stops a running job. Bad input raises
:class:`Error` (a ``ValueError``) with the library's message.
"""

from ._pgo import Cancel, Error, PoseGraph, Result, __version__, option_names, read_g2o

__all__ = ["Cancel", "Error", "PoseGraph", "Result", "__version__", "option_names", "read_g2o"]
