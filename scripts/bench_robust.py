#!/usr/bin/env python3
"""Outlier benchmark: pgo's gate and robust back ends against GTSAM's and g2o's
robust kernels on pose graphs with wrong loop closures, in one run.

usage: .venv/bin/python scripts/bench_robust.py [--only NAME ...] [--policies random local grouped aliased]
           [--alias-group-size 5] [--alias-true-like 0.5] [--outliers 100 1000] [--maxmix | --no-maxmix] [--scales published calibrated overconfident]
           [--tools TOOL ...] [--timeout 300] [--seed 1] [--out bench-out/robust.json]
           [--peers-from EARLIER.json] [--keep-reports]

Run it with the Python of the peers' virtual environment (scripts/setup_peers.sh
makes .venv; numpy and the peers' peerlib are imported). CI does not run it.

Cases
  * every clean dataset (intel, manhattan, city10000, sphere2500, parking-garage,
    torus3D) corrupted by `pgo corrupt` with wrong loop candidates of each policy
    (random: any two poses; local: poses at most 20 apart; grouped: groups of 10
    consecutive mutually consistent wrong loops) and each count in --outliers;
    every existing edge with |i - j| != 1 is a true loop candidate. Every
    candidate gets an inlier count: log-normal, median 150 for true loops and
    25 for wrong ones, sigma 0.5 in log space (pgo corrupt's defaults);
    `--policies aliased` (not in the default list) adds perceptual aliasing:
    candidates i-j measuring the file's pose j+s from i (|s| in 5..40 steps,
    pgo corrupt's default), in groups of --alias-group-size (default 5; 1 =
    scattered) sharing s, a share --alias-true-like (default 0.5) of them with
    counts from the true-loop model (aliases pass geometric verification).
    Aliased cases take their seeds from a counter of their own, so that adding
    them leaves every other case's file (and the peers' cached results on it)
    unchanged;
  * the public max-mixture outlier files (*-maxmix-*.g2o; component 0 of every
    mixture edge; the last 1000 mixture edges are the outliers, MANIFEST.md),
    counts assigned the same way (`pgo corrupt --wrong 0 --known-wrong-last 1000`).
  Each case is run twice: with the information matrices as published, and
  calibrated: every information matrix multiplied by one factor per dataset so
  that the clean graph's optimum has chi2/dof = 1 (dof = sum of edge
  dimensions - free pose parameters). Several files carry square-root
  information (MANIFEST.md, quirk 1) and are 20-20 000x under-confident, which
  changes what every kernel of fixed width does. `--scales overconfident`
  adds a third run with the calibrated information multiplied by 10 (a file
  10x over-confident, as front ends' covariances often are): the case EM's
  search for the noise scale must leave alone.

Tools (all on the same corrupted file)
  pgo               the default: gate auto (T_GV learned from the counts) + EM
  pgo soft          --gate soft: every candidate enters EM with its posterior
                    P(true loop | count) as prior
  pgo no gate       --gate off --robust em
  pgo huber|cauchy|dcs|gnc (no gate)   --gate off --robust K
  GTSAM huber|cauchy|dcs|gnc, g2o cauchy|dcs   ../shared/peers/{gtsam,g2o}_opt.py
                    --robust K with their default widths (Huber/Cauchy:
                    sqrt(chi2_D(0.95)) on the whitened residual norm; DCS: phi = 1;
                    GNC: GTSAM's GncOptimizer, TLS, inlier threshold chi2_D(0.99),
                    mu schedule x1.4), kernels on the edges with |i - j| > 1, no
                    gating (they cannot read counts), from the file's initial guess.

Metrics
  * accepted loops: weight >= 1/2. pgo: `loops[].weight` of its JSON report (0
    for candidates the gate dropped). Peers: the weight their kernel gives the
    final residual r^2 = e^T Omega e (each in its own error definition,
    evaluated by peerlib on the optimised poses): Huber min(1, k/r),
    Cauchy k^2/(k^2 + r^2), DCS min(1, 2 phi/(phi + r^2))^2, GNC-TLS 1 if
    r^2 <= chi2_D(0.99) else 0 (GTSAM's TLS weights at convergence; checked
    against the number of weights < 1/2 its script reports);
  * precision = accepted true / accepted; recall = accepted true / true loops;
    F1; for pgo also the recall of the true loops that passed the gate;
  * ATE: RMSE of the positions after the rigid alignment (Kabsch, no scale)
    onto the optimum of the clean graph (pgo, no candidates, chordal initial
    guess), and as % of the trajectory's size (the diagonal of the bounding
    box of the reference positions);
  * time: pgo: initialisation + optimisation (all robust rounds) from its
    report; peers: their optimize() call (`time_optimize_s`).

Writes the raw results to --out (JSON) and the tables to the same name with
.md, and prints the tables.
"""
import argparse
import copy
import json
import math
import os
import shlex
import signal
import subprocess
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
CLEAN = ["intel", "manhattan", "city10000", "sphere2500", "parking-garage", "torus3D",
         # real maps beyond the five: few loops (MIT: 20), two sessions
         # (ais2klinik), an office and drives (CSAIL, kitti_00; kitti_02 and
         # kitti_05 with 43 and 66 loops), a 3D building; Vertigo's
         # simulated ring (26 loops) and ringCity
         "MIT", "ais2klinik", "CSAIL", "kitti_00", "cubicle", "kitti_02", "kitti_05",
         "ring", "ringCity"]
