#!/usr/bin/env bash
# The main job on the simulated rig: collect 50 poses of the demo plan from the three simulated
# sensors (simulated MG400 over TCP on loopback), then synthesise the 85 grid poses not
# collected. Installs what it needs first. Re-running continues where it stopped.
set -euo pipefail
cd "$(dirname "$0")/.."
# RIG_DEMO_BIN=PATH runs a rig binary already built instead (no set-up, no build): how
# `scripts/check-docs.py --tour RIG --after-demo` runs the demo before the README's tour.
if [ -n "${RIG_DEMO_BIN:-}" ]; then
  RIG="$RIG_DEMO_BIN"
else
  RIG_SETUP_BROWSER=0 ./scripts/setup.sh
  cargo build --release --locked --quiet
  RIG=./target/release/rig
fi
OUT="${RIG_DEMO_OUT:-datasets}"
$RIG collect --object sphere --plan plans/demo.toml --sensor all --out "$OUT" --resume
$RIG synth --fill-missing --dataset "$OUT/sphere"
for s in tactip vitac vitactip; do
  $RIG dataset verify "$OUT/sphere/$s" | tail -n 1
done
