#!/usr/bin/env python3
"""How well pgo told true loops from wrong ones, against the labels that
`pgo simulate` / `pgo corrupt` write.

usage: pgo optimize G.g2o --json | scripts/loop_accuracy.py LABELS.csv
       scripts/loop_accuracy.py LABELS.csv REPORT.json

Prints, for the gate (candidates kept) and for the final result (weight >= 1/2):
true loops kept / all true loops (recall), wrong candidates kept / all wrong
ones, and precision. Standard library only.
"""
import collections
import csv
import json
import sys


def accuracy(labels_csv, report):
    wrong = collections.defaultdict(collections.deque)
    with open(labels_csv) as f:
        for row in csv.DictReader(f):
            wrong[(int(row["from"]), int(row["to"]))].append(row["wrong"] == "1")
    rows = []
    for loop in report["loops"]:
        rows.append((wrong[(loop["from"], loop["to"])].popleft(), loop["kept"], loop["weight"] >= 0.5))
    out = {}
    for stage, index in (("gate", 1), ("final", 2)):
        tp = sum(1 for r in rows if not r[0] and r[index])
        fp = sum(1 for r in rows if r[0] and r[index])
        trues = sum(1 for r in rows if not r[0])
        wrongs = len(rows) - trues
        out[stage] = {"true_kept": tp, "true": trues, "wrong_kept": fp, "wrong": wrongs,
                      "recall": tp / trues if trues else 1.0,
                      "precision": tp / (tp + fp) if tp + fp else 1.0}
    return out


def main():
    if len(sys.argv) not in (2, 3):
        sys.exit(__doc__)
    report = json.load(open(sys.argv[2]) if len(sys.argv) == 3 else sys.stdin)
    for stage, a in accuracy(sys.argv[1], report).items():
        print("%-5s: kept %d of %d true loops (recall %.3f), %d of %d wrong candidates; precision %.3f"
              % (stage, a["true_kept"], a["true"], a["recall"], a["wrong_kept"], a["wrong"], a["precision"]))


if __name__ == "__main__":
    main()