# Maps whose published information has matrices that are not positive
# definite (cubicle: 5,021 of them): corrupted with `--fix-information`,
# which writes the nearest positive-definite matrices, and their clean
# optimum solved with it.
FIX_INFORMATION = {"cubicle"}
MAXMIX_BASES = ["manhattanOlson3500", "manhattanG2O3500", "city10000", "sphere2500"]
MAXMIX_KINDS = ["n1000-randm", "n1000-local", "n100-grp10", "n100-lgr10"]
PGO_TOOLS = {
    "pgo": [],
    "pgo soft": ["--gate", "soft"],
    "pgo no gate": ["--gate", "off"],
    "pgo huber": ["--gate", "off", "--robust", "huber"],
    "pgo cauchy": ["--gate", "off", "--robust", "cauchy"],
    "pgo dcs": ["--gate", "off", "--robust", "dcs"],
    "pgo gnc": ["--gate", "off", "--robust", "gnc"],
}
PEER_TOOLS = {
    "GTSAM huber": ("gtsam_opt.py", "huber"),
    "GTSAM cauchy": ("gtsam_opt.py", "cauchy"),
    "GTSAM dcs": ("gtsam_opt.py", "dcs"),
    "GTSAM gnc": ("gtsam_opt.py", "gnc"),
    "g2o cauchy": ("g2o_opt.py", "cauchy"),
    "g2o dcs": ("g2o_opt.py", "dcs"),
    # The same kernels behind pgo's gate: the candidates below T_GV (as
    # `pgo gate` learns it from the file's counts) are removed first.
    "GTSAM cauchy+gate": ("gtsam_opt.py", "cauchy"),
    "GTSAM gnc+gate": ("gtsam_opt.py", "gnc"),
}
GATED = {"GTSAM cauchy+gate", "GTSAM gnc+gate"}
CHI2_95 = {3: 7.814727903251178, 6: 12.591587243743977}
CHI2_99 = {3: 11.344866730144373, 6: 16.811893829770927}
EDGE_LAYOUT = {"EDGE_SE2": (3, 6), "EDGE_SE3:QUAT": (7, 21)}
POLICIES = ["random", "local", "grouped", "aliased"]
# Aliased cases count their seeds from here, apart from the other cases'
# counter (which advances once per case, far fewer than this many times).
ALIAS_SEED_OFFSET = 1_000_000


def log(msg):
    print(msg, file=sys.stderr, flush=True)


def run(cmd, timeout, capture=True, ok=(0,), cpu_limit=None):
    """Runs cmd; (stdout, None, seconds), or (None, error, seconds) on a
    timeout or an exit status not in `ok`. With `cpu_limit`, the limit is
    on the process's CPU time (RLIMIT_CPU), which a loaded machine does not
    shorten, and the wall-clock timeout is ten times as long."""
    t0 = time.perf_counter()
    preexec = None
    if cpu_limit:
        import resource

        def preexec():
            resource.setrlimit(resource.RLIMIT_CPU, (cpu_limit, cpu_limit + 5))
        timeout = 10 * cpu_limit
    try:
        out = subprocess.run(cmd, capture_output=capture, text=True, timeout=timeout,
                             preexec_fn=preexec)
    except subprocess.TimeoutExpired:
        return None, "timeout after %d s" % timeout, time.perf_counter() - t0
    if cpu_limit and out.returncode in (-signal.SIGXCPU, -signal.SIGKILL):
        return None, "CPU time limit of %d s" % cpu_limit, time.perf_counter() - t0
    if out.returncode not in ok:
        tail = (out.stdout or "")[-300:] + (out.stderr or "")[-300:]
        return None, "exit %d: %s" % (out.returncode, " ".join(tail.split())), time.perf_counter() - t0
    return out.stdout, None, time.perf_counter() - t0


