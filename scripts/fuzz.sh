#!/usr/bin/env bash
# Runs each cargo-fuzz target (libFuzzer) for a bounded time.
#
#   scripts/fuzz.sh [SECONDS] [TARGET...]     # default: 600 s each, targets parse, optimize and write
#
# Needs cargo-fuzz (`cargo install cargo-fuzz`). cargo-fuzz wants nightly
# flags; on a stable toolchain RUSTC_BOOTSTRAP=1 lets them through.
# The corpus is fuzz/corpus/<target>/ (git-ignored): seeded from the tiny
# files in fuzz/seeds/ and from the first 40 poses of each g2o_samples/ file.
# A crash lands in fuzz/artifacts/<target>/; turn it into a regression test
# (tests/integration/hostile.rs or the module's unit tests) and fix it.
set -euo pipefail
cd "$(dirname "$0")/.."
seconds=${1:-600}
shift || true
targets=("$@")
[ ${#targets[@]} -gt 0 ] || targets=(parse optimize write options)
command -v cargo-fuzz >/dev/null || { echo "cargo-fuzz not found: cargo install cargo-fuzz" >&2; exit 1; }
export RUSTC_BOOTSTRAP=1

# Seed corpus: the committed seeds, and each sample trimmed to its first 40
# poses (the edges among them, in file order).
for t in "${targets[@]}"; do
    mkdir -p "fuzz/corpus/$t"
    cp fuzz/seeds/*.g2o "fuzz/corpus/$t/"
    for f in g2o_samples/*.g2o; do
        awk '($1 ~ /^VERTEX/ && $2 < 40) || ($1 ~ /^EDGE/ && $2 < 40 && $3 < 40) || $1 == "FIX"' \
            "$f" > "fuzz/corpus/$t/sample-$(basename "$f")"
    done
done

for t in "${targets[@]}"; do
    echo "== fuzzing $t for $seconds s"
    # The optimize target skips inputs above 8 KiB; parse gets up to 64 KiB
    # so that the line-length limit is reachable; write, 16 KiB.
    max_len=8192
    [ "$t" = parse ] && max_len=70000
    [ "$t" = write ] && max_len=16384
    cargo fuzz run "$t" "fuzz/corpus/$t" -- \
        -max_total_time="$seconds" -max_len="$max_len" -timeout=10 -rss_limit_mb=2048 \
        -print_final_stats=1
done
