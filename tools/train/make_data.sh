#!/usr/bin/env bash
# Collects the training set of the default synthesis model on the simulated rig and renders,
# for every row, the control image and prompt exactly as `rig synth --fill-missing` makes them.
#
#   tools/train/make_data.sh [RIG_BINARY]        (default: target/release/rig)
#
# Writes out/train-data/<object>/<sensor>/ (datasets), out/train-controls/<object>/<sensor>/
# (<pose_id>.png at 128x128 + prompts.csv) and out/train/data.npz (the packed arrays train.py
# reads). SIZE=256 (say) renders the hints and packs the data at that size instead, into
# out/train-controls-256/ and out/train-256/data.npz. To train on a real rig's data, collect with your rig.toml instead (same command) or
# point prepare.py at your own datasets (see docs/src/training.md, "Retraining on your own data").
set -euo pipefail
cd "$(dirname "$0")/../.."
RIG=${1:-target/release/rig}
PY=${PYTHON:-.venv/bin/python}
OBJECTS=${OBJECTS:-"edge cuboid sphere pacman cross"}
SIZE=${SIZE:-128}
# 128 px (the default model's size) uses the plain paths; other sizes get their own, so
# the 128 px data is not overwritten: out/train-controls-<SIZE>, out/train-<SIZE>/data.npz.
if [ "$SIZE" = 128 ]; then SUFFIX=""; else SUFFIX="-$SIZE"; fi
# One collection per object, all at once: each starts its own simulated rig on free loopback
# ports, and most of a collection's time is the simulated arm's motion, not CPU.
pids=()
for o in $OBJECTS; do
  "$RIG" collect --plan plans/train.toml --object "$o" --sensor all --out out/train-data --resume &
  pids+=($!)
done
for p in "${pids[@]}"; do wait "$p"; done
pids=()
for o in $OBJECTS; do
  for s in tactip vitac vitactip; do
    "$RIG" render --controls-of "out/train-data/$o/$s" --size "${SIZE}x${SIZE}" --out "out/train-controls$SUFFIX/$o/$s" &
    pids+=($!)
  done
  for p in "${pids[@]}"; do wait "$p"; done
  pids=()
done
"$PY" tools/train/prepare.py --data out/train-data --controls "out/train-controls$SUFFIX" --size "$SIZE" --out "out/train$SUFFIX/data.npz"
