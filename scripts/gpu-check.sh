#!/usr/bin/env bash
# rig against diffusers on a GPU, full size: builds a Stable Diffusion 1.5 + ControlNet pipeline
# with random weights and the real shapes (tools/build_sd15.py), exports it as rig packages in
# float32 and float16 (tools/export_package.py --diffusers), runs rig and diffusers from the same
# initial latents on the same GPU, and prints the parity, the timing table, the fills' split (load,
# warm-up, steady state) and the issue's GPU acceptance criteria, each met or NOT met. The tables
# come from the logs it keeps in the work folder: `tools/gpu_check_summary.py WORK_DIR` prints them
# again. See docs/src/benchmarks.md#gpu-rig-against-diffusers.
#
#   RIG_ORT_LIB=/path/to/onnxruntime-gpu/capi scripts/gpu-check.sh
#   scripts/gpu-check.sh --tiny            # a dry run on the CPU: tiny shapes, 4 steps, 2 images
#
# Needs:
#   RIG_ORT_LIB   folder (or file) of ONNX Runtime's CUDA build: libonnxruntime.so.1.31.1 and
#                 libonnxruntime_providers_{shared,cuda}.so (the onnxruntime-gpu 1.31.1 wheel's
#                 onnxruntime/capi/), with CUDA 13 and cuDNN 9 on LD_LIBRARY_PATH (a CUDA 13
#                 PyTorch install has them: site-packages/nvidia/*/lib). Not needed with --tiny
#                 (rig's usual CPU library).
#   RIG_PYTHON    a Python with tools/requirements.txt (torch, diffusers 0.42.1, transformers, onnx,
#                 onnxruntime); default .venv/bin/python. With a GPU, its torch must see it.
#   RIG_BIN       the rig binary (default target/release/rig, built here when missing).
# Optional: GPU_CHECK_DIR (work folder, default .rig/gpu-check; the full-size pipeline and two
# packages take about 17 GB), GPU_CHECK_STEPS (50; --tiny 4), GPU_CHECK_IMAGES (images of the
# fill, 16; --tiny 2), RIG_SHARED (for the MultiDiffSense kit's CLIP tokenizer files and hint).
set -euo pipefail
cd "$(dirname "$0")/.."
repo=$(pwd)

tiny=0
for arg in "$@"; do
  case "$arg" in
    --tiny) tiny=1 ;;
    -h|--help) sed -n '2,26p' "$0"; exit 0 ;;
    *) echo "gpu-check: unknown argument $arg (see --help)" >&2; exit 2 ;;
  esac
done

stage() { echo; echo "== gpu-check: $*"; }
die() { echo "gpu-check: error: $1" >&2; exit "${2:-1}"; }
now() { date +%s.%N; }
# diffusers' and transformers' advice about optional packages, not about this run
quiet() { tr '\r' '\n' | grep -v "should be kept in float32\|^Loading\|accelerate\|^\`\`\`\|^\.$\|requires torchvision" || true; }
since() { awk -v a="$1" -v b="$(now)" 'BEGIN { printf "%.1f", b - a }'; }

py=${RIG_PYTHON:-$repo/.venv/bin/python}
export HF_HUB_DISABLE_PROGRESS_BARS=1 DIFFUSERS_VERBOSITY=error TRANSFORMERS_VERBOSITY=error HF_HUB_OFFLINE=1
shared=${RIG_SHARED:-$repo/../shared}
kit=$shared/multidiffsense-cldm-kit
work=${GPU_CHECK_DIR:-$repo/.rig/gpu-check}
if [ "$tiny" = 1 ]; then
  steps=${GPU_CHECK_STEPS:-4}; images=${GPU_CHECK_IMAGES:-2}; size=64; provider=cpu; device=cpu; work=$work/tiny
else
  steps=${GPU_CHECK_STEPS:-50}; images=${GPU_CHECK_IMAGES:-16}; size=512; provider=cuda; device=cuda
fi

# --- prerequisites -------------------------------------------------------------------------------
stage "prerequisites"
[ -x "$py" ] || die "no Python at $py: make one (python3 -m venv .venv && .venv/bin/pip install -r tools/requirements.txt) or set RIG_PYTHON" 2
"$py" - "$device" <<'PY' || die "prerequisites not met (see above): tools/requirements.txt in RIG_PYTHON, and for a GPU run a torch that sees the GPU" 2
import sys, importlib
bad = []
for name in ("torch", "diffusers", "transformers", "onnx", "onnxruntime", "numpy", "PIL"):
    try:
        m = importlib.import_module(name)
        print(f"  {name} {getattr(m, '__version__', '?')}")
    except ImportError as e:
        bad.append(f"{name} ({e})")
if not bad:
    import diffusers
    if diffusers.__version__ != "0.42.1":
        bad.append(f"diffusers {diffusers.__version__}, not 0.42.1")
    import torch
    if sys.argv[1] == "cuda":
        if not torch.cuda.is_available():
            bad.append("torch sees no CUDA GPU (torch.cuda.is_available() is False)")
        else:
            print(f"  GPU {torch.cuda.get_device_name(0)}")
