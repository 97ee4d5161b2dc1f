#!/usr/bin/env bash
# Times rig on a model package at guidance 1 and 9: load, warm-up (the first step's extra
# cost) and steady-state time per image, N images made in batches as a fill makes them. Each
# guidance runs in its own process, so each pays (and reports) its own load and warm-up.
#
#   scripts/gpu-bench-rig.sh PACKAGE CONTROL.png PROMPT INIT_LATENTS.npy [IMAGES] [BATCH] [-- RIG FLAGS...]
#
# e.g. scripts/gpu-bench-rig.sh sd15-pkg control.png "a tactile image" x_T.npy 16 4 -- \
#        --provider cuda --ort-lib /opt/ort-gpu/lib --cudnn-conv-search heuristic
# Without `-- FLAGS` it runs on the CPU provider. RIG (default: target/release/rig, built
# if missing) names another binary; STEPS (default 50) the DDIM steps.
set -euo pipefail
pos=()
while [ $# -gt 0 ] && [ "$1" != "--" ]; do pos+=("$1"); shift; done
[ "${1:-}" = "--" ] && shift
if [ ${#pos[@]} -lt 4 ] || [ ${#pos[@]} -gt 6 ]; then
    sed -n '2,11p' "$0" | sed 's/^# \{0,1\}//'
    exit 2
fi
pkg=${pos[0]} control=${pos[1]} prompt=${pos[2]} latents=${pos[3]}
images=${pos[4]:-16}
batch=${pos[5]:-4}
here=$(cd "$(dirname "$0")/.." && pwd)
rig=${RIG:-$here/target/release/rig}
if [ ! -x "$rig" ]; then
    (cd "$here" && cargo build --release --locked --bin rig)
fi
steps=${STEPS:-50}
echo "package $pkg, $images images in batches of $batch, $steps DDIM steps; flags: ${*:-(cpu)}"
for g in 1 9; do
    "$rig" synth bench --model "$pkg" --control "$control" --prompt "$prompt" --init-latents "$latents" \
        --images "$images" --batch "$batch" --steps "$steps" --sampler ddim --eta 0 --guidance "$g" --json "$@" \
        | tee /dev/stderr | tail -n 1 > "${TMPDIR:-/tmp}/rig-bench-g$g.json"
done
python3 - "${TMPDIR:-/tmp}/rig-bench-g1.json" "${TMPDIR:-/tmp}/rig-bench-g9.json" <<'PY'
import json, sys
g1, g9 = (json.load(open(p)) for p in sys.argv[1:3])
print("| | guidance 1 | guidance 9 |")
print("|---|---|---|")
for key, name in [("load_s", "load, s"), ("warmup_s", "warm-up (first step), s"), ("steady_s_per_image", "steady state, s an image")]:
    print(f"| {name} | {g1[key]:.3f} | {g9[key]:.3f} |")
print(f"guidance 9 / guidance 1, steady state: {g9['steady_s_per_image'] / g1['steady_s_per_image']:.2f}x")
PY
