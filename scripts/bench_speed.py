#!/usr/bin/env python3
"""Side-by-side speed: pgo against GTSAM's and g2o's Levenberg-Marquardt on
the standard datasets, in one run, alternating the tools round by round.

usage: .venv/bin/python scripts/bench_speed.py [--rounds 3] [--datasets DIR]
                                               [--only NAME ...] [--out bench-out/speed.json]

Each tool starts from the same initial guess (the file's, odometry composed in
file order where the file has no vertices) with the same stopping rule (at
most 100 iterations, relative decrease of chi2 below 1e-9). Times are each
tool's process-internal optimisation time, never interpreter or process start-up:
GTSAM and g2o: the optimize() call (scripts in ../shared/peers, see
BASELINE.md there); pgo: `optimizer.time_s` of its JSON report (its
spanning-tree initialisation and ordering are set-up, like the peers'
ordering). pgo's default run (chordal initial guess, whose time is included)
is shown as well. The minimum over the rounds is reported.

Peers: ../shared/peers/{gtsam,g2o}_opt.py with the .venv made by
scripts/setup_peers.sh. cubicle: every tool gets the copy whose information
matrices pgo projected to positive definite (`--fix-information`).
"""
import argparse
import json
import os
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
DATASETS = ["intel", "manhattan", "city10000", "sphere2500", "torus3D", "parking-garage", "cubicle"]


def run_json(cmd):
    out = subprocess.run(cmd, capture_output=True, text=True)
    if out.returncode != 0:
        raise RuntimeError("%s failed (%d): %s" % (" ".join(cmd), out.returncode, out.stderr[-500:]))
    return json.loads(out.stdout)


def pgo_run(pgo, path, extra):
    r = run_json([pgo, "optimize", path, "--json", "-q"] + extra)
    o = r["optimizer"]
    return {"iterations": o["iterations"], "chi2": o["final_chi2"], "time": o["time_s"],
            "time_init": r["initialization"]["time_s"], "stop": o["stop_reason"], "timing": o["timing"],
            "nnz_factor": o["nnz_factor"]}


def peer_run(python, peers, script, path):
    r = run_json([python, os.path.join(peers, script), path, "--solver", "lm", "--json"])
    return {"iterations": r.get("iterations"), "chi2": r.get("chi2_g2o_errdef"),
            "time": r.get("time_optimize_s"), "stop": r.get("termination")}


def psd_copy(pgo, src, out_dir):
    """cubicle with projected information matrices, vertices as in the file."""
    dst = os.path.join(out_dir, "cubicle_psd.g2o")
    if not os.path.exists(dst):
        subprocess.run([pgo, "optimize", src, "--fix-information", "--init", "file", "--max-iters", "0",
                        "-o", dst, "-q"], check=True)
    return dst


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--datasets", default=os.environ.get("PGO_DATASETS", os.path.join(ROOT, "../shared/datasets")))
    ap.add_argument("--peers", default=os.path.join(ROOT, "../shared/peers"))
    ap.add_argument("--python", default=os.path.join(ROOT, ".venv/bin/python"))
    ap.add_argument("--pgo", default=os.path.join(ROOT, "target/release/pgo"))
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--only", nargs="*", default=None)
    ap.add_argument("--out", default=os.path.join(ROOT, "bench-out/speed.json"))
    args = ap.parse_args()
    os.makedirs(os.path.dirname(args.out), exist_ok=True)

    tools = {
        "pgo 1 thread (file's guess)": lambda p: pgo_run(args.pgo, p, ["--init", "file", "--threads", "1"]),
        "pgo 2 threads (file's guess)": lambda p: pgo_run(args.pgo, p, ["--init", "file", "--threads", "2"]),
        "pgo default (chordal, 2 threads)": lambda p: pgo_run(args.pgo, p, ["--threads", "2"]),
        "GTSAM LM": lambda p: peer_run(args.python, args.peers, "gtsam_opt.py", p),
        "g2o LM": lambda p: peer_run(args.python, args.peers, "g2o_opt.py", p),
    }
    results = {}
    for name in args.only or DATASETS:
        path = os.path.join(args.datasets, name + ".g2o")
        if not os.path.exists(path):
            print("skipped %s: %s not found" % (name, path), file=sys.stderr)
            continue
        if name == "cubicle":
            path = psd_copy(args.pgo, path, os.path.dirname(args.out))
        runs = {tool: [] for tool in tools}
        for rnd in range(args.rounds):
            for tool, run in tools.items():
                try:
                    r = run(path)
                except RuntimeError as e:
                    r = {"error": str(e)}
                print("%s round %d %s: %s" % (name, rnd + 1, tool,
                                             {k: r.get(k) for k in ("iterations", "chi2", "time", "error")}),
                      file=sys.stderr)
                runs[tool].append(r)
        best = {}
        for tool, rs in runs.items():
            ok = [r for r in rs if "error" not in r]
            best[tool] = min(ok, key=total) if ok else rs[0]
        results[name] = best
    json.dump(results, open(args.out, "w"), indent=1)
    print_table(results)


def total(r):
    return r["time"] + (r.get("time_init") or 0.0)


def print_table(results):
    print("| dataset | tool | iterations | final χ² | time (s) | pgo (file's guess, 2 threads) / tool |")
    print("|---|---|---|---|---|---|")
    for name, best in results.items():
        ref = best.get("pgo 2 threads (file's guess)")
        for tool, r in best.items():
            if "error" in r:
                print("| %s | %s | error | | | |" % (name, tool))
                continue
            ratio = ""
            if ref and "error" not in ref and not tool.startswith("pgo"):
                ratio = "%.2f" % (total(ref) / r["time"]) if r["time"] else ""
            print("| %s | %s | %s | %.10g | %.4f | %s |" % (name, tool, r["iterations"], r["chi2"], total(r), ratio))


if __name__ == "__main__":
    main()
