#!/usr/bin/env python3
"""Measure pgo again on the cases of earlier bench_robust.py results, the
peers' results kept.

usage: .venv/bin/python scripts/remeasure_pgo.py [--pgo PATH] [--keep-earlier-on-error]
           --earlier DIR RESULT.json [RESULT.json ...]

Each RESULT.json (a file bench_robust.py wrote: bench/results/...) is copied
into DIR, then bench_robust.py runs again with the options recorded in it,
`--tools pgo` and the peers it ran, and `--peers-from` the copy: only pgo
runs (a peer's result on a file depends on nothing pgo does, and
bench_robust.py checks the cases are the same), and RESULT.json is written
anew. The results of pgo's other variants in the earlier run ("pgo soft",
"pgo huber", ...) are kept as they were, and so is the file's recorded
`--peers-from`, so that the command docs/benchmarks.md shows is still the
one that makes the peers' results. A file whose copy is already in DIR is
not run again, so a long re-measurement can be stopped and resumed.

With --keep-earlier-on-error, a case where pgo now fails (its time limit)
keeps pgo's earlier result on it, and the script says which.
Then `python3 scripts/benchmarks_md.py` writes docs/benchmarks.md.
"""
import argparse
import json
import os
import shutil
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "scripts"))
from bench_robust import PEER_TOOLS  # noqa: E402


def command(args, recorded, earlier, out):
    """bench_robust.py's command for the cases `recorded` (a result's args)."""
    a = recorded
    tools = ["pgo"] + [t for t in a["tools"] if t in PEER_TOOLS]
    cmd = [sys.executable, os.path.join(ROOT, "scripts/bench_robust.py"), "--tools", *tools,
           "--policies", *a["policies"], "--outliers", *map(str, a["outliers"]),
           "--scales", *a["scales"], "--seed", str(a["seed"]), "--timeout", str(a["timeout"]),
           "--work", a["work"], "--out", out, "--pgo", args.pgo, "--peers-from", earlier,
           "--alias-group-size", str(a["alias_group_size"]),
           "--alias-true-like", str(a["alias_true_like"]),
           "--alias-place", a.get("alias_place", "revisited")]
    if a.get("only"):
        cmd += ["--only", *a["only"]]
    if not a.get("maxmix", True):
        cmd += ["--no-maxmix"]
    if a.get("alias_by_group"):
        cmd += ["--alias-by-group"]
    if a.get("alias_offset"):
        cmd += ["--alias-offset", a["alias_offset"]]
    if a.get("gnc_rel_tol"):
        cmd += ["--gnc-rel-tol", str(a["gnc_rel_tol"])]
    if a.get("pgo_flags"):
        cmd += ["--pgo-flags", *a["pgo_flags"]]
    return cmd


def merge(path, before, keep_on_error):
    """Puts back what the new run of `path` does not measure (module doc)."""
    new = json.load(open(path))
    by_case = {(r["case"], r["scale"]): r for r in before["results"]}
    for r in new["results"]:
        old = by_case[(r["case"], r["scale"])]["tools"]
        if keep_on_error and "error" in r["tools"]["pgo"] and "pgo" in old:
            print("  kept pgo's earlier result on %s (%s): %s" % (
                r["case"], r["scale"], r["tools"]["pgo"]["error"][:100]), flush=True)
            r["tools"]["pgo"] = old["pgo"]
        for tool, res in old.items():
            r["tools"].setdefault(tool, res)
    new["args"]["tools"] = before["args"]["tools"]
    new["args"]["peers_from"] = before["args"].get("peers_from")
    with open(path, "w") as f:
        json.dump(new, f, indent=1)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--pgo", default=os.path.join(ROOT, "target/release/pgo"))
    ap.add_argument("--earlier", required=True, help="where the earlier results are copied")
    ap.add_argument("--keep-earlier-on-error", action="store_true")
    ap.add_argument("results", nargs="+")
    args = ap.parse_args()
    os.makedirs(args.earlier, exist_ok=True)
    for path in args.results:
        copy = os.path.join(args.earlier, os.path.relpath(os.path.abspath(path), ROOT).replace("/", "__"))
        if os.path.exists(copy):
            print("already measured:", path, flush=True)
            continue
        shutil.copy(path, copy + ".tmp")
        before = json.load(open(copy + ".tmp"))
        p = subprocess.run(command(args, before["args"], copy + ".tmp", path), cwd=ROOT,
                           capture_output=True, text=True)
        if p.returncode != 0:
            print("FAILED", path, p.stderr[-500:], flush=True)
            shutil.copy(copy + ".tmp", path)
            os.remove(copy + ".tmp")
            continue
        merge(path, before, args.keep_earlier_on_error)
        os.rename(copy + ".tmp", copy)
        print("measured:", path, flush=True)


if __name__ == "__main__":
    main()
