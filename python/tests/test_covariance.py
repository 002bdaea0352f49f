"""Marginal covariances of a result: shapes, the gauge, the CLI's CSV, the
relative covariance against the gauge moved, and errors."""

import subprocess

import numpy as np
import pytest

import pgo
from conftest import SAMPLES, line_graph

SAMPLE_NAMES = ["grid2d.g2o", "sphere3d.g2o"]


def chain():
    """Three poses 1 m apart, σ = 0.1 m and 0.01 rad per step."""
    graph = pgo.PoseGraph(2)
    for k in range(3):
        graph.add_pose(k, (float(k), 0.0, 0.0))
    info = np.diag([100.0, 100.0, 1e4])
    for k in range(1, 3):
        graph.add_edge(k - 1, k, (1.0, 0.0, 0.0), info)
    return graph


def test_a_chain_adds_up_its_steps():
    result = chain().optimize()
    assert np.array_equal(result.covariance(0), np.zeros((3, 3)))
    last = result.covariance(2)
    assert last.shape == (3, 3) and last.dtype == np.float64
    # x: two steps; y: two steps and the first heading 1 m back; θ: two.
    want = np.array([[0.02, 0, 0], [0, 0.0201, 1e-4], [0, 1e-4, 2e-4]])
    assert np.allclose(last, want, rtol=0, atol=1e-12)
    assert np.allclose(result.relative_covariance(1, 2), np.diag([0.01, 0.01, 1e-4]), atol=1e-12)
    joint = result.joint_covariance(1, 2)
    assert joint.shape == (6, 6)
    assert np.allclose(joint[:3, :3], result.covariance(1), atol=1e-14)
    assert np.allclose(joint[3:, 3:], last, atol=1e-14)
    assert np.allclose(joint, joint.T, atol=0)


@pytest.mark.parametrize("name", SAMPLE_NAMES)
def test_every_pose_is_the_cli_s_csv(name, pgo_bin, tmp_path):
    csv = tmp_path / "cov.csv"
    done = subprocess.run([str(pgo_bin), "optimize", str(SAMPLES / name), "-q",
                           "--covariances", str(csv)], capture_output=True, text=True)
    assert done.returncode in (0, 3), done.stderr
    rows = np.loadtxt(csv, delimiter=",", skiprows=1)
    result = pgo.read_g2o(SAMPLES / name).optimize()
    ids, covariances = result.covariances()
    d = 3 if result.covariance(ids[0]).shape == (3, 3) else 6
    assert ids.dtype == np.uint64 and covariances.shape == (len(ids), d, d)
    assert np.array_equal(rows[:, 0].astype(np.uint64), ids)
    scale = np.sqrt(np.abs(np.einsum("nii,njj->nij", covariances, covariances)))
    assert np.all(np.abs(rows[:, 1:].reshape(-1, d, d) - covariances) <= 1e-9 * scale)
    # The first pose is the gauge; the others are positive definite.
    assert np.array_equal(covariances[0], np.zeros((d, d)))
    assert np.all(np.linalg.eigvalsh(covariances[1:]) > 0)
    # Chosen ids, any iterable, in the order given.
    some, chosen = result.covariances(np.array([ids[5], ids[2]]))
    assert list(some) == [ids[5], ids[2]]
    assert np.array_equal(chosen[0], covariances[5]) and np.array_equal(chosen[1], covariances[2])


def test_relative_is_the_pose_with_the_first_fixed():
    graph = line_graph(n=8)
    fixed_at_3 = line_graph(n=8)
    fixed_at_3.fix(3)
    a, b = graph.optimize(), fixed_at_3.optimize()
    for k in (0, 5, 7):
        want = b.covariance(k)
        got = a.relative_covariance(3, k)
        assert np.allclose(got, want, rtol=1e-9, atol=1e-15), (k, got, want)


def test_bad_ids_are_named():
    result = chain().optimize()
    with pytest.raises(pgo.Error, match="unknown vertex id 9"):
        result.covariance(9)
    with pytest.raises(pgo.Error, match="unknown vertex id 9"):
        result.covariances([0, 9])
    with pytest.raises(pgo.Error, match="unknown vertex id 9"):
        result.joint_covariance(9, 0)
    with pytest.raises(pgo.Error, match="vertex id"):
        result.covariances(["a"])
    with pytest.raises(pgo.Error, match="iterable"):
        result.covariances(3)
    ids, empty = result.covariances([])
    assert ids.shape == (0,) and empty.shape == (0, 3, 3)

