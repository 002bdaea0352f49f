#!/usr/bin/env bash
# Perceptual aliasing over where aliases fall, how long their groups are,
# how far off they are and how many look like true loops: `pgo corrupt
# --wrong-mode aliased` with
#   * --alias-place revisited (a group at a true loop, a few poses off) and
#     anywhere (between any two places, most never revisited: a stretch of
#     the map said to be another, moved rigidly);
#   * groups of 1, 10 and 20 candidates, offsets of 5 to 50 steps;
#   * seeds 1 and 2, with 30 % and 100 % of the aliases' groups given counts
#     drawn like a true loop's (one share per seed; seed 3: 50 %; the whole
#     group alike: verification fooled by a repeated place is fooled along
#     all of it);
# on the five datasets of the outlier benchmark and MIT (a real 2D map with
# 20 loops: 30 aliases per case), with the information calibrated and as
# published. pgo and the peers (GTSAM's GNC-TLS and LM + Cauchy, each alone
# and behind pgo's gate; GNC's inner LM at GTSAM's own tolerance, 1e-5)
# run on every case, each peer within 300 s of CPU time; their results are
# cached in the work directory (bench-out/aliasing_sweep/peers), so
# re-running measures pgo alone.
# One JSON per (place, seed, group) into OUT_DIR (default
# bench/results/aliasing_sweep); scripts/benchmarks_md.py tabulates them.
#
# usage: scripts/bench_aliasing_sweep.sh [OUT_DIR] (extra arguments go to
#        bench_robust.py, e.g. --pgo target/release/pgo)
#        SWEEP_DATASETS="intel MIT" restricts the data
#        PEERS_FROM=DIR takes the peers' results from the JSON of the same
#        name in DIR, an earlier run of the same cases (bench_robust.py
#        --peers-from checks that its options match), where no cache is
#        left: pgo is measured again, the peers are notsets; SWEEP_PLACES,
#        SWEEP_SEEDS and SWEEP_GROUPS the other axes.
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-bench/results/aliasing_sweep}
shift || true
mkdir -p "$out"
py=${PYTHON:-.venv/bin/python}
datasets=${SWEEP_DATASETS:-"intel manhattan city10000 sphere2500 parking-garage MIT"}
tools=(pgo "GTSAM cauchy" "GTSAM gnc" "GTSAM cauchy+gate" "GTSAM gnc+gate")
share() { case $1 in 1) echo 0.3 ;; 2) echo 1.0 ;; *) echo 0.5 ;; esac; }
for place in ${SWEEP_PLACES:-anywhere revisited}; do
    for seed in ${SWEEP_SEEDS:-1 2}; do
        for group in ${SWEEP_GROUPS:-1 10 20}; do
            for name in $datasets; do
                count=300
                [[ $name == MIT ]] && count=30
                "$py" scripts/bench_robust.py --tools "${tools[@]}" --policies aliased \
                    --alias-place "$place" --alias-offset 5,50 --alias-by-group \
                    --alias-group-size "$group" --alias-true-like "$(share "$seed")" \
                    --outliers "$count" --no-maxmix --scales calibrated published \
                    --seed "$seed" --only "$name" --timeout 300 --gnc-rel-tol 1e-5 \
                    --work "bench-out/aliasing_sweep" \
                    --out "$out/${place}_s${seed}_g${group}_${name}.json" \
                    ${PEERS_FROM:+--peers-from "$PEERS_FROM/${place}_s${seed}_g${group}_${name}.json"} "$@"
            done
        done
    done
done
