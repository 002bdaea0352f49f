#!/usr/bin/env bash
# Perceptual aliasing beyond the benchmark's one setting: pgo alone on 300
# aliased candidates per case (`pgo corrupt --wrong-mode aliased`), for
# groups of 1, 5 and 10 candidates sharing an offset, shares 0.3 and 1.0 of
# them with counts drawn like a true loop's, and seeds 1 to 3, on five
# datasets with the information calibrated and as published: 180 runs. One
# JSON per (seed, group, share) into OUT_DIR (default
# bench/results/aliasing_sweep); scripts/benchmarks_md.py tabulates them.
#
# usage: scripts/bench_aliasing_sweep.sh [OUT_DIR] (extra arguments go to
#        bench_robust.py, e.g. --pgo target/release/pgo)
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-bench/results/aliasing_sweep}
shift || true
mkdir -p "$out"
py=${PYTHON:-.venv/bin/python}
for seed in 1 2 3; do
    for group in 1 5 10; do
        for share in 0.3 1.0; do
            "$py" scripts/bench_robust.py --tools pgo --policies aliased \
                --alias-group-size "$group" --alias-true-like "$share" --outliers 300 \
                --no-maxmix --scales calibrated published --seed "$seed" \
                --only intel manhattan city10000 sphere2500 parking-garage \
                --work "bench-out/aliasing_sweep/seed$seed" \
                --out "$out/s${seed}_g${group}_t${share}.json" "$@"
        done
    done
done
