"""Every bad input raises the pgo.Error subclass of its kind (all
ValueErrors) with a message saying what is wrong in Python's words; a
wrong type is also a TypeError, a missing file a FileNotFoundError."""

import errno
import logging
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


def a_result():
    return line_graph().optimize()


# name: (call, class, text the message holds)
BAD_CALLS = {
    "dimension": (lambda: pgo.PoseGraph(4), pgo.DimensionError,
                  "a pose graph is 2D or 3D, not 4D"),
    "negative dimension": (lambda: pgo.PoseGraph(-1), pgo.DimensionError,
                           "a pose graph is 2D or 3D, not -1D"),
    "huge dimension": (lambda: pgo.PoseGraph(2**70), pgo.DimensionError, "not 1180591620717411303424D"),
    "float dimension": (lambda: pgo.PoseGraph(2.0), pgo.ArgumentTypeError,
                        "dim must be an integer, got 2.0 (float)"),
    "bool dimension": (lambda: pgo.PoseGraph(True), pgo.ArgumentTypeError,
                       "dim must be an integer, not a bool"),
    "duplicate id": (lambda: two_poses().add_pose(1, (0, 0, 0)), pgo.DuplicateVertexError,
                     "vertex 1 already exists"),
    "unknown id": (lambda: two_poses().add_edge(0, 9, (1, 0, 0), I3), pgo.UnknownVertexError,
                   "unknown vertex id 9"),
    "unknown fixed id": (lambda: two_poses().fix(5), pgo.UnknownVertexError, "unknown vertex id 5"),
    "unknown pose asked": (lambda: two_poses().pose(5), pgo.UnknownVertexError,
                           "unknown vertex id 5"),
    "unknown result pose": (lambda: a_result().pose(99), pgo.UnknownVertexError,
                            "unknown vertex id 99"),
    "negative result pose": (lambda: a_result().pose(-1), pgo.InvalidArgumentError,
                             "a vertex id must be an integer in 0..=18446744073709551615, got -1 (int)"),
    "negative id": (lambda: two_poses().add_pose(-1, (0, 0, 0)), pgo.InvalidArgumentError,
                    "vertex id must be an integer in 0..="),
    "id beyond 2**64": (lambda: two_poses().add_pose(2**64, (0, 0, 0)), pgo.InvalidArgumentError,
                        "got 18446744073709551616 (int)"),
    "id not an int": (lambda: two_poses().add_pose("a", (0, 0, 0)), pgo.ArgumentTypeError,
                      "a vertex id must be an integer, got 'a' (str)"),
    "float id": (lambda: two_poses().add_pose(2.0, (0, 0, 0)), pgo.ArgumentTypeError,
                 "got 2.0 (float)"),
    "bool id": (lambda: two_poses().add_pose(True, (0, 0, 0)), pgo.ArgumentTypeError,
                "a vertex id must be an integer, not a bool, got True (bool)"),
    "numpy bool id": (lambda: two_poses().add_pose(np.True_, (0, 0, 0)), pgo.ArgumentTypeError,
                      "not a bool"),
    "bool edge end": (lambda: two_poses().add_edge(False, 1, (1, 0, 0), I3), pgo.ArgumentTypeError,
                      "not a bool"),
    "bool fixed id": (lambda: two_poses().fix(True), pgo.ArgumentTypeError, "not a bool"),
    "bool pose asked": (lambda: a_result().pose(True), pgo.ArgumentTypeError, "not a bool"),
    "self loop": (lambda: two_poses().add_edge(1, 1, (0, 0, 0), I3), pgo.SelfLoopError,
                  "edge from vertex 1 to itself"),
    "NaN pose": (lambda: two_poses().add_pose(2, (math.nan, 0, 0)), pgo.InvalidPoseError,
                 "vertex 2: is not finite"),
    "infinite measurement": (
        lambda: two_poses().add_edge(0, 1, (math.inf, 0, 0), I3), pgo.InvalidPoseError,
        "edge 0 → 1: measurement is not finite"),
    "NaN information": (
        lambda: two_poses().add_edge(0, 1, (1, 0, 0), [[1, 0, 0], [0, math.nan, 0], [0, 0, 1]]),
        pgo.InvalidInformationError, "information matrix has a non-finite entry at (1, 1)"),
    "information not positive definite": (
        lambda: two_poses().add_edge(0, 1, (1, 0, 0), [[1, 0, 0], [0, -1, 0], [0, 0, 1]]),
        pgo.InvalidInformationError,
        "information matrix is not positive definite (smallest eigenvalue -1e0); "
        "PoseGraph(dim, repair_information=True) projects such matrices"),
    "information not symmetric": (
        lambda: two_poses().add_edge(0, 1, (1, 0, 0), [[1, 0.5, 0], [0, 1, 0], [0, 0, 1]]),
        pgo.InvalidInformationError, "information matrix is not symmetric"),
    "information too small": (
        lambda: two_poses().add_edge(0, 1, (1, 0, 0), np.eye(3) * 1e-120),
        pgo.InvalidInformationError,
        "information matrix has diagonal entry (0, 0) = 1e-120, outside the range pgo computes "
        "with (1e-100 to 1e100"),
    "information too large": (
        lambda: two_poses().add_edge(0, 1, (1, 0, 0), np.eye(3) * 1e104),
        pgo.InvalidInformationError, "= 1e104, outside the range"),
    "zero quaternion": (
        lambda: pgo.PoseGraph(3).add_pose(0, (0, 0, 0, 0, 0, 0, 0)), pgo.InvalidPoseError,
        "vertex 0: has a quaternion of zero norm"),
    "short pose": (lambda: two_poses().add_pose(2, (0, 0)), pgo.LengthError,
                   "pose: expected 3 numbers for a 2D graph, got 2"),
    "3D pose in 2D": (lambda: two_poses().add_pose(2, np.zeros(7)), pgo.LengthError,
                      "pose: expected 3 numbers for a 2D graph, got 7"),
    "long measurement": (lambda: two_poses().add_edge(0, 1, (1, 0, 0, 0), I3), pgo.LengthError,
                         "measurement: expected 3 numbers for a 2D graph, got 4"),
    "6×6 information in 2D": (lambda: two_poses().add_edge(0, 1, (1, 0, 0), np.eye(6)),
                              pgo.InvalidArgumentError,
                              "information: expected a 3×3 matrix, got an array of shape (6, 6)"),
    "flat information too short": (lambda: two_poses().add_edge(0, 1, (1, 0, 0), [1.0] * 8),
                                   pgo.LengthError,
                                   "information: expected 9 numbers for a 2D graph, got 8"),
    "ragged information": (lambda: two_poses().add_edge(0, 1, (1, 0, 0), [[1, 0, 0], [0, 1]]),
                           pgo.InvalidArgumentError, "information: expected numbers"),
    "pose of text": (lambda: two_poses().add_pose(2, "abc"), pgo.ArgumentTypeError,
                     "pose: expected numbers, got 'abc' (str)"),
    "pose of texts": (lambda: two_poses().add_pose(2, ["1", "2", "3"]), pgo.ArgumentTypeError,
                      "pose: expected real numbers, got text: ['1', '2', '3'] (list)"),
    "pose of bytes": (lambda: two_poses().add_pose(2, b"abc"), pgo.ArgumentTypeError,
                      "pose: expected numbers, got b'abc' (bytes)"),
    "pose of a bytearray": (lambda: two_poses().add_pose(2, bytearray(b"abc")),
                            pgo.ArgumentTypeError, "(bytearray)"),
    "pose of a view of bytes": (lambda: two_poses().add_pose(2, memoryview(b"abc")),
                                pgo.ArgumentTypeError,
                                "pose: expected numbers, got a view of bytes b'abc' (bytes)"),
    "nested texts": (lambda: two_poses().add_edge(0, 1, (1, 0, 0), [["1", "0", "0"], I3[1], I3[2]]),
                     pgo.ArgumentTypeError, "information: expected real numbers, got text"),
    "pose of bools": (lambda: two_poses().add_pose(2, [True, False, True]),
                      pgo.ArgumentTypeError, "pose: expected real numbers, got booleans"),
    "complex pose": (lambda: two_poses().add_pose(2, np.array([1 + 2j, 0, 0])),
                     pgo.ArgumentTypeError, "pose: expected real numbers, got complex numbers"),
    "complex list": (lambda: two_poses().add_edge(0, 1, [1j, 0, 0], I3),
                     pgo.ArgumentTypeError, "measurement: expected real numbers, got complex"),
    "complex information": (lambda: two_poses().add_edge(0, 1, (1, 0, 0), np.eye(3) * (1 + 0j)),
                            pgo.ArgumentTypeError, "information: expected real numbers"),
    "masked pose": (lambda: two_poses().add_pose(2, np.ma.masked_array([1.0, 2.0, 3.0],
                                                                        mask=[0, 1, 0])),
                    pgo.ArgumentTypeError, "pose: a masked array's mask would be ignored"),
    "masked information": (lambda: two_poses().add_edge(0, 1, (1, 0, 0), np.ma.masked_array(np.eye(3))),
                           pgo.ArgumentTypeError, "information: a masked array"),
    "masked rows": (lambda: two_poses().add_edge(
                        0, 1, (1, 0, 0),
                        [np.ma.masked_array([1.0, 0, 0], mask=[1, 0, 0]), I3[1], I3[2]]),
                    pgo.ArgumentTypeError, "information: a masked array's mask would be ignored"),
    "masked element": (lambda: two_poses().add_pose(2, [np.ma.masked, 0.0, 0.0]),
                       pgo.ArgumentTypeError, "got masked (MaskedConstant) inside [masked, 0.0"),
    "pose of objects": (lambda: two_poses().add_pose(2, [1.0, None, 0.0]), pgo.ArgumentTypeError,
                        "pose: expected real numbers, got no numbers"),
    "pose as a matrix": (lambda: two_poses().add_pose(2, np.zeros((3, 1))), pgo.InvalidArgumentError,
                         "pose: expected a sequence of numbers, got an array of shape (3, 1)"),
    "negative inliers": (
        lambda: two_poses().add_loop_candidate(0, 1, (1, 0, 0), I3, inliers=-3),
        pgo.InvalidArgumentError, "inliers must be None or a non-negative integer, got -3"),
    "bool inliers": (
        lambda: two_poses().add_loop_candidate(0, 1, (1, 0, 0), I3, inliers=True),
        pgo.ArgumentTypeError, "inliers must be an integer, not a bool"),
    "float inliers": (
        lambda: two_poses().add_loop_candidate(0, 1, (1, 0, 0), I3, inliers=3.5),
        pgo.ArgumentTypeError, "inliers must be an integer, got 3.5 (float)"),
    "unknown option": (lambda: line_graph().optimize(no_such_option=1), pgo.UnknownOptionError,
                       "unknown option 'no_such_option' (options: gate,"),
    "bad option value": (lambda: line_graph().optimize(alpha=1.5), pgo.InvalidOptionError,
                         "option alpha must be in (0, 1), got 1.5"),
    "bad option choice": (lambda: line_graph().optimize(robust="sometimes"),
                          pgo.InvalidOptionError, "option robust must be one of"),
    "bad layer list": (lambda: line_graph().optimize(expert="no-magic"), pgo.InvalidOptionError,
                       "option expert unknown layer 'no-magic'"),
    "negative count option": (lambda: line_graph().optimize(max_iters=-1), pgo.InvalidOptionError,
                              "option max_iters must be a non-negative integer, got '-1'"),
    "robust_c beyond its range": (lambda: line_graph().optimize(robust_c=1e-101),
                                  pgo.InvalidOptionError,
                                  "option robust_c must be between 1e-100 and 1e100, got 1e-101"),
    "option of a list": (lambda: line_graph().optimize(gate=[1]), pgo.ArgumentTypeError,
                         "option gate: expected a bool, int, float or str, got [1] (list)"),
    "empty graph": (lambda: pgo.PoseGraph(2).optimize(), pgo.EmptyGraphError,
                    "the pose graph has no poses"),
    "unconstrained pose": (lambda: two_poses().optimize(), pgo.UnconstrainedError,
                           "not connected to the fixed vertex 0"),
    "missing file": (lambda: pgo.read_g2o("/nonexistent/graph.g2o"), pgo.MissingFileError,
                     "[Errno 2] No such file or directory: '/nonexistent/graph.g2o'"),
    "unwritable file": (lambda: two_poses().write_g2o("/nonexistent/dir/out.g2o"),
                        pgo.MissingFileError,
                        "/nonexistent/dir/out.g2o: cannot write: cannot create a file in "
                        "/nonexistent/dir: No such file or directory"),
    "path of an int": (lambda: pgo.read_g2o(3), pgo.ArgumentTypeError,
                       "path: expected a str or os.PathLike, got 3 (int)"),
    "write to a path of None": (lambda: two_poses().write_g2o(None), pgo.ArgumentTypeError,
                                "path: expected a str or os.PathLike, got None"),
}

