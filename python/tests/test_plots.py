"""Result.write_plots: the pictures `pgo optimize --plot DIR` writes, from
a str or an os.PathLike, raising pgo.FileError when they cannot be
written."""

import pathlib

import pytest

import pgo
from conftest import SAMPLES, line_graph


def read_svg(path):
    text = pathlib.Path(path).read_text()
    assert text.startswith("<svg") and text.rstrip().endswith("</svg>"), path
    return text


@pytest.mark.parametrize("name", ["grid2d.g2o", "sphere3d.g2o"])
def test_the_three_pictures_of_a_sample(name, tmp_path):
    result = pgo.read_g2o(SAMPLES / name).optimize()
    out = tmp_path / "made" / "pictures"  # made, parents too
    written = result.write_plots(out)
    assert all(isinstance(p, str) for p in written)
    assert [pathlib.Path(p).name for p in written] == [
        "counts.svg", "loops.svg", "trajectory.svg"]
    assert all(pathlib.Path(p).parent == out for p in written)
    counts, loops, trajectory = (read_svg(p) for p in written)
    assert "T_GV = " in counts
    assert "posterior ½: accepted above" in loops
    assert name in trajectory
    if name.startswith("sphere"):
        assert "3D: seen from above" in trajectory


def test_a_graph_without_candidates_gets_the_trajectory_only(tmp_path):
    graph = pgo.PoseGraph(2)
    for k in range(4):
        graph.add_pose(k, (float(k), 0.1 * k, 0.0))
    for k in range(1, 4):
        graph.add_edge(k - 1, k, (1.0, 0.0, 0.0), [[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0]])
    written = graph.optimize().write_plots(str(tmp_path))  # str
    assert written == [str(tmp_path / "trajectory.svg")]
    assert "pose graph" in read_svg(written[0])


def test_a_directory_that_cannot_be_made_raises_a_file_error(tmp_path):
    result = line_graph().optimize()
    (tmp_path / "a-file").write_text("x")
    target = tmp_path / "a-file" / "pictures"
    with pytest.raises(pgo.FileError) as raised:
        result.write_plots(target)
    assert isinstance(raised.value, OSError) and isinstance(raised.value, pgo.Error)
    assert str(target) in str(raised.value)
    # A file is no directory: refused, and left as it was.
    with pytest.raises(pgo.FileError):
        result.write_plots(tmp_path / "a-file")
    assert (tmp_path / "a-file").read_text() == "x"
    with pytest.raises(pgo.ArgumentTypeError):
        result.write_plots(None)
