"""Writing what the job found: Result.write_g2o (the optimised map),
write_tum and write_kitti (the trajectory as evo reads it), each from a
str or an os.PathLike, atomically, raising pgo.FileError when it cannot."""

import math
import pathlib

import numpy as np
import pytest

import pgo
from conftest import SAMPLES, line_graph


def rotation(pose):
    """The rotation matrix of a pose's numbers (x y θ or x y z qx qy qz qw)."""
    if len(pose) == 3:
        c, s = math.cos(pose[2]), math.sin(pose[2])
        return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    x, y, z, w = pose[3:]
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def translation(pose):
    return list(pose[:2]) + [0.0] if len(pose) == 3 else list(pose[:3])


def check_trajectories(result, tum_path, kitti_path):
    """The TUM and KITTI files hold the result's poses, in its order."""
    tum = np.loadtxt(tum_path, ndmin=2)
    kitti = np.loadtxt(kitti_path, ndmin=2)
    poses = result.poses
    assert tum.shape == (len(poses), 8) and kitti.shape == (len(poses), 12)
    for (id_, pose), t, k in zip(poses.items(), tum, kitti):
        assert t[0] == id_
        assert list(t[1:4]) == translation(pose)  # to the bit
        assert np.abs(rotation(t[1:]) - rotation(pose)).max() < 1e-12
        matrix = k.reshape(3, 4)
        assert list(matrix[:, 3]) == translation(pose)
        assert np.abs(matrix[:, :3] - rotation(pose)).max() < 1e-12


@pytest.mark.parametrize("name", ["grid2d.g2o", "sphere3d.g2o"])
def test_the_map_and_trajectories_read_back_to_the_poses(name, tmp_path):
    result = pgo.read_g2o(SAMPLES / name).optimize()
    result.write_g2o(tmp_path / "map.g2o")  # os.PathLike
    result.write_tum(str(tmp_path / "map.tum"))  # str
    result.write_kitti(tmp_path / "map.kitti")
    back = pgo.read_g2o(tmp_path / "map.g2o")
    assert back.ids == list(result.poses)
    for id_, pose in result.poses.items():
        assert back.pose(id_) == pose  # shortest round-trip numbers
    # The file's own text with the new poses: its other lines unchanged.
    lines = lambda p: [l for l in pathlib.Path(p).read_text().splitlines()
                       if not l.startswith("VERTEX")]
    assert lines(tmp_path / "map.g2o") == lines(SAMPLES / name)
    check_trajectories(result, tmp_path / "map.tum", tmp_path / "map.kitti")


def test_a_graph_built_in_memory_writes_its_map(tmp_path):
    result = line_graph().optimize()
    result.write_g2o(tmp_path / "map.g2o")
    back = pgo.read_g2o(tmp_path / "map.g2o")
    assert back.ids == list(result.poses)
    assert all(back.pose(i) == p for i, p in result.poses.items())
    result.write_tum(tmp_path / "map.tum")
    result.write_kitti(tmp_path / "map.kitti")
    check_trajectories(result, tmp_path / "map.tum", tmp_path / "map.kitti")
    # 2D: z = 0 and a rotation about z, qw ≥ 0.
    tum = np.loadtxt(tmp_path / "map.tum", ndmin=2)
    assert (tum[:, 3:6] == 0).all() and (tum[:, 7] >= 0).all()


@pytest.mark.parametrize("method", ["write_g2o", "write_tum", "write_kitti"])
def test_a_file_that_cannot_be_written_raises_a_file_error(method, tmp_path):
    result = line_graph().optimize()
    target = tmp_path / "missing" / "out.txt"
    with pytest.raises(pgo.MissingFileError) as raised:
        getattr(result, method)(target)
    assert isinstance(raised.value, pgo.FileError)
    assert isinstance(raised.value, OSError) and isinstance(raised.value, pgo.Error)
    assert str(target) in str(raised.value)
    assert not (tmp_path / "missing").exists()
    # A directory is no file: refused, and left as it was.
    (tmp_path / "taken").mkdir()
    with pytest.raises(pgo.FileError):
        getattr(result, method)(tmp_path / "taken")
    assert (tmp_path / "taken").is_dir()
    with pytest.raises(pgo.ArgumentTypeError):
        getattr(result, method)(None)
