#!/usr/bin/env bash
# The model-package rewrites of tools/repack_package.py (and so of tools/export_package.py's
# --external-data and --fp16) checked end to end with the rig binary. scripts/test.sh runs it after
# cargo test; see docs/src/bring-your-model.md#how-this-is-checked.
#
#   tests/export/run.sh
#
# 1. Makes .rig/exportcheck, a Python venv with onnx, onnxruntime, numpy and Pillow (pip; skipped
#    when there). No PyTorch: the rewrite works on the ONNX files.
# 2. External data: tests/data/tiny-package rewritten with every weight in one model.onnx.data per
#    model (--external-data always, the layout a model over 2 GB gets). Each model folder must hold
#    exactly model.onnx and model.onnx.data; `rig synth info` must accept it; `rig synth one` must
#    give the same raw output, bit for bit, as from the package it came from; without its
#    unet/model.onnx.data the package must be refused, naming the UNet. A UNet saved one file per
#    tensor (as torch writes a model over 2 GB) is joined into one model.onnx.data by default,
#    with the same output bit for bit.
# 3. Float16: tests/data/mds-small-package (exported from a MultiDiffSense-built checkpoint)
#    rewritten with --fp16. `rig synth info` must accept it, and `rig synth one` from the same
#    x_T must stay within FP16_MAX_ABS of the float32 package's raw output and FP16_MAX_LEVELS of
#    its PNG (4 and 50 DDIM steps, guidance 1 and 9).
# 4. Opt-in, RIG_EXPORT_PYTHON=<python with tools/requirements.txt, e.g. .venv/bin/python>: the
#    MultiDiffSense kit's checkpoint ($RIG_SHARED/multidiffsense-cldm-kit) exported by
#    tools/export_package.py in float32 and with --fp16 --external-data always, then the checks
#    of 3 on those two packages.
#
# RIG_BIN: the rig binary (default: target/release/rig, built here). Everything is written to a
# temporary folder, removed at the end unless RIG_EXPORT_KEEP=1 or a check failed.
set -euo pipefail
cd "$(dirname "$0")/../.."
repo="$(pwd)"
say() { echo "export-test: $*"; }
fail() { echo "export-test: FAIL: $*" >&2; echo "export-test: files kept in $work" >&2; exit 1; }

# The float16 package's bound against the float32 one (rig's raw decoder output, about [-1.7, 1.8],
# and its 8-bit PNG); docs/src/bring-your-model.md#float16-packages gives the measured differences.
FP16_MAX_ABS=0.03
FP16_MAX_LEVELS=3

if [ -n "${RIG_BIN:-}" ]; then
  rig="$(cd "$(dirname "$RIG_BIN")" && pwd)/$(basename "$RIG_BIN")"
else
  cargo build --release --locked --quiet
  rig="$repo/target/release/rig"
fi
ort_lib="$repo/.rig/onnxruntime"
kit_inputs="$repo/tests/data/mds-small"

# --- 1. Python -------------------------------------------------------------------------------
venv="$repo/.rig/exportcheck"
. "$repo/scripts/lib/pyvenv.sh"
pyvenv "$venv" "onnx, onnxruntime, numpy, PIL" "onnx==1.23.2" "onnxruntime==1.31.1" "numpy==2.4.6" "pillow==13.0.0"
py="$venv/bin/python"
work=$(mktemp -d)

# rig synth one on the inputs of $kit (hint.png, prompt.txt, x_T.npy): PKG TAG STEPS GUIDANCE
one() {
  local pkg=$1 tag=$2 steps=$3 guidance=$4 kit=${5:-$kit_inputs}
  "$rig" synth one --model "$pkg" --control "$kit/hint.png" --prompt "$(cat "$kit/prompt.txt")" \
    --init-latents "$kit/x_T.npy" --steps "$steps" --guidance "$guidance" --ort-lib "$ort_lib" --threads 1 \
    --out "$work/$tag.png" --dump-raw "$work/$tag.npy" >"$work/$tag.log" 2>&1 || { cat "$work/$tag.log"; fail "rig synth one $tag"; }
}
info() {
  "$rig" synth info --model "$1" --ort-lib "$ort_lib" >"$work/info.log" 2>&1 || { cat "$work/info.log"; fail "rig synth info $1"; }
}
# Float16 package $2 against float32 package $1, on kit inputs $3.
fp16_parity() {
  local fp32=$1 fp16=$2 kit=$3 name=$4
  info "$fp16"
  for steps in 4 50; do
    for guidance in 1 9; do
      one "$fp32" "$name-fp32-s$steps-g$guidance" "$steps" "$guidance" "$kit"
      one "$fp16" "$name-fp16-s$steps-g$guidance" "$steps" "$guidance" "$kit"
      "$py" tests/export/compare.py "$name fp16 against fp32, $steps steps, guidance $guidance" \
        "$work/$name-fp32-s$steps-g$guidance.npy" "$work/$name-fp16-s$steps-g$guidance.npy" \
        "$work/$name-fp32-s$steps-g$guidance.png" "$work/$name-fp16-s$steps-g$guidance.png" \
        --max-abs "$FP16_MAX_ABS" --max-levels "$FP16_MAX_LEVELS" || fail "$name: float16 outside its bound"
    done
  done
}

