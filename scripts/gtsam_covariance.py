#!/usr/bin/env python3
"""GTSAM's `Marginals` beside pgo's covariances on one g2o file, on pgo's map.

usage: .venv/bin/python scripts/gtsam_covariance.py FILE
           [--model pgo|gtsam] [--pgo-json P.json] [--pairs 100 1000] [--dump 12]
           [--budget SECONDS] [--no-all] [--reference OUT.json] [--out OUT.json]

pgo side: `target/release/examples/covariances FILE --map` (or --pgo-json, its
saved output): the optimised poses, the edges out of the map (rejected loop
candidates), pgo's covariances of --dump poses and of --dump pairs (joint and
relative), and the random pairs it timed.

GTSAM side, at pgo's poses, over the edges in pgo's map:
  --model pgo   each edge a CustomFactor with pgo's error (g2o's: E = Z⁻¹Xi⁻¹Xj,
                e = (t_E, θ_E) in 2D, (t_E, vec(q_E)) with w ≥ 0 in 3D) and its
                Jacobians derived here (checked against central differences),
                the information as written. The same H as pgo's: the comparison
                of the linear algebra, the gauge and the conventions.
  --model gtsam GTSAM's own BetweenFactors (error Logmap(Z⁻¹Xi⁻¹Xj)) with the
                information converted to their error: 3D Ω_gtsam = JᵀΩJ,
                J = ∂(t, vec q)/∂(ω, u) = [[0, I], [½I, 0]] (gtsam.readG2o
                reorders the blocks but does not halve the rotation part). The
                same to first order at zero error: its marginals differ from
                pgo's by the model's difference at the residuals. The one the
                benchmark times (GTSAM's usual factors).
Gauge: pgo fixes the FIX poses, else the first pose of the file; GTSAM gets a
prior of σ = PRIOR_SIGMA on each (see there). GTSAM's Pose3 tangent is (ω, u),
pgo's (u, ω): GTSAM's matrices are permuted into pgo's order. Both perturb on
the right, so the coordinates agree to first order and no other conversion is
needed. The relative covariance in GTSAM is [H₁ H₂]·J·[H₁ H₂]ᵀ from the
Jacobians of between (H₁ = −Ad(A⁻¹) by GTSAM's AdjointMap, H₂ = I).

Reported (JSON on stdout or --out): GTSAM's times (Marginals, every pose's
marginalCovariance within --budget, jointMarginalCovariance of pgo's random
pairs), its peak RSS before and after (getrusage), and the largest and median
relative difference from pgo over the dumped matrices: |Δ_rc| / √(G_rr·G_cc).
--reference OUT.json stores GTSAM's dumped matrices (pgo's order) under the
file's name, for the Rust test tests/integration/covariance.rs.
"""
import argparse
import json
import math
import os
import resource
import subprocess
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, os.environ.get("PGO_PEERS", os.path.join(ROOT, "..", "shared", "peers")))
import peerlib  # noqa: E402
import gtsam  # noqa: E402

# The prior that fixes GTSAM's gauge: σ in metres and radians. It adds to a
# pose's marginal the propagation of its covariance, σ²·(1 + ℓ²) with ℓ the
# distance to the fixed pose, 10⁻¹⁸·(1 + 10⁴) for ℓ = 100 m: 10⁻¹⁰ of a
# variance of 10⁻⁴ m² (a centimetre), far below the 10⁻⁶ compared. Its
# information, 10¹⁸, against H's 10⁰–10⁶ costs the factorisation no accuracy
# that matters (the pose's block is eliminated with a pivot that large).
PRIOR_SIGMA = 1e-9

# pgo's 3D tangent (u, ω) from GTSAM's (ω, u): pgo component i is GTSAM's ORDER_3D[i].
ORDER_3D = [3, 4, 5, 0, 1, 2]


def skew(v):
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def rot2(t):
    c, s = math.cos(t), math.sin(t)
    return np.array([[c, -s], [s, c]])


def perp(v):
    return np.array([-v[1], v[0]])