# ----------------------------------------------------------------------------- files

def read_positions(path):
    """Vertex id -> position (x, y[, z]) of a g2o file."""
    pos = {}
    with open(path) as f:
        for line in f:
            t = line.split()
            if not t:
                continue
            if t[0] == "VERTEX_SE2":
                pos[int(t[1])] = (float(t[2]), float(t[3]))
            elif t[0] == "VERTEX_SE3:QUAT":
                pos[int(t[1])] = (float(t[2]), float(t[3]), float(t[4]))
    return pos


def read_labels(path):
    """(from, to, wrong) of every edge with |from - to| != 1, in file order."""
    rows = []
    with open(path) as f:
        next(f)
        for line in f:
            _, a, b, w = line.strip().split(",")
            a, b = int(a), int(b)
            if abs(a - b) != 1:
                rows.append((a, b, w == "1"))
    return rows


def scale_information(src, dst, factor):
    """Copy of a g2o file with every edge's information multiplied by factor
    (written to a temporary and renamed: a killed run leaves none)."""
    with open(src) as f, open(dst + ".tmp", "w") as g:
        for line in f:
            t = line.split()
            if t and t[0] in EDGE_LAYOUT:
                nmeas, ninfo = EDGE_LAYOUT[t[0]]
                a = 3 + nmeas
                t[a:a + ninfo] = [repr(float(x) * factor) for x in t[a:a + ninfo]]
                line = " ".join(t) + "\n"
            g.write(line)
    os.replace(dst + ".tmp", dst)


def drop_wrong(src, labels_csv, dst):
    """Copy of a corrupted g2o file without its wrong edges (the clean graph)."""
    wrong = set()
    with open(labels_csv) as f:
        next(f)
        for line in f:
            k, _, _, w = line.strip().split(",")
            if w == "1":
                wrong.add(int(k))
    k = 0
    with open(src) as f, open(dst, "w") as g:
        for line in f:
            t = line.split()
            if t and t[0] in EDGE_LAYOUT:
                k += 1
                if k - 1 in wrong:
                    continue
            g.write(line)


def gate_file(args, src, dst):
    """Copy of a g2o file without the loop candidates below pgo's T_GV (none
    when the counts are degenerate: pgo's default keeps them all); returns,
    for every edge with |i - j| > 1 in file order, whether it was kept."""
    # Prints T_GV alone on stdout; exit 1 when the counts are degenerate.
    stdout, err, _ = run([args.pgo, "gate", src], args.timeout)
    threshold = float(stdout.split()[0]) if stdout and not err else None
    kept = []
    with open(src) as f, open(dst + ".tmp", "w") as g:
        for line in f:
            t = line.split()
            if t and t[0] in EDGE_LAYOUT:
                nmeas, ninfo = EDGE_LAYOUT[t[0]]
                count = int(t[3 + nmeas + ninfo]) if len(t) > 3 + nmeas + ninfo else None
                if abs(int(t[1]) - int(t[2])) > 1:
                    keep = threshold is None or count is None or count >= threshold
                    kept.append(keep)
                    if not keep:
                        continue
            g.write(line)
    os.replace(dst + ".tmp", dst)
    return kept


# ----------------------------------------------------------------------------- metrics

def ate(result, reference):
    """RMSE of the positions after rigid alignment onto the reference, and the
    reference's size (bounding-box diagonal)."""
    ids = sorted(set(result) & set(reference))
    a = np.array([result[i] for i in ids])
    b = np.array([reference[i] for i in ids])
    if not np.all(np.isfinite(a)):
        return float("inf"), float(np.linalg.norm(b.max(0) - b.min(0)))
    ca, cb = a.mean(0), b.mean(0)
    h = (a - ca).T @ (b - cb)
    u, _, vt = np.linalg.svd(h)
    d = np.eye(a.shape[1])
    d[-1, -1] = np.sign(np.linalg.det(vt.T @ u.T))
    r = vt.T @ d @ u.T
    aligned = (a - ca) @ r.T + cb
    rmse = float(np.sqrt(np.mean(np.sum((aligned - b) ** 2, axis=1))))
    return rmse, float(np.linalg.norm(b.max(0) - b.min(0)))


