#!/usr/bin/env python3
"""Young maps from labelled runs: the first poses of each file, with labels.

A mapping front end optimises its map long before the run ends. For each
labelled FILE.g2o (or FILE.cal.g2o) given, with FILE.labels.csv beside it
(as `pgo corrupt --labels` writes it and scripts/bench_robust.py keeps
under its --work folder), writes into OUT_DIR the graph of its first
`int(fraction · poses)` poses (vertex ids below that number: every vertex
and edge among them, in file order) and its labels, for each fraction (a file without labels is skipped,
with a message).
The prefixes keep the file's name with `-pN` added (N poses), so that
scripts/decision_scan.py finds their labels as it finds the files'.

usage: python3 scripts/young_prefixes.py OUT_DIR FILE.g2o [FILE.g2o ...]
           [--fractions 0.3 0.5 0.7]

Prints the paths of the prefixes written, one per line.
"""
import argparse
import os
import sys


def labels_of(path):
    stem = path[:-len(".g2o")]
    if stem.endswith(".cal"):
        stem = stem[:-len(".cal")]
    return stem + ".labels.csv"


def first_ids(tokens):
    """The vertex ids of a g2o line: one for a vertex, two for an edge,
    none for anything else."""
    if not tokens:
        return None
    if tokens[0].startswith("VERTEX"):
        return [int(tokens[1])]
    if tokens[0].startswith("EDGE"):
        return [int(tokens[1]), int(tokens[2])]
    return []


def write_prefix(path, out_dir, fraction):
    with open(path) as f:
        lines = f.read().splitlines()
    poses = sum(1 for line in lines if line.startswith("VERTEX"))
    n = int(poses * fraction)
    cal = path.endswith(".cal.g2o")
    stem = os.path.basename(labels_of(path))[:-len(".labels.csv")]
    base = os.path.join(out_dir, "%s-p%d" % (stem, n))
    graph = base + (".cal.g2o" if cal else ".g2o")
    with open(graph + ".tmp", "w") as g:
        for line in lines:
            ids = first_ids(line.split())
            if ids is not None and all(i < n for i in ids):
                g.write(line + "\n")
    os.replace(graph + ".tmp", graph)
    with open(labels_of(path)) as f:
        rows = f.read().splitlines()
    with open(base + ".labels.csv.tmp", "w") as g:
        g.write(rows[0] + "\n")
        for row in rows[1:]:
            _, a, b, _ = row.split(",")
            if int(a) < n and int(b) < n:
                g.write(row + "\n")
    os.replace(base + ".labels.csv.tmp", base + ".labels.csv")
    return graph


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("out_dir")
    parser.add_argument("files", nargs="+")
    parser.add_argument("--fractions", type=float, nargs="+", default=[0.3, 0.5, 0.7])
    args = parser.parse_args()
    os.makedirs(args.out_dir, exist_ok=True)
    for path in args.files:
        if not os.path.exists(labels_of(path)):
            print("%s: skipped, no labels beside it (%s)" % (path, labels_of(path)), file=sys.stderr)
            continue
        for fraction in args.fractions:
            if not 0.0 < fraction <= 1.0:
                sys.exit("--fractions: %s is not in (0, 1]" % fraction)
            print(write_prefix(path, args.out_dir, fraction))


if __name__ == "__main__":
    main()