def error_se2(xi, xj, z):
    """pgo's SE(2) error and its Jacobians (right perturbations, (x, y, θ))."""
    ti, tj, tz = (np.array([p.x(), p.y()]) for p in (xi, xj, z))
    rz_t = rot2(z.theta()).T
    t_a = rot2(xi.theta()).T @ (tj - ti)
    t_e = rz_t @ (t_a - tz)
    th_e = peerlib._wrap(xj.theta() - xi.theta() - z.theta())
    jj = np.eye(3)
    jj[:2, :2] = rot2(th_e)
    ji = np.zeros((3, 3))
    ji[:2, :2] = -rz_t
    ji[:2, 2] = -(rz_t @ perp(tz) + perp(t_e))
    ji[2, 2] = -1.0
    return np.array([t_e[0], t_e[1], th_e]), ji, jj


def quaternion_of(r):
    """(w, v) of a rotation matrix, w ≥ 0."""
    q = gtsam.Rot3(r).toQuaternion()
    w, v = q.w(), np.array([q.x(), q.y(), q.z()])
    return (-w, -v) if w < 0 else (w, v)


def error_se3(xi, xj, z):
    """pgo's SE(3) error (t_E, vec q_E) and its Jacobians in pgo's tangent (u, ω)."""
    ri, rj, rz = (p.rotation().matrix() for p in (xi, xj, z))
    ti, tj, tz = (np.asarray(p.translation()) for p in (xi, xj, z))
    rz_t = rz.T
    r_a, t_a = ri.T @ rj, ri.T @ (tj - ti)
    r_e, t_e = rz_t @ r_a, rz_t @ (t_a - tz)
    w, v = quaternion_of(r_e)
    q = 0.5 * (w * np.eye(3) + skew(v))
    jj = np.zeros((6, 6))
    jj[:3, :3], jj[3:, 3:] = r_e, q
    ji = np.zeros((6, 6))
    ji[:3, :3] = -rz_t
    ji[:3, 3:] = rz_t @ skew(tz) + skew(t_e) @ rz_t
    ji[3:, 3:] = -q @ r_e.T @ rz_t
    return np.concatenate([t_e, v]), ji, jj


def check_jacobians(is3d, poses, rng):
    """The Jacobians above against central differences of the error under
    GTSAM's retract (which agrees with pgo's perturbation to first order)."""
    err = error_se3 if is3d else error_se2
    d = 6 if is3d else 3
    order = ORDER_3D if is3d else list(range(3))
    worst = 0.0
    for _ in range(20):
        xi, xj, z = (poses[k] for k in rng.choice(len(poses), 3))
        _, ji, jj = err(xi, xj, z)
        for which, jac in ((0, ji), (1, jj)):
            num = np.zeros((d, d))
            for k in range(d):
                step = np.zeros(d)
                step[order[k]] = 1e-6  # pgo's component k is GTSAM's order[k]
                args_p, args_m = [xi, xj, z], [xi, xj, z]
                args_p[which] = args_p[which].retract(step)
                args_m[which] = args_m[which].retract(-step)
                diff = err(*args_p)[0] - err(*args_m)[0]
                if not is3d:
                    diff[2] = peerlib._wrap(diff[2])
                num[:, k] = diff / 2e-6
            worst = max(worst, np.abs(num - jac).max() / max(1.0, np.abs(jac).max()))
    if worst > 1e-6:
        raise RuntimeError("analytic Jacobians disagree with central differences: %g" % worst)
    return worst


def pgo_factor(is3d, ki, kj, z, info):
    err = error_se3 if is3d else error_se2
    at = (lambda v, k: v.atPose3(k)) if is3d else (lambda v, k: v.atPose2(k))
    order = ORDER_3D if is3d else list(range(3))
    # GTSAM's column c is pgo's component order.index(c).
    cols = [order.index(c) for c in range(len(order))]

    def error(this, values, H):
        e, ji, jj = err(at(values, ki), at(values, kj), z)
        if H is not None:
            H[0] = ji[:, cols]
            H[1] = jj[:, cols]
        return e

    return gtsam.CustomFactor(gtsam.noiseModel.Gaussian.Information(info), [ki, kj], error)


def gtsam_information(is3d, info):
    """pgo's information on its error, on GTSAM's BetweenFactor error."""
    if not is3d:
        return info
    j = np.zeros((6, 6))
    j[:3, 3:] = np.eye(3)
    j[3:, :3] = 0.5 * np.eye(3)
    return j.T @ info @ j


