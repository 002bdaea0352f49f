"""Result.certificate(): the certificate of global optimality, as the CLI's
`--certify` report gives it."""

import json
import math
import subprocess

import pgo
from conftest import SAMPLES


def test_a_sample_is_certified_as_the_cli_certifies_it(pgo_bin):
    path = SAMPLES / "grid2d.g2o"
    c = pgo.read_g2o(path).optimize().certificate()
    assert c["certified"] is True
    assert 0.0 <= c["gap_bound"] < 1e-4 * c["cost"]
    assert c["cost"] <= c["map_cost"] * (1 + 1e-12)
    assert c["lambda_min"] is None and c["eigenvector_poses"] == []
    out = subprocess.run([str(pgo_bin), "optimize", str(path), "--certify", "--json", "-q"],
                         capture_output=True, text=True)
    cli = json.loads(out.stdout)["certificate"]
    for key in ["certified", "eta", "cost", "map_cost", "gap_bound", "poses", "edges"]:
        assert cli[key] == c[key], key


def test_a_twisted_ring_is_not_certified_and_names_its_poses():
    # Ten poses at one place, every measurement "no motion", the map
    # twisted once around: a strict local minimum, far from the optimum.
    graph = pgo.PoseGraph(2)
    n = 10
    for k in range(n):
        graph.add_pose(k, (0.0, 0.0, math.remainder(2 * math.pi * k / n, 2 * math.pi)))
    info = [[1.0, 0, 0], [0, 1.0, 0], [0, 0, 100.0]]
    for k in range(n):
        graph.add_edge(k, (k + 1) % n, (0.0, 0.0, 0.0), info)
    c = graph.optimize(init="file").certificate()
    assert c["certified"] is False and c["gap_bound"] is None
    assert c["lambda_min"] < -c["eta"]
    lower, upper = c["lambda_min_bounds"]
    assert lower <= c["lambda_min"] and upper < -c["eta"]
    assert len(c["eigenvector_poses"]) == n
    assert {p["id"] for p in c["eigenvector_poses"]} == set(range(n))


def test_several_fixed_poses_raise():
    graph = pgo.PoseGraph(2)
    for k in range(3):
        graph.add_pose(k, (float(k), 0.0, 0.0))
    for k in range(1, 3):
        graph.add_edge(k - 1, k, (1.0, 0.0, 0.0), [[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0]])
    graph.fix(0)
    graph.fix(2)
    result = graph.optimize()
    try:
        result.certificate()
    except pgo.Error as e:
        assert "[0, 2]" in str(e)
    else:
        raise AssertionError("no error")
