#!/usr/bin/env bash
# End-to-end test of examples/slurm on a real single-node SLURM (Debian's slurm-wlm 22.05 and
# munge), started and stopped here. scripts/test.sh runs it after cargo test; see
# docs/src/testing.md#the-slurm-test.
#
#   tests/slurm/run.sh
#
# 1. Installs slurm-wlm and munge with apt (no recommended packages) when slurmctld, slurmd,
#    sbatch or munged is missing (root; RIG_SLURM_INSTALL=0 refuses instead).
# 2. Starts munged with its own key and socket, slurmctld and slurmd with a slurm.conf written
#    here (loopback only, checked with ss; free ports; linuxproc/none plugins), everything
#    under one temporary folder; /etc/slurm and /etc/munge are not read or written. A trap
#    stops every daemon it started.
# 3. Collects a small plan on the simulated rig (edge, TacTip and ViTac), fills one copy
#    unsharded, and submits the example (submit.sh: an array of 3 fill tasks, then the merge
#    job, --dependency=afterok) for the other copy with the tiny test model.
# 4. SIGKILLs array task 2 (scancel --full --signal=KILL) once it has written some but not all
#    of its rows: the merge job must then wait forever (DependencyNeverSatisfied); it is
#    cancelled and the same submit.sh command is run again.
# 5. Checks that every task of the second array completed, that the merge job ran after all of
#    them, that the finished tasks redid nothing and task 2 only its missing poses, that no
#    shard holds a pose twice, and that the merged datasets equal the unsharded fill pose for
#    pose (same rows, same decoded pixels, no pose twice) and verify clean.
# 6. Submits the GPU variant (submit.sh --gpu) to the node's one pretend GPU: the task must get
#    it (CUDA_VISIBLE_DEVICES=0) and fail saying that this ONNX Runtime has no CUDA provider.
#
# RIG_BIN: the rig binary (default: target/release/rig, built here). RIG_SLURM_KEEP=1 keeps the
# temporary folder. Exits non-zero on any failure, and then keeps the folder and prints the logs.
set -euo pipefail
cd "$(dirname "$0")/../.."
repo="$(pwd)"
start_all=$(date +%s.%N)
elapsed() { python3 -c "import sys; print(f'{float(sys.argv[2]) - float(sys.argv[1]):.1f}')" "$1" "$(date +%s.%N)"; }
say() { echo "slurm-test: $*"; }
fail() { echo "slurm-test: FAIL: $*" >&2; exit 1; }

# --- 1. SLURM and munge --------------------------------------------------------------------
t=$(date +%s.%N)
if ! command -v slurmctld >/dev/null || ! command -v slurmd >/dev/null || ! command -v sbatch >/dev/null || ! command -v munged >/dev/null; then
  [ "${RIG_SLURM_INSTALL:-1}" = 1 ] || fail "slurm-wlm and munge are not installed (apt-get install slurm-wlm munge)"
  [ "$(id -u)" = 0 ] || fail "installing slurm-wlm and munge needs root"
  say "installing slurm-wlm and munge"
  apt-get update -qq
  DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends slurm-wlm munge >/dev/null
  say "installed in $(elapsed "$t") s"
fi
[ "$(id -u)" = 0 ] || fail "slurmd runs jobs as their owner, so this test runs as root"

# --- rig and ONNX Runtime ------------------------------------------------------------------
RIG_SETUP_BROWSER=0 ./scripts/setup.sh >/dev/null
ort_lib="$repo/.rig/onnxruntime"
if [ -n "${RIG_BIN:-}" ]; then
  rig="$(cd "$(dirname "$RIG_BIN")" && pwd)/$(basename "$RIG_BIN")"
else
  cargo build --release --locked --quiet
  rig="$repo/target/release/rig"
fi
model="$repo/tests/data/tiny-package"

