#!/usr/bin/env bash
# The places sweep's cases (bench/results/aliasing_places) again with one of
# EM's layers off: `--expert no-LAYER` for pgo, the peers' results taken
# from the cache of the sweep's work directory (bench-out/aliasing_sweep).
# One JSON per case into bench/results/aliasing_places_no_LAYER;
# scripts/benchmarks_md.py tabulates them beside the sweep.
#
# usage: scripts/bench_places_ablation.sh LAYER [extra bench_robust.py args]
set -euo pipefail
cd "$(dirname "$0")/.."
layer=$1
shift
py=${PYTHON:-.venv/bin/python}
out=bench/results/aliasing_places_no_$layer
mkdir -p "$out"
for f in bench/results/aliasing_places/*.json; do
    b=$(basename "$f" .json)
    IFS=_ read -r place seed group name <<< "$b"
    seed=${seed#s}
    group=${group#g}
    count=300
    [[ $name == MIT ]] && count=30
    # The sweep's shares (scripts/bench_aliasing_sweep.sh): seed 1 30 %,
    # seed 2 100 %, the others 50 %.
    share=0.5
    [[ $seed == 1 ]] && share=0.3
    [[ $seed == 2 ]] && share=1.0
    "$py" scripts/bench_robust.py --tools pgo --policies aliased \
        --alias-place "$place" --alias-offset 5,50 --alias-by-group \
        --alias-group-size "$group" --alias-true-like "$share" \
        --outliers "$count" --no-maxmix --scales calibrated published \
        --seed "$seed" --only "$name" --timeout 300 \
        --work bench-out/aliasing_sweep --pgo-flags "--expert no-$layer" \
        --out "$out/$b.json" "$@"
done
rm -f "$out"/*.md