# The Rust API's and the command line's words, which a Python user
# should not see.
FOREIGN = ["set_repair_information", "--fix-information", "read_g2o_repairing", "--max-iters",
           "--alpha", "--robust", "--expert"]


@pytest.mark.parametrize("name", list(BAD_CALLS))
def test_bad_input_raises_the_error_of_its_kind(name):
    call, cls, message = BAD_CALLS[name]
    with pytest.raises(pgo.Error) as raised:
        call()
    assert type(raised.value) is cls, (type(raised.value), str(raised.value))
    assert isinstance(raised.value, ValueError)
    assert message in str(raised.value), str(raised.value)
    assert not any(word in str(raised.value) for word in FOREIGN), str(raised.value)


def test_the_classes_derive_as_python_expects():
    kinds = [name for name in pgo.__all__ if name.endswith("Error")]
    # One class per ErrorKind (19 kinds) plus the base class pgo.Error.
    assert len(kinds) == 20 and "UnsupportedError" in kinds, kinds
    for name in kinds:
        cls = getattr(pgo, name)
        assert issubclass(cls, pgo.Error) and issubclass(cls, ValueError), name
        assert cls.__module__ == "pgo" and cls.__doc__, name
    assert issubclass(pgo.Error, ValueError)
    assert issubclass(pgo.ArgumentTypeError, TypeError)
    assert issubclass(pgo.ArgumentTypeError, pgo.InvalidArgumentError)
    assert issubclass(pgo.FileError, OSError)
    assert issubclass(pgo.MissingFileError, FileNotFoundError)
    assert issubclass(pgo.MissingFileError, pgo.FileError)
    assert issubclass(pgo.UnknownVertexError, LookupError)
    # Python's own exceptions are not shadowed.
    assert not hasattr(pgo, "FileNotFoundError") and not hasattr(pgo, "TypeError")


