#!/usr/bin/env bash
# The downstream tables of docs/src/evaluation.md#is-the-fill-worth-training-on-rig-eval---downstream:
# the edge collected by the three simulated sensors with plans/downstream.toml (180 of 324 grid
# poses), the other 144 filled by MODEL, then `rig eval --downstream` at the small scale, and its
# shuffled-label control; both tables are appended to $OUT/downstream.md (JSON beside it).
#
# Usage: tools/downstream_sim.sh [MODEL]        (default models/default)
# Environment: RIG (binary, default target/release/rig, built if missing), OUT (default
# out/downstream), OBJECT (default edge), SCALE (default small). Every step resumes.
set -euo pipefail
cd "$(dirname "$0")/.."

MODEL=${1:-models/default}
RIG=${RIG:-target/release/rig}
OUT=${OUT:-out/downstream}
OBJECT=${OBJECT:-edge}
SCALE=${SCALE:-small}

if [ ! -x "$RIG" ]; then
    cargo build --release --locked
fi
mkdir -p "$OUT"
"$RIG" collect --object "$OBJECT" --plan plans/downstream.toml --sensor all --out "$OUT/data" --resume
"$RIG" synth --fill-missing --dataset "$OUT/data/$OBJECT" --model "$MODEL"
"$RIG" eval --downstream "$OUT/data" --scale "$SCALE" --markdown "$OUT/downstream.md" --json "$OUT/downstream.json"
"$RIG" eval --downstream "$OUT/data" --scale "$SCALE" --shuffle-labels --markdown "$OUT/downstream.md" --json "$OUT/downstream-control.json"
