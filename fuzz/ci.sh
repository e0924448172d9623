#!/usr/bin/env bash
# Builds every fuzz target and runs each for a short while from the committed corpus.
# A crash fails the script; libFuzzer leaves the input under fuzz/artifacts/<target>/.
# FUZZ_SECONDS sets the time per target (default 20); FUZZ_DEV=1 builds unoptimised (with overflow
# checks), a minute quicker from cold, for a short smoke run. New inputs go to a scratch corpus
# under fuzz/target/, so the committed corpus only changes on purpose.
set -euo pipefail
cd "$(dirname "$0")"
seconds="${FUZZ_SECONDS:-20}"

if ! cargo fuzz --version >/dev/null 2>&1; then
    cargo install cargo-fuzz --locked
fi

# Stable Rust: no sanitizer (they need nightly); libFuzzer's coverage and crash detection remain.
mode=()
if [ "${FUZZ_DEV:-0}" = 1 ]; then
    mode=(--dev)
fi
cargo fuzz build "${mode[@]}" --sanitizer none
for target in $(cargo fuzz list); do
    scratch="target/ci-corpus/$target"
    mkdir -p "$scratch" "corpus/$target"
    echo "== fuzz $target for ${seconds}s"
    cargo fuzz run "$target" "${mode[@]}" --sanitizer none "$scratch" "corpus/$target" -- \
        -max_total_time="$seconds" -timeout=10 -rss_limit_mb=2048 -print_final_stats=1
done