def classification(weights, wrong, kept=None):
    acc = [w >= 0.5 for w in weights]
    tp = sum(1 for a, w in zip(acc, wrong) if a and not w)
    fp = sum(1 for a, w in zip(acc, wrong) if a and w)
    n_true = sum(1 for w in wrong if not w)
    precision = tp / (tp + fp) if tp + fp else float("nan")
    recall = tp / n_true if n_true else float("nan")
    f1 = 2 * tp / (2 * tp + fp + (n_true - tp)) if n_true + fp else float("nan")
    out = {"tp": tp, "fp": fp, "true": n_true, "wrong": len(wrong) - n_true,
           "precision": precision, "recall": recall, "f1": f1}
    if kept is not None:
        gated_true = sum(1 for k, w in zip(kept, wrong) if k and not w)
        out["gated_true"] = gated_true
        out["gated_wrong"] = sum(1 for k, w in zip(kept, wrong) if k and w)
        out["recall_gated"] = (sum(1 for a, k, w in zip(acc, kept, wrong) if a and k and not w) / gated_true
                               if gated_true else float("nan"))
    return out


def peer_weights(kind, r2, dim, delta):
    if kind == "huber":
        r = np.sqrt(r2)
        return np.where(r <= delta, 1.0, delta / np.maximum(r, 1e-300))
    if kind == "cauchy":
        return delta ** 2 / (delta ** 2 + r2)
    if kind == "dcs":
        s = np.minimum(1.0, 2 * delta / (delta + r2))
        return s * s
    if kind == "gnc":
        return np.where(r2 <= CHI2_99[dim], 1.0, 0.0)
    raise ValueError(kind)


# ----------------------------------------------------------------------------- tools

def run_pgo(args, path, flags, out_g2o):
    # Exit status 3: the result failed its χ² test; 4: its loop decisions
    # did not settle (`unsettled` below); the output is written either way.
    stdout, err, wall = run([args.pgo, "optimize", path, "--json", "-q", "-o", out_g2o] + flags + [t for f in args.pgo_flags for t in shlex.split(f)],
                            args.timeout, ok=(0, 3, 4, 5), cpu_limit=args.timeout)
    if err:
        return {"error": err, "wall_s": wall}
    if args.keep_reports and not flags:
        # The default run's whole report, beside its input (for
        # scripts/tail_shape_scan.py).
        with open(path + ".report.json", "w") as f:
            f.write(stdout)
    r = json.loads(stdout)
    return {
        "weights": [l["weight"] for l in r["loops"]],
        "kept": [l["kept"] for l in r["loops"]],
        # Initialisation and the whole robust solve (the optimiser, EM's
        # relaxations and evaluations): what the peers' optimize call does.
        "time": r["time"]["initialize_s"] + r["time"]["solve_s"],
        "wall_s": wall,
        "chi2_passed": (r.get("chi2_test") or {}).get("passed"),
        # Candidates whose decisions did not settle, and the report's
        # warnings (one of which says so).
        "unsettled": sum(1 for l in r["loops"] if l["reason"] == "unsettled"),
        # Accepted clusters a passing map cannot vouch for (each warns).
        "doubtful": len(r["robust"].get("doubtful", [])),
        "held_back": len(r["robust"].get("held_back", [])),
        "outlying": len(r["robust"].get("outlying", [])),
        "warnings": r.get("warnings", []),
        "gate_threshold": r["gate"].get("threshold"),
        "degenerate": r["gate"].get("degenerate"),
        "rounds": r["robust"]["rounds"],
        "iterations": r["optimizer"]["iterations"],
        "factorizations": r["optimizer"]["factorizations"],
        "positions": read_positions(out_g2o),
    }


def run_peer(args, path, script, kind, out_g2o, dim, gated=False):
    import peerlib  # noqa: E402 (the peers' helpers; on sys.path from main)
    kept = None
    if gated:
        gated_path = path[:-4] + ".gated.g2o"
        kept = gate_file(args, path, gated_path)
        path = gated_path
    cmd = [args.python, os.path.join(args.peers, script), path, "--robust", kind, "--json", "--out", out_g2o]
    if kind == "gnc" and args.gnc_rel_tol:
        cmd += ["--rel-tol", repr(args.gnc_rel_tol)]
    stdout, err, wall = run(cmd, args.timeout, cpu_limit=args.timeout)
    if err:
        return {"error": err, "wall_s": wall}
    r = json.loads(stdout.strip().splitlines()[-1])
    if "error" in r:
        return {"error": r["error"], "wall_s": wall}
    g = peerlib.parse_g2o(out_g2o)
    poses = g.vertices
    r2 = peerlib.edge_chi2_gtsam(g, poses) if script.startswith("gtsam") else peerlib.edge_chi2_g2o(g, poses)
    loop = g.loop_mask()
    delta = r.get("robust_delta")
    w = [float(x) for x in peer_weights(kind, r2[loop], dim, delta)]
    if kept is not None:
        it = iter(w)
        w = [next(it) if k else 0.0 for k in kept]
    out = {
        "weights": w,
        "time": r["time_optimize_s"],
        "wall_s": wall,
        "iterations": r.get("iterations"),
        "termination": r.get("termination"),
        "positions": {k: tuple(v[:3]) if dim == 6 else tuple(v[:2]) for k, v in poses.items()},
    }
    if kind == "gnc" and r.get("gnc"):
        out["gnc_rejected_reported"] = r["gnc"]["n_weights_below_0.5"]
        out["gnc_rejected_derived"] = int(np.sum(np.asarray(w) < 0.5))
    return out