# --- 2. external data ------------------------------------------------------------------------
ext="$work/tiny-external"
"$py" tools/repack_package.py tests/data/tiny-package --out "$ext" --external-data always >"$work/repack.log" 2>&1 \
  || { cat "$work/repack.log"; fail "repack_package.py --external-data always"; }
for model in text_encoder controlnet unet vae_decoder; do
  listing=$(cd "$ext/$model" && ls | tr '\n' ' ')
  [ "$listing" = "model.onnx model.onnx.data " ] || fail "$model/ holds: $listing (want model.onnx model.onnx.data)"
  graph=$(stat -c %s "$ext/$model/model.onnx"); data=$(stat -c %s "$ext/$model/model.onnx.data")
  [ "$data" -gt "$graph" ] || fail "$model: model.onnx.data ($data bytes) is not where the weights are (model.onnx $graph bytes)"
done
info "$ext"
one tests/data/tiny-package tiny-inline 4 9
one "$ext" tiny-external 4 9
"$py" tests/export/compare.py "external data against inline" "$work/tiny-inline.npy" "$work/tiny-external.npy" \
  "$work/tiny-inline.png" "$work/tiny-external.png" --identical || fail "external data changed the output"
# The layout torch writes for a model over 2 GB, one file per tensor (here the UNet's), becomes
# one model.onnx.data by default (--external-data auto); the other models stay as they were.
cp -r tests/data/tiny-package "$work/tiny-per-tensor"
"$py" -c 'import onnx, sys; m = onnx.load(sys.argv[1]); onnx.save_model(m, sys.argv[1], save_as_external_data=True, all_tensors_to_one_file=False, size_threshold=0)' \
  "$work/tiny-per-tensor/unet/model.onnx"
[ "$(ls "$work/tiny-per-tensor/unet" | wc -l)" -gt 10 ] || fail "the per-tensor layout was not made"
"$py" tools/repack_package.py "$work/tiny-per-tensor" --out "$work/tiny-joined" >"$work/repack.log" 2>&1 \
  || { cat "$work/repack.log"; fail "repack_package.py on one file per tensor"; }
listing=$(cd "$work/tiny-joined/unet" && ls | tr '\n' ' ')
[ "$listing" = "model.onnx model.onnx.data " ] || fail "unet/ of the joined package holds: $listing"
cmp -s tests/data/tiny-package/vae_decoder/model.onnx "$work/tiny-joined/vae_decoder/model.onnx" || fail "a small model was rewritten"
one "$work/tiny-joined" tiny-joined 4 9
"$py" tests/export/compare.py "one file per tensor, joined, against inline" "$work/tiny-inline.npy" "$work/tiny-joined.npy" \
  "$work/tiny-inline.png" "$work/tiny-joined.png" --identical || fail "joining the external data changed the output"
mv "$ext/unet/model.onnx.data" "$work/unet.data"
if "$rig" synth info --model "$ext" --ort-lib "$ort_lib" >"$work/missing.log" 2>&1; then
  fail "a package without unet/model.onnx.data was accepted"
fi
grep -q "unet/model.onnx" "$work/missing.log" || { cat "$work/missing.log"; fail "the refusal does not name unet/model.onnx"; }
say "external data: one model.onnx.data per model, accepted, same output bit for bit; refused without it: $(tail -n 1 "$work/missing.log" | cut -c1-160)"

# --- 3. float16 --------------------------------------------------------------------------------
"$py" tools/repack_package.py tests/data/mds-small-package --out "$work/mds-small-fp16" --fp16 >"$work/repack.log" 2>&1 \
  || { cat "$work/repack.log"; fail "repack_package.py --fp16"; }
fp16_parity tests/data/mds-small-package "$work/mds-small-fp16" "$kit_inputs" mds-small

# --- 4. the kit's checkpoint through export_package.py (opt-in) -------------------------------
if [ -n "${RIG_EXPORT_PYTHON:-}" ]; then
  kit="${RIG_SHARED:-$repo/../shared}/multidiffsense-cldm-kit"
  [ -f "$kit/tiny_cldm.ckpt" ] || fail "$kit has no tiny_cldm.ckpt (set RIG_SHARED)"
  for variant in fp32 fp16; do
    flags=(); [ "$variant" = fp16 ] && flags=(--fp16 --external-data always)
    "$RIG_EXPORT_PYTHON" tools/export_package.py --original-ckpt "$kit/tiny_cldm.ckpt" --original-config "$kit/tiny_cldm.yaml" \
      --clip-dir "$kit/clip" --out "$work/kit-$variant" "${flags[@]}" >"$work/export-$variant.log" 2>&1 \
      || { cat "$work/export-$variant.log"; fail "export_package.py ($variant)"; }
    grep "check\|wrote" "$work/export-$variant.log"
  done
  [ -f "$work/kit-fp16/unet/model.onnx.data" ] || fail "the kit's fp16 export has no unet/model.onnx.data"
  fp16_parity "$work/kit-fp32" "$work/kit-fp16" "$kit" kit
else
  say "kit export skipped (opt-in: RIG_EXPORT_PYTHON=<python with tools/requirements.txt>)"
fi

if [ "${RIG_EXPORT_KEEP:-0}" = 1 ]; then
  say "files kept in $work"
else
  rm -rf "$work"
fi
say "ok"
