#!/usr/bin/env python3
"""Compare the loop decisions of two or more pgo builds over labelled files.

Usage:
  decision_scan.py --pgo base=target/release/pgo --pgo variant=/path/to/pgo \
      --out bench-out/decision_scan FILE.g2o [FILE.g2o ...]

Each FILE.g2o (or FILE.cal.g2o) needs FILE.labels.csv beside it, as
`pgo corrupt --labels` writes it (and scripts/bench_robust.py keeps under its
--work folder). Every build runs `pgo optimize FILE --json` with its defaults;
its wrong loops accepted, true loops rejected, exit status, EM's starts (the
one kept marked `*`) and the true and wrong loops the report names
doubtful, held back or outlying are kept in
OUT/NAME.jsonl (a file already there is not run again, so a scan can be
stopped and resumed). The script prints each file where a build decides
otherwise than the first, and the totals; then, over the files where both
builds recorded them, how many maps they wrote are the same bytes (a
SHA-256 of the map) and, where the number of EM's decisions (solves of an
accepted set) differs, those numbers and the builds' times; and each
build's totals of the loops named doubtful, held back and outlying.
"""

import argparse
import hashlib
import json
import os
import subprocess
import sys
import tempfile
import time

from bench_robust import read_labels


# The report's lists of loops the evidence questions in a passing map.
NAMING_CHECKS = ("doubtful", "held_back", "outlying")


def labels_of(path):
    stem = path[:-len(".g2o")]
    if stem.endswith(".cal"):
        stem = stem[:-len(".cal")]
    return stem + ".labels.csv"


def run(binary, path, timeout):
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        p = subprocess.run([binary, "optimize", path, "-o", os.path.join(tmp, "out.g2o"), "--json"],
                           capture_output=True, text=True, timeout=timeout)
        seconds = time.perf_counter() - t0
        try:
            with open(os.path.join(tmp, "out.g2o"), "rb") as written:
                digest = hashlib.sha256(written.read()).hexdigest()
        except OSError:
            digest = None
    try:
        report = json.loads(p.stdout)
    except json.JSONDecodeError:
        return {"exit": p.returncode, "error": p.stderr.strip()[-300:]}
    # In file order, the order of the report's loops.
    wrong = [w for _, _, w in read_labels(labels_of(path))]
    loops = report["loops"]
    if len(loops) != len(wrong):
        return {"exit": p.returncode, "error": "%d loops in the report, %d in the labels" % (len(loops), len(wrong))}
    accepted = [l["accepted"] for l in loops]
    robust = report.get("robust") or {}
    # The loops each check of the evidence names (docs/method.md §7), true
    # and wrong by the labels.
    named = {}
    for check in NAMING_CHECKS:
        ks = [k for entry in robust.get(check) or [] for k in entry["loops"]]
        named[check] = [sum(not wrong[k] for k in ks), sum(wrong[k] for k in ks)]
    return {"exit": p.returncode, "seconds": round(seconds, 2), "map_sha256": digest,
            "decisions": robust.get("decisions"),
            "wrong_accepted": sum(a and w for a, w in zip(accepted, wrong)),
            "true_rejected": sum((not a) and (not w) for a, w in zip(accepted, wrong)),
            "true": sum(not w for w in wrong), "named": named,
            "starts": ["%s%s" % (e["start"], "*" if e["chosen"] else "") for e in robust.get("starts") or []]}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--pgo", action="append", required=True, metavar="NAME=PATH")
    ap.add_argument("--out", required=True)
    ap.add_argument("--timeout", type=float, default=1200)
    ap.add_argument("files", nargs="+")
    args = ap.parse_args()
    builds = [b.split("=", 1) for b in args.pgo]
    os.makedirs(args.out, exist_ok=True)
    files = [f for f in args.files if os.path.exists(labels_of(f))]
    results = {}
    for name, binary in builds:
        path = os.path.join(args.out, name + ".jsonl")
        done = {}
        if os.path.exists(path):
            with open(path) as f:
                for line in f:
                    row = json.loads(line)
                    done[row["file"]] = row
        with open(path, "a") as out:
            for f in files:
                if f not in done:
                    done[f] = dict(file=f, **run(binary, f, args.timeout))
                    out.write(json.dumps(done[f]) + "\n")
                    out.flush()
        results[name] = done
    first = builds[0][0]
    key = ("wrong_accepted", "true_rejected", "exit")
    for name, _ in builds[1:]:
        differ, lost, runs_lost, gained, worse = 0, 0, 0, 0, 0
        for f in files:
            a, b = results[first][f], results[name][f]
            if "error" in a or "error" in b:
                print("%s: %s" % (os.path.basename(f), a.get("error") or b.get("error")), file=sys.stderr)
                continue
            if tuple(a[k] for k in key) == tuple(b[k] for k in key):
                continue
            differ += 1
            if b["true_rejected"] > a["true_rejected"]:
                runs_lost += 1
                lost += b["true_rejected"] - a["true_rejected"]
            gained += max(0, a["wrong_accepted"] - b["wrong_accepted"])
            worse += max(0, b["wrong_accepted"] - a["wrong_accepted"])
            print("%-62s %s: %d wrong accepted, %d true rejected, exit %d | %s: %d, %d, exit %d" % (
                os.path.basename(f)[:62], first, a["wrong_accepted"], a["true_rejected"], a["exit"],
                name, b["wrong_accepted"], b["true_rejected"], b["exit"]))
        print("%s against %s: %d files, %d decided otherwise; %d runs reject more true loops (%d loops), "
              "wrong loops accepted: %d fewer, %d more" % (name, first, len(files), differ, runs_lost, lost, gained, worse))
        both = [f for f in files if results[first][f].get("map_sha256") and results[name][f].get("map_sha256")]
        same = sum(results[first][f]["map_sha256"] == results[name][f]["map_sha256"] for f in both)
        print("%s against %s: maps the same bytes on %d of %d files" % (name, first, same, len(both)))
        for build in (first, name):
            rows = [results[build][f].get("named") for f in files]
            if any(r is None for r in rows):
                continue
            print("%s: loops named (true / wrong) %s" % (build, ", ".join(
                "%s %d / %d" % (check, sum(r[check][0] for r in rows), sum(r[check][1] for r in rows))
                for check in NAMING_CHECKS)))
        moved = [f for f in both if results[first][f].get("decisions") != results[name][f].get("decisions")]
        if moved:
            total = lambda build, k: sum(results[build][f][k] or 0 for f in moved)
            print("%s against %s: EM's decisions differ on %d files: %d against %d, in %.1f s against %.1f s" % (
                name, first, len(moved), total(name, "decisions"), total(first, "decisions"),
                total(name, "seconds"), total(first, "seconds")))


if __name__ == "__main__":
    main()