def test_a_missing_file_is_a_file_not_found_error():
    with pytest.raises(FileNotFoundError) as raised:
        pgo.read_g2o("/nonexistent/graph.g2o")
    e = raised.value
    assert (e.errno, e.filename) == (errno.ENOENT, "/nonexistent/graph.g2o")
    assert str(e) == "[Errno 2] No such file or directory: '/nonexistent/graph.g2o'"
    with pytest.raises(OSError):
        pgo.read_g2o("/nonexistent/graph.g2o", repair_information=True)


def test_a_file_that_cannot_be_written_is_an_os_error(tmp_path):
    (tmp_path / "taken").mkdir()
    (tmp_path / "taken" / "inside").write_text("")
    with pytest.raises(OSError) as raised:
        two_poses().write_g2o(tmp_path / "taken")
    assert isinstance(raised.value, pgo.FileError), type(raised.value)
    assert "taken" in str(raised.value)


def test_a_wrong_type_is_a_type_error():
    with pytest.raises(TypeError):
        pgo.read_g2o(3)
    with pytest.raises(TypeError):
        two_poses().add_pose(True, (0, 0, 0))


def test_membership_of_what_is_no_id_is_false():
    graph = two_poses()
    assert 1 in graph and 0 in graph
    assert True not in graph and -1 not in graph and "1" not in graph and 2**70 not in graph


