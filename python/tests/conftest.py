"""Shared fixtures: the bundled samples, the `pgo` command-line binary, and
a small g2o reader that builds a graph call by call."""

import json
import os
import pathlib
import subprocess

import pytest

import pgo

REPO = pathlib.Path(__file__).resolve().parents[2]
SAMPLES = REPO / "g2o_samples"


def cli_binary():
    """The `pgo` binary the tests compare with: $PGO_BIN, else the release
    build in $CARGO_TARGET_DIR (or the repository's target/)."""
    if "PGO_BIN" in os.environ:
        return pathlib.Path(os.environ["PGO_BIN"])
    target = pathlib.Path(os.environ.get("CARGO_TARGET_DIR", REPO / "target"))
    return target / "release" / "pgo"


@pytest.fixture(scope="session")
def pgo_bin():
    path = cli_binary()
    if not path.is_file():
        pytest.fail(
            f"no pgo binary at {path}: run `cargo build --release` or set PGO_BIN"
        )
    return path


def run_cli(pgo_bin, graph_file, output, *flags):
    """Runs `pgo optimize` on a file; returns its JSON report as text."""
    done = subprocess.run(
        [str(pgo_bin), "optimize", str(graph_file), "--output", str(output),
         "--json", "-q", *flags],
        capture_output=True, text=True, check=False,
    )
    # 3: the result failed its χ² test (the output is still written).
    assert done.returncode in (0, 3), done.stderr
    failed = json.loads(done.stdout).get("chi2_test", {}) or {}
    assert (done.returncode == 3) == (failed.get("passed") is False), done.stderr
    return done.stdout


def build_from_file(path):
    """The graph of a g2o file built call by call: VERTEX_SE2 /
    VERTEX_SE3:QUAT lines as poses, edges with a trailing inlier count as
    loop candidates, the others as trusted edges, FIX lines."""
    rows = [line.split() for line in pathlib.Path(path).read_text().splitlines()]
    rows = [r for r in rows if r and not r[0].startswith("#")]
    dim = 3 if any(r[0].startswith("VERTEX_SE3") for r in rows) else 2
    graph = pgo.PoseGraph(dim)
    numbers, size = (3, 3) if dim == 2 else (7, 6)
    for r in rows:
        if r[0].startswith("VERTEX"):
            graph.add_pose(int(r[1]), [float(x) for x in r[2:]])
        elif r[0].startswith("EDGE"):
            i, j = int(r[1]), int(r[2])
            meas = [float(x) for x in r[3:3 + numbers]]
            upper = [float(x) for x in r[3 + numbers:3 + numbers + size * (size + 1) // 2]]
            info = symmetric(upper, size)
            rest = r[3 + numbers + len(upper):]
            if rest:
                graph.add_loop_candidate(i, j, meas, info, inliers=int(rest[0]))
            else:
                graph.add_edge(i, j, meas, info)
        elif r[0] == "FIX":
            for v in r[1:]:
                graph.fix(int(v))
    return graph


def symmetric(upper, size):
    """The matrix whose upper triangle, row by row, is `upper`."""
    m = [[0.0] * size for _ in range(size)]
    k = 0
    for a in range(size):
        for b in range(a, size):
            m[a][b] = m[b][a] = upper[k]
            k += 1
    return m


def line_graph(n=6, loop_inliers=150):
    """A 2D graph: n poses on a line 1 m apart, odometry between
    neighbours and one loop candidate from the first to the last."""
    graph = pgo.PoseGraph(2)
    for k in range(n):
        graph.add_pose(k, (float(k), 0.0, 0.0))
    info = [[100.0, 0, 0], [0, 100.0, 0], [0, 0, 400.0]]
    for k in range(1, n):
        graph.add_edge(k - 1, k, (1.0, 0.0, 0.0), info)
    graph.add_loop_candidate(0, n - 1, (n - 1.0, 0.0, 0.0), info, inliers=loop_inliers)
    return graph


# The library's optimum is reproducible to round-off only (two runs of the
# same job may differ in the last bits, as two runs of the CLI do), so
# numbers are compared to this relative tolerance.
TOLERANCE = 1e-9


def assert_close(a, b, where="result"):
    """Two JSON-like values are equal, floats to TOLERANCE (relative, or
    absolute near zero)."""
    if isinstance(a, float) or isinstance(b, float):
        assert isinstance(a, (int, float)) and isinstance(b, (int, float)), where
        assert abs(a - b) <= TOLERANCE * max(1.0, abs(a), abs(b)), (where, a, b)
    elif isinstance(a, dict):
        assert isinstance(b, dict) and a.keys() == b.keys(), (where, a.keys(), b)
        for k in a:
            assert_close(a[k], b[k], f"{where}[{k!r}]")
    elif isinstance(a, (list, tuple)):
        assert isinstance(b, (list, tuple)) and len(a) == len(b), (where, a, b)
        for k, (x, y) in enumerate(zip(a, b)):
            assert_close(x, y, f"{where}[{k}]")
    else:
        assert a == b, (where, a, b)


def assert_same_result(a, b):
    """Two results have the same poses (to round-off) and decisions."""
    assert_close(a.poses, b.poses, "poses")
    assert_close(a.loops, b.loops, "loops")
    assert_close((a.chi2, a.d2, a.passed, a.verdict), (b.chi2, b.d2, b.passed, b.verdict))