# ----------------------------------------------------------------------------- cases

def prepare(args, work):
    """Corrupted files, labels, clean references: a list of cases."""
    cases = []
    seed = args.seed
    alias_seed = args.seed + ALIAS_SEED_OFFSET
    for name in CLEAN:
        if args.only and name not in args.only:
            continue
        src = os.path.join(args.datasets, name + ".g2o")
        if not os.path.exists(src):
            log("skipped %s: %s not found" % (name, src))
            continue
        for policy in args.policies:
            for n in args.outliers:
                if policy == "aliased":
                    alias_seed += 1
                    # The revisited placement with the default offsets keeps
                    # the names (and files) of earlier runs.
                    wide = args.alias_place != "revisited" or args.alias_offset or args.alias_by_group
                    tag = "-%s-o%s%s" % (args.alias_place, args.alias_offset or "",
                                         "-G" if args.alias_by_group else "") if wide else ""
                    case = "%s aliased%s %d" % (name, " " + args.alias_place if wide else "", n)
                    # The seed is in the name: seeds of one share are different
                    # files (the revisited placement's seed 1 keeps the name of
                    # earlier runs, and its cached peers).
                    seeded = "-s%d" % args.seed if wide or args.seed != 1 else ""
                    stem = os.path.join(work, "%s-aliased%s-g%d-t%g%s-%d" % (
                        name, tag.replace(",", "_"), args.alias_group_size, args.alias_true_like,
                        seeded, n))
                    flags = ["--wrong", str(n), "--wrong-mode", "aliased", "--seed", str(alias_seed),
                             "--group-size", str(args.alias_group_size),
                             "--true-like-counts", repr(args.alias_true_like),
                             "--alias-place", args.alias_place]
                    if args.alias_offset:
                        flags += ["--alias-offset", args.alias_offset]
                    if args.alias_by_group:
                        flags += ["--true-like-by-group"]
                    cases.append(corrupt_case(args, case, name, src, stem, flags, clean=src))
                    continue
                seed += 1
                case = "%s %s %d" % (name, policy, n)
                stem = os.path.join(work, "%s-%s-%d" % (name, policy, n))
                flags = ["--wrong", str(n), "--wrong-mode", policy, "--seed", str(seed)]
                cases.append(corrupt_case(args, case, name, src, stem, flags, clean=src))
    if args.maxmix:
        for base in MAXMIX_BASES:
            for kind in MAXMIX_KINDS:
                name = "%s-maxmix-%s" % (base, kind)
                if args.only and name not in args.only and base not in args.only:
                    continue
                src = os.path.join(args.datasets, name + ".g2o")
                if not os.path.exists(src):
                    log("skipped %s: not found" % name)
                    continue
                seed += 1
                stem = os.path.join(work, name)
                flags = ["--wrong", "0", "--known-wrong-last", "1000", "--seed", str(seed)]
                cases.append(corrupt_case(args, name, base, src, stem, flags, clean=None))
    return cases


def corrupt_case(args, case, dataset, src, stem, flags, clean):
    path, labels = stem + ".g2o", stem + ".labels.csv"
    if not (os.path.exists(path) and os.path.exists(labels)):
        repair = ["--fix-information"] if needs_repair(src) else []
        subprocess.run([args.pgo, "corrupt", src, "-o", path, "--labels", labels] + flags + repair,
                       check=True, capture_output=True)
    if clean is None:
        clean = stem + ".clean.g2o"
        drop_wrong(path, labels, clean)
    return {"case": case, "dataset": dataset, "path": path, "labels": labels, "clean": clean}


def needs_repair(path):
    """Whether the file at `path` is one of FIX_INFORMATION's maps or made
    from one (its name starts with the map's)."""
    name = os.path.basename(path)
    return any(name.startswith(m + ".") or name.startswith(m + "-") for m in FIX_INFORMATION)


