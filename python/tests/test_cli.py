"""read_g2o(f).optimize() is `pgo optimize f`: the same poses, the same
loop decisions, the same report."""

import json

import pytest

import pgo
from conftest import SAMPLES, TOLERANCE, assert_close, run_cli

CASES = [(path.name, ()) for path in sorted(SAMPLES.glob("*.g2o"))] + [
    ("grid2d.g2o", ("--gate", "off", "--robust", "none")),
    ("sphere3d.g2o", ("--gate", "40", "--robust-c", "3.5", "--expert", "no-clusters")),
]


def as_options(flags):
    """Command-line flags as optimize's keyword arguments."""
    options, k = {}, 0
    while k < len(flags):
        name = flags[k][2:].replace("-", "_")
        if k + 1 < len(flags) and not flags[k + 1].startswith("--"):
            options[name] = flags[k + 1]
            k += 2
        else:
            options[name] = True
            k += 1
    return options


# What differs between two runs of the same job, of the CLI as of the
# library: file names, wall-clock durations (the `timing` blocks and the
# keys in seconds, `..._s`, at any depth) and the sizes of the sparse
# system (`nnz_...`: two runs of `pgo optimize g2o_samples/degenerate.g2o`
# report nnz_hessian 6102, 6192 or 7812).
RUN_DEPENDENT = {"input", "output", "timing"}


def run_dependent(key):
    """Whether a report's key is RUN_DEPENDENT."""
    return key in RUN_DEPENDENT or key.endswith("_s") or "nnz" in key


def without_run_details(report):
    """The report without its run-dependent keys, at any depth."""
    if isinstance(report, dict):
        return {k: without_run_details(v) for k, v in report.items() if not run_dependent(k)}
    if isinstance(report, list):
        return [without_run_details(v) for v in report]
    return report


@pytest.mark.parametrize("name,flags", CASES)
def test_optimize_is_the_command_line(name, flags, pgo_bin, tmp_path):
    out = tmp_path / "out.g2o"
    cli_report = json.loads(run_cli(pgo_bin, SAMPLES / name, out, *flags))
    result = pgo.read_g2o(SAMPLES / name).optimize(**as_options(flags))

    cli_poses = pgo.read_g2o(out)
    assert cli_poses.ids == list(result.poses)
    for id_, pose in result.poses.items():
        assert max(abs(a - b) for a, b in zip(pose, cli_poses.pose(id_))) <= TOLERANCE

    assert len(result.loops) == len(cli_report["loops"])
    for mine, theirs in zip(result.loops, cli_report["loops"]):
        assert (mine["from"], mine["to"], mine["inliers"]) == (
            theirs["from"], theirs["to"], theirs["inliers"])
        assert abs(mine["weight"] - theirs["weight"]) <= TOLERANCE
        assert mine["reason"] == theirs["reason"]
        for key in ("posterior", "innovation"):
            a, b = mine[key], theirs[key]
            assert (a is None) == (b is None), (key, a, b)
            assert a is None or abs(a - b) <= TOLERANCE * max(1.0, abs(b)), (key, a, b)
    assert_close(without_run_details(result.report), without_run_details(cli_report), "report")