if bad:
    print("  missing or wrong: " + "; ".join(bad), file=sys.stderr)
    sys.exit(1)
PY
for f in vocab.json merges.txt; do [ -f "$kit/clip/$f" ] || die "$kit/clip/$f not found: set RIG_SHARED to the folder holding multidiffsense-cldm-kit" 2; done
[ -f "$kit/hint.png" ] || die "$kit/hint.png not found (set RIG_SHARED)" 2
ort_args=()
if [ "$tiny" = 0 ]; then
  [ -n "${RIG_ORT_LIB:-}" ] || die "set RIG_ORT_LIB to ONNX Runtime's CUDA build (the onnxruntime-gpu 1.31.1 wheel's onnxruntime/capi folder)" 2
  ort_dir=$RIG_ORT_LIB; [ -d "$ort_dir" ] || ort_dir=$(dirname "$ort_dir")
  for f in libonnxruntime.so.1.31.1 libonnxruntime_providers_shared.so libonnxruntime_providers_cuda.so; do
    [ -f "$ort_dir/$f" ] || die "$ort_dir has no $f: RIG_ORT_LIB must name the onnxruntime-gpu 1.31.1 libraries" 2
  done
  missing=$(LD_LIBRARY_PATH="$ort_dir:${LD_LIBRARY_PATH:-}" ldd "$ort_dir/libonnxruntime_providers_cuda.so" | awk '/not found/ {print $1}' | tr '\n' ' ')
  [ -z "$missing" ] || die "the CUDA provider cannot find: $missing; put CUDA 13's and cuDNN 9's lib folders on LD_LIBRARY_PATH (e.g. site-packages/nvidia/cu13/lib and site-packages/nvidia/cudnn/lib of a CUDA 13 PyTorch)" 2
  command -v nvidia-smi >/dev/null && nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader | sed 's/^/  /'
  ort_args=(--ort-lib "$RIG_ORT_LIB")
fi
if [ -n "${RIG_BIN:-}" ]; then
  rig=$RIG_BIN
else
  rig=$repo/target/release/rig
  [ -x "$rig" ] || { echo "  building rig (cargo build --release)"; cargo build --release --locked --quiet; }
fi
[ -x "$rig" ] || die "no rig binary at $rig" 2
echo "  rig $rig; work folder $work; $size x $size px, $steps steps, provider $provider"
mkdir -p "$work"

# --- the pipeline and its packages ---------------------------------------------------------------
pipe=$work/pipeline
declare -A timing
if [ -f "$pipe/model_index.json" ]; then
  stage "random-weight pipeline: $pipe (kept from an earlier run)"
else
  stage "random-weight pipeline: building $pipe"
  t=$(now)
  "$py" tools/build_sd15.py "$pipe" --clip-dir "$kit/clip" $([ "$tiny" = 1 ] && echo --tiny)
  timing[build]=$(since "$t")
fi
for variant in fp32 fp16; do
  pkg=$work/package-$variant
  if [ -f "$pkg/model.toml" ] && [ "$pkg/model.toml" -nt "$pipe/model_index.json" ]; then
    stage "package $variant: $pkg (kept from an earlier run)"
    continue
  fi
  stage "package $variant: exporting to $pkg"
  t=$(now)
  flags=(); [ "$variant" = fp16 ] && flags=(--fp16)
  "$py" tools/export_package.py --diffusers "$pipe" --resolution "$size" --out "$pkg" "${flags[@]}" 2>&1 | quiet
  timing[export_$variant]=$(since "$t")
  "$rig" synth info --model "$pkg" --provider "$provider" "${ort_args[@]}" | sed 's/^/  /'
done