def to_pose(is3d, p):
    p = np.asarray(p, dtype=float)
    if is3d:
        return gtsam.Pose3(gtsam.Rot3.Quaternion(p[6], p[3], p[4], p[5]), gtsam.Point3(*p[:3]))
    return gtsam.Pose2(*p)


def build(path, pgo, model):
    """GTSAM's graph of pgo's map and its values at pgo's poses."""
    is3d = pgo["dimension"] == 3
    g = peerlib.parse_g2o(path, is3d)
    if g.n_edges != pgo["edges"]:
        raise RuntimeError("%s: %d edges parsed, pgo read %d" % (path, g.n_edges, pgo["edges"]))
    values = gtsam.Values()
    poses = {}
    for k, p in pgo["map"]:
        poses[k] = to_pose(is3d, p)
        values.insert(k, poses[k])
    out = set(pgo["out_of_map"])
    graph = gtsam.NonlinearFactorGraph()
    between = gtsam.BetweenFactorPose3 if is3d else gtsam.BetweenFactorPose2
    for n in range(g.n_edges):
        if n in out:
            continue
        i, j, z, info = g.edge_i[n], g.edge_j[n], to_pose(is3d, g.edge_meas[n]), g.edge_info[n]
        if model == "pgo":
            graph.add(pgo_factor(is3d, i, j, z, info))
        else:
            noise = gtsam.noiseModel.Gaussian.Information(gtsam_information(is3d, info))
            graph.add(between(i, j, z, noise))
    fixed = sorted(g.fixed) or [pgo["first_id"]]
    d = 6 if is3d else 3
    prior = gtsam.PriorFactorPose3 if is3d else gtsam.PriorFactorPose2
    for k in fixed:
        graph.add(prior(k, poses[k], gtsam.noiseModel.Isotropic.Sigma(d, PRIOR_SIGMA)))
    return graph, values, poses, is3d, fixed


