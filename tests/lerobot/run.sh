#!/usr/bin/env bash
# The LeRobot export checked by readers rig shares no code with. scripts/test.sh runs it after
# cargo test; see docs/src/testing.md#the-lerobot-export-check.
#
#   tests/lerobot/run.sh
#
# 1. Makes .rig/pycheck, a Python venv with pyarrow, Pillow and numpy (pip; skipped when there).
# 2. Collects a small plan of two objects (edge, sphere) with the three simulated sensors, and
#    fills the poses not collected with the tiny test model, so the export holds simulated and
#    synthetic frames, two episodes and three image keys.
# 3. Exports it with `rig dataset export --format lerobot`, once as is (one data file) and once
#    with --max-file-mb 3 (ten data files, episodes cut where the files are), and runs
#    tools/check_lerobot.py on each with --datasets: every file within the size bound and read
#    whole by pyarrow, the schema against meta/info.json, row and episode counts, each episode in
#    the data file it names, every image decoded by Pillow, tasks, stats, and every frame against
#    its dataset row (pose, source, pixels).
# 4. Opt-in: with RIG_LEROBOT_PYTHON set to a Python that has the `lerobot` package, also loads
#    both exports with LeRobotDataset from the local folder (HF_HUB_OFFLINE=1) and iterates every
#    frame (tools/check_lerobot.py --lerobot).
#
# RIG_BIN: the rig binary (default: target/release/rig, built here). Everything is written to a
# temporary folder, removed at the end unless RIG_LEROBOT_KEEP=1 or a check failed.
set -euo pipefail
cd "$(dirname "$0")/../.."
repo="$(pwd)"
say() { echo "lerobot-test: $*"; }
fail() { echo "lerobot-test: FAIL: $*" >&2; echo "lerobot-test: files kept in $work" >&2; exit 1; }

if [ -n "${RIG_BIN:-}" ]; then
  rig="$(cd "$(dirname "$RIG_BIN")" && pwd)/$(basename "$RIG_BIN")"
else
  cargo build --release --locked --quiet
  rig="$repo/target/release/rig"
fi
model="$repo/tests/data/tiny-package"
ort_lib="$repo/.rig/onnxruntime"

# --- 1. pyarrow ------------------------------------------------------------------------------
venv="$repo/.rig/pycheck"
. "$repo/scripts/lib/pyvenv.sh"
pyvenv "$venv" "pyarrow, PIL, numpy" "pyarrow==26.0.1" "pillow==13.0.0" "numpy==2.2.6"

# --- 2. data ---------------------------------------------------------------------------------
work=$(mktemp -d)
cat > "$work/plan.toml" <<'PLAN'
# 2 x 2 x 1 x 3 = 12 grid poses; 5 collected, 7 per sensor filled.
sampling = "random"
n_poses = 5
seed = 3
order = "optimised"
[x_mm]
min = -1.0
max = 1.0
step = 2.0
[y_mm]
min = -1.0
max = 1.0
step = 2.0
[z_mm]
min = 0.0
max = 0.0
step = 1.0
[yaw_deg]
min = -30.0
max = 30.0
step = 30.0
PLAN
for object in edge sphere; do
  "$rig" collect --object "$object" --sensor all --plan "$work/plan.toml" --out "$work/datasets" >"$work/collect-$object.log" 2>&1 \
    || { cat "$work/collect-$object.log"; fail "rig collect $object failed"; }
  "$rig" synth --fill-missing --dataset "$work/datasets/$object" --model "$model" --ort-lib "$ort_lib" --threads 1 --steps 4 \
    >"$work/fill-$object.log" 2>&1 || { cat "$work/fill-$object.log"; fail "rig synth --fill-missing $object failed"; }
done
say "collected 5 poses of edge and sphere with three simulated sensors, filled the other 7 of each"

# --- 3. export and check ---------------------------------------------------------------------
# Once with the default bound (100 MB: one data file), once with files of at most 3 MB: a frame
# of three 640 x 480 images is about 1 MB, so the 24 frames roll over ten data files and
# the objects' episodes end with them.
"$rig" dataset export "$work/datasets" --format lerobot --out "$work/lerobot" --fps 5 || fail "the export failed"
"$rig" dataset export "$work/datasets" --format lerobot --out "$work/lerobot-rolled" --fps 5 --max-file-mb 3 \
  || fail "the export with --max-file-mb 3 failed"
for export in lerobot lerobot-rolled; do
  "$venv/bin/python" tools/check_lerobot.py "$work/$export" --datasets "$work/datasets" || fail "tools/check_lerobot.py $export"
  frames=$("$venv/bin/python" -c 'import json, sys; print(json.load(open(sys.argv[1]))["total_frames"])' "$work/$export/meta/info.json")
  [ "$frames" = 24 ] || fail "$export holds $frames frames, not 2 objects x 12 poses"
done
files=$(find "$work/lerobot-rolled/data" -name '*.parquet' | wc -l)
[ "$files" -ge 4 ] || fail "--max-file-mb 3 wrote $files data files; the check meant to read several"
say "the export with --max-file-mb 3 has $files data files, each read whole by pyarrow"

# --- 4. LeRobotDataset (opt-in) --------------------------------------------------------------
if [ -n "${RIG_LEROBOT_PYTHON:-}" ]; then
  for export in lerobot lerobot-rolled; do
    HF_HOME="$work/hf" HF_HUB_OFFLINE=1 "$RIG_LEROBOT_PYTHON" tools/check_lerobot.py "$work/$export" --lerobot \
      || fail "LeRobotDataset did not load $export"
  done
else
  say "LeRobotDataset check skipped (opt-in: RIG_LEROBOT_PYTHON=<python with lerobot>)"
fi

if [ "${RIG_LEROBOT_KEEP:-0}" = 1 ]; then
  say "files kept in $work"
else
  rm -rf "$work"
fi
say "ok"
