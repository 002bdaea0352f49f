#!/usr/bin/env python3
"""The cost of the robust job against a plain solve: a `pgo simulate` world
of --poses poses with 9 % true and 1 % wrong loop candidates (with counts),
optimised with pgo's defaults, and the same world simulated without wrong
candidates optimised with `--gate off --robust none`. Each run under
/usr/bin/time -v; reports LM factorisations, EM's evaluations and chordal
relaxations (from the report), times, peak RSS, and the accepted true and
wrong candidates (from the simulator's labels).

usage: python3 scripts/bench_plain.py [--pgo target/release/pgo] [--poses 100000]
           [--world grid2d|sphere3d] [--work DIR] [--out FILE]
"""
import argparse
import csv
import json
import os
import re
import subprocess
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def timed(cmd):
    start = time.perf_counter()
    out = subprocess.run(["/usr/bin/time", "-v"] + cmd, capture_output=True, text=True)
    wall = time.perf_counter() - start
    if out.returncode not in (0, 3):
        raise RuntimeError("%s failed (%d): %s" % (cmd, out.returncode, out.stderr[-800:]))
    rss = int(re.search(r"Maximum resident set size \(kbytes\): (\d+)", out.stderr).group(1))
    return json.loads(out.stdout), wall, rss * 1024 / 1e6


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--pgo", default=os.path.join(ROOT, "target/release/pgo"))
    ap.add_argument("--poses", type=int, default=100000)
    ap.add_argument("--world", default="grid2d", choices=["grid2d", "sphere3d"])
    ap.add_argument("--work", default=tempfile.gettempdir())
    ap.add_argument("--out", help="default: bench/results/plain_vs_robust_WORLD.json")
    a = ap.parse_args()
    a.out = a.out or os.path.join(ROOT, "bench/results/plain_vs_robust_%s.json" % a.world)
    n, loops, wrong = a.poses, a.poses * 9 // 100, a.poses // 100
    robust_g2o = os.path.join(a.work, "plain-vs-robust-%s-%d.g2o" % (a.world, n))
    labels = os.path.join(a.work, "plain-vs-robust-%s-%d.csv" % (a.world, n))
    plain_g2o = os.path.join(a.work, "plain-%s-%d.g2o" % (a.world, n))
    sim = [a.pgo, "simulate", "--world", a.world, "--poses", str(n), "--loops", str(loops),
           "--inliers", "--seed", "1"]
    subprocess.run(sim + ["--outliers", str(wrong), "--output", robust_g2o, "--labels", labels], check=True)
    subprocess.run(sim + ["--outliers", "0", "--output", plain_g2o], check=True)
    wrong_pairs = {(int(r["from"]), int(r["to"])) for r in csv.DictReader(open(labels)) if r["wrong"] == "1"}
    runs = []
    for name, path, flags in [("robust (defaults)", robust_g2o, []),
                              ("plain (--gate off --robust none, no wrong candidates)", plain_g2o,
                               ["--gate", "off", "--robust", "none"])]:
        r, wall, rss = timed([a.pgo, "optimize", path, "--json", "-q"] + flags)
        accepted = [(l["from"], l["to"]) for l in r["loops"] if l["accepted"]]
        bad = sum(1 for p in accepted if p in wrong_pairs)
        o, rb = r["optimizer"], r["robust"]
        runs.append({"name": name, "factorizations": o["factorizations"], "iterations": o["iterations"],
                     "evaluations": rb.get("decisions", 0), "chordal": rb.get("relaxations", rb.get("rounds", 0)),
                     "optimizer_s": o["time_s"], "wall_s": wall, "rss_mb": rss,
                     "accepted": "%d / %d" % (len(accepted) - bad, bad)})
        print(runs[-1])
    cmd = "python3 scripts/bench_plain.py --world %s --poses %d" % (a.world, n)
    os.makedirs(os.path.dirname(a.out), exist_ok=True)
    json.dump({"command": cmd, "world": a.world, "poses": n, "true_loops": loops, "wrong": wrong, "runs": runs},
              open(a.out, "w"), indent=1)


if __name__ == "__main__":
    main()
