#!/usr/bin/env bash
# Chooses `rig eval`'s contact estimator for each sensor on TRUE images only: for every
# BLUR_DIVISOR,REGION_FRACTION of a grid it runs `rig eval --estimator D,F` with the collected
# (real) images standing in as their own twins, and prints what the estimator gets wrong on
# them against the contact each commanded pose gives the mesh (position mm, yaw deg, and how
# many images gave an estimate). No model's image is ever looked at, so the choice cannot
# favour a method; run it on training data, never on a test set.
#
# This is how eval::ContactEstimator::{TACTIP, VITAC, VITACTIP} were chosen (docs/src/evaluation.md,
# "Choosing the estimator"): out/train-data, object edge (the one whose contact has a yaw).
#
# Usage: tools/tune_estimator.sh [DATA]        (default out/train-data)
# Environment: RIG (binary, default target/release/rig, built if missing), OBJECTS (default
# "edge"), DIVISORS (default "128 64 32"), FRACTIONS (default "0 0.1 0.2 0.3 0.4 0.5"),
# SIZE (px, default 128).
set -euo pipefail
cd "$(dirname "$0")/.."

DATA=${1:-out/train-data}
RIG=${RIG:-target/release/rig}
OBJECTS=${OBJECTS:-edge}
DIVISORS=${DIVISORS:-"128 64 32"}
FRACTIONS=${FRACTIONS:-"0 0.1 0.2 0.3 0.4 0.5"}
SIZE=${SIZE:-128}

if [ ! -x "$RIG" ]; then
    cargo build --release
fi
if [ ! -d "$DATA" ]; then
    echo "error: no $DATA (collect one with rig collect, e.g. tools/train/make_data.sh)" >&2
    exit 2
fi

# The true images as their own synthetic twins: a view of DATA whose rows say source=synthetic
# (images and reference linked, not copied).
view=$(mktemp -d)
trap 'rm -rf "$view"' EXIT
object_flags=()
for o in $OBJECTS; do
    object_flags+=(--object "$o")
    for ds in "$DATA/$o"/*/; do
        ds=${ds%/}
        [ -f "$ds/poses.csv" ] || continue
        v="$view/$o/$(basename "$ds")"
        mkdir -p "$v"
        ln -s "$(realpath "$ds/images")" "$v/images"
        ln -s "$(realpath "$ds/reference.png")" "$v/reference.png"
        cp "$ds/manifest.toml" "$v/"
        sed 's/,real,/,synthetic,/' "$ds/poses.csv" > "$v/poses.csv"
    done
done

printf '%-9s %8s %9s %12s %12s %12s\n' sensor divisor fraction "pos err mm" "yaw err deg" found
for d in $DIVISORS; do
    for f in $FRACTIONS; do
        # --collected is the view itself: it has no real rows, so no baseline is computed and
        # no pose is dropped as seen.
        "$RIG" eval --real "$DATA" --synthetic "$view" --collected "$view" "${object_flags[@]}" \
            --size "$SIZE" --label tune --estimator "$d,$f" --json "$view/eval.json" > /dev/null
        python3 - "$view/eval.json" "$d" "$f" <<'EOF'
import json, sys
report = json.load(open(sys.argv[1]))
for r in report["rows"]:
    if r["method"] != "true-image":
        continue
    fmt = lambda v, k: "n/a" if v is None else f"{v:.{k}f}"
    print(f"{r['sensor']:<9} {sys.argv[2]:>8} {sys.argv[3]:>9} {fmt(r['position_err_mm'], 3):>12} "
          f"{fmt(r['yaw_err_deg'], 3):>12} {r['position_found']:>5}/{r['position_attempts']:<6}")
EOF
    done
done
