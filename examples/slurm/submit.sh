#!/usr/bin/env bash
# Submits a sharded fill to SLURM: an array of fill tasks (fill.sbatch, or fill-gpu.sbatch with
# --gpu), one shard each, and a merge job that runs once every task has succeeded
# (--dependency=afterok). Prints the two job ids. See docs/src/cluster.md.
#
#   examples/slurm/submit.sh --datasets datasets/sphere --shards 16 --work /scratch/$USER/sphere-shards \
#       --model models/multidiffsense --ort-lib /shared/onnxruntime/libonnxruntime.so.1.31.1
#
# After a failed task, run the same command again: finished shards find nothing to do, the
# failed one continues where it stopped. --array 3,7 resubmits only those indices. Any other
# sbatch option goes through sbatch's own environment variables (SBATCH_PARTITION,
# SBATCH_ACCOUNT, SBATCH_TIMELIMIT, ...) or after `--`; rig synth flags go in RIG_SYNTH_ARGS.
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"

usage() {
  sed -n '2,12p' "$0" | sed 's/^# \{0,1\}//' >&2
  echo "usage: $0 --datasets DIR --shards N --work DIR --model DIR --ort-lib PATH [--rig PATH] [--gpu] [--array SPEC] [-- SBATCH OPTIONS]" >&2
  exit "${1:-2}"
}
datasets= shards= work= model= ort_lib="${RIG_ORT_LIB:-}" rig="${RIG:-}" gpu=0 array=
while [ $# -gt 0 ]; do
  case "$1" in
    --datasets) datasets="$2"; shift 2 ;;
    --shards) shards="$2"; shift 2 ;;
    --work) work="$2"; shift 2 ;;
    --model) model="$2"; shift 2 ;;
    --ort-lib) ort_lib="$2"; shift 2 ;;
    --rig) rig="$2"; shift 2 ;;
    --gpu) gpu=1; shift ;;
    --array) array="$2"; shift 2 ;;
    --) shift; break ;;
    -h|--help) usage 0 ;;
    *) echo "submit.sh: unknown argument $1" >&2; usage ;;
  esac
done
[ -n "$datasets" ] && [ -n "$shards" ] && [ -n "$work" ] && [ -n "$model" ] && [ -n "$ort_lib" ] || usage
case "$shards" in ''|*[!0-9]*|0) echo "submit.sh: --shards must be a positive integer" >&2; exit 2 ;; esac
[ -n "$rig" ] || rig="$(command -v rig || true)"
[ -n "$rig" ] || { echo "submit.sh: no rig on the PATH: give --rig PATH" >&2; exit 2; }

# The tasks run elsewhere, later: absolute paths, checked now.
abs() { (cd "$(dirname "$1")" && echo "$(pwd)/$(basename "$1")"); }
[ -d "$datasets" ] || { echo "submit.sh: no folder $datasets" >&2; exit 2; }
[ -f "$model/model.toml" ] || { echo "submit.sh: $model is not a model package (no model.toml)" >&2; exit 2; }
[ -e "$ort_lib" ] || { echo "submit.sh: $ort_lib does not exist (libonnxruntime.so or its folder)" >&2; exit 2; }
[ -x "$rig" ] || rig="$(command -v "$rig")"
datasets="$(cd "$datasets" && pwd)"
model="$(cd "$model" && pwd)"
ort_lib="$(abs "$ort_lib")"
rig="$(abs "$rig")"
mkdir -p "$work"
work="$(cd "$work" && pwd)"
case "$work/" in
  "$datasets"/*) echo "submit.sh: --work must not be inside --datasets (the shards would be taken for datasets)" >&2; exit 2 ;;
esac
"$rig" synth --fill-missing --dataset "$datasets" --dry-run >/dev/null

export RIG="$rig" RIG_DATASETS="$datasets" RIG_WORK="$work" RIG_SHARDS="$shards" RIG_MODEL="$model" \
  RIG_ORT_LIB="$ort_lib" RIG_SLURM_DIR="$here"
fill="$here/fill.sbatch"
[ "$gpu" = 1 ] && fill="$here/fill-gpu.sbatch"
fill_job="$(sbatch --parsable --array="${array:-1-$shards}" --chdir="$work" --export=ALL "$@" "$fill")"
fill_job="${fill_job%%;*}"
merge_job="$(sbatch --parsable --dependency="afterok:$fill_job" --chdir="$work" --export=ALL "$@" "$here/merge.sbatch")"
merge_job="${merge_job%%;*}"
echo "submitted fill array $fill_job (tasks ${array:-1-$shards} of $shards) and merge job $merge_job (after every task succeeds); logs in $work"