def to_pgo_order(is3d, m):
    """A GTSAM covariance of poses (blocks of 6 in 3D) in pgo's order."""
    if not is3d:
        return m
    idx = [6 * (k // 6) + ORDER_3D[k % 6] for k in range(m.shape[0])]
    return m[np.ix_(idx, idx)]


def joint(marginals, a, b):
    """GTSAM's joint covariance of a and b, [[aa, ab], [ba, bb]] (its order)."""
    jm = marginals.jointMarginalCovariance(gtsam.KeyVector([a, b]))
    return np.block([[jm.at(a, a), jm.at(a, b)], [jm.at(b, a), jm.at(b, b)]])


def relative(is3d, marginals, poses, a, b):
    """The covariance of Xa⁻¹Xb by GTSAM's Jacobians of between."""
    h1 = -poses[a].between(poses[b]).inverse().AdjointMap()
    m = np.hstack([h1, np.eye(h1.shape[0])])
    return m @ joint(marginals, a, b) @ m.T


def max_rss_mb():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024 / 1e6


def timed_marginals(marginals, keys, budget):
    """Every key's marginalCovariance until `budget` seconds are spent."""
    start, done = time.perf_counter(), 0
    for k in keys:
        marginals.marginalCovariance(k)
        done += 1
        if time.perf_counter() - start > budget:
            break
    return time.perf_counter() - start, done


def timed_pairs(marginals, pairs, budget):
    start, done = time.perf_counter(), 0
    for a, b in pairs:
        joint(marginals, a, b)
        done += 1
        if time.perf_counter() - start > budget:
            break
    return time.perf_counter() - start, done


def relative_difference(p, g):
    """max |p − g|_rc / √(g_rr·g_cc) over the rows and columns of free poses
    (pgo's variance not 0), and the largest |g| on those of fixed poses
    (pgo's 0; GTSAM's prior's σ² and its propagation)."""
    free = np.diag(p) > 0
    scale = np.sqrt(np.abs(np.outer(np.diag(g), np.diag(g))))
    both = np.outer(free, free)
    worst = float((np.abs(p - g)[both] / scale[both]).max()) if both.any() else 0.0
    return worst, float(np.abs(g[~both]).max()) if (~both).any() else 0.0


def compare(pgo, marginals, poses, is3d):
    """GTSAM's dumped matrices (pgo's order) and their differences from pgo's."""
    d = 6 if is3d else 3
    ours = {"poses": [], "joint": [], "relative": []}
    diffs, gauge = [], []

    def add(kind, ids, m, g, n):
        ours[kind].append(list(ids) + [g.flatten().tolist()])
        rel, fixed = relative_difference(np.reshape(m, (n, n)), g)
        diffs.append(rel)
        gauge.append(fixed)

    for k, m in pgo["dump"]["poses"]:
        add("poses", [k], m, to_pgo_order(is3d, marginals.marginalCovariance(k)), d)
    for a, b, m in pgo["dump"]["joint"]:
        add("joint", [a, b], m, to_pgo_order(is3d, joint(marginals, a, b)), 2 * d)
    for a, b, m in pgo["dump"]["relative"]:
        add("relative", [a, b], m, to_pgo_order(is3d, relative(is3d, marginals, poses, a, b)), d)
    return ours, {"max": max(diffs), "median": float(np.median(diffs)), "matrices": len(diffs),
                  "fixed_max_abs": max(gauge)}


def gtsam_version():
    try:
        from importlib.metadata import version
        return version("gtsam")
    except Exception:  # noqa: BLE001
        return "unknown"


def run_pgo(path, args):
    exe = os.path.join(ROOT, "target", "release", "examples", "covariances")
    cmd = [exe, path, "--map", "--dump", str(args.dump), "--pairs"] + [str(n) for n in args.pairs]
    return json.loads(subprocess.run(cmd, check=True, capture_output=True, text=True).stdout)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("file")
    ap.add_argument("--model", choices=["pgo", "gtsam"], default="pgo")
    ap.add_argument("--pgo-json", help="the example's saved output (else it is run)")
    ap.add_argument("--pairs", nargs="*", type=int, default=[100, 1000])
    ap.add_argument("--dump", type=int, default=12)
    ap.add_argument("--budget", type=float, default=600.0, help="seconds for each timed loop")
    ap.add_argument("--no-all", action="store_true", help="skip every pose's marginal (timing)")
    ap.add_argument("--reference", help="store GTSAM's dumped matrices here under the file's name")
    ap.add_argument("--out")
    args = ap.parse_args()
    pgo = json.load(open(args.pgo_json)) if args.pgo_json else run_pgo(args.file, args)

    rss_start = max_rss_mb()
    graph, values, poses, is3d, fixed = build(args.file, pgo, args.model)
    result = {"file": args.file, "model": args.model, "poses": len(poses), "factors": graph.size(),
              "fixed": fixed, "prior_sigma": PRIOR_SIGMA, "gtsam": gtsam_version()}
    if args.model == "pgo":
        rng = np.random.default_rng(1)
        result["jacobian_check"] = check_jacobians(is3d, list(poses.values()), rng)
    rss_built = max_rss_mb()
    start = time.perf_counter()
    marginals = gtsam.Marginals(graph, values)
    result["marginals_s"] = time.perf_counter() - start
    if not args.no_all:
        t, done = timed_marginals(marginals, [k for k, _ in pgo["map"]], args.budget)
        result["all_poses"] = {"time_s": t, "done": done, "complete": done == len(poses)}
    result["pairs"] = []
    for run in pgo["pairs"]:
        pairs = [tuple(p) for p in run["pairs"]]
        t, done = timed_pairs(marginals, pairs, args.budget)
        result["pairs"].append({"count": run["count"], "time_s": t, "done": done,
                                "complete": done == len(pairs)})
    ours, result["difference"] = compare(pgo, marginals, poses, is3d)
    result["rss_mb"] = {"start": rss_start, "graph": rss_built, "peak": max_rss_mb()}
    if args.reference:
        ref = json.load(open(args.reference)) if os.path.exists(args.reference) else {}
        name = os.path.basename(args.file)
        # Twelve significant digits: far more than the 10⁻⁶ the test asks.
        short = {kind: [row[:-1] + [[float("%.12g" % x) for x in row[-1]]] for row in rows]
                 for kind, rows in ours.items()}
        ref[name] = dict(short, accepted_loops=pgo["loop_candidates"] - len(pgo["out_of_map"]),
                         difference=result["difference"]["max"])
        with open(args.reference, "w") as f:
            json.dump(ref, f, sort_keys=True)
            f.write("\n")
    text = json.dumps(result, indent=1)
    if args.out:
        with open(args.out, "w") as f:
            f.write(text + "\n")
    print(text)


if __name__ == "__main__":
    main()
