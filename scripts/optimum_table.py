#!/usr/bin/env python3
"""The optimum table of the README: pgo's final chi2 on the standard datasets
against the lowest chi2 that g2o or GTSAM reached (LM or GN, from the file's
own guess), in g2o's error definition.

usage: scripts/optimum_table.py [--datasets DIR] [--peers DIR] [--pgo BIN]

The peers' numbers come from their recorded runs in
../shared/peers/results/baseline_{lm,gn}.json (see BASELINE.md there, which
also says how to re-run them); pgo is run here, once with its default
initial guess (chordal) and once from the file's guess (--init file).
Standard library only.
"""
import argparse
import json
import os
import subprocess
import sys

DATASETS = ["intel", "manhattan", "city10000", "kitti_00", "CSAIL", "MIT",
            "sphere2500", "torus3D", "parking-garage"]


def best_peer(results_dir, name):
    best = None
    for run in ("baseline_lm.json", "baseline_gn.json"):
        path = os.path.join(results_dir, run)
        if not os.path.exists(path):
            continue
        entry = json.load(open(path)).get(name, {})
        for peer in ("gtsam", "g2o"):
            r = entry.get(peer, {})
            chi2 = r.get("chi2_g2o_errdef")
            if r.get("status", "ok") == "ok" and isinstance(chi2, (int, float)):
                label = "%s %s" % ("GTSAM" if peer == "gtsam" else "g2o", "LM" if "lm" in run else "GN")
                if best is None or chi2 < best[0]:
                    best = (chi2, label)
    return best


def run_pgo(binary, path, extra):
    out = subprocess.run([binary, "optimize", path, "--json", "-q"] + extra,
                         capture_output=True, text=True, check=True)
    return json.loads(out.stdout)


def main():
    here = os.path.dirname(os.path.abspath(__file__))
    root = os.path.dirname(here)
    ap = argparse.ArgumentParser()
    ap.add_argument("--datasets", default=os.environ.get("PGO_DATASETS", os.path.join(root, "../shared/datasets")))
    ap.add_argument("--peers", default=os.path.join(root, "../shared/peers/results"))
    ap.add_argument("--pgo", default=os.path.join(root, "target/release/pgo"))
    args = ap.parse_args()
    print("| file | best peer χ² (who) | pgo χ² (chordal init) | its./time | pgo χ² (file's guess) | its./time | pgo ≤ (1+1e-5)·peer |")
    print("|---|---|---|---|---|---|---|")
    ok = True
    for name in DATASETS:
        path = os.path.join(args.datasets, name + ".g2o")
        if not os.path.exists(path):
            print("| %s | (dataset not found) | | | | | |" % name)
            continue
        peer = best_peer(args.peers, name)
        a = run_pgo(args.pgo, path, [])
        b = run_pgo(args.pgo, path, ["--init", "file"])
        ca, cb = a["optimizer"]["final_chi2"], b["optimizer"]["final_chi2"]
        verdict = "n/a"
        if peer:
            good = ca <= peer[0] * (1 + 1e-5)
            ok &= good
            verdict = "yes" if good else "**no**"
        t = lambda r: "%d / %.3f s" % (r["optimizer"]["iterations"],
                                       r["optimizer"]["time_s"] + r["initialization"]["time_s"])
        print("| %s | %s | %.10g | %s | %.10g | %s | %s |" % (
            name, "%.10g (%s)" % peer if peer else "n/a", ca, t(a), cb, t(b), verdict))
    sys.exit(0 if ok else 1)


if __name__ == "__main__":
    main()