def test_malformed_file_names_the_line(tmp_path):
    path = tmp_path / "bad.g2o"
    path.write_text("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 zero 0 0\n")
    with pytest.raises(pgo.ParseError, match=r"bad\.g2o:2: 'zero' is not a number"):
        pgo.read_g2o(path)


def test_a_file_s_repair_is_named_as_read_g2o_takes_it(tmp_path):
    path = tmp_path / "indefinite.g2o"
    path.write_text("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nEDGE_SE2 0 1 1 0 0 -1 0 0 1 0 1\n")
    with pytest.raises(pgo.ParseError) as raised:
        pgo.read_g2o(path)
    message = str(raised.value)
    assert "indefinite.g2o:3: information matrix is not positive definite" in message
    assert "read_g2o(path, repair_information=True) projects such matrices" in message
    assert not any(word in message for word in FOREIGN), message
    graph = pgo.read_g2o(path, repair_information=True)
    assert graph.optimize().report["information_fixed"] == 1


def test_a_file_s_information_out_of_range_is_refused(tmp_path):
    path = tmp_path / "tiny.g2o"
    path.write_text("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\n"
                    "EDGE_SE2 0 1 1 0 0 1e-120 0 0 1e-120 0 1e-120\n")
    with pytest.raises(pgo.InvalidInformationError, match="outside the range pgo computes with"):
        pgo.read_g2o(path)


