"""A pgo.Cancel token stops optimize and update from another thread, and
Ctrl-C stops them with KeyboardInterrupt; a stopped update keeps the
graph's earlier state."""

import os
import signal
import subprocess
import threading

import pytest

import pgo
from conftest import SAMPLES


@pytest.fixture(scope="module")
def big_graph(pgo_bin, tmp_path_factory):
    """A simulated grid whose job takes about a second: long enough for a
    cancellation sent after 0.1 s to land while it runs."""
    path = tmp_path_factory.mktemp("cancel") / "grid.g2o"
    subprocess.run(
        [str(pgo_bin), "simulate", "--world", "grid2d", "--poses", "60000", "--loops",
         "6000", "--wrong", "600", "--inliers", "--seed", "3", "-o", str(path)],
        check=True, capture_output=True,
    )
    return pgo.read_g2o(path)


@pytest.fixture(scope="module")
def full_iterations(big_graph):
    """The iterations of the big graph's whole job."""
    full = big_graph.optimize()
    assert not full.cancelled
    return full.report["optimizer"]["iterations"]


def test_a_token_cancelled_before_the_job_stops_it_at_once():
    graph = pgo.read_g2o(SAMPLES / "aliased.g2o")
    token = pgo.Cancel()
    assert not token.cancelled and repr(token) == "Cancel(cancelled=False)"
    token.cancel()
    assert token.cancelled
    result = graph.optimize(cancel=token)
    assert result.cancelled and result.status == "cancelled"
    assert result.report["optimizer"]["stop_reason"] == "cancelled"
    assert result.report["optimizer"]["iterations"] == 0
    again = graph.optimize()
    assert not again.cancelled and again.status == "ok"


@pytest.mark.parametrize("job", ["optimize", "update"])
def test_another_thread_cancels_a_running_job(big_graph, full_iterations, job):
    big_graph.forget()
    token = pgo.Cancel()
    timer = threading.Timer(0.1, token.cancel)
    timer.start()
    try:
        result = getattr(big_graph, job)(cancel=token)
    finally:
        timer.cancel()
    assert result.cancelled
    assert result.report["optimizer"]["iterations"] < full_iterations


def test_a_cancelled_update_keeps_the_earlier_state():
    graph = pgo.read_g2o(SAMPLES / "grid2d.g2o")
    graph.update()
    first, last = 0, len(graph) - 1
    graph.add_edge(first, last, (0.0, 0.0, 0.0), [[1, 0, 0], [0, 1, 0], [0, 0, 1]])
    token = pgo.Cancel()
    token.cancel()
    assert graph.update(cancel=token).cancelled
    # The next update starts from the state before the cancelled one: the
    # new edge is still new.
    result = graph.update()
    assert not result.cancelled
    assert result.incremental["new_edges"] == 1
    assert abs(result.chi2 / graph.optimize().chi2 - 1) < 1e-6


def test_ctrl_c_raises_keyboard_interrupt_and_the_graph_stays_usable(big_graph):
    big_graph.forget()
    # Python's own Ctrl-C handler, even where the runner started it with
    # SIGINT ignored (a background job of a shell script).
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    timer = threading.Timer(0.1, lambda: os.kill(os.getpid(), signal.SIGINT))
    timer.start()
    try:
        with pytest.raises(KeyboardInterrupt):
            big_graph.update()
    finally:
        timer.cancel()
        signal.signal(signal.SIGINT, previous)
    result = big_graph.update()
    assert not result.cancelled
    assert result.incremental["solve"] == "batch"


@pytest.mark.parametrize("job", ["optimize", "update"])
def test_progress_sees_every_solver_iteration(job):
    graph = pgo.read_g2o(SAMPLES / "aliased.g2o")
    seen = []
    result = getattr(graph, job)(progress=lambda n, objective: seen.append((n, objective)))
    assert not result.cancelled
    assert [n for n, _ in seen] == list(range(1, len(seen) + 1))
    assert len(seen) >= result.report["optimizer"]["iterations"] > 0
    assert all(isinstance(o, float) and o >= 0.0 for _, o in seen)


def test_an_exception_in_progress_stops_the_job_and_is_raised():
    graph = pgo.read_g2o(SAMPLES / "aliased.g2o")
    calls = []

    def give_up(n, objective):
        calls.append(n)
        raise RuntimeError("enough")

    with pytest.raises(RuntimeError, match="enough"):
        graph.optimize(progress=give_up)
    assert calls == [1]
