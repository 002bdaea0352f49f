#!/usr/bin/env python3
"""How pgo's time and memory grow with the size of the graph, and what the
robust job costs against a plain solve of the same world.

For each world (2D grid, 3D sphere) and size, `pgo simulate` makes two
graphs from one seed: one with loop-closure candidates on 10 % of the
poses (9 % true, 1 % wrong, all with inlier counts), and the same world
without its wrong candidates. The first is optimised by `pgo optimize`
with its defaults (gate, chordal guess, robust EM), the second by a plain
solve (`--gate off --robust none`), each once per --threads value under
/usr/bin/time -v.

usage: .venv/bin/python scripts/bench_scale.py [--sizes 1e4 1e5 1e6]
           [--worlds grid2d sphere3d] [--threads 1 2] [--work DIR]
           [--out bench-out/scale.json] [--svg docs/scaling.svg] [--plot-only]

Needs a release build and matplotlib (in the peers' .venv). The graphs
(about 0.5 GB for 10^6 poses in 3D) go to --work (default: the system's
temporary directory), never into the repository; a graph already there is
reused. Reported per run: the whole command's wall time (read, gate,
initial guess, optimisation, report), the optimiser's time, LM iterations
and factorisations, EM's chordal relaxations and evaluations (count and
seconds), peak RSS, the largest Cholesky factor (max_nnz_factor x 8 bytes),
the accepted true and wrong candidates (from the simulator's labels), and
whether the map passed its χ² test.
--plot-only redraws the SVG from the JSON.
"""
import argparse
import csv
import json
import os
import re
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
PLAIN_FLAGS = ["--gate", "off", "--robust", "none"]


def simulate(pgo, world, poses, wrong, path, labels=None):
    """The world's graph with `wrong` wrong candidates (its labels to `labels`)."""
    if os.path.exists(path) and (labels is None or os.path.exists(labels)):
        return
    cmd = [pgo, "simulate", "--world", world, "--poses", str(poses), "--loops", str(poses * 9 // 100),
           "--outliers", str(wrong), "--inliers", "--seed", "1", "--output", path]
    subprocess.run(cmd + (["--labels", labels] if labels else []), check=True, capture_output=True)


def wrong_pairs(labels):
    return {(int(r["from"]), int(r["to"])) for r in csv.DictReader(open(labels)) if r["wrong"] == "1"}


def optimize(pgo, path, threads, flags, wrong):
    """One timed `pgo optimize` run, summarised from its report."""
    start = time.perf_counter()
    out = subprocess.run(["/usr/bin/time", "-v", pgo, "optimize", path, "--json", "-q",
                          "--threads", str(threads)] + flags,
                         capture_output=True, text=True)
    wall = time.perf_counter() - start
    # Exit status 3: the map failed its χ² test (recorded; at α = 0.05 a
    # correct map of a simulated world fails one time in twenty).
    if out.returncode not in (0, 3):
        raise RuntimeError("pgo optimize %s failed (%d): %s" % (path, out.returncode, out.stderr[-800:]))
    r = json.loads(out.stdout)
    rss_kb = int(re.search(r"Maximum resident set size \(kbytes\): (\d+)", out.stderr).group(1))
    o, rb = r["optimizer"], r["robust"]
    accepted = [(l["from"], l["to"]) for l in r["loops"] if l["accepted"]]
    bad = sum(1 for p in accepted if p in wrong)
    return {"poses": r["poses"], "edges": r["edges"], "candidates": r["loop_candidates"], "threads": threads,
            "optimizer_s": o["time_s"], "init_s": r["initialization"]["time_s"], "wall_s": wall,
            "rss_mb": rss_kb * 1024 / 1e6, "factor_mb": o["max_nnz_factor"] * 8 / 1e6,
            "iterations": o["iterations"], "factorizations": o["factorizations"],
            "final_objective": o["final_objective"],
            "relaxations": rb.get("relaxations", 0), "decisions": rb.get("decisions", 0),
            "time": r.get("time"), "chi2_passed": r["chi2_test"]["passed"], "accepted_true": len(accepted) - bad, "accepted_wrong": bad}


def plot(results, svg):
    import matplotlib
    matplotlib.use("svg")
    import matplotlib.pyplot as plt
    fig, (ax_t, ax_m) = plt.subplots(1, 2, figsize=(9, 3.8))
    for world, marker, colour in (("grid2d", "o", "C0"), ("sphere3d", "s", "C1")):
        rows = sorted((r for r in results if r["world"] == world and r["threads"] == 1),
                      key=lambda r: r["robust"]["poses"])
        if not rows:
            continue
        n = [r["robust"]["poses"] for r in rows]
        for run, style in (("robust", "-"), ("plain", ":")):
            for ax, key in ((ax_t, "wall_s"), (ax_m, "rss_mb")):
                ax.loglog(n, [r[run][key] for r in rows], marker + style, color=colour,
                          label="%s: %s" % (world, run))
    for ax, label, title in ((ax_t, "seconds", "pgo optimize, wall time"), (ax_m, "MB", "peak RSS")):
        ax.set_xlabel("poses")
        ax.set_ylabel(label)
        ax.set_title(title)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    fig.suptitle("pgo simulate worlds, one thread: robust job (10 % candidates, 1 % wrong) "
                 "and plain solve (no wrong candidates)", fontsize=9)
    fig.tight_layout()
    os.makedirs(os.path.dirname(os.path.abspath(svg)), exist_ok=True)
    fig.savefig(svg, metadata={"Date": None})


def run_world(args, world, size, results):
    poses = int(float(size))
    stem = os.path.join(args.work, "pgo-scale-%s-%d" % (world, poses))
    simulate(args.pgo, world, poses, poses // 100, stem + ".g2o", stem + ".labels.csv")
    simulate(args.pgo, world, poses, 0, stem + "-plain.g2o")
    wrong = wrong_pairs(stem + ".labels.csv")
    for threads in args.threads:
        row = {"world": world, "threads": threads,
               "robust": optimize(args.pgo, stem + ".g2o", threads, [], wrong),
               "plain": optimize(args.pgo, stem + "-plain.g2o", threads, PLAIN_FLAGS, set())}
        print("%s %d poses, %d threads: robust %.1f s %.0f MB, plain %.1f s %.0f MB" % (
            world, poses, threads, row["robust"]["wall_s"], row["robust"]["rss_mb"],
            row["plain"]["wall_s"], row["plain"]["rss_mb"]), file=sys.stderr)
        same = lambda x: (x["world"], x["robust"]["poses"], x["threads"]) == (world, poses, threads)
        results = [x for x in results if not same(x)] + [row]
        json.dump(results, open(args.out, "w"), indent=1)
    return results


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
    if not args.plot_only:
        os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
        os.makedirs(args.work, exist_ok=True)
        results = json.load(open(args.out)) if os.path.exists(args.out) else []
        for world in args.worlds:
            for size in args.sizes:
                results = run_world(args, world, size, results)
    plot(json.load(open(args.out)), args.svg)


if __name__ == "__main__":
    main()