def reference(args, clean, cache):
    """The clean graph's optimum: positions, chi2, dof, and the calibration factor."""
    if clean in cache:
        return cache[clean]
    out = clean + ".opt.g2o" if clean.startswith(args.work) else os.path.join(
        args.work, os.path.basename(clean) + ".opt.g2o")
    repair = ["--fix-information"] if needs_repair(clean) else []
    stdout, err, _ = run([args.pgo, "optimize", clean, "--gate", "off", "--robust", "none",
                          "--json", "-q", "-o", out] + repair, args.timeout)
    if err:
        raise RuntimeError("%s: reference failed: %s" % (clean, err))
    r = json.loads(stdout)
    chi2, dof = r["optimizer"]["final_chi2"], r["chi2_test"]["dof_residual"]
    ref = {"positions": read_positions(out), "chi2": chi2, "dof": dof, "factor": dof / chi2,
           "dim": 3 if r["dimension"] == 2 else 6}
    cache[clean] = ref
    return ref


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--datasets", default=os.environ.get("PGO_DATASETS", os.path.join(ROOT, "../shared/datasets")))
    ap.add_argument("--peers", default=os.environ.get("PGO_PEERS", os.path.join(ROOT, "../shared/peers")))
    ap.add_argument("--python", default=os.path.join(ROOT, ".venv/bin/python"))
    ap.add_argument("--pgo", default=os.path.join(ROOT, "target/release/pgo"))
    ap.add_argument("--work", default=os.path.join(ROOT, "bench-out/robust"))
    ap.add_argument("--out", default=os.path.join(ROOT, "bench-out/robust.json"))
    ap.add_argument("--only", nargs="*", default=None, help="datasets (clean names, maxmix names or bases)")
    ap.add_argument("--policies", nargs="*", default=["random", "local", "grouped"], choices=POLICIES)
    ap.add_argument("--alias-group-size", type=int, default=5,
                    help="aliased candidates per group sharing one offset (1: scattered)")
    ap.add_argument("--alias-true-like", type=float, default=0.5,
                    help="share of aliased candidates with counts from the true-loop model")
    ap.add_argument("--alias-place", default="revisited", choices=["revisited", "anywhere"],
                    help="where aliased groups fall (pgo corrupt --alias-place)")
    ap.add_argument("--alias-by-group", action="store_true",
                    help="a group of aliases draws --alias-true-like once for all its members")
    ap.add_argument("--alias-offset", default=None, metavar="MIN,MAX",
                    help="range of the aliases' offsets in steps (pgo corrupt --alias-offset)")
    ap.add_argument("--outliers", nargs="*", type=int, default=[100, 1000])
    ap.add_argument("--maxmix", action=argparse.BooleanOptionalAction, default=True)
    ap.add_argument("--scales", nargs="*", default=["published", "calibrated"],
                    choices=["published", "calibrated", "overconfident"])
    ap.add_argument("--tools", nargs="*", default=list(PGO_TOOLS) + list(PEER_TOOLS))
    ap.add_argument("--timeout", type=int, default=300,
                    help="seconds of CPU time each run may take")
    ap.add_argument("--gnc-rel-tol", type=float, default=None,
                    help="relative error tolerance of GNC's inner LM solves (the peers' script "
                         "defaults to 1e-9; GTSAM's own default is 1e-5)")
    ap.add_argument("--pgo-flags", nargs="*", default=[], help="extra flags for every pgo run (e.g. --robust-c 4)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--keep-reports", action="store_true",
                    help="keep the JSON report of each default pgo run beside its input in --work "
                         "(INPUT.report.json)")
    ap.add_argument("--peers-from", default=None, metavar="JSON",
                    help="take the peers' results from an earlier --out file of the same cases "
                         "(same --policies, --outliers, --only, --seed and alias options) instead of "
                         "running them: a peer's result does not depend on pgo")
    ap.add_argument("--tables-from", nargs="*", default=None, metavar="JSON",
                    help="print the tables of earlier runs' --out files (merged) and exit")
    args = ap.parse_args()
    if args.tables_from:
        results = []
        for path in args.tables_from:
            with open(path) as f:
                results += json.load(f)["results"]
        print(tables(results, args.tools))
        return
    args.work = os.path.abspath(args.work)
    os.makedirs(args.work, exist_ok=True)
    # The results' folder too: a run of many minutes must not end unable
    # to write them.
    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    sys.path.insert(0, args.peers)
    unknown = set(args.tools) - set(PGO_TOOLS) - set(PEER_TOOLS)
    if unknown:
        ap.error("unknown tools: %s" % ", ".join(sorted(unknown)))

    earlier = peers_from(args) if args.peers_from else {}
    t_start = time.perf_counter()
    cases = prepare(args, args.work)
    refs = {}
    results = []
    for c in cases:
        ref = reference(args, c["clean"], refs)
        labels = read_labels(c["labels"])
        wrong = [w for _, _, w in labels]
        for scale in args.scales:
            path = c["path"]
            factor = {"published": 1.0, "calibrated": ref["factor"],
                      "overconfident": 10 * ref["factor"]}[scale]
            if scale != "published":
                path = c["path"][:-4] + (".cal.g2o" if scale == "calibrated" else ".oc10.g2o")
                if not os.path.exists(path):
                    scale_information(c["path"], path, factor)
            row = {"case": c["case"], "dataset": c["dataset"], "scale": scale,
                   "factor": factor,
                   "candidates": len(wrong), "wrong": sum(wrong), "tools": {}}
            for tool in args.tools:
                # One scratch file per process: several runs may share --work.
                out_g2o = os.path.join(args.work, "result-%d.g2o" % os.getpid())
                if tool in PGO_TOOLS:
                    r = run_pgo(args, path, PGO_TOOLS[tool], out_g2o)
                elif args.peers_from:
                    r = earlier.get((c["case"], scale, tool))
                    if r is None:
                        raise SystemExit("--peers-from %s has no %s on %s (%s)" % (
                            args.peers_from, tool, c["case"], scale))
                    row["tools"][tool] = copy.deepcopy(r)
                    log("%-40s %-10s %-14s %s (from %s)" % (c["case"], scale, tool, brief(r), args.peers_from))
                    continue
                else:
                    # A peer's result on a file depends on nothing pgo does:
                    # cached per input, tool and timeout, so that pgo can be
                    # re-run alone (delete --work/peers to run them again).
                    script, kind = PEER_TOOLS[tool]
                    tol = ".rt%g" % args.gnc_rel_tol if kind == "gnc" and args.gnc_rel_tol else ""
                    cache = os.path.join(args.work, "peers", "%s.%s.t%g%s.json" % (
                        os.path.basename(path), tool.replace(" ", "-"), args.timeout, tol))
                    if os.path.exists(cache):
                        with open(cache) as f:
                            r = json.load(f)
                        if "positions" in r:
                            r["positions"] = {int(k): tuple(v) for k, v in r["positions"].items()}
                    else:
                        r = run_peer(args, path, script, kind, out_g2o, ref["dim"], tool in GATED)
                        os.makedirs(os.path.dirname(cache), exist_ok=True)
                        with open(cache + ".tmp", "w") as f:
                            json.dump(r, f)
                        os.replace(cache + ".tmp", cache)
                    r = copy.deepcopy(r)
                if "error" not in r:
                    if len(r["weights"]) != len(wrong):
                        r = {"error": "%d loop weights for %d candidates" % (len(r["weights"]), len(wrong))}
                    else:
                        r.update(classification(r["weights"], wrong, r.get("kept")))
                        rmse, size = ate(r.pop("positions"), ref["positions"])
                        r["ate"], r["ate_pct"] = rmse, 100 * rmse / size
                        del r["weights"]
                        r.pop("kept", None)
                row["tools"][tool] = r
                log("%-40s %-10s %-14s %s" % (c["case"], scale, tool, brief(r)))
            results.append(row)
            json.dump({"results": results, "args": vars(args)}, open(args.out, "w"), indent=1)
    total = time.perf_counter() - t_start
    json.dump({"results": results, "args": vars(args), "total_s": total}, open(args.out, "w"), indent=1)
    md = tables(results, args.tools)
    md += "\nTotal benchmark time: %.0f s.\n" % total
    open(os.path.splitext(args.out)[0] + ".md", "w").write(md)
    print(md)


