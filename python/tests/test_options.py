"""Options pass through to the library by their command-line names."""

import pytest

import pgo
from conftest import SAMPLES, assert_close, assert_same_result


@pytest.fixture(scope="module")
def grid():
    return pgo.read_g2o(SAMPLES / "grid2d.g2o")


@pytest.fixture(scope="module")
def default(grid):
    return grid.optimize()


def test_option_names_are_the_flags():
    names = pgo.option_names()
    for name in ["gate", "robust", "robust-c", "max-iters", "alpha", "expert"]:
        assert name in names


def test_gate_off_keeps_every_candidate(grid, default):
    assert not all(d["kept"] for d in default.loops)
    assert all(d["kept"] for d in grid.optimize(gate="off").loops)


def test_gate_threshold_as_an_int(grid):
    loops = grid.optimize(gate=200).loops
    assert all(d["kept"] == (d["inliers"] >= 200) for d in loops)


def test_robust_none_accepts_what_the_gate_keeps(grid, default):
    loops = grid.optimize(robust="none").loops
    assert all(d["accepted"] == d["kept"] and d["weight"] in (0.0, 1.0) for d in loops)
    assert {d["reason"] for d in loops} == {"trusted", "dropped"}
    assert [d["accepted"] for d in loops] != [d["accepted"] for d in default.loops]


def test_reasons_are_snake_case_names(default):
    reasons = {d["reason"] for d in default.loops}
    assert len(reasons) > 1
    assert all(r.isidentifier() and r == r.lower() for r in reasons)


def test_expert_layers_switch_off(grid, default):
    def aliasing_rate(result):
        return result.report["robust"]["model"]["aliasing_rate"]

    assert aliasing_rate(default) > 0
    assert aliasing_rate(grid.optimize(expert="no-aliasing")) == 0
    assert_close(grid.optimize(expert="").loops, default.loops)


def test_float_option(grid):
    narrow = grid.optimize(robust="cauchy", robust_c=1.0)
    wide = grid.optimize(robust="cauchy")
    change = [abs(a["weight"] - b["weight"]) for a, b in zip(narrow.loops, wide.loops)]
    assert max(change) > 0.1


def test_none_leaves_the_default(grid, default):
    assert_same_result(grid.optimize(robust_c=None, gate=None), default)


def test_kebab_and_snake_names_agree(grid, default):
    snake = grid.optimize(max_iters=3)
    kebab = grid.optimize(**{"max-iters": 3})
    assert_same_result(snake, kebab)
    moved = max(abs(a - b) for i in default.poses for a, b in zip(snake.poses[i], default.poses[i]))
    assert moved > 1e-6


def test_alpha_changes_the_verdict_not_the_decisions(grid, default):
    # A failed test makes the job search for loops that explain it; here
    # none does, and the decisions (and the map, to the solver's tolerance)
    # stay.
    strict = grid.optimize(alpha=0.9)
    assert [d["accepted"] for d in strict.loops] == [d["accepted"] for d in default.loops]
    for k, pose in default.poses.items():
        assert all(abs(a - b) <= 1e-6 * max(1.0, abs(a)) for a, b in zip(strict.poses[k], pose))
    assert (default.verdict, strict.verdict) == ("passed", "failed")
    assert (default.status, strict.status) == ("ok", "chi2_failed")
    assert strict.passed is False


def test_a_map_nothing_questions_names_no_loop(default):
    # The report's three checks of a passing map (docs/method.md §7) are
    # lists, empty where the status is "ok".
    robust = default.report["robust"]
    assert default.status == "ok"
    for check in ("doubtful", "held_back", "outlying"):
        assert robust[check] == [], check
