#!/usr/bin/env python3
"""Variance components of a solved 2D pose graph: odometry against accepted loops.

usage: .venv/bin/python scripts/variance_components.py OUT.g2o REPORT.json

OUT.g2o is what `pgo optimize IN.g2o -o OUT.g2o --json > REPORT.json` wrote
(an SE(2) graph). The edges the map was solved with are the odometry edges
(|i - j| = 1) and the loops the report accepted (weight >= 1/2). For each
group it prints the sum of e^T Omega e at the map, the group's redundancy
(its share of the degrees of freedom: the number of its residuals minus the
trace of its rows of the hat matrix, J (J^T J)^-1 J^T, exactly, by sparse
solves), and their ratio: the group's variance factor (Helmert's estimate;
1 for information that is right). Where the two factors differ, one group's
information is wrong relative to the other's; where they agree, the
residuals cannot tell wrong loops from information too tight for every
edge alike (docs/method.md, section 7). Needs numpy and scipy (the peers'
environment, scripts/setup_peers.sh).
"""
import json
import math
import sys

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla


def read_se2(path):
    poses, edges = {}, []
    for line in open(path):
        p = line.split()
        if p and p[0] == "VERTEX_SE2":
            poses[int(p[1])] = np.array([float(v) for v in p[2:5]])
        elif p and p[0] == "EDGE_SE2":
            a = [float(v) for v in p[6:12]]
            info = np.array([[a[0], a[1], a[2]], [a[1], a[3], a[4]], [a[2], a[4], a[5]]])
            edges.append((int(p[1]), int(p[2]), np.array([float(v) for v in p[3:6]]), info))
    return poses, edges


def error(xi, xj, z):
    """g2o's SE(2) error: Z^-1 (Xi^-1 Xj) as (x, y, theta)."""
    c, s = math.cos(xi[2]), math.sin(xi[2])
    d = xj[:2] - xi[:2]
    local = np.array([c * d[0] + s * d[1], -s * d[0] + c * d[1]]) - z[:2]
    cz, sz = math.cos(z[2]), math.sin(z[2])
    theta = (xj[2] - xi[2] - z[2] + math.pi) % (2 * math.pi) - math.pi
    return np.array([cz * local[0] + sz * local[1], -sz * local[0] + cz * local[1], theta])


def whitened_jacobian(poses, edges):
    """Rows of L J per edge (Omega = L^T L), the first pose fixed; and each edge's e^T Omega e."""
    index = {v: k for k, v in enumerate(sorted(poses))}
    rows, cols, vals, chi2 = [], [], [], []
    h = 1e-6
    for r, (i, j, z, info) in enumerate(edges):
        e0 = error(poses[i], poses[j], z)
        jac = np.zeros((3, 6))
        for k in range(3):
            xi, xj = poses[i].copy(), poses[j].copy()
            xi[k] += h
            xj[k] += h
            jac[:, k] = (error(xi, poses[j], z) - e0) / h
            jac[:, 3 + k] = (error(poses[i], xj, z) - e0) / h
        lj = np.linalg.cholesky(info).T @ jac
        for b in range(6):
            pose = index[i if b < 3 else j]
            if pose == 0:
                continue
            for a in range(3):
                rows.append(3 * r + a)
                cols.append(3 * (pose - 1) + b % 3)
                vals.append(lj[a, b])
        chi2.append(e0 @ info @ e0)
    shape = (3 * len(edges), 3 * (len(poses) - 1))
    return sp.csr_matrix((vals, (rows, cols)), shape=shape), np.array(chi2)


def main():
    if len(sys.argv) != 3:
        raise SystemExit(__doc__.split("\n\n")[1])
    poses, edges = read_se2(sys.argv[1])
    report = json.load(open(sys.argv[2]))
    accepted = {(l["from"], l["to"]) for l in report["loops"] if l["weight"] >= 0.5}
    edges = [e for e in edges if abs(e[0] - e[1]) == 1 or (e[0], e[1]) in accepted]
    is_loop = np.array([abs(i - j) != 1 or (i, j) in accepted for i, j, _, _ in edges])
    jac, chi2 = whitened_jacobian(poses, edges)
    normal = sla.splu((jac.T @ jac).tocsc())
    loop_rows = jac[np.repeat(is_loop, 3)]
    leverage = 0.0
    for start in range(0, loop_rows.shape[0], 600):
        block = loop_rows[start:start + 600]
        leverage += np.einsum("ij,ji->", block.toarray(), normal.solve(block.T.toarray()))
    redundancy_loops = loop_rows.shape[0] - leverage
    redundancy_odometry = jac.shape[0] - jac.shape[1] - redundancy_loops
    for name, mask, red in (("odometry", ~is_loop, redundancy_odometry), ("loops", is_loop, redundancy_loops)):
        print("%-9s edges %6d  chi2 %12.1f  redundancy %8.1f  variance factor %10.3f" %
              (name, mask.sum(), chi2[mask].sum(), red, chi2[mask].sum() / red if red > 0 else float("nan")))


if __name__ == "__main__":
    main()
