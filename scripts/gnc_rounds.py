#!/usr/bin/env python3
"""GTSAM's GNC-TLS schedule on a 3D g2o file, with each round's solve started
either from the initial values (as GTSAM's GncOptimizer does) or from the last
round's map.

usage: .venv/bin/python scripts/gnc_rounds.py FILE.g2o {initial|warm} OUT.g2o

The loop is GncOptimizer's with GTSAM's LM as the inner solver (relative
tolerance 1e-5, at most 100 iterations): the least-squares map of every edge
at weight 1; mu0 from the loop edges' residuals at the initial values; then per
round the TLS weights at the last map (inlier threshold chi2_6(0.99)), the
weighted problem solved again, mu x 1.4, until the weights are binary or the
weighted cost changed by less than 1e-5 of itself. Edges between consecutive
ids are known inliers; the first pose is held by a tight prior. Prints one
line per round (mu, candidates of weight >= 1/2, the weighted chi2) and writes
the last map to OUT.g2o (docs/method.md section 5, "Two starts").
"""

import sys
import time

import gtsam
import numpy as np
from scipy.stats import chi2


def main():
    path, mode, out = sys.argv[1], sys.argv[2], sys.argv[3]
    if mode not in ("initial", "warm"):
        sys.exit("mode must be initial or warm, not %r" % mode)
    graph, initial = gtsam.readG2o(path, True)
    first = min(int(k) for k in initial.keys())
    prior = gtsam.PriorFactorPose3(first, initial.atPose3(first),
                                   gtsam.noiseModel.Diagonal.Sigmas(np.full(6, 1e-6)))
    factors = [graph.at(i) for i in range(graph.size())]
    loop = np.array([abs(f.keys()[0] - f.keys()[1]) != 1 for f in factors])
    barc = 0.5 * chi2.ppf(0.99, 6)

    def weighted(w):
        g = gtsam.NonlinearFactorGraph()
        g.add(prior)
        for f, wi in zip(factors, w):
            if wi == 1:
                g.add(f)
            elif wi > 0:
                info = np.linalg.inv(f.noiseModel().covariance()) * wi
                g.add(gtsam.BetweenFactorPose3(f.keys()[0], f.keys()[1], f.measured(),
                                               gtsam.noiseModel.Gaussian.Information(info)))
        return g

    params = gtsam.LevenbergMarquardtParams()
    params.setRelativeErrorTol(1e-5)
    params.setMaxIterations(100)
    t0 = time.time()
    w = np.ones(len(factors))
    result = gtsam.LevenbergMarquardtOptimizer(weighted(w), initial, params).optimize()
    errors = lambda values: np.array([f.error(values) for f in factors])  # noqa: E731
    r0 = errors(initial)
    mus = [barc / (2 * r - barc) for r, l in zip(r0, loop) if l and 2 * r - barc > 0]
    mu = max(min(mus), 1e-6) if mus else None
    if mu is None:
        print("every residual inside the inlier band: least squares")
    previous = weighted(w).error(result)
    for it in range(100 if mu else 0):
        r = errors(result)
        upper, lower = (mu + 1) / mu * barc, mu / (mu + 1) * barc
        for k in np.flatnonzero(loop):
            if r[k] >= upper:
                w[k] = 0.0
            elif r[k] <= lower:
                w[k] = 1.0
            else:
                w[k] = min(1.0, max(0.0, np.sqrt(barc * mu * (mu + 1) / r[k]) - mu))
        g = weighted(w)
        start = initial if mode == "initial" else result
        result = gtsam.LevenbergMarquardtOptimizer(g, start, params).optimize()
        cost = g.error(result)
        print("round %d mu %.3e held %d chi2 %.6e" % (it, mu, int(np.sum(w[loop] >= 0.5)), 2 * cost),
              flush=True)
        binary = bool(np.all(np.minimum(w[loop], 1 - w[loop]) < 1e-4))
        if binary or abs(cost - previous) / max(previous, 1e-7) < 1e-5:
            break
        mu *= 1.4
        previous = cost
    print("%.1f s, %d candidates held" % (time.time() - t0, int(np.sum(w[loop] >= 0.5))))
    gtsam.writeG2o(weighted(w), result, out)


if __name__ == "__main__":
    main()
