"""optimize and update release the GIL: other Python threads run while they
solve, and several threads can optimise at once without deadlock."""

import sys
import threading
import time

import pytest

import pgo
from conftest import SAMPLES, assert_close


def batch_update(graph):
    """An update that runs the whole job."""
    graph.forget()
    return graph.update()


@pytest.mark.parametrize("job", [pgo.PoseGraph.optimize, batch_update], ids=["optimize", "update"])
def test_python_runs_while_a_job_solves(job):
    graph = pgo.read_g2o(SAMPLES / "sphere3d.g2o")
    old = sys.getswitchinterval()
    sys.setswitchinterval(1e-4)
    try:
        started, finished = [], []

        def solve():
            started.append(time.perf_counter())
            for _ in range(3):
                job(graph)
            finished.append(time.perf_counter())

        worker = threading.Thread(target=solve)
        worker.start()
        ticks = [time.perf_counter()]
        while worker.is_alive():
            ticks.append(time.perf_counter())
        worker.join()
    finally:
        sys.setswitchinterval(old)
    duration = finished[0] - started[0]
    # Held for the whole solve, the GIL would stop this thread's loop for
    # about a third of the duration at a time.
    solving = [b - a for a, b in zip(ticks, ticks[1:]) if a >= started[0]]
    assert duration > 0.05, f"the solve took only {duration:.3f} s: too short to tell"
    assert max(solving) < duration / 6, (max(solving), duration)


def test_concurrent_optimizations_agree():
    graph = pgo.read_g2o(SAMPLES / "grid2d.g2o")
    expected = graph.optimize().poses
    results = [None] * 4

    def solve(k):
        results[k] = graph.optimize().poses

    threads = [threading.Thread(target=solve, args=(k,)) for k in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=300)
    assert not any(t.is_alive() for t in threads)
    for poses in results:
        assert_close(poses, expected, "poses")


def test_the_graph_is_busy_while_update_solves():
    """update changes the graph: while it runs, another thread's use of the
    graph raises RuntimeError (PyO3's borrow check) instead of racing it;
    the update then stands."""
    graph = pgo.read_g2o(SAMPLES / "sphere3d.g2o")
    results, refused = [], []
    worker = threading.Thread(target=lambda: results.append(graph.update()))
    worker.start()
    while worker.is_alive():
        try:
            graph.len()
        except RuntimeError as e:
            refused.append(str(e))
    worker.join()
    assert refused and all("borrowed" in e for e in refused), refused[:1]
    assert results[0].incremental["solve"] == "batch"
    assert graph.update().incremental["solve"] == "none"
