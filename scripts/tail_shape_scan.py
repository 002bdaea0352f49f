#!/usr/bin/env python3
"""Would a tail of the χ² shape tell the true loops' reach? (docs/method.md §7)

For every labelled run of a scan (pgo's default job, its report kept by
`bench_robust.py --keep-reports`), takes the accepted loops' innovations
ν² as `s²·χ²_D`, `s²` from their median, and flags those whose Bonferroni
tail `K·P(χ²_D > ν²/s²)` is below α = 0.05 (K accepted loops). Prints, per
run with a flag, the flagged true loops and aliases, then the totals: the
check pgo's outlying test would make with that tail instead of the fitted
log-normal's.

usage: .venv/bin/python scripts/tail_shape_scan.py [WORK_DIR] [--run] [--seeds S ...]
       --run first makes the scan's runs in WORK_DIR (default
       bench-out/tail_scan): intel, manhattan, CSAIL, MIT, kitti_00 and
       parking-garage, seeds 21 and 22 (or those after --seeds), aliases at revisited places in
       groups of 5 (30 % true-like counts), placed anywhere in groups of
       10 (50 %) and scattered one by one (100 %), both information scales.
"""
import csv
import glob
import json
import os
import subprocess
import sys

import numpy as np
from scipy.stats import chi2

ALPHA = 0.05
SETTINGS = [
    ["--alias-place", "revisited", "--alias-group-size", "5", "--alias-true-like", "0.3"],
    ["--alias-place", "anywhere", "--alias-offset", "5,50", "--alias-by-group",
     "--alias-group-size", "10", "--alias-true-like", "0.5"],
    ["--alias-place", "anywhere", "--alias-offset", "5,50", "--alias-by-group",
     "--alias-group-size", "1", "--alias-true-like", "1.0"],
]
DATASETS = ["intel", "manhattan", "CSAIL", "MIT", "kitti_00", "parking-garage"]


def make_runs(work, seeds):
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    for seed in seeds:
        for name in DATASETS:
            for setting in SETTINGS:
                subprocess.run(
                    [sys.executable, os.path.join(root, "scripts/bench_robust.py"), "--tools", "pgo",
                     "--policies", "aliased", "--outliers", "30" if name == "MIT" else "300",
                     "--no-maxmix", "--scales", "calibrated", "published", "--seed", str(seed),
                     "--only", name, "--timeout", "300", "--work", work, "--keep-reports",
                     "--out", os.path.join(work, "scan-%s-%d.json" % (name, seed))] + setting,
                    check=True, stdout=subprocess.DEVNULL, cwd=root)


def wrong_pairs(labels):
    with open(labels) as f:
        return {(int(r["from"]), int(r["to"])) for r in csv.DictReader(f) if r["wrong"] == "1"}


def flagged(report, wrong):
    """(K, s², [(from, to, ν², K·p, wrong)]) of one report's accepted loops."""
    dof = 3 if report["dimension"] == 2 else 6
    acc = [l for l in report["loops"] if l["accepted"] and l.get("innovation")]
    if len(acc) < 8:
        return None
    nu2 = np.array([l["innovation"] for l in acc])
    s2 = np.median(nu2) / chi2.median(dof)
    kp = len(acc) * chi2.sf(nu2 / s2, dof)
    out = [(acc[i]["from"], acc[i]["to"], nu2[i], kp[i], (acc[i]["from"], acc[i]["to"]) in wrong)
           for i in np.argsort(kp) if kp[i] < ALPHA]
    return len(acc), s2, out


def main():
    argv = sys.argv[1:]
    seeds = [21, 22]
    if "--seeds" in argv:
        at = argv.index("--seeds")
        given = [a for a in argv[at + 1:] if a.isdigit()]
        seeds = [int(a) for a in given]
        argv = argv[:at] + argv[at + 1 + len(given):]
    args = [a for a in argv if a != "--run"]
    work = os.path.abspath(args[0] if args else "bench-out/tail_scan")
    if "--run" in sys.argv:
        os.makedirs(work, exist_ok=True)
        make_runs(work, seeds)
    runs = runs_true = runs_wrong = n_true = n_wrong = 0
    for path in sorted(glob.glob(os.path.join(work, "*.report.json"))):
        stem = path[:-len(".report.json")]
        stem = stem[:-len(".cal.g2o")] if stem.endswith(".cal.g2o") else stem[:-len(".g2o")]
        if not os.path.exists(stem + ".labels.csv"):
            continue
        with open(path) as f:
            res = flagged(json.load(f), wrong_pairs(stem + ".labels.csv"))
        if res is None:
            continue
        runs += 1
        k, s2, flags = res
        t = [x for x in flags if not x[4]]
        w = [x for x in flags if x[4]]
        runs_true += bool(t)
        runs_wrong += bool(w)
        n_true += len(t)
        n_wrong += len(w)
        if flags:
            top = ", ".join("%d-%d ν² %.1f K·p %.2g" % x[:4] for x in t[:2])
            print("%-60s K %5d s² %.3f true flagged %4d (%s) aliases flagged %d"
                  % (os.path.basename(path), k, s2, len(t), top, len(w)))
    print("runs %d; true loops flagged in %d runs, %d in all; aliases flagged in %d runs, %d in all"
          % (runs, runs_true, n_true, runs_wrong, n_wrong))


if __name__ == "__main__":
    main()