def peers_from(args):
    """The peers' results of an earlier run of the same cases, by (case, scale, tool)."""
    with open(args.peers_from) as f:
        earlier = json.load(f)
    same = ("policies", "outliers", "only", "seed", "alias_group_size", "alias_true_like", "maxmix", "timeout",
            "alias_place", "alias_offset", "alias_by_group", "gnc_rel_tol")
    # Options added later: an earlier run without them ran their defaults.
    added = {"alias_place": "revisited", "alias_offset": None, "alias_by_group": False, "gnc_rel_tol": None}
    for key in same:
        if earlier["args"].get(key, added.get(key)) != getattr(args, key):
            raise SystemExit("--peers-from %s: its --%s was %r, not %r: not the same cases" % (
                args.peers_from, key.replace("_", "-"), earlier["args"].get(key), getattr(args, key)))
    return {(r["case"], r["scale"], tool): res for r in earlier["results"]
            for tool, res in r["tools"].items() if tool in PEER_TOOLS}


def brief(r):
    if "error" in r:
        return "ERROR " + r["error"][:120]
    s = "P %.3f R %.3f F1 %.3f ATE %.3g%% t %.3fs" % (r["precision"], r["recall"], r["f1"], r["ate_pct"], r["time"])
    if "recall_gated" in r:
        s += " Rgate %.3f" % r["recall_gated"]
    return s


