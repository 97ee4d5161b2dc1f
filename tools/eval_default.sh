#!/usr/bin/env bash
# The evaluation behind the `rig eval` tables of docs/src/evaluation.md: test sets for all 8 objects
# collected on the simulated rig with plans/test.toml, their synthetic twins made by MODEL, and
# `rig eval` twice, appending both tables to out/eval.md (JSON and per-pose CSV beside it):
#
#   unseen poses    training objects (edge cuboid sphere pacman cross) at the test plan's poses;
#                   poses also in out/train-data are dropped by rig eval
#   unseen objects  hollow_cylinder cone wedge, never trained on
#
# Both use out/train-data (tools/train/make_data.sh: `rig collect --plan plans/train.toml
# --object O --sensor all --out out/train-data` per training object) as the collected set the
# baselines come from.
#
# The test sets are collected with tools/train/training-unit.toml: the same simulated sensor
# units (static specks and dust) as the training collection.
#
# Usage: tools/eval_default.sh [MODEL]        (default models/default)
# Environment (for a quick try): RIG (binary, default target/release/rig, built if missing),
# OUT (default out), TEST_PLAN (default plans/test.toml), STEPS (sampling steps, default 20),
# SIZE (px measured at, default 128), TRAIN_OBJECTS, TEST_OBJECTS.
# Every step resumes: run it again after an interruption.
set -euo pipefail
cd "$(dirname "$0")/.."

MODEL=${1:-models/default}
RIG=${RIG:-target/release/rig}
OUT=${OUT:-out}
TEST_PLAN=${TEST_PLAN:-plans/test.toml}
STEPS=${STEPS:-20}
SIZE=${SIZE:-128}
TRAIN_OBJECTS=${TRAIN_OBJECTS:-"edge cuboid sphere pacman cross"}
TEST_OBJECTS=${TEST_OBJECTS:-"hollow_cylinder cone wedge"}

if [ ! -x "$RIG" ]; then
    cargo build --release
fi
if [ ! -d "$OUT/train-data" ]; then
    echo "error: no $OUT/train-data (the training collection); run tools/train/make_data.sh first" >&2
    exit 2
fi
if [ ! -f "$MODEL/model.toml" ]; then
    echo "error: $MODEL is not a model package (no model.toml)" >&2
    exit 2
fi

echo "== collecting the test sets ($TEST_PLAN) into $OUT/test-data"
for o in $TRAIN_OBJECTS $TEST_OBJECTS; do
    "$RIG" collect --config tools/train/training-unit.toml --plan "$TEST_PLAN" --object "$o" \
        --sensor all --out "$OUT/test-data" --resume
done

echo "== synthesising their poses with $MODEL into $OUT/synth-test"
"$RIG" synth --poses-of "$OUT/test-data" --out "$OUT/synth-test" --model "$MODEL" --steps "$STEPS"

echo "== rig eval"
objects_flags() { for o in "$@"; do printf -- '--object\n%s\n' "$o"; done; }
mapfile -t seen < <(objects_flags $TRAIN_OBJECTS)
mapfile -t unseen < <(objects_flags $TEST_OBJECTS)
"$RIG" eval --real "$OUT/test-data" --synthetic "$OUT/synth-test" --collected "$OUT/train-data" \
    "${seen[@]}" --size "$SIZE" --label "unseen poses, model $(basename "$MODEL")" \
    --markdown "$OUT/eval.md" --json "$OUT/eval-unseen-poses.json" --pairs "$OUT/pairs-unseen-poses.csv"
"$RIG" eval --real "$OUT/test-data" --synthetic "$OUT/synth-test" --collected "$OUT/train-data" \
    "${unseen[@]}" --size "$SIZE" --label "unseen objects, model $(basename "$MODEL")" \
    --markdown "$OUT/eval.md" --json "$OUT/eval-unseen-objects.json" --pairs "$OUT/pairs-unseen-objects.csv"
echo "tables appended to $OUT/eval.md"
