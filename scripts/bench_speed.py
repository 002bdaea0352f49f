#!/usr/bin/env python3
"""Side-by-side speed: pgo against GTSAM's and g2o's Levenberg-Marquardt on
the standard datasets, in one run, alternating the tools round by round.

usage: .venv/bin/python scripts/bench_speed.py [--rounds 3] [--datasets DIR]
           [--only NAME ...] [--out bench-out/speed.json]

Needs a release build (cargo build --release) and the peers' virtual
environment (scripts/setup_peers.sh makes .venv with gtsam and g2opy; the
peer drivers are ../shared/peers/{gtsam,g2o}_opt.py, see BASELINE.md there).

Protocol. Every tool starts from the file's initial guess (vertices without
a line: odometry composed in file order) with the same stopping rule: at most
100 iterations, stop when the relative decrease of chi2 in an iteration is
below 1e-9. Times are each tool's process-internal optimisation time, never
interpreter or process start-up: for GTSAM and g2o the optimize() call; for
pgo `optimizer.time_s` of its JSON report (its ordering and symbolic
factorisation are set-up, like GTSAM's ordering). The minimum over the rounds
is reported. pgo runs three ways: the file's guess with 1 thread (like the
peers, which are single-threaded), the file's guess with 2 threads, and its
default (chordal initial guess, all threads), whose time includes the
initial guess. cubicle: every tool gets the copy whose information matrices
pgo projected to positive definite (`--fix-information`).

chi2 is compared in g2o's error definition (BASELINE.md caveat 2): GTSAM
minimises another objective in 3D, so its column is its final poses scored
with g2o's error (`chi2_g2o_errdef`). "chi2 ok" says whether pgo's final chi2
is within (1 + 1e-5) of the lower of the peers'.

Also reported per dataset: pgo's peak RSS (/usr/bin/time -v, 1-thread run)
against the size of its Cholesky factor (nnz_factor x 8 bytes), and how one
iteration splits between linearisation (errors, Jacobians, assembly),
factorisation, triangular solves and evaluation of the trial point.
"""
import argparse
import json
import os
import re
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
DATASETS = ["intel", "manhattan", "city10000", "sphere2500", "torus3D", "parking-garage", "cubicle"]
TOL = 1e-5


def run_json(cmd):
    out = subprocess.run(cmd, capture_output=True, text=True)
    if out.returncode != 0:
        raise RuntimeError("%s failed (%d): %s" % (" ".join(cmd), out.returncode, out.stderr[-500:]))
    return json.loads(out.stdout), out.stderr


def pgo_run(pgo, path, extra, rss=False):
    cmd = [pgo, "optimize", path, "--json", "-q"] + extra
    if rss:
        cmd = ["/usr/bin/time", "-v"] + cmd
    r, err = run_json(cmd)
    o = r["optimizer"]
    res = {"iterations": o["iterations"], "chi2": o["final_chi2"], "time": o["time_s"],
           "time_init": r["initialization"]["time_s"], "stop": o["stop_reason"], "timing": o["timing"],
           "factorizations": o["factorizations"], "nnz_factor": o["max_nnz_factor"]}
    m = re.search(r"Maximum resident set size \(kbytes\): (\d+)", err)
    if m:
        res["rss_mb"] = int(m.group(1)) * 1024 / 1e6
    return res


def peer_run(python, peers, script, path):
    r, _ = run_json([python, os.path.join(peers, script), path, "--solver", "lm", "--json"])
    return {"iterations": r.get("iterations"), "chi2": r.get("chi2_g2o_errdef"),
            "time": r.get("time_optimize_s"), "stop": r.get("termination")}


def psd_copy(pgo, src, out_dir):
    """cubicle with projected information matrices, vertices as in the file."""
    dst = os.path.join(out_dir, "cubicle_psd.g2o")
    if not os.path.exists(dst):
        subprocess.run([pgo, "optimize", src, "--fix-information", "--init", "file", "--max-iters", "0",
                        "-o", dst, "-q"], check=True)
    return dst