def fmt(x, spec="%.3f"):
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "–"
    return spec % x


def tables(results, tools):
    """Markdown: a summary per tool and scale, and a per-case table."""
    md = []
    for scale in ("published", "calibrated", "overconfident"):
        rows = [r for r in results if r["scale"] == scale]
        if not rows:
            continue
        md.append("\n### Summary, information %s (%d cases)\n" % (scale, len(rows)))
        md.append("| tool | failed | min precision | min recall | mean F1 | min F1 | max ATE % | median ATE % | "
                  "cases F1 ≥ every peer | total time (s) |")
        md.append("|---|---|---|---|---|---|---|---|---|---|")
        for tool in tools:
            ok = [r["tools"][tool] for r in rows if tool in r["tools"] and "error" not in r["tools"][tool]]
            failed = sum(1 for r in rows if tool in r["tools"] and "error" in r["tools"][tool])
            if not ok:
                md.append("| %s | %d | | | | | | | | |" % (tool, failed))
                continue
            beats = sum(1 for r in rows if tool in r["tools"] and "error" not in r["tools"][tool]
                        and all(r["tools"][tool]["f1"] >= p["f1"] - 1e-12 for t, p in r["tools"].items()
                                if t in PEER_TOOLS and "error" not in p))
            f1 = [x["f1"] for x in ok]
            ates = sorted(x["ate_pct"] for x in ok)
            md.append("| %s | %d | %s | %s | %s | %s | %s | %s | %d / %d | %.1f |" % (
                tool, failed, fmt(np.nanmin([x["precision"] for x in ok])),
                fmt(min(x["recall"] for x in ok)), fmt(float(np.nanmean(f1))), fmt(float(np.nanmin(f1))),
                fmt(ates[-1], "%.3g"), fmt(ates[len(ates) // 2], "%.3g"), beats, len(rows),
                sum(x["time"] for x in ok)))
        md.append("\n### Per case, information %s\n" % scale)
        md.append("pgo = gate + EM (the default); R_gate = recall of the true loops that passed the gate; "
                  "best peer = the peer configuration with the highest F1; GNC ratio = pgo time / GTSAM GNC time.\n")
        md.append("| case | cand. (wrong) | gate kept true / wrong | pgo P | pgo R_gate | pgo F1 | pgo ATE % | "
                  "pgo χ² test | pgo soft F1 | pgo no gate F1 | best peer F1 (who) | peer ATE % | pgo t (s) | GNC t (s) | "
                  "GNC ratio |")
        md.append("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
        for r in rows:
            t = r["tools"]
            p = t.get("pgo", {})
            if "error" in p or not p:
                md.append("| %s | %d (%d) | pgo: %s |" % (r["case"], r["candidates"], r["wrong"],
                                                        p.get("error", "not run")))
                continue
            peers = [(k, v) for k, v in t.items() if k in PEER_TOOLS and "error" not in v]
            best = max(peers, key=lambda kv: kv[1]["f1"]) if peers else None
            gnc = t.get("GTSAM gnc", {})
            gnc_t = gnc.get("time") if "error" not in gnc else None
            md.append("| %s | %d (%d) | %d / %d | %s | %s | %s | %s | %s | %s | %s | %s | %s | %.2f | %s | %s |" % (
                r["case"], r["candidates"], r["wrong"], p["gated_true"], p["gated_wrong"],
                fmt(p["precision"]), fmt(p["recall_gated"]), fmt(p["f1"]), fmt(p["ate_pct"], "%.3g"),
                {True: "pass", False: "fail", None: "–"}[p.get("chi2_passed")],
                fmt(t.get("pgo soft", {}).get("f1")), fmt(t.get("pgo no gate", {}).get("f1")),
                "%s (%s)" % (fmt(best[1]["f1"]), best[0]) if best else "–",
                fmt(best[1]["ate_pct"], "%.3g") if best else "–",
                p["time"], fmt(gnc_t, "%.2f"), fmt(p["time"] / gnc_t if gnc_t else None, "%.2f")))
    return "\n".join(md) + "\n"


if __name__ == "__main__":
    main()
