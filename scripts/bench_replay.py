#!/usr/bin/env python3
"""Incremental replay: pose graphs fed keyframe by keyframe to GTSAM's iSAM2
and to pgo's incremental update (`PoseGraph.update()` of the Python module),
side by side in one run.

usage: .venv/bin/python scripts/bench_replay.py [--only manhattan city10000] [--every 1 10 100]
           [--tools isam2 pgo] [--aliased] [--no-clean] [--quick] [--max-poses N] [--repeat R]
           [--pgo-option KEY=VALUE ...]
           [--pgo target/release/pgo] [--work bench-out/replay] [--out bench/results/replay.json]
           [--svg bench/results/replay_latency.svg] [--plot-only]

Run it with the Python of the peers' virtual environment (scripts/setup_peers.sh
makes .venv with gtsam and numpy; the peers' peerlib is imported from --peers)
into which pgo's Python module is installed (`.venv/bin/pip install ./python`);
without it (or one without PoseGraph.update) pgo's rows hold the error and
iSAM2 runs alone, as with --tools isam2. It needs the
release binary (`cargo build --release`) for the batch references and for
`pgo corrupt`. CI does not run it. --quick: manhattan only, N = 10 and 100,
written to bench-out/replay-quick.json unless --out says otherwise.
--repeat R: each dataset and N R times, the tools in turn in each round, each
row with its round (bench/results/replay_rounds.json: the spread of the ratios
on a shared machine).

Replay (the same for both tools)
  * Poses in file order (the order of the VERTEX_SE2 lines); each edge is
    added, in file order, as soon as both its ends exist. The tool optimises
    after every N-th pose (N from --every), counting from the first pose, and
    after the last one; the first optimisation comes no earlier than the
    second pose.
  * A new pose's initial value: the odometry edge (previous pose -> new pose,
    inverted if the file has it the other way) composed onto the latest
    estimate of the previous pose (the last optimisation's, or, for a pose
    added since, its own initial value). pgo re-initialises new poses itself
    from its last solution; it is given the same composed pose.
  * Gauge: the first pose is held at its file value. iSAM2: a
    PriorFactorPose2 there with variances (1e-6, 1e-6, 1e-8), as the peers'
    gtsam_opt.py and GTSAM's Pose2SLAMExample_g2o; pgo fixes its first pose.
  * iSAM2: gtsam.ISAM2 with GTSAM's default ISAM2Params (Gauss-Newton,
    relinearizeThreshold 0.1, relinearizeSkip 10; written to the JSON); one
    step = isam.update(new factors, new values) + isam.calculateEstimate()
    (a front end needs the estimate every step); no extra update() calls.
    Every edge is a Gaussian BetweenFactorPose2 (iSAM2 has no gate).
  * pgo: one step = g.update(**options) (options from --pgo-option, none by
    default: pgo's defaults, one thread). Edges without an inlier count are
    trusted edges (add_edge), edges with one are loop candidates
    (add_loop_candidate), as `pgo optimize` reads a file.
  * pgo-capped: the same with update_iters=1, at
    most one iteration per solve of an update (loop candidates EM decides
    are still solved to convergence), as iSAM2 takes one Gauss-Newton step
    per update; after the last step a closing g.update() without the cap
    (nothing added) finishes the convergence, timed as one more step.

Cases
  * clean: manhattan (manhattanOlson3500-g2o.g2o, 3500 poses, 2099 loops)
    and city10000 (10000 poses, 10688 loops): every edge trusted;
  * --aliased: manhattan corrupted by `pgo corrupt --wrong 100 --wrong-mode
    aliased --group-size 5 --true-like-counts 0.5 --seed 1`: 100 wrong loop
    candidates that measure the pose j+s seen from i, in groups of 5 sharing
    s, half with counts drawn like a true loop's; every loop edge (the true
    ones too) carries an inlier count, so every loop reaches pgo as a
    candidate and iSAM2 as a plain factor.

Metrics (per dataset, N and tool)
  * steps; total_s = the sum of the step latencies; wall_s = the whole
    replay (graph building in Python included, metric bookkeeping
    excluded); latency_ms median, p90, p99, max; a downsampled latency series
    (per bucket of consecutive steps: first step, median, max);
  * final_chi2: χ² of the tool's last estimate in pgo's error definition
    (e = (t, wrap θ) of Z⁻¹ Xi⁻¹ Xj, χ² = Σ eᵀΩe; peerlib's
    edge_chi2_g2o, which reproduces pgo's reported χ²: checked every run on the
    batch reference, `chi2_check`), over the clean graph's edges;
    batch_chi2: the batch optimum of the same graph (`pgo optimize` of the
    clean file; for pgo rows also `g.optimize()` of its replayed graph);
    chi2_rel = final_chi2 / batch_chi2 - 1;
  * map error: max and RMS distance of the final positions from the clean
    batch optimum's, as % of the diagonal of its bounding box (no alignment:
    both fix the first pose at the same value);
  * pgo: pgo_solves, how many steps its update called "none", "extended"
    (only odometry: new poses composed, no factorisation), "warm", "full"
    and "batch" (Result.incremental["solve"]);
  * iSAM2: parts, the sums of the update and calculateEstimate times;
  * aliased: at each step precision (accepted true / accepted) and recall
    (accepted true / true candidates added so far) against the labels, as a
    downsampled series, with the minimum precision and the final values
    (iSAM2 takes every candidate: precision is the share of true ones so
    far, recall 1); final_chi2 and the map error against the clean graph's
    batch optimum. pgo also: its final accepted set against that of a batch
    g.optimize() of the same graph (identical or not, how many differ, and
    that batch's precision, recall and map error); and the number of steps
    at which a candidate of the previous step changed its decision without
    Result.incremental["changed"] saying so, or "changed" disagreed with
    Result.loops (`changed_mismatch_steps`, 0 when they agree).

Writes --out (JSON) and, when matplotlib can be imported, --svg (latency
per step; --plot-only redraws it from --out). Prints one line per run.
"""
import argparse
import itertools
import json
import math
import os
import platform
import re
import shlex
import subprocess
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
DATASETS = {"manhattan": "manhattanOlson3500-g2o.g2o", "city10000": "city10000.g2o"}
ALIAS_FLAGS = ["--wrong", "100", "--wrong-mode", "aliased", "--group-size", "5",
               "--true-like-counts", "0.5", "--seed", "1"]
