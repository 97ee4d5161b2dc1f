#!/usr/bin/env bash
# Adaptive collection against a Latin hypercube of as many presses, on the simulated rig,
# where the truth at every pose is free: per seed, the simulator collects the whole grid (the
# truth), `rig collect --adaptive` presses BUDGET poses and fills the rest, and a Latin
# hypercube of BUDGET poses is collected and filled by `rig synth --fill-missing` with the same
# model and steps. `rig eval --pairs` compares each filled dataset's synthesised poses with the
# truth; the table is the mean contact SSIM of the model's images over those poses, pooled over
# the seeds, with a 95% percentile-bootstrap interval, per sensor and method; then each seed's
# mean and the mean of the worst tenth of the poses; then, per seed, the most any choice of presses
# could gain (the best possible mean over the poses filled, from the union of both methods').
#
#   scripts/adaptive-vs-lhs.sh OUT [MODEL] [SEED...]
#
# The simulated sensor renders 128 px frames (OUT/rig.toml), the size of models/default.
# With DOWNSTREAM=1, each filled dataset is also judged by what it teaches: `rig eval --downstream`
# on the seed's truth with the method's synthesised rows as the synthetic pool (`--synthetic`,
# `--sets synthetic`), so both methods' regressors are tested on the same held-out truth rows
# (20 of the 100, drawn once from --seed 1), trained on the same number of rows (TRAIN_SIZE, 50),
# 3 regressor seeds each; the table pools X and yaw R² and MAE over seeds, and Z's where the plan
# has depth.
# Environment: RIG (default target/release/rig, else target/debug/rig), OBJECT (sphere), SENSOR (tactip),
# STEPS (model sampling steps, 5), BUDGET (30 of the 100-pose grid), ROUNDS (3), SEEDS_PER_POSE (2),
# DOWNSTREAM (0), TRAIN_SIZE (50), SIZE (regressor input px, 64), Z_MIN, Z_MAX, Z_STEP (the plan's
# depth axis in mm, 0, 0, 1: one depth; z -1 to 1 by 1 makes the grid 300 poses, then set BUDGET 90),
# X_MIN, X_MAX, X_STEP and Y_MIN, Y_MAX, Y_STEP (the plan's x and y axes in mm, -4, 4, 2 each: the
# range models/default was trained on; x -8 to 8 by 4 reaches 4 mm past it with as many poses),
# PRESS_LIMIT_MM (unset: the sensor's default press limit; set, the simulated sensor's
# max_indentation_mm in OUT/rig.toml, e.g. 4.5 to let a ViTac plan reach z 3 on the simulator,
# whose skin takes any press: a real ViTac's default limit is 2.5 mm, z 1).
set -euo pipefail
out=${1:?usage: scripts/adaptive-vs-lhs.sh OUT [MODEL] [SEED...]}
model=${2:-models/default}
shift $(( $# >= 2 ? 2 : 1 ))
seeds=${*:-1 2 3}
rig=${RIG:-$( [ -x target/release/rig ] && echo target/release/rig || echo target/debug/rig )}
sensor=${SENSOR:-tactip}
object=${OBJECT:-sphere}
steps=${STEPS:-5}
budget=${BUDGET:-30}
rounds=${ROUNDS:-3}
k=${SEEDS_PER_POSE:-2}
mkdir -p "$out"
# The simulated sensor's frames at the model's 128 px (models/default): no upscaled fill.
printf '[sensors.%s]\nwidth = 128\nheight = 128\n' "$sensor" > "$out/rig.toml"
if [ -n "${PRESS_LIMIT_MM:-}" ]; then printf 'max_indentation_mm = %s\n' "$PRESS_LIMIT_MM" >> "$out/rig.toml"; fi

z_min=${Z_MIN:-0.0} z_max=${Z_MAX:-0.0} z_step=${Z_STEP:-1.0}
x_min=${X_MIN:--4.0} x_max=${X_MAX:-4.0} x_step=${X_STEP:-2.0}
y_min=${Y_MIN:--4.0} y_max=${Y_MAX:-4.0} y_step=${Y_STEP:-2.0}
plan() { # plan SEED SAMPLING-LINES > file: x, y as set ([-4, 4] mm by 2), z as set (0), yaw -90..45 by 45: 100 poses a depth
    printf '%s\nseed = %s\norder = "optimised"\n' "$2" "$1"
    printf '[x_mm]\nmin = %s\nmax = %s\nstep = %s\n[y_mm]\nmin = %s\nmax = %s\nstep = %s\n' "$x_min" "$x_max" "$x_step" "$y_min" "$y_max" "$y_step"
    printf '[z_mm]\nmin = %s\nmax = %s\nstep = %s\n[yaw_deg]\nmin = -90.0\nmax = 45.0\nstep = 45.0\n' "$z_min" "$z_max" "$z_step"
}

for seed in $seeds; do
    plan "$seed" 'sampling = "full"' > "$out/full-$seed.toml"
    plan "$seed" "$(printf 'sampling = "lhs"\nn_poses = %s' "$budget")" > "$out/lhs-$seed.toml"
    [ -f "$out/truth-$seed/$object/$sensor/poses.csv" ] && r=--resume || r=
    "$rig" collect --object "$object" --plan "$out/full-$seed.toml" --sensor "$sensor" --config "$out/rig.toml" --out "$out/truth-$seed" $r
    "$rig" collect --object "$object" --adaptive --budget "$budget" --rounds "$rounds" --seeds-per-pose "$k" --steps "$steps" \
        --model "$model" --plan "$out/full-$seed.toml" --sensor "$sensor" --config "$out/rig.toml" --out "$out/adaptive-$seed" --resume
    "$rig" collect --object "$object" --plan "$out/lhs-$seed.toml" --sensor "$sensor" --config "$out/rig.toml" --out "$out/lhs-$seed" --resume
    "$rig" synth --fill-missing --dataset "$out/lhs-$seed" --model "$model" --steps "$steps"
    for method in adaptive lhs; do
        "$rig" eval --real "$out/truth-$seed" --synthetic "$out/$method-$seed" --pairs "$out/pairs-$method-$seed.csv" > "$out/eval-$method-$seed.md"
        if [ "${DOWNSTREAM:-0}" = 1 ]; then
            "$rig" eval --downstream "$out/truth-$seed" --synthetic "$out/$method-$seed" --sets synthetic --seeds 3 --seed 1 \
                --train-size "${TRAIN_SIZE:-50}" --size "${SIZE:-64}" --json "$out/downstream-$method-$seed.json" > "$out/downstream-$method-$seed.md"
        fi
    done
done

python3 - "$out" $seeds <<'PY'
import csv, random, sys
out, seeds = sys.argv[1], sys.argv[2:]
def boot(v, n=10000):
    rng = random.Random(1)
    means = sorted(sum(rng.choice(v) for _ in v) / len(v) for _ in range(n))
    return sum(v) / len(v), means[int(0.025 * n)], means[int(0.975 * n) - 1]
rows, by_seed = {}, {}
for method in ("adaptive", "lhs"):
    for seed in seeds:
        with open(f"{out}/pairs-{method}-{seed}.csv") as f:
            for r in csv.DictReader(f):
                if r["method"] == "model" and r["contact_ssim"] not in ("", "nan", "NaN"):
                    rows.setdefault((r["sensor"], method), []).append(float(r["contact_ssim"]))
                    by_seed.setdefault((r["sensor"], method), {}).setdefault(seed, []).append(float(r["contact_ssim"]))
by_seed = {k: list(v.values()) for k, v in by_seed.items()}
print("| sensor | method | n | contact SSIM, mean | 95% interval | per seed | worst tenth, mean |")
print("|---|---|---:|---:|---|---|---:|")
for (sensor, method), v in sorted(rows.items()):
    m, lo, hi = boot(v)
    worst = sorted(v)[: max(1, len(v) // 10)]
    per_seed = ", ".join(f"{sum(x) / len(x):.4f}" for x in by_seed[(sensor, method)])
    print(f"| {sensor} | {method} | {len(v)} | {m:.4f} | [{lo:.4f}, {hi:.4f}] | {per_seed} | {sum(worst) / len(worst):.4f} |")

# The ceiling of any choice of presses: the model's image at a pose does not depend on which
# poses were pressed (its seed is the pose's), so the union of the two methods' synthesised poses
# gives the fill's contact SSIM at most of the grid. Pressing the worst poses of those would
# leave the best ones to fill: "best possible" is the mean of the best as many poses as each
# method synthesised, against the mean over every pose known.
print()
print("| sensor | seed | poses known | mean, every pose known | best possible | adaptive | lhs |")
print("|---|---|---:|---:|---:|---:|---:|")
for sensor in sorted({s for s, _ in rows}):
    for seed in seeds:
        at, n = {}, {}
        for method in ("adaptive", "lhs"):
            with open(f"{out}/pairs-{method}-{seed}.csv") as f:
                got = [r for r in csv.DictReader(f) if r["sensor"] == sensor and r["method"] == "model" and r["contact_ssim"] not in ("", "nan", "NaN")]
            for r in got:
                at[r["pose_id"]] = float(r["contact_ssim"])
            n[method] = (len(got), sum(float(r["contact_ssim"]) for r in got) / max(1, len(got)))
        k = n["lhs"][0]
        vals = sorted(at.values())
        best = sum(vals[-k:]) / k if k and len(vals) >= k else float("nan")
        print(f"| {sensor} | {seed} | {len(vals)} | {sum(vals) / len(vals):.4f} | {best:.4f} | {n['adaptive'][1]:.4f} | {n['lhs'][1]:.4f} |")
PY

[ "${DOWNSTREAM:-0}" = 1 ] || exit 0
python3 - "$out" $seeds <<'PY'
import json, statistics, sys
out, seeds = sys.argv[1], sys.argv[2:]
rows = {}
for method in ("adaptive", "lhs"):
    for seed in seeds:
        with open(f"{out}/downstream-{method}-{seed}.json") as f:
            report = json.load(f)
        for s in report["sensors"]:
            for t in s["sets"]:
                for r in t["seeds"]:
                    x, z, yaw = r["scores"]
                    rows.setdefault((s["sensor"], method), []).append((x["r2"], x["mae"], yaw["r2"], yaw["mae"], z["r2"], z["mae"]))
# Z is scored only where the plan has depth (its R² is null on one depth).
depth = all(r[4] is not None for v in rows.values() for r in v)
print()
print("| sensor | method | regressors | X R² | X MAE (mm) | yaw R² | yaw MAE (deg) |" + (" Z R² | Z MAE (mm) |" if depth else ""))
print("|---|---|---:|---:|---:|---:|---:|" + ("---:|---:|" if depth else ""))
for (sensor, method), v in sorted(rows.items()):
    cell = lambda k: f"{statistics.mean(r[k] for r in v):.3f} ± {statistics.stdev(r[k] for r in v):.3f}"
    cells = [cell(k) for k in range(6 if depth else 4)]
    print(f"| {sensor} | {method} | {len(v)} | " + " | ".join(cells) + " |")
PY