# --- inputs: control image, prompt, initial latents ----------------------------------------------
stage "inputs"
prompt="a tactile image of an edge, captured by a vision only sensor"
"$py" - "$kit/hint.png" "$work" "$size" <<'PY'
import sys, numpy as np
from PIL import Image
hint, work, size = sys.argv[1], sys.argv[2], int(sys.argv[3])
Image.open(hint).convert("RGB").resize((size, size), Image.BICUBIC).save(f"{work}/control.png")
np.save(f"{work}/x_T.npy", np.random.default_rng(0).standard_normal((1, 4, size // 8, size // 8)).astype(np.float32))
print(f"  {work}/control.png ({size} x {size}), {work}/x_T.npy (1, 4, {size // 8}, {size // 8}), seed 0")
PY

# --- diffusers -----------------------------------------------------------------------------------
stage "diffusers ($device): warm-up, then guidance 1 and 9"
"$py" tools/diffusers_anchor.py "$pipe" --control "$work/control.png" --prompt "$prompt" --latents "$work/x_T.npy" \
  --out-prefix "$work/diffusers" --steps "$steps" --guidance 1,9 --device "$device" $([ "$tiny" = 0 ] && echo --fp16) \
  2>&1 | quiet | tee "$work/diffusers.log"

# --- rig -----------------------------------------------------------------------------------------
# Every rig run goes through these two functions: PACKAGE GUIDANCE TAG. Their logs, rig-TAG.log and
# fill-TAG.log, are what tools/gpu_check_summary.py reads.
# rig_one: the first image of a process (`rig synth one`).
rig_one() {
  local pkg=$1 g=$2 tag=$3
  "$rig" synth one --model "$pkg" --control "$work/control.png" --prompt "$prompt" --init-latents "$work/x_T.npy" \
    --steps "$steps" --guidance "$g" --provider "$provider" "${ort_args[@]}" \
    --out "$work/rig-$tag.png" --dump-raw "$work/rig-$tag.npy" >"$work/rig-$tag.log" 2>&1 \
    || { cat "$work/rig-$tag.log"; die "rig synth one ($tag) failed"; }
  grep "^wrote" "$work/rig-$tag.log" | sed 's/^/  /' || true
}
# rig_fill: a fill of $images poses of a simulated dataset, as a lab fills (pipeline loaded once):
# its `synthesised N poses in S s` and `timing:` (load, warm-up, steady state) lines.
rig_fill() {
  local pkg=$1 g=$2 tag=$3
  local data=$work/fill-$tag
  rm -rf "$data"
  "$rig" collect --object edge --sensor ViTacTip --plan "$work/plan.toml" --out "$data" >"$work/collect-$tag.log" 2>&1 \
    || { cat "$work/collect-$tag.log"; die "rig collect failed"; }
  "$rig" synth --fill-missing --dataset "$data/edge" --model "$pkg" --steps "$steps" --guidance "$g" --limit "$images" \
    --provider "$provider" "${ort_args[@]}" >"$work/fill-$tag.log" 2>&1 || { cat "$work/fill-$tag.log"; die "rig synth --fill-missing ($tag) failed"; }
  grep "synthesised\|^timing:" "$work/fill-$tag.log" | sed 's/^/  /' || true
}
# A plan of 1 + $images poses: one collected, the rest for the fill.
{
  echo "sampling = \"random\""; echo "n_poses = 1"; echo "seed = 3"; echo "order = \"optimised\""
  printf '[x_mm]\nmin = -4.0\nmax = 4.0\nstep = %s\n' "$(awk -v n="$images" 'BEGIN { printf "%.6f", 8.0 / n }')"
  printf '[y_mm]\nmin = 0.0\nmax = 0.0\nstep = 1.0\n[z_mm]\nmin = 0.0\nmax = 0.0\nstep = 1.0\n[yaw_deg]\nmin = 0.0\nmax = 0.0\nstep = 1.0\n'
} >"$work/plan.toml"

for variant in fp32 fp16; do
  for g in 1 9; do
    stage "rig $variant ($provider), guidance $g"
    rig_one "$work/package-$variant" "$g" "$variant-g$g"
    rig_fill "$work/package-$variant" "$g" "$variant-g$g"
  done
done

# --- parity and the tables -----------------------------------------------------------------------
stage "parity: rig's PNG against diffusers' (8-bit levels of 255), same latents"
: >"$work/parity.log"
for variant in fp32 fp16; do
  for g in 1 9; do
    level=$("$py" - "$work/rig-$variant-g$g.png" "$work/diffusers_g$g.png" <<'PY'
import sys, numpy as np
from PIL import Image
a, b = (np.asarray(Image.open(p).convert("RGB"), dtype=np.int16) for p in sys.argv[1:3])
print(int(np.abs(a - b).max()))
PY
)
    echo "rig $variant guidance $g: max level difference $level" | tee -a "$work/parity.log" | sed 's/^/  /'
  done
done

stage "summary"
gpu="CPU ($(nproc) cores)"
[ "$tiny" = 0 ] && gpu=$("$py" -c 'import torch; print(torch.cuda.get_device_name(0))')
v=$("$py" -c 'import diffusers, torch, onnxruntime; print(f"diffusers {diffusers.__version__}, torch {torch.__version__}, onnxruntime (Python) {onnxruntime.__version__}")')
echo "device: $gpu; $size x $size px, $steps DDIM steps, one image; $v; $(date -u +%Y-%m-%d)"
cell() { [ -n "${1:-}" ] && echo "$1 s" || echo "n/a"; }
echo "build pipeline $(cell "${timing[build]:-}"), export fp32 $(cell "${timing[export_fp32]:-}"), export fp16 $(cell "${timing[export_fp16]:-}") (n/a: kept from an earlier run)"
echo
# The timing table, the fills' split and the acceptance check, from the logs above.
"$py" tools/gpu_check_summary.py "$work" $([ "$tiny" = 1 ] && echo --tiny)
