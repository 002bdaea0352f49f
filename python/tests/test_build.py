"""A graph built call by call is the graph read from its file; the writer
and reader round-trip; the accessors say what was added."""

import numpy as np
import pytest

import pgo
from conftest import SAMPLES, assert_same_result as same_result, build_from_file, line_graph

SAMPLE_NAMES = ["grid2d.g2o", "sphere3d.g2o"]


@pytest.mark.parametrize("name", SAMPLE_NAMES)
def test_built_call_by_call_is_the_file_read(name):
    built = build_from_file(SAMPLES / name)
    read = pgo.read_g2o(SAMPLES / name)
    assert (built.dim, built.ids, built.num_edges, built.num_loop_candidates) == (
        read.dim, read.ids, read.num_edges, read.num_loop_candidates)
    assert all(built.pose(i) == read.pose(i) for i in read.ids)
    same_result(built.optimize(), read.optimize())


@pytest.mark.parametrize("name", SAMPLE_NAMES)
def test_write_then_read_is_the_same_graph(name, tmp_path):
    built = build_from_file(SAMPLES / name)
    out = tmp_path / "graph.g2o"
    built.write_g2o(out)
    again = pgo.read_g2o(str(out))  # str as well as os.PathLike
    assert again.ids == built.ids
    assert all(again.pose(i) == built.pose(i) for i in built.ids)
    same_result(again.optimize(), built.optimize())


def test_numpy_arrays_are_taken_like_sequences():
    lists = line_graph()
    arrays = pgo.PoseGraph(2)
    for k in range(6):
        arrays.add_pose(np.uint32(k), np.array([k, 0, 0], dtype=np.float32))
    info = np.diag([100.0, 100.0, 400.0])
    for k in range(1, 6):
        arrays.add_edge(k - 1, k, np.array([1.0, 0.0, 0.0]), info)
    # The information's numbers flat, row by row, are taken too.
    arrays.add_loop_candidate(0, 5, (5.0, 0.0, 0.0), info.ravel(), inliers=np.int64(150))
    same_result(arrays.optimize(), lists.optimize())


def test_accessors():
    graph = line_graph(n=4)
    assert len(graph) == graph.len() == 4
    assert graph.dim == 2 and graph.ids == [0, 1, 2, 3]
    assert (graph.num_edges, graph.num_loop_candidates) == (4, 1)
    assert 3 in graph and 4 not in graph and "x" not in graph
    assert graph.pose(2) == (2.0, 0.0, 0.0)
    assert repr(graph) == "PoseGraph(dim=2, poses=4, edges=4, loop_candidates=1)"


def test_indices_returned_are_those_the_decisions_carry():
    graph = line_graph(n=4)
    index = graph.add_loop_candidate(1, 3, (2.0, 0.0, 0.0), np.eye(3) * 100, inliers=120)
    assert index == 4
    loops = graph.optimize().loops
    assert [d["index"] for d in loops] == [3, 4]
    assert [(d["from"], d["to"], d["inliers"]) for d in loops] == [(0, 3, 150), (1, 3, 120)]


def test_3d_quaternion_is_normalised():
    graph = pgo.PoseGraph(3)
    graph.add_pose(7, (1.0, 2.0, 3.0, 0.0, 0.0, 0.0, 2.0))
    assert graph.pose(7) == (1.0, 2.0, 3.0, 0.0, 0.0, 0.0, 1.0)


def test_result_poses_array_and_accessors():
    result = line_graph().optimize()
    ids, poses = result.poses_array()
    assert ids.dtype == np.uint64 and poses.dtype == np.float64
    assert poses.shape == (6, 3)
    assert [tuple(row) for row in poses] == [result.poses[i] for i in ids.tolist()]
    assert result.pose(5) == result.poses[5]
    assert abs(result.poses[5][0] - 5.0) < 1e-9
    assert result.verdict in ("passed", "failed") and result.passed == (result.verdict == "passed")
    assert result.d2 is not None and result.chi2 >= 0.0
    [loop] = result.loops
    assert set(loop) == {"index", "from", "to", "inliers", "kept", "weight", "accepted",
                         "posterior", "innovation", "reason"}
    assert loop["accepted"] and loop["weight"] >= 0.5 and isinstance(loop["reason"], str)
    assert isinstance(result.report, dict) and len(result.report["loops"]) == 1
    assert repr(result).startswith("Result(poses=6, loops=1, accepted=1, chi2=")
    assert repr(result).endswith(", status='ok')")


def test_3d_poses_array_is_n_by_7():
    _, poses = pgo.read_g2o(SAMPLES / "sphere3d.g2o").optimize().poses_array()
    assert poses.shape[1] == 7
    assert np.allclose(np.linalg.norm(poses[:, 3:], axis=1), 1.0)


def test_file_vertex_without_line_has_no_pose(tmp_path):
    path = tmp_path / "g.g2o"
    path.write_text(
        "VERTEX_SE2 0 0 0 0\n"
        "EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n"
    )
    graph = pgo.read_g2o(path)
    assert graph.ids == [0, 1]
    assert graph.pose(0) == (0.0, 0.0, 0.0) and graph.pose(1) is None
    assert abs(graph.optimize().poses[1][0] - 1.0) < 1e-9
