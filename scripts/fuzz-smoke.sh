#!/usr/bin/env bash
# Smoke-runs the cargo-fuzz targets in fuzz/ for a few seconds each (CI) and exits non-zero
# if any target finds a crash. Installs cargo-fuzz when it is missing.
#
# Targets: MG400 replies and requests (reply_decoder), feedback frames (feedback_decoder),
# Dobot Magician serial packets (magician_decoder), the recording file (recording_decoder),
# STL (stl_decoder), plan TOML (plan_toml), the daemon's job requests, JSON to validated
# and confined request (job_request), and the model package loader's model.toml,
# scheduler_config.json and tokenizer.json (package_loader, seeded with the tiny package). The firmware profile, calibration and rig config TOML and
# the MDS CSV import have no cargo-fuzz target (they reach too far into rig to compile
# alone); tests/files/decoders_never_panic.rs covers them, and every decoder here, with
# proptest as part of `cargo test`.
#
# Only a stable toolchain is installed here; cargo fuzz passes nightly-only flags (-Z...),
# which RUSTC_BOOTSTRAP=1 unlocks on stable. Where cargo fuzz cannot run at all, the same
# decoders are covered by the proptest fallbacks `decoders_never_panic` and
# `mutated_valid_input_never_panics` in src/arm/dobot/proto.rs, `decoder_never_panics` in
# src/arm/magician/proto.rs and tests/files/decoders_never_panic.rs (part of `cargo test`).
#
# The targets are built once, in cargo's dev profile (`--dev`: unoptimised, with debug
# assertions, overflow checks and AddressSanitizer, as cargo fuzz's default has): a smoke run of
# seconds gains nothing from optimised code, and the build is half the time. Measured with an
# empty target folder on a 2-core machine (`cargo fuzz build`, all eight targets): 1 min 42 s with
# `--dev`, 3 min 33 s for cargo fuzz's default release build (one codegen unit per crate).
# RIG_FUZZ_RELEASE=1 builds and runs the release build instead (for longer runs, where the
# fuzzer's speed matters). Installing cargo-fuzz was not timed here (it was preinstalled); each
# run is the given seconds plus about a second of start-up.
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
profile=(--dev)
[ "${RIG_FUZZ_RELEASE:-0}" = 1 ] && profile=()
cargo fuzz build --fuzz-dir fuzz "${profile[@]}"
for target in $(cargo fuzz list); do
  echo "fuzz-smoke: $target for ${seconds}s"
  mkdir -p "fuzz/corpus/$target"
  # Committed seeds (fuzz/seeds/<target>/) and a dictionary (fuzz/<target>.dict) where a
  # target has them: a few seconds of random bytes rarely make a valid JSON request.
  seeds=()
  [ -d "fuzz/seeds/$target" ] && seeds=("fuzz/seeds/$target")
  dict=()
  [ -f "fuzz/$target.dict" ] && dict=("-dict=fuzz/$target.dict")
  cargo fuzz run --fuzz-dir fuzz "${profile[@]}" "$target" "fuzz/corpus/$target" "${seeds[@]}" -- -max_total_time="$seconds" -rss_limit_mb=2048 "${dict[@]}"
done
echo "fuzz-smoke: no crashes"
