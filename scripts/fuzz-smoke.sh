#!/usr/bin/env bash
# Smoke-runs the cargo-fuzz targets in fuzz/ for a few seconds each (CI) and exits non-zero
# if any target finds a crash. Installs cargo-fuzz when it is missing.
#
# Targets: reply_decoder and feedback_decoder (MG400), magician_decoder (Dobot Magician serial
# packets, src/arm/magician/proto.rs).
#
# Only a stable toolchain is installed here; cargo fuzz passes nightly-only flags (-Z...),
# which RUSTC_BOOTSTRAP=1 unlocks on stable. Where cargo fuzz cannot run at all, the same
# decoders are covered by the proptest fallbacks `decoders_never_panic` and
# `mutated_valid_input_never_panics` in src/arm/dobot/proto.rs and `decoder_never_panics` in
# src/arm/magician/proto.rs (part of `cargo test`).
#
# Usage: scripts/fuzz-smoke.sh [seconds-per-target]   (default 10)
set -euo pipefail
cd "$(dirname "$0")/.."
seconds="${1:-${FUZZ_SECONDS:-10}}"

if ! cargo fuzz --version >/dev/null 2>&1; then
  echo "fuzz-smoke: installing cargo-fuzz"
  cargo install cargo-fuzz --locked
fi

export RUSTC_BOOTSTRAP=1
for target in $(cargo fuzz list); do
  echo "fuzz-smoke: $target for ${seconds}s"
  mkdir -p "fuzz/corpus/$target"
  cargo fuzz run --fuzz-dir fuzz "$target" -- -max_total_time="$seconds" -rss_limit_mb=2048
done
echo "fuzz-smoke: no crashes"