# The peers' prior on the first pose (gtsam_opt.py): variances x, y, θ.
PRIOR_VARIANCES = [1e-6, 1e-6, 1e-8]
SERIES_POINTS = 100


def log(msg):
    print(msg, file=sys.stderr, flush=True)


# ----------------------------------------------------------------------------- SE(2)

def wrap(a):
    return (a + math.pi) % (2 * math.pi) - math.pi


def compose(a, b):
    c, s = math.cos(a[2]), math.sin(a[2])
    return (a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], wrap(a[2] + b[2]))


def inverse(a):
    c, s = math.cos(a[2]), math.sin(a[2])
    return (-c * a[0] - s * a[1], s * a[0] - c * a[1], wrap(-a[2]))


# ----------------------------------------------------------------------------- graphs

class Replay:
    """A g2o file in replay order: poses, and per pose the edges that become
    available with it (both ends exist), in file order."""

    def __init__(self, path, labels=None):
        import peerlib
        g = peerlib.parse_g2o(path, is3d=False)
        if not g.vertices:
            raise ValueError("%s: no VERTEX_SE2 lines (the replay takes poses in file order)" % path)
        self.graph = g
        self.order = list(g.vertices)          # dict order = file order
        self.rank = {v: k for k, v in enumerate(self.order)}
        self.first = g.vertices[self.order[0]]
        self.edges = []                        # (i, j, z tuple, info 3x3, inliers or None)
        self.at = [[] for _ in self.order]     # pose rank -> edge indices
        for e in range(g.n_edges):
            i, j = g.edge_i[e], g.edge_j[e]
            extra = g.edge_extra[e]
            inliers = int(extra[0]) if extra else None
            self.edges.append((i, j, tuple(float(x) for x in g.edge_meas[e]), g.edge_info[e], inliers))
            self.at[max(self.rank[i], self.rank[j])].append(e)
        self.wrong = None
        if labels is not None:
            self.wrong = labels
            if len(labels) != len(self.edges):
                raise ValueError("%d labels for %d edges" % (len(labels), len(self.edges)))

    def odometry(self, k):
        """The edge (index, forward?) that hangs pose rank k on rank k - 1,
        or on any pose already there (None if there is none)."""
        cur, prev = self.order[k], self.order[k - 1]
        fallback = None
        for e in self.at[k]:
            i, j = self.edges[e][:2]
            if (i, j) == (prev, cur):
                return e, True
            if (i, j) == (cur, prev):
                return e, False
            if fallback is None and i != j:
                fallback = (e, j == cur)
        return fallback

    def clean_graph(self):
        """The peerlib graph of the edges not labelled wrong (all without labels)."""
        import peerlib
        if self.wrong is None:
            return self.graph
        g = peerlib.G2oGraph(is3d=False, vertices=self.graph.vertices)
        for e, w in enumerate(self.wrong):
            if not w:
                g.edge_i.append(self.graph.edge_i[e])
                g.edge_j.append(self.graph.edge_j[e])
                g.edge_meas.append(self.graph.edge_meas[e])
                g.edge_info.append(self.graph.edge_info[e])
                g.edge_extra.append(self.graph.edge_extra[e])
        return g


