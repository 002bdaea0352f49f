#!/usr/bin/env bash
# Regenerates every file in g2o_samples/ with `pgo simulate` (deterministic
# for a given seed). Run from the repository root: g2o_samples/make.sh
set -euo pipefail
pgo() { cargo run --release --quiet -- "$@"; }
cd "$(dirname "$0")/.."

# 2D grid walk, 300 true loops and 100 wrong candidates, all with inlier counts.
pgo simulate --world grid2d --poses 1000 --loops 300 --wrong 100 --wrong-mode random --inliers --seed 1 \
    -o g2o_samples/grid2d.g2o --truth g2o_samples/grid2d_truth.g2o --labels g2o_samples/grid2d_labels.csv
# 3D sphere, 200 true loops and 50 wrong candidates in groups of 10 sharing one wrong transform.
pgo simulate --world sphere3d --poses 900 --loops 200 --wrong 50 --wrong-mode grouped --inliers --seed 2 \
    -o g2o_samples/sphere3d.g2o --truth g2o_samples/sphere3d_truth.g2o --labels g2o_samples/sphere3d_labels.csv
# 2D grid walk without candidates: a plain pose graph (all edges trusted).
pgo simulate --world grid2d --poses 500 --loops 150 --seed 3 -o g2o_samples/grid2d_clean.g2o
# The degenerate case: 8 true loops among 200 wrong candidates whose counts look alike.
pgo simulate --world grid2d --poses 400 --loops 8 --wrong 200 --wrong-mode local --inliers \
    --true-inliers 40 --wrong-inliers 30 --seed 4 -o g2o_samples/degenerate.g2o --labels g2o_samples/degenerate_labels.csv
# Perceptual aliasing: 60 wrong candidates in groups of 5 consecutive pairs i–j starting at a true
# loop (a revisited place), each measuring the true pose of j+s from i (one offset s per group,
# |s| in 5..40 steps), with the usual noise; a
# share of 0.3 of them has counts drawn from the true-loop model, as aliases that pass verification.
pgo simulate --world grid2d --poses 800 --loops 200 --wrong 60 --wrong-mode aliased --group-size 5 \
    --true-like-counts 0.3 --inliers --seed 5 \
    -o g2o_samples/aliased.g2o --truth g2o_samples/aliased_truth.g2o --labels g2o_samples/aliased_labels.csv