def test_refused_additions_leave_the_graph_unchanged():
    graph = two_poses()
    with pytest.raises(pgo.Error):
        graph.add_edge(0, 1, (1, 0, 0), [[1, 0, 0], [0, -1, 0], [0, 0, 1]])
    with pytest.raises(pgo.Error):
        graph.add_pose(2, ["1", "2", "3"])
    assert (graph.len(), graph.num_edges) == (2, 0)


def test_numbers_of_any_real_type_are_taken():
    graph = pgo.PoseGraph(2)
    graph.add_pose(np.uint64(0), np.array([0, 0, 0], dtype=np.int32))
    graph.add_pose(1, np.array([1.0, 0.0, 0.0], dtype=np.float32))
    graph.add_edge(0, np.int64(1), [1, 0, 0], np.eye(3, dtype=np.int64))
    graph.add_loop_candidate(0, 1, (1.0, 0.0, 0.0), I3, inliers=np.int16(40))
    assert graph.pose(1) == (1.0, 0.0, 0.0)


def test_the_valid_forms_of_numbers_and_ids_are_taken():
    graph = pgo.PoseGraph(np.int64(2))
    graph.add_pose(0, (0, 0, 0))
    graph.add_pose(1, [1.0, 0, 0.5])
    graph.add_pose(2, np.array([2, 0, 0]))
    graph.add_pose(3, memoryview(np.array([3.0, 0.0, 0.0])))
    graph.add_pose(2**64 - 1, np.array([4.0, 0.0, 0.0], dtype=np.float32))
    graph.add_edge(0, 1, (1, 0, 0.5), I3)
    graph.add_edge(1, 2, [1.0, 0.0, -0.5], np.eye(3))
    graph.add_edge(2, 3, np.array([1, 0, 0]), tuple(tuple(row) for row in I3))
    graph.add_edge(3, 2**64 - 1, (1.0, 0.0, 0.0), [1, 0, 0, 0, 1, 0, 0, 0, 1])
    graph.add_loop_candidate(0, 3, np.array([3.0, 0.0, 0.0]), np.eye(3, dtype=np.int32),
                             inliers=40)
    assert graph.pose(1) == (1.0, 0.0, 0.5)
    assert graph.pose(3) == (3.0, 0.0, 0.0)
    result = graph.optimize()
    assert len(result.pose(np.uint64(2**64 - 1))) == 3


def test_a_huge_quaternion_is_normalised_not_called_zero():
    graph = pgo.PoseGraph(3)
    graph.add_pose(0, (1.0, 2.0, 3.0, 0.0, 0.0, 1e200, 1e200))
    q = graph.pose(0)[3:]
    assert q == pytest.approx((0.0, 0.0, math.sqrt(0.5), math.sqrt(0.5)), abs=1e-15)


def test_information_and_robust_c_at_the_ends_of_their_ranges_solve():
    for scale in (1e-100, 1e100):
        graph = pgo.PoseGraph(2)
        for k in range(4):
            graph.add_pose(k, (k * 1.1, 0.0, 0.0))
        for k in range(1, 4):
            graph.add_edge(k - 1, k, (1.0, 0.0, 0.0), np.eye(3) * scale)
        graph.add_edge(0, 3, (3.0, 0.0, 0.0), np.eye(3) * scale)
        assert graph.optimize().pose(3)[0] == pytest.approx(3.0, abs=1e-9)
    for c in (1e-100, 1e100):
        line_graph().optimize(robust_c=c)


def test_the_library_s_warnings_reach_logging(caplog):
    # One candidate: EM's model needs more, and says so in a warning.
    with caplog.at_level(logging.WARNING, logger="pgo"):
        result = line_graph().optimize()
    records = [r for r in caplog.records if r.name.startswith("pgo")]
    assert result.report["warnings"], "the example warns"
    assert result.warnings == result.report["warnings"]
    assert [r.getMessage() for r in records] == result.warnings
    assert all(r.levelno == logging.WARNING for r in records)


def test_logging_level_set_later_applies(caplog):
    logging.getLogger("pgo").setLevel(logging.ERROR)
    try:
        with caplog.at_level(logging.WARNING):
            line_graph().optimize()
        assert not [r for r in caplog.records if r.name.startswith("pgo")]
    finally:
        logging.getLogger("pgo").setLevel(logging.NOTSET)


def test_the_report_times_the_job():
    report = line_graph().optimize().report
    assert report["time"]["total_s"] > 0.0
    graph = line_graph()
    assert graph.update().report["time"]["total_s"] > 0.0