# --- 2. a private single-node cluster ------------------------------------------------------
work="$(mktemp -d "${TMPDIR:-/tmp}/rig-slurm.XXXXXX")"
chmod 755 "$work" # munged wants its socket's folders searchable by all
export SLURM_CONF="$work/slurm/slurm.conf"
pids=() jobs=() ok=0
cleanup() {
  set +e
  if [ "${#jobs[@]}" != 0 ]; then
    scancel "${jobs[@]}" 2>/dev/null
    for _ in $(seq 1 60); do
      [ -z "$(squeue -h 2>/dev/null)" ] && break
      sleep 0.5
    done
  fi
  for ((k = ${#pids[@]} - 1; k >= 0; k--)); do kill "${pids[k]}" 2>/dev/null; done
  for p in "${pids[@]}"; do
    for _ in $(seq 1 40); do kill -0 "$p" 2>/dev/null || break; sleep 0.25; done
    kill -0 "$p" 2>/dev/null && kill -KILL "$p" 2>/dev/null
  done
  if [ "$ok" = 1 ] && [ "${RIG_SLURM_KEEP:-0}" != 1 ]; then
    rm -rf "$work"
  else
    if [ "$ok" != 1 ]; then
      for f in "$work"/slurm/log/*.log "$work"/shards/*.out; do
        [ -f "$f" ] && { echo "--- $f (last lines)"; tail -n 15 "$f"; }
      done
    fi
    say "kept $work"
  fi
}
trap cleanup EXIT

t=$(date +%s.%N)
mkdir -p "$work/munge" "$work/munge-run" "$work/slurm/state" "$work/slurm/spool/localhost" "$work/slurm/log"
chmod 700 "$work/munge"
chmod 755 "$work/munge-run"
mungekey --create --keyfile="$work/munge/munge.key"
munged -F --key-file="$work/munge/munge.key" --socket="$work/munge-run/munge.socket" \
  --pid-file="$work/munge-run/munged.pid" --log-file="$work/munge/munged.log" --seed-file="$work/munge/munged.seed" \
  >"$work/munge/munged.out" 2>&1 &
pids+=($!)
for _ in $(seq 1 40); do [ -S "$work/munge-run/munge.socket" ] && break; sleep 0.25; done
[ -S "$work/munge-run/munge.socket" ] || fail "munged did not start (see $work/munge/munged.log)"

free_port() { python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])'; }
ctld_port=$(free_port)
slurmd_port=$(free_port)
[ "$ctld_port" != "$slurmd_port" ] || slurmd_port=$(free_port)
cpus=$(nproc)
# Configured memory above what the node has would drain it; 3000 MB is plenty for the jobs here.
mem_mb=$(awk '/^MemTotal:/ {print int($2 / 1024)}' /proc/meminfo)
[ "$mem_mb" -lt 3000 ] || mem_mb=3000
cat > "$SLURM_CONF" <<CONF
# A single-node cluster for tests/slurm/run.sh; everything under $work.
ClusterName=rigtest
SlurmctldHost=localhost(127.0.0.1)
SlurmctldPort=$ctld_port
SlurmdPort=$slurmd_port
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
CredType=cred/munge
AuthInfo=socket=$work/munge-run/munge.socket
StateSaveLocation=$work/slurm/state
SlurmdSpoolDir=$work/slurm/spool/%n
SlurmctldPidFile=$work/slurm/slurmctld.pid
SlurmdPidFile=$work/slurm/slurmd.pid
SlurmctldLogFile=$work/slurm/log/slurmctld.log
SlurmdLogFile=$work/slurm/log/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SwitchType=switch/none
MpiDefault=none
SchedulerType=sched/builtin
SelectType=select/cons_tres
SelectTypeParameters=CR_Core_Memory
ReturnToService=2
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/none
MailProg=/bin/true
MinJobAge=600
CommunicationParameters=NoCtldInAddrAny,NoInAddrAny
GresTypes=gpu
NodeName=localhost NodeAddr=127.0.0.1 CPUs=$cpus RealMemory=$mem_mb Gres=gpu:1 State=UNKNOWN
PartitionName=rig Nodes=localhost Default=YES MaxTime=INFINITE State=UP
CONF
# One pretend GPU (/dev/null as its device file): enough for the scheduler to run the GPU variant.
echo "NodeName=localhost Name=gpu File=/dev/null" > "$work/slurm/gres.conf"
slurmctld -D -c -f "$SLURM_CONF" >"$work/slurm/log/slurmctld.out" 2>&1 &
pids+=($!)
slurmd -D -N localhost -f "$SLURM_CONF" >"$work/slurm/log/slurmd.out" 2>&1 &
pids+=($!)
for _ in $(seq 1 120); do
  [ "$(sinfo -h -n localhost -o %T 2>/dev/null)" = idle ] && break
  sleep 0.25
done
[ "$(sinfo -h -n localhost -o %T 2>/dev/null)" = idle ] || fail "the node did not come up idle"
daemons_s=$(elapsed "$t")
# Nothing of this cluster listens beyond the loopback interface.
if command -v ss >/dev/null; then
  wide=$(ss -H -ltnup | grep -E "pid=($(IFS='|'; echo "${pids[*]}"))," | awk '{print $5}' | grep -v '^127\.' || true)
  [ -z "$wide" ] || fail "a daemon listens beyond the loopback interface: $wide"
fi
say "munged, slurmctld and slurmd up in $daemons_s s (node localhost, $cpus CPUs, ports $ctld_port/$slurmd_port)"

# --- 3. data: a collection, one copy filled unsharded --------------------------------------
t=$(date +%s.%N)
cat > "$work/plan.toml" <<'PLAN'
# 3 x 3 x 1 x 3 = 27 grid poses; 6 collected, 21 per sensor filled.
sampling = "random"
n_poses = 6
seed = 4
order = "optimised"
[x_mm]
min = -2.0
max = 2.0
step = 2.0
[y_mm]
min = -2.0
max = 2.0
step = 2.0
[z_mm]
min = 0.0
max = 0.0
step = 1.0
[yaw_deg]
min = -45.0
max = 45.0
step = 45.0
PLAN
"$rig" collect --object edge --sensor tactip,vitac --plan "$work/plan.toml" --out "$work/collected" >"$work/collect.log" 2>&1 \
  || { cat "$work/collect.log"; fail "rig collect failed"; }
cp -a "$work/collected" "$work/whole"
cp -a "$work/collected" "$work/sharded"
synth_args="--steps ${RIG_SLURM_STEPS:-20} --batch 1"
# shellcheck disable=SC2086
"$rig" synth --fill-missing --dataset "$work/whole" --model "$model" --ort-lib "$ort_lib" --threads 1 $synth_args \
  >"$work/whole.log" 2>&1 || { cat "$work/whole.log"; fail "the unsharded fill failed"; }
cat "$work/whole.log"
say "collected and filled unsharded in $(elapsed "$t") s"

# What shard 2 of 3 has to do, over both datasets.
shard2_total=0
for d in "$work"/sharded/edge/*; do
  n=$("$rig" synth --fill-missing --dataset "$d" --shard 2/3 --out "$work/dry" --dry-run | sed -n 's/.*, \([0-9]*\) to synthesise.*/\1/p')
  shard2_total=$((shard2_total + n))
done
[ "$shard2_total" -gt 1 ] || fail "shard 2 has $shard2_total poses to do; the kill needs at least 2"

# --- 4. submit, kill task 2 mid-run --------------------------------------------------------
t_array=$(date +%s.%N)
submit() {
  RIG_SYNTH_ARGS="$synth_args" examples/slurm/submit.sh --datasets "$work/sharded" --shards 3 --work "$work/shards" \
    --model "$model" --ort-lib "$ort_lib" --rig "$rig" -- --cpus-per-task=1 --mem=500M
}
out=$(submit)
echo "$out"
fill_job=$(echo "$out" | sed -n 's/^submitted fill array \([0-9]*\) .* merge job \([0-9]*\) .*/\1/p')
merge_job=$(echo "$out" | sed -n 's/^submitted fill array \([0-9]*\) .* merge job \([0-9]*\) .*/\2/p')
[ -n "$fill_job" ] && [ -n "$merge_job" ] || fail "could not read the job ids"
jobs+=("$fill_job" "$merge_job")

rows_of_task() { # rows written by task $1 so far (complete lines, header excluded)
  local n=0 f
  for f in "$work/shards/task-$1"/edge/*/poses.csv; do
    [ -f "$f" ] && n=$((n + $(grep -c '' "$f") - 1))
  done
  echo "$n"
}
killed_at=
for _ in $(seq 1 2400); do
  r=$(rows_of_task 2)
  if [ "$r" -ge 1 ] && [ "$r" -lt "$shard2_total" ]; then
    scancel --full --signal=KILL "${fill_job}_2"
    killed_at=$r
    break
  fi
  [ "$r" -ge "$shard2_total" ] && break
  sleep 0.05
done
[ -n "$killed_at" ] || fail "task 2 was not caught mid-run ($(rows_of_task 2) of $shard2_total rows)"
say "killed task 2 (SIGKILL) after $killed_at of its $shard2_total rows"

wait_for_queue() { # until none of the given jobs is pending or running, or only the merge job waits
  for _ in $(seq 1 1200); do
    local q
    q=$(squeue -h -o '%i %T %r' 2>/dev/null)
    [ -z "$q" ] && return 0
    [ -n "${1:-}" ] && [ "$(echo "$q" | grep -vc "^$1 PENDING DependencyNeverSatisfied")" = 0 ] && return 0
    sleep 0.5
  done
  fail "the queue did not drain: $(squeue)"
}
field() { echo "$1" | tr ' ' '\n' | sed -n "s/^$2=//p"; }
task_state() { field "$(scontrol show job -o "${1}_$2")" JobState; }
wait_for_queue "$merge_job"
states="$(task_state "$fill_job" 1) $(task_state "$fill_job" 2) $(task_state "$fill_job" 3)"
say "first array: task states $states"
[ "$(task_state "$fill_job" 1)" = COMPLETED ] && [ "$(task_state "$fill_job" 3)" = COMPLETED ] || fail "tasks 1 and 3 should have completed: $states"
[ "$(task_state "$fill_job" 2)" != COMPLETED ] || fail "task 2 completed although it was killed"
merge_info=$(scontrol show job -o "$merge_job")
[ "$(field "$merge_info" JobState)" = PENDING ] && [ "$(field "$merge_info" Reason)" = DependencyNeverSatisfied ] \
  || fail "the merge job should wait forever after a failed task: $(field "$merge_info" JobState) $(field "$merge_info" Reason)"
squeue
say "merge job $merge_job: PENDING (DependencyNeverSatisfied); cancelling it and resubmitting"
scancel "$merge_job"
partial=$(rows_of_task 2)

# --- 5. resubmit the same command; everything must finish ----------------------------------
out=$(submit)
echo "$out"
fill2=$(echo "$out" | sed -n 's/^submitted fill array \([0-9]*\) .* merge job \([0-9]*\) .*/\1/p')
merge2=$(echo "$out" | sed -n 's/^submitted fill array \([0-9]*\) .* merge job \([0-9]*\) .*/\2/p')
jobs+=("$fill2" "$merge2")
wait_for_queue
array_s=$(elapsed "$t_array")
merge_info=$(scontrol show job -o "$merge2")
[ "$(field "$merge_info" JobState)" = COMPLETED ] || fail "merge job $merge2: $(field "$merge_info" JobState) (log: $work/shards/rig-merge-$merge2.out)"
merge_start=$(field "$merge_info" StartTime)
for i in 1 2 3; do
  info=$(scontrol show job -o "${fill2}_$i")
  [ "$(field "$info" JobState)" = COMPLETED ] || fail "task $i of the resubmitted array: $(field "$info" JobState)"
  [[ "$(field "$info" EndTime)" < "$merge_start" || "$(field "$info" EndTime)" = "$merge_start" ]] \
    || fail "the merge job started ($merge_start) before task $i ended ($(field "$info" EndTime))"
  log="$work/shards/rig-fill-${fill2}_$i.out"
  grep -q "rig-fill: task $i of 3 done" "$log" || fail "task $i's log lacks its end: $log"
done
# Finished shards redo nothing; shard 2 does only what it lacked.
for i in 1 3; do
  [ "$(grep -c 'synthesised 0 poses' "$work/shards/rig-fill-${fill2}_$i.out")" = 2 ] || fail "resubmitted task $i synthesised something again"
done
redone=0
while read -r n; do redone=$((redone + n)); done < <(sed -n 's/.*: synthesised \([0-9]*\) poses.*/\1/p' "$work/shards/rig-fill-${fill2}_2.out")
[ "$redone" = $((shard2_total - partial)) ] || fail "task 2 synthesised $redone poses on resubmission; it lacked $((shard2_total - partial))"
# Each shard holds every pose id once.
for f in "$work"/shards/task-*/edge/*/poses.csv; do
  python3 - "$f" <<'PY' || fail "$f holds a pose more than once"
import csv, sys
rows = list(csv.DictReader(open(sys.argv[1], newline="")))
ids = [r["pose_id"] for r in rows]
sys.exit(len(ids) != len(set(ids)))
PY
done
say "resubmitted array: every task COMPLETED, merge job after them; task 2 synthesised the $redone poses it lacked, tasks 1 and 3 none"
cat "$work/shards/rig-merge-$merge2.out"

# --- the merged datasets equal the unsharded fill ------------------------------------------
for d in "$work"/whole/edge/*; do
  s="$work/sharded/edge/$(basename "$d")"
  "$rig" dataset verify "$s" >"$work/verify.log" 2>&1 || { cat "$work/verify.log"; fail "$s does not verify clean"; }
  python3 tests/slurm/compare.py "$d" "$s" || fail "$s differs from the unsharded fill"
done

# --- 6. the GPU variant: scheduled with its GPU, rig asked for CUDA ---------------------------
# There is no GPU here and the PyPI library has no CUDA provider, so the task must fail, and
# say why, after the scheduler gave it the (pretend) GPU; its merge job then never runs.
out=$(examples/slurm/submit.sh --gpu --datasets "$work/sharded" --shards 3 --array 1 --work "$work/gpu" \
  --model "$model" --ort-lib "$ort_lib" --rig "$rig" -- --cpus-per-task=1 --mem=500M)
echo "$out"
gpu_job=$(echo "$out" | sed -n 's/^submitted fill array \([0-9]*\) .* merge job \([0-9]*\) .*/\1/p')
gpu_merge=$(echo "$out" | sed -n 's/^submitted fill array \([0-9]*\) .* merge job \([0-9]*\) .*/\2/p')
[ -n "$gpu_job" ] && [ -n "$gpu_merge" ] || fail "could not read the GPU job ids"
jobs+=("$gpu_job" "$gpu_merge")
wait_for_queue "$gpu_merge"
info=$(scontrol show job -o "${gpu_job}_1")
[ "$(field "$info" JobState)" = FAILED ] || fail "the GPU task: $(field "$info" JobState), expected FAILED"
log="$work/gpu/rig-fill-${gpu_job}_1.out"
grep -q 'provider cuda, CUDA_VISIBLE_DEVICES=0,' "$log" || fail "the GPU task was not given a GPU: $(head -n 1 "$log")"
grep -q 'execution provider cuda is not available' "$log" || fail "the GPU task's log does not say that CUDA is missing: $log"
scancel "$gpu_merge"
say "GPU variant: the task got the GPU (CUDA_VISIBLE_DEVICES=0), rig ran with --provider cuda and failed as it must without CUDA"
ok=1
say "array run (submit, kill, resubmit, merge) $array_s s; daemons $daemons_s s; whole test $(elapsed "$start_all") s"
say "ok"
