#!/usr/bin/env bash
# Ablation of EM's layers: the outlier benchmark's pgo run with each layer
# switched off (`pgo optimize --expert no-LAYER`), on every dataset family,
# with random, grouped and aliased wrong candidates (100 per case) and on
# the public max-mixture outlier files, information calibrated and as
# published. One JSON per configuration
# into OUT_DIR (default bench/results/ablation); scripts/benchmarks_md.py
# tabulates them.
#
# usage: scripts/bench_ablation.sh [OUT_DIR] (extra arguments go to
#        bench_robust.py, e.g. --pgo target/release/pgo --work DIR)
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-bench/results/ablation}
shift || true
mkdir -p "$out"
py=${PYTHON:-.venv/bin/python}
for layer in all annealing decisions clusters agreement aliasing populations search relaxation; do
    flags=()
    if [ "$layer" != all ]; then
        flags=(--pgo-flags "--expert no-$layer")
    fi
    "$py" scripts/bench_robust.py --tools pgo "${flags[@]}" \
        --policies random grouped aliased --outliers 100 --maxmix --scales calibrated published \
        --only intel manhattan sphere2500 city10000 parking-garage manhattanOlson3500 manhattanG2O3500 \
        --out "$out/$layer.json" "$@"
done
