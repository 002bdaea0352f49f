"""Every bad input raises pgo.Error (a ValueError) with a message saying
what is wrong."""

import math

import numpy as np
import pytest

import pgo
from conftest import line_graph

I3 = [[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0]]


def two_poses():
    graph = pgo.PoseGraph(2)
    graph.add_pose(0, (0.0, 0.0, 0.0))
    graph.add_pose(1, (1.0, 0.0, 0.0))
    return graph


BAD_CALLS = {
    "dimension": (lambda: pgo.PoseGraph(4), "a pose graph is 2D or 3D, not 4D"),
    "duplicate id": (lambda: two_poses().add_pose(1, (0, 0, 0)), "vertex 1 already exists"),
    "unknown id": (lambda: two_poses().add_edge(0, 9, (1, 0, 0), I3), "unknown vertex id 9"),
    "unknown fixed id": (lambda: two_poses().fix(5), "unknown vertex id 5"),
    "unknown pose asked": (lambda: two_poses().pose(5), "unknown vertex id 5"),
    "negative id": (lambda: two_poses().add_pose(-1, (0, 0, 0)), "vertex id must be an integer"),
    "id not an int": (lambda: two_poses().add_pose("a", (0, 0, 0)), "'a' (str)"),
    "self loop": (lambda: two_poses().add_edge(1, 1, (0, 0, 0), I3), "edge from vertex 1 to itself"),
    "NaN pose": (lambda: two_poses().add_pose(2, (math.nan, 0, 0)), "vertex 2: is not finite"),
    "infinite measurement": (
        lambda: two_poses().add_edge(0, 1, (math.inf, 0, 0), I3),
        "edge 0 → 1: measurement is not finite"),
    "NaN information": (
        lambda: two_poses().add_edge(0, 1, (1, 0, 0), [[1, 0, 0], [0, math.nan, 0], [0, 0, 1]]),
        "information matrix has a non-finite entry at (1, 1)"),
    "information not positive definite": (
        lambda: two_poses().add_edge(0, 1, (1, 0, 0), [[1, 0, 0], [0, -1, 0], [0, 0, 1]]),
        "information matrix is not positive definite"),
    "information not symmetric": (
        lambda: two_poses().add_edge(0, 1, (1, 0, 0), [[1, 0.5, 0], [0, 1, 0], [0, 0, 1]]),
        "information matrix is not symmetric"),
    "zero quaternion": (
        lambda: pgo.PoseGraph(3).add_pose(0, (0, 0, 0, 0, 0, 0, 0)),
        "vertex 0: has a quaternion of zero norm"),
    "short pose": (lambda: two_poses().add_pose(2, (0, 0)),
                   "pose: expected 3 numbers for a 2D graph, got 2"),
    "3D pose in 2D": (lambda: two_poses().add_pose(2, np.zeros(7)),
                      "pose: expected 3 numbers for a 2D graph, got 7"),
    "long measurement": (lambda: two_poses().add_edge(0, 1, (1, 0, 0, 0), I3),
                         "measurement: expected 3 numbers for a 2D graph, got 4"),
    "6×6 information in 2D": (lambda: two_poses().add_edge(0, 1, (1, 0, 0), np.eye(6)),
                              "information: expected a 3×3 matrix, got an array of shape (6, 6)"),
    "flat information too short": (lambda: two_poses().add_edge(0, 1, (1, 0, 0), [1.0] * 8),
                                   "information: expected 9 numbers for a 2D graph, got 8"),
    "ragged information": (lambda: two_poses().add_edge(0, 1, (1, 0, 0), [[1, 0, 0], [0, 1]]),
                           "information: expected numbers"),
    "pose of text": (lambda: two_poses().add_pose(2, "abc"), "pose: expected numbers"),
    "pose as a matrix": (lambda: two_poses().add_pose(2, np.zeros((3, 1))),
                         "pose: expected a sequence of numbers, got an array of shape (3, 1)"),
    "negative inliers": (
        lambda: two_poses().add_loop_candidate(0, 1, (1, 0, 0), I3, inliers=-3),
        "inliers must be None or a non-negative integer, got -3"),
    "unknown option": (lambda: line_graph().optimize(no_such_option=1),
                       "unknown option 'no_such_option' (options: gate,"),
    "bad option value": (lambda: line_graph().optimize(alpha=1.5),
                         "--alpha must be in (0, 1), got 1.5"),
    "bad option choice": (lambda: line_graph().optimize(robust="sometimes"), "--robust"),
    "bad layer list": (lambda: line_graph().optimize(expert="no-magic"),
                       "--expert unknown layer 'no-magic'"),
    "negative count option": (lambda: line_graph().optimize(max_iters=-1), "--max-iters"),
    "option of a list": (lambda: line_graph().optimize(gate=[1]),
                         "option gate: expected a bool, int, float or str, got [1] (list)"),
    "empty graph": (lambda: pgo.PoseGraph(2).optimize(), "the pose graph has no poses"),
    "unconstrained pose": (lambda: two_poses().optimize(), "not connected to the fixed vertex 0"),
    "missing file": (lambda: pgo.read_g2o("/nonexistent/graph.g2o"), "/nonexistent/graph.g2o"),
    "unwritable file": (lambda: two_poses().write_g2o("/nonexistent/dir/out.g2o"),
                        "/nonexistent/dir/out.g2o"),
}


@pytest.mark.parametrize("name", list(BAD_CALLS))
def test_bad_input_raises_pgo_error(name):
    call, message = BAD_CALLS[name]
    with pytest.raises(pgo.Error) as raised:
        call()
    assert message in str(raised.value)


def test_error_is_a_value_error():
    assert issubclass(pgo.Error, ValueError)
    with pytest.raises(ValueError):
        pgo.PoseGraph(1)


def test_malformed_file_names_the_line(tmp_path):
    path = tmp_path / "bad.g2o"
    path.write_text("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 zero 0 0\n")
    with pytest.raises(pgo.Error, match=r"bad\.g2o.*2"):
        pgo.read_g2o(path)


def test_refused_additions_leave_the_graph_unchanged():
    graph = two_poses()
    with pytest.raises(pgo.Error):
        graph.add_edge(0, 1, (1, 0, 0), [[1, 0, 0], [0, -1, 0], [0, 0, 1]])
    assert (graph.len(), graph.num_edges) == (2, 0)