def read_labels(path):
    """wrong? per edge line of a `pgo corrupt` labels CSV (edge,from,to,wrong)."""
    rows = []
    with open(path) as f:
        next(f)
        for line in f:
            k, _, _, w = line.strip().split(",")
            assert int(k) == len(rows), "labels out of order"
            rows.append(w == "1")
    return rows


def read_positions(path):
    pos = {}
    with open(path) as f:
        for line in f:
            t = line.split()
            if t and t[0] == "VERTEX_SE2":
                pos[int(t[1])] = (float(t[2]), float(t[3]))
    return pos


def batch_reference(args, clean, cache):
    """`pgo optimize` of the clean file: chi2 (pgo's), positions, and the
    check that peerlib's chi2 of its output agrees with pgo's."""
    if clean in cache:
        return cache[clean]
    import peerlib
    out = os.path.join(args.work, os.path.basename(clean)[:-4] + ".batch.g2o")
    t0 = time.perf_counter()
    p = subprocess.run([args.pgo, "optimize", clean, "--json", "-q", "-o", out],
                       capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if p.returncode not in (0, 3):
        raise RuntimeError("pgo optimize %s: exit %d: %s" % (clean, p.returncode, p.stderr[-400:]))
    r = json.loads(p.stdout)
    g = peerlib.parse_g2o(out, is3d=False)
    ours = float(peerlib.edge_chi2_g2o(g, g.vertices).sum())
    chi2 = r["optimizer"]["final_chi2"]
    ref = {"chi2": chi2, "chi2_check": {"pgo": chi2, "peerlib": ours, "rel_diff": abs(ours - chi2) / chi2},
           "wall_s": wall, "positions": read_positions(out)}
    if ref["chi2_check"]["rel_diff"] > 1e-6:
        log("WARNING: peerlib's chi2 %.9g differs from pgo's %.9g on %s" % (ours, chi2, out))
    cache[clean] = ref
    return ref


# ----------------------------------------------------------------------------- tools

class Isam2:
    name = "isam2"

    def __init__(self, options):
        import gtsam
        self.gtsam = gtsam
        self.params = gtsam.ISAM2Params()
        self.isam = gtsam.ISAM2(self.params)
        self.prior = gtsam.noiseModel.Diagonal.Variances(np.array(PRIOR_VARIANCES))
        self.factors = gtsam.NonlinearFactorGraph()
        self.values = gtsam.Values()
        self.est = None
        self.parts = {"update_s": 0.0, "estimate_s": 0.0}

    def add_pose(self, vid, pose, first):
        p = self.gtsam.Pose2(*pose)
        self.values.insert(vid, p)
        if first:
            self.factors.add(self.gtsam.PriorFactorPose2(vid, p, self.prior))

    def add_edge(self, i, j, z, info, inliers):
        g = self.gtsam
        self.factors.add(g.BetweenFactorPose2(i, j, g.Pose2(*z), g.noiseModel.Gaussian.Information(info)))
        return None

    def step(self):
        t0 = time.perf_counter()
        self.isam.update(self.factors, self.values)
        t1 = time.perf_counter()
        self.est = self.isam.calculateEstimate()
        t2 = time.perf_counter()
        self.parts["update_s"] += t1 - t0
        self.parts["estimate_s"] += t2 - t1
        dt = t2 - t0
        self.factors = self.gtsam.NonlinearFactorGraph()
        self.values = self.gtsam.Values()
        return dt

    def estimate(self, vid):
        p = self.est.atPose2(vid)
        return (p.x(), p.y(), p.theta())

    def final_poses(self, ids):
        out = {}
        for v in ids:
            p = self.est.atPose2(v)
            out[v] = np.array([p.x(), p.y(), p.theta()])
        return out


class Pgo:
    name = "pgo"

    def __init__(self, options):
        import pgo
        if not hasattr(pgo.PoseGraph, "update"):
            raise RuntimeError("pgo's Python module has no PoseGraph.update (install a newer one: "
                               ".venv/bin/pip install ./python)")
        self.pgo = pgo
        self.options = options
        self.g = pgo.PoseGraph(2)
        self.r = None
        self.phases = {}    # where the updates' time went, summed (s)

    def add_pose(self, vid, pose, first):
        self.g.add_pose(vid, tuple(pose))

    def add_edge(self, i, j, z, info, inliers):
        if inliers is None:
            self.g.add_edge(i, j, z, info)
            return None
        return self.g.add_loop_candidate(i, j, z, info, inliers)

    def step(self):
        t0 = time.perf_counter()
        self.r = self.g.update(**self.options)
        return time.perf_counter() - t0

    def profile(self):
        """Adds the last update's phases (its report's times) to `phases`:
        the optimiser's runs, EM's evaluations — the innovations (the
        factorisation of the map, its selected inverse, each cluster's
        innovations, the decisions) and the loop model's fit — and
        relaxations, the initial guess and the gate; the rest of an
        update's time is bookkeeping."""
        report = self.r.report
        t = report["time"]
        for key, v in (("optimizer", report["optimizer"]["time_s"]),
                       ("innovations", t["evaluation_s"] - t["loop_model_s"]),
                       ("loop model", t["loop_model_s"]), ("relaxations", t["relaxation_s"]),
                       ("initial guess", t["initialize_s"]), ("gate", t["gate_s"])):
            self.phases[key] = self.phases.get(key, 0.0) + float(v)

    def estimate(self, vid):
        return tuple(self.r.pose(vid))

    def final_poses(self, ids):
        rid, poses = self.r.poses_array()
        return {int(v): poses[k] for k, v in enumerate(rid)}


class PgoCapped(Pgo):
    """pgo with update_iters=1: at most one iteration per solve of an update
    (as iSAM2 does one Gauss-Newton step per update), and a closing update
    after the last step (nothing added, no cap) that finishes the
    convergence; its time is the replay's last step."""
    name = "pgo-capped"

    def __init__(self, options):
        super().__init__(options)
        self.closing_options = dict(options)
        self.options = dict(options, update_iters=1)

    def close(self):
        t0 = time.perf_counter()
        self.r = self.g.update(**self.closing_options)
        return time.perf_counter() - t0


TOOLS = {"isam2": Isam2, "pgo": Pgo, "pgo-capped": PgoCapped}


# ----------------------------------------------------------------------------- replay

def replay(data, tool, every, max_poses):
    """Replays data through tool, optimising every `every` poses. Returns
    latencies (s), wall (s), pgo's solve kinds and, on a labelled file, the
    classification of the candidates at each step (pgo: its accepted set;
    other tools take every candidate in)."""
    n = len(data.order) if max_poses is None else min(max_poses, len(data.order))
    latencies, steps_at = [], []
    pending = {}            # poses added since the last step: id -> initial value
    bookkeeping = 0.0
    solves = {}
    track = data.wrong is not None
    series = []             # (poses, precision, recall, tp, fp) per step (track)
    n_true = n_wrong = 0    # candidates added so far (track)
    cand_label = {}         # candidate index -> wrong?
    prev_acc = None         # candidate index -> accepted, at the last step
    mismatch_steps = 0
    t_start = time.perf_counter()
    for k in range(n):
        vid = data.order[k]
        if k == 0:
            init = tuple(float(x) for x in data.first)
        else:
            odo = data.odometry(k)
            if odo is None:
                init = tuple(float(x) for x in data.graph.vertices[vid])
            else:
                e, forward = odo
                i, j, z = data.edges[e][:3]
                anchor = i if forward else j
                base = pending[anchor] if anchor in pending else tool.estimate(anchor)
                init = compose(base, z if forward else inverse(z))
        tool.add_pose(vid, init, k == 0)
        pending[vid] = init
        for e in data.at[k]:
            i, j, z, info, inliers = data.edges[e]
            idx = tool.add_edge(i, j, z, info, inliers)
            if track and inliers is not None:
                n_wrong += data.wrong[e]
                n_true += not data.wrong[e]
                if idx is not None:
                    cand_label[idx] = data.wrong[e]
        if k == 0 or not ((k + 1) % every == 0 or k == n - 1):
            continue
        latencies.append(tool.step())
        steps_at.append(k + 1)
        pending = {}
        if isinstance(tool, Pgo):
            t0 = time.perf_counter()
            tool.profile()
            inc = getattr(tool.r, "incremental", None)
            if inc is None:
                inc = tool.r.report.get("incremental") or {}
            kind = inc.get("solve", "?")
            solves[kind] = solves.get(kind, 0) + 1
            if track:
                acc = {l["index"]: bool(l["accepted"]) for l in tool.r.loops}
                if prev_acc is not None and kind != "batch":
                    # The candidates of the last step keep their decision
                    # unless "changed" lists them; "changed" agrees with loops.
                    expected = dict(prev_acc)
                    expected.update({c["index"]: bool(c["accepted"]) for c in inc.get("changed", [])})
                    if any(acc.get(i) != a for i, a in expected.items()):
                        mismatch_steps += 1
                prev_acc = acc
                tp = sum(1 for i, a in acc.items() if a and not cand_label[i])
                fp = sum(1 for i, a in acc.items() if a and cand_label[i])
                series.append((k + 1, tp / (tp + fp) if tp + fp else None,
                               tp / n_true if n_true else None, tp, fp))
            bookkeeping += time.perf_counter() - t0
        elif track:
            series.append((k + 1, n_true / (n_true + n_wrong) if n_true + n_wrong else None,
                           1.0 if n_true else None, n_true, n_wrong))
    if hasattr(tool, "close"):
        latencies.append(tool.close())
        steps_at.append(n)
    wall = time.perf_counter() - t_start - bookkeeping
    return {"latencies": latencies, "steps_at": steps_at, "wall": wall, "poses": n,
            "solves": solves, "series": series, "mismatch_steps": mismatch_steps, "cand_label": cand_label}


def latency_summary(lat):
    ms = np.array(lat) * 1e3
    return {"median": float(np.median(ms)), "p90": float(np.percentile(ms, 90)),
            "p99": float(np.percentile(ms, 99)), "max": float(ms.max()), "mean": float(ms.mean())}


def downsample(steps_at, lat):
    """Per bucket of consecutive steps: first step (pose count), median and max ms."""
    n = len(lat)
    size = max(1, math.ceil(n / SERIES_POINTS))
    out = {"bucket_steps": size, "pose": [], "median_ms": [], "max_ms": []}
    for a in range(0, n, size):
        chunk = np.array(lat[a:a + size]) * 1e3
        out["pose"].append(steps_at[a])
        out["median_ms"].append(round(float(np.median(chunk)), 4))
        out["max_ms"].append(round(float(chunk.max()), 4))
    return out


def map_error(poses, ref_positions):
    ids = [v for v in ref_positions if v in poses]
    a = np.array([poses[v][:2] for v in ids])
    b = np.array([ref_positions[v] for v in ids])
    diag = float(np.linalg.norm(b.max(0) - b.min(0)))
    d = np.linalg.norm(a - b, axis=1)
    return {"max_pct": float(100 * d.max() / diag), "rms_pct": float(100 * np.sqrt(np.mean(d * d)) / diag),
            "max": float(d.max()), "rms": float(np.sqrt(np.mean(d * d))), "diag": diag, "poses": len(ids)}


def chi2_of(graph, poses):
    import peerlib
    return float(peerlib.edge_chi2_g2o(graph, poses).sum())


def run_case(args, case, data, ref, tool_name, every, options):
    row = {"dataset": case, "every": every, "tool": tool_name}
    try:
        tool = TOOLS[tool_name](options)
    except Exception as exc:  # noqa: BLE001 (module missing or too old)
        row["error"] = "%s: %s" % (type(exc).__name__, exc)
        return row
    try:
        rr = replay(data, tool, every, args.max_poses)
    except Exception as exc:  # noqa: BLE001 (a solver's failure is a result)
        row["error"] = "%s: %s" % (type(exc).__name__, " ".join(str(exc).split())[:300])
        return row
    lat = rr["latencies"]
    row.update({"poses": rr["poses"], "steps": len(lat), "total_s": float(sum(lat)), "wall_s": rr["wall"],
                "latency_ms": latency_summary(lat), "latency_series": downsample(rr["steps_at"], lat)})
    if hasattr(tool, "parts"):
        row["parts"] = tool.parts
    if isinstance(tool, Pgo):
        row["phases_s"] = tool.phases
    ids = data.order[:rr["poses"]]
    poses = tool.final_poses(ids)
    clean = data.clean_graph()
    partial = rr["poses"] < len(data.order)
    if not partial:
        row["final_chi2"] = chi2_of(clean, poses)
        row["batch_chi2"] = ref["chi2"]
        row["batch_source"] = "pgo optimize (CLI) of the clean file"
        row["chi2_rel"] = row["final_chi2"] / ref["chi2"] - 1
        row["map_error"] = map_error(poses, ref["positions"])
    if tool_name.startswith("pgo"):
        row["pgo_solves"] = {k: rr["solves"].get(k, 0) for k in ("none", "extended", "warm", "full", "batch")}
        other = {k: v for k, v in rr["solves"].items() if k not in row["pgo_solves"]}
        if other:
            row["pgo_solves"].update(other)
        row["pgo_chi2"] = tool.r.chi2
        row["pgo_options"] = options
        t0 = time.perf_counter()
        b = tool.g.optimize(**options)
        row["batch_python_s"] = time.perf_counter() - t0
        row["batch_python_chi2"] = b.chi2
        if data.wrong is None:
            if not partial:
                # pgo's own chi2 of its map against the evaluator's: definitions agree?
                row["pgo_chi2_check_rel"] = abs(tool.r.chi2 - row["final_chi2"]) / row["final_chi2"]
                row["batch_chi2"] = b.chi2
                row["batch_source"] = "g.optimize() of the replayed graph"
                row["chi2_rel"] = row["final_chi2"] / b.chi2 - 1
        else:
            inc = {l["index"] for l in tool.r.loops if l["accepted"]}
            bat = {l["index"] for l in b.loops if l["accepted"]}
            labels = rr["cand_label"]   # candidate index (add_loop_candidate's) -> wrong?
            bposes = {int(v): p for v, p in zip(*b.poses_array())}
            row["accepted_vs_batch"] = {
                "identical": inc == bat, "incremental": len(inc), "batch": len(bat),
                "only_incremental": len(inc - bat), "only_batch": len(bat - inc),
                "batch_precision": precision(bat, labels), "batch_recall": recall(bat, labels),
            }
            if not partial:
                row["batch_map_error"] = map_error(bposes, ref["positions"])
                row["batch_chi2_clean"] = chi2_of(clean, bposes)
            row["changed_mismatch_steps"] = rr["mismatch_steps"]
    if data.wrong is not None:
        s = rr["series"]
        if not tool_name.startswith("pgo"):
            row["accepts"] = "every candidate (no gate)"
        prec = [(p, at) for at, p, _, _, _ in s if p is not None]
        row["precision"] = s[-1][1] if s else None
        row["recall"] = s[-1][2] if s else None
        row["accepted_true"], row["accepted_wrong"] = (s[-1][3], s[-1][4]) if s else (0, 0)
        if prec:
            row["min_precision"], row["min_precision_at_pose"] = min(prec)
        row["pr_series"] = downsample_pr(s)
    return row


def precision(acc, labels):
    if not acc:
        return None
    return sum(1 for i in acc if not labels[i]) / len(acc)


def recall(acc, labels):
    n_true = sum(1 for w in labels.values() if not w)
    return sum(1 for i in acc if not labels[i]) / n_true if n_true else None


def downsample_pr(series):
    """Every k-th step's (pose, precision, recall), and always the step of the
    lowest precision and the last one."""
    if not series:
        return {"pose": [], "precision": [], "recall": []}
    size = max(1, math.ceil(len(series) / SERIES_POINTS))
    keep = set(range(0, len(series), size)) | {len(series) - 1}
    prec = [(p, k) for k, (_, p, _, _, _) in enumerate(series) if p is not None]
    if prec:
        keep.add(min(prec)[1])
    pick = [series[k] for k in sorted(keep)]
    r4 = lambda x: None if x is None else round(x, 4)  # noqa: E731
    return {"pose": [s[0] for s in pick], "precision": [r4(s[1]) for s in pick],
            "recall": [r4(s[2]) for s in pick]}


def brief(row):
    if "error" in row:
        return "ERROR " + row["error"]
    s = "%5d steps  total %8.3f s  wall %8.3f s  median %7.3f ms  p99 %8.3f ms  max %8.3f ms" % (
        row["steps"], row["total_s"], row["wall_s"], row["latency_ms"]["median"], row["latency_ms"]["p99"],
        row["latency_ms"]["max"])
    if "chi2_rel" in row:
        s += "  chi2 %.6g / batch %.6g - 1 = %.3g" % (row["final_chi2"], row["batch_chi2"], row["chi2_rel"])
    if "map_error" in row:
        s += "  map err max %.3g%% rms %.3g%%" % (row["map_error"]["max_pct"], row["map_error"]["rms_pct"])
    if "pgo_solves" in row:
        s += "  solves %s" % row["pgo_solves"]
    if "precision" in row:
        s += "  P %s R %s minP %s" % (row["precision"], row["recall"], row.get("min_precision"))
    return s


# ----------------------------------------------------------------------------- output

def machine():
    u = platform.uname()
    cpu = ""
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    return {"uname": "%s %s %s" % (u.system, u.release, u.machine), "nproc": os.cpu_count(), "cpu": cpu,
            "python": platform.python_version()}


def package_version(name):
    try:
        from importlib.metadata import version
        return version(name)
    except Exception:  # noqa: BLE001
        return None


def isam2_params():
    """GTSAM's default ISAM2Params as its own printout gives them."""
    import gtsam
    out = {}
    for line in str(gtsam.ISAM2Params()).splitlines():
        if ":" in line:
            k, v = line.split(":", 1)
            v = v.strip()
            try:
                v = int(v) if v.lstrip("-").isdigit() else float(v)
            except ValueError:
                pass
            out[k.strip()] = v
    return out


def command_line():
    exe = sys.executable
    if exe.startswith(ROOT + os.sep):
        exe = os.path.relpath(exe, ROOT)
    elif os.path.basename(os.path.dirname(os.path.dirname(exe))) == ".venv":
        exe = ".venv/bin/python"
    return shlex.join([exe] + sys.argv)


def write_json(doc, path):
    """Indented JSON with every list of numbers on one line, atomically."""
    text = json.dumps(doc, indent=1)
    text = re.sub(r"\[[^\[\]{}\"]*\]", lambda m: "[" + " ".join(m.group(0)[1:-1].split()) + "]", text)
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    with open(path + ".tmp", "w") as f:
        f.write(text + "\n")
    os.replace(path + ".tmp", path)


def plot(results, svg):
    try:
        import matplotlib
        matplotlib.use("svg")
        import matplotlib.pyplot as plt
        matplotlib.rcParams["svg.fonttype"] = "none"   # text as text: a smaller file
    except ImportError:
        log("no matplotlib: %s not drawn" % svg)
        return
    rows = [r for r in results if "latency_series" in r]
    groups = []
    for r in rows:
        if (r["dataset"], r["every"]) not in groups:
            groups.append((r["dataset"], r["every"]))
    fig, axes = plt.subplots(len(groups), 1, figsize=(8, 2.6 * len(groups)), squeeze=False)
    for ax, (ds, n) in zip(axes[:, 0], groups):
        for r in rows:
            if (r["dataset"], r["every"]) == (ds, n):
                s = r["latency_series"]
                ax.plot(s["pose"], s["max_ms"], label="%s max" % r["tool"])
                ax.plot(s["pose"], s["median_ms"], linestyle="--", label="%s median" % r["tool"])
        ax.set_yscale("log")
        ax.set_title("%s, N = %d (per bucket of %d steps)" % (ds, n, max(
            r["latency_series"]["bucket_steps"] for r in rows if (r["dataset"], r["every"]) == (ds, n))))
        ax.set_xlabel("poses")
        ax.set_ylabel("step latency (ms)")
        ax.legend(fontsize=7)
    fig.tight_layout()
    os.makedirs(os.path.dirname(os.path.abspath(svg)), exist_ok=True)
    fig.savefig(svg, metadata={"Date": None})
    log("wrote %s" % svg)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--datasets", default=os.environ.get("PGO_DATASETS", os.path.join(ROOT, "../shared/datasets")))
    ap.add_argument("--peers", default=os.environ.get("PGO_PEERS", os.path.join(ROOT, "../shared/peers")))
    ap.add_argument("--pgo", default=os.path.join(ROOT, "target/release/pgo"),
                    help="the pgo binary (batch references, pgo corrupt)")
    ap.add_argument("--work", default=os.path.join(ROOT, "bench-out/replay"))
    ap.add_argument("--out", default=None,
                    help="default bench/results/replay.json (--quick: bench-out/replay-quick.json)")
    ap.add_argument("--svg", default=None,
                    help="latency plot; default beside --out as replay_latency.svg (needs matplotlib)")
    ap.add_argument("--only", nargs="*", default=None, choices=list(DATASETS), help="clean datasets")
    ap.add_argument("--every", nargs="*", type=int, default=[1, 10, 100])
    ap.add_argument("--tools", nargs="*", default=["isam2", "pgo", "pgo-capped"], choices=list(TOOLS))
    ap.add_argument("--aliased", action="store_true", help="add the aliased manhattan case")
    ap.add_argument("--no-clean", action="store_true", help="only the aliased case")
    ap.add_argument("--quick", action="store_true", help="manhattan only, N = 10 and 100")
    ap.add_argument("--max-poses", type=int, default=None, help="replay only the first N poses (a test)")
    ap.add_argument("--repeat", type=int, default=1, metavar="R",
                    help="run each dataset and N R times, the tools in turn in each round "
                         "(each row says its round): the spread of the ratios on a noisy machine")
    ap.add_argument("--plot-only", action="store_true", help="redraw --svg from --out and exit")
    ap.add_argument("--pgo-option", action="append", default=[], metavar="KEY=VALUE",
                    help="an option for every g.update() and g.optimize() (e.g. threads=1)")
    args = ap.parse_args()
    if args.quick:
        args.only = args.only or ["manhattan"]
        if args.every == [1, 10, 100]:
            args.every = [10, 100]
    if args.out is None:
        args.out = os.path.join(ROOT, "bench-out/replay-quick.json" if args.quick else "bench/results/replay.json")
    if args.svg is None:
        args.svg = os.path.join(os.path.dirname(os.path.abspath(args.out)), "replay_latency.svg")
    if args.plot_only:
        with open(args.out) as f:
            plot(json.load(f)["cases"], args.svg)
        return
    if any(n < 1 for n in args.every):
        ap.error("--every takes positive integers")
    if args.repeat < 1:
        ap.error("--repeat takes a positive integer")
    if args.no_clean and not args.aliased:
        ap.error("--no-clean leaves only the aliased case: add --aliased")
    options = {}
    for kv in args.pgo_option:
        k, _, v = kv.partition("=")
        for conv in (int, float):
            try:
                v = conv(v)
                break
            except ValueError:
                pass
        options[k] = {"true": True, "false": False}.get(v, v) if isinstance(v, str) else v
    args.work = os.path.abspath(args.work)
    os.makedirs(args.work, exist_ok=True)
    sys.path.insert(0, args.peers)

    cases = []
    if not args.no_clean:
        for name in args.only or list(DATASETS):
            path = os.path.join(args.datasets, DATASETS[name])
            cases.append((name, path, None, path))
    if args.aliased:
        src = os.path.join(args.datasets, DATASETS["manhattan"])
        path = os.path.join(args.work, "manhattan_aliased.g2o")
        labels = os.path.join(args.work, "manhattan_aliased.csv")
        if not (os.path.exists(path) and os.path.exists(labels)):
            subprocess.run([args.pgo, "corrupt", src] + ALIAS_FLAGS + ["--output", path, "--labels", labels],
                           check=True, capture_output=True)
        cases.append(("manhattan aliased", path, labels, src))

    doc = {"command": command_line(), "machine": machine(), "gtsam_version": package_version("gtsam"),
           "pgo_version": None, "isam2_params": None, "prior_variances": PRIOR_VARIANCES,
           "corrupt_flags": ALIAS_FLAGS if args.aliased else None, "complete": False, "cases": []}
    if "isam2" in args.tools:
        doc["isam2_params"] = isam2_params()
    if any(t.startswith("pgo") for t in args.tools):
        try:
            import pgo
            doc["pgo_version"] = getattr(pgo, "__version__", None)
        except ImportError as exc:
            log("pgo's Python module: %s" % exc)
    refs = {}
    t_start = time.perf_counter()
    for name, path, labels, clean in cases:
        data = Replay(path, read_labels(labels) if labels else None)
        ref = batch_reference(args, clean, refs)
        log("%s: %d poses, %d edges; batch chi2 %.9g (peerlib %.9g)" % (
            name, len(data.order), len(data.edges), ref["chi2"], ref["chi2_check"]["peerlib"]))
        for every, rnd, tool in itertools.product(args.every, range(args.repeat), args.tools):
            row = run_case(args, name, data, ref, tool, every, options)
            row["batch_chi2_check"] = ref["chi2_check"]
            if args.repeat > 1:
                row["round"] = rnd
            doc["cases"].append(row)
            log("%-18s N=%-4d %-6s %s" % (name, every, tool, brief(row)))
            doc["total_s"] = time.perf_counter() - t_start
            os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
            write_json(doc, args.out)
    doc["complete"] = True
    doc["total_s"] = time.perf_counter() - t_start
    write_json(doc, args.out)
    log("wrote %s (%.0f s)" % (args.out, doc["total_s"]))
    plot(doc["cases"], args.svg)


if __name__ == "__main__":
    main()
