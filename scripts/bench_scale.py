#!/usr/bin/env python3
"""How pgo's time and memory grow with the size of the graph: `pgo simulate`
graphs of 10^4, 10^5 and 10^6 poses (2D grid world, 3D sphere world) with
loop-closure candidates on 10 % of the poses (9 % true, 1 % wrong, all with
inlier counts), each optimised once by `pgo optimize` with its defaults
(gate, chordal guess, robust EM) and --threads (default 1) under
/usr/bin/time -v.

usage: .venv/bin/python scripts/bench_scale.py [--sizes 1e4 1e5 1e6]
           [--worlds grid2d sphere3d] [--threads 1 2] [--work DIR] [--out bench-out/scale.json]
           [--svg docs/scaling.svg] [--plot-only]

Needs a release build and matplotlib (in the peers' .venv). The graphs
(up to ~230 MB for 10^6 poses in 2D) go to --work (default: the system's
temporary directory), never into the repository. Reported per graph:
optimiser time (`optimizer.time_s`), EM's chordal relaxations and
evaluations (count and seconds, the report's `time`), the whole command's
wall time (read, gate, initial guess, optimisation, report), peak RSS, the Cholesky factor's
size (max_nnz_factor x 8 bytes: the largest factor of the run, the first
pattern before robust weighting removed loops; the last one in parentheses),
iterations and factorisations. --plot-only
redraws the SVG and prints the table from the JSON.
"""
import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)


def simulate(pgo, world, poses, path):
    if os.path.exists(path):
        return
    loops = poses * 9 // 100
    outliers = poses // 100
    subprocess.run([pgo, "simulate", "--world", world, "--poses", str(poses), "--loops", str(loops),
                    "--outliers", str(outliers), "--inliers", "--seed", "1", "--output", path],
                   check=True, capture_output=True)


def optimize(pgo, path, threads):
    start = time.perf_counter()
    out = subprocess.run(["/usr/bin/time", "-v", pgo, "optimize", path, "--json", "-q",
                          "--threads", str(threads)],
                         capture_output=True, text=True)
    wall = time.perf_counter() - start
    if out.returncode != 0:
        raise RuntimeError("pgo optimize %s failed (%d): %s" % (path, out.returncode, out.stderr[-800:]))
    r = json.loads(out.stdout)
    rss_kb = int(re.search(r"Maximum resident set size \(kbytes\): (\d+)", out.stderr).group(1))
    o = r["optimizer"]
    return {"poses": r["poses"], "edges": r["edges"], "candidates": r["loop_candidates"], "threads": threads,
            "optimizer_s": o["time_s"], "init_s": r["initialization"]["time_s"], "wall_s": wall,
            "rss_mb": rss_kb * 1024 / 1e6, "factor_mb": o["max_nnz_factor"] * 8 / 1e6,
            "last_factor_mb": o["nnz_factor"] * 8 / 1e6,
            "iterations": o["iterations"], "factorizations": o["factorizations"],
            "timing": o["timing"], "final_objective": o["final_objective"],
            "robust_rounds": r["robust"]["rounds"], "kept": r["gate"].get("kept"),
            "relaxations": r["robust"].get("relaxations"), "decisions": r["robust"].get("decisions"),
            "time": r.get("time")}


def plot(results, svg):
    import matplotlib
    matplotlib.use("svg")
    import matplotlib.pyplot as plt
    fig, (ax_t, ax_m) = plt.subplots(1, 2, figsize=(9, 3.8))
    for world, marker in (("grid2d", "o"), ("sphere3d", "s")):
        # One curve per world: its single-threaded runs.
        rows = sorted((r for r in results if r["world"] == world and r.get("threads", 1) == 1),
                      key=lambda r: r["poses"])
        if not rows:
            continue
        n = [r["poses"] for r in rows]
        ax_t.loglog(n, [r["wall_s"] for r in rows], marker + "-", label="%s: pgo optimize (wall)" % world)
        ax_t.loglog(n, [r["optimizer_s"] for r in rows], marker + "--", label="%s: optimiser" % world)
        ax_m.loglog(n, [r["rss_mb"] for r in rows], marker + "-", label="%s: peak RSS" % world)
        ax_m.loglog(n, [r["factor_mb"] for r in rows], marker + "--", label="%s: largest Cholesky factor" % world)
    for ax, label in ((ax_t, "seconds"), (ax_m, "MB")):
        ax.set_xlabel("poses")
        ax.set_ylabel(label)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    ax_t.set_title("time")
    ax_m.set_title("memory")
    fig.suptitle("pgo optimize on pgo simulate graphs (10 % loop candidates, 1 % wrong)", fontsize=9)
    fig.tight_layout()
    os.makedirs(os.path.dirname(svg), exist_ok=True)
    fig.savefig(svg, metadata={"Date": None})


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--pgo", default=os.path.join(ROOT, "target/release/pgo"))
    ap.add_argument("--sizes", nargs="*", default=["1e4", "1e5", "1e6"])
    ap.add_argument("--worlds", nargs="*", default=["grid2d", "sphere3d"])
    ap.add_argument("--threads", nargs="*", type=int, default=[1],
                    help="run each graph once per thread count (pgo's --threads)")
    ap.add_argument("--work", default=tempfile.gettempdir())
    ap.add_argument("--out", default=os.path.join(ROOT, "bench-out/scale.json"))
    ap.add_argument("--svg", default=os.path.join(ROOT, "docs/scaling.svg"))
    ap.add_argument("--plot-only", action="store_true")
    args = ap.parse_args()
    if args.plot_only:
        results = json.load(open(args.out))
        plot(results, args.svg)
        table(results)
        return
    os.makedirs(os.path.dirname(args.out), exist_ok=True)
    results = json.load(open(args.out)) if os.path.exists(args.out) else []
    for world in args.worlds:
        for size in args.sizes:
            poses = int(float(size))
            path = os.path.join(args.work, "pgo-scale-%s-%d.g2o" % (world, poses))
            simulate(args.pgo, world, poses, path)
            for threads in args.threads:
                r = optimize(args.pgo, path, threads)
                r["world"] = world
                print("%s %d poses, %d threads: %s" % (world, poses, threads, {k: r[k] for k in (
                    "wall_s", "optimizer_s", "rss_mb", "factor_mb", "iterations", "factorizations")}),
                      file=sys.stderr)
                same = lambda x: (x["world"], x["poses"], x.get("threads", 1)) == (world, r["poses"], threads)
                results = [x for x in results if not same(x)] + [r]
                json.dump(results, open(args.out, "w"), indent=1)
    plot(results, args.svg)
    table(results)


def table(results):
    """The results as a Markdown table on stdout."""
    print("| world | poses | edges | candidates | threads | pgo optimize wall (s) | optimiser (s) | iterations / "
          "factorisations | peak RSS (MB) | largest (last) factor (MB) | RSS / factor |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for r in sorted(results, key=lambda r: (r["world"], r["poses"], r.get("threads", 1))):
        print("| %s | %d | %d | %d | %d | %.2f | %.2f | %d / %d | %.0f | %.0f (%.0f) | %.2f |" % (
            r["world"], r["poses"], r["edges"], r["candidates"], r.get("threads", 1), r["wall_s"], r["optimizer_s"],
            r["iterations"], r["factorizations"], r["rss_mb"], r["factor_mb"], r.get("last_factor_mb", r["factor_mb"]),
            r["rss_mb"] / r["factor_mb"]))


if __name__ == "__main__":
    main()