TOOLS = ["pgo file 1t", "pgo file 2t", "pgo default", "GTSAM LM", "g2o LM"]


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
        "pgo file 1t": lambda p, first: pgo_run(args.pgo, p, ["--init", "file", "--threads", "1"], rss=first),
        "pgo file 2t": lambda p, first: pgo_run(args.pgo, p, ["--init", "file", "--threads", "2"]),
        "pgo default": lambda p, first: pgo_run(args.pgo, p, []),
        "GTSAM LM": lambda p, first: peer_run(args.python, args.peers, "gtsam_opt.py", p),
        "g2o LM": lambda p, first: peer_run(args.python, args.peers, "g2o_opt.py", p),
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
                    r = run(path, rnd == 0)
                except RuntimeError as e:
                    r = {"error": str(e)}
                print("%s round %d %s: %s" % (name, rnd + 1, tool,
                                             {k: r.get(k) for k in ("iterations", "chi2", "time", "error")}),
                      file=sys.stderr)
                runs[tool].append(r)
        best = {}
        for tool, rs in runs.items():
            ok = [r for r in rs if "error" not in r]
            best[tool] = dict(min(ok, key=total)) if ok else rs[0]
            rss = [r["rss_mb"] for r in ok if "rss_mb" in r]
            if rss:
                best[tool]["rss_mb"] = rss[0]
        results[name] = best
    json.dump(results, open(args.out, "w"), indent=1)
    print_tables(results)


def total(r):
    return r["time"] + (r.get("time_init") or 0.0)


def fmt_time(r):
    return "%.3f" % total(r) if "error" not in r else "error"


def print_tables(results):
    print("| dataset | pgo, file's guess, 1 thread: it. / χ² / s | 2 threads: s | pgo default (chordal): it. / χ² / s "
          "| GTSAM LM: it. / χ² (g2o def.) / s | g2o LM: it. / χ² / s | pgo 1 thread / GTSAM | / g2o "
          "| pgo default / GTSAM | / g2o | χ² ok (file / default) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for name, b in results.items():
        p1, p2, pd, gt, go = (b.get(t, {"error": "missing"}) for t in TOOLS)
        peers = [r["chi2"] for r in (gt, go) if "error" not in r and r.get("chi2") is not None]
        low = min(peers) if peers else float("nan")

        def cell(r, chi=True):
            if "error" in r:
                return "error"
            return "%s / %.10g / %s" % (r["iterations"], r["chi2"], fmt_time(r)) if chi else fmt_time(r)

        def ratio(a, c):
            if "error" in a or "error" in c or not c["time"]:
                return ""
            return "%.2f" % (total(a) / c["time"])

        def ok(r):
            return "yes" if "error" not in r and r["chi2"] <= (1 + TOL) * low else "no"

        print("| %s | %s | %s | %s | %s | %s | %s | %s | %s | %s | %s / %s |" % (
            name, cell(p1), cell(p2, False), cell(pd), cell(gt), cell(go),
            ratio(p1, gt), ratio(p1, go), ratio(pd, gt), ratio(pd, go), ok(p1), ok(pd)))
    print()
    print("| dataset | iterations / factorisations | linearise + assemble | factorise | solve | evaluate "
          "| one iteration / one factorisation | factor (MB) | peak RSS (MB) | RSS / factor |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for name, b in results.items():
        r = b.get("pgo file 1t", {"error": "missing"})
        if "error" in r:
            continue
        t, it, nf = r["timing"], max(r["iterations"], 1), max(r["factorizations"], 1)
        per_fact = t["factorize_s"] / nf
        factor_mb = r["nnz_factor"] * 8 / 1e6
        rss = r.get("rss_mb")
        print("| %s | %d / %d | %.2f ms | %.2f ms | %.2f ms | %.2f ms | %.2f | %.1f | %s | %s |" % (
            name, r["iterations"], r["factorizations"], 1e3 * t["linearize_s"] / it, 1e3 * per_fact,
            1e3 * t["solve_s"] / nf, 1e3 * t["evaluate_s"] / nf, r["time"] / it / per_fact, factor_mb,
            "%.1f" % rss if rss else "", "%.2f" % (rss / factor_mb) if rss else ""))


if __name__ == "__main__":
    main()
