#!/usr/bin/env bash
# Regenerates tests/data/mds-small/ (its CLIP folder and MultiDiffSense's references) and
# tests/data/mds-small-package/ (rig's export of the same checkpoint); see
# tests/data/mds-small/README.md. The checkpoint itself is made in a temporary folder and not kept.
#
#   MDS_REPO=/path/to/MultiDiffSense MDS_PYTHON=/tmp/mds-venv/bin/python tools/make_mds_small.sh
#
# MDS_REPO: a checkout of MultiDiffSense (commit d58ce6a). MDS_PYTHON: a Python that runs it
# (transformers 4.x; tools/mds_reference.py says how to make one). The export uses .venv
# (tools/requirements.txt). hint.png, prompt.txt and x_T.npy come from the MultiDiffSense kit
# ($RIG_SHARED/multidiffsense-cldm-kit). The tokenizer's BPE training is not bit-repeatable, so
# everything is rewritten together.
set -euo pipefail
cd "$(dirname "$0")/.."
root=$PWD
mds_repo=$(cd "${MDS_REPO:?set MDS_REPO to a checkout of MultiDiffSense (commit d58ce6a)}" && pwd)
mds_python=${MDS_PYTHON:-/tmp/mds-venv/bin/python}
shared=${RIG_SHARED:-../shared}
kit=$shared/multidiffsense-cldm-kit
data=tests/data/mds-small
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT

for f in hint.png prompt.txt x_T.npy; do install -m 644 "$kit/$f" "$data/$f"; done
rm -rf "$data/clip" "$data/ref"
# The yaml names CLIP as ./clip, as MultiDiffSense's loader reads it: run from the data folder.
(cd "$data" && "$mds_python" "$root/tools/mds_reference.py" clip --out clip --prompt prompt.txt)
(cd "$data" && "$mds_python" "$root/tools/mds_reference.py" checkpoint --mds-repo "$mds_repo" --config cldm.yaml \
    --out "$tmp/mds_small.ckpt")
(cd "$data" && "$mds_python" "$root/tools/mds_reference.py" references --mds-repo "$mds_repo" --config cldm.yaml \
    --ckpt "$tmp/mds_small.ckpt" --hint hint.png --prompt prompt.txt --x-t x_T.npy --out ref)
.venv/bin/python tools/export_package.py --original-ckpt "$tmp/mds_small.ckpt" --original-config "$data/cldm.yaml" \
    --clip-dir "$data/clip" --out tests/data/mds-small-package --name mds-small
echo "check: cargo test --test synth mds_parity::"
