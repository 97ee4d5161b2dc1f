#!/usr/bin/env bash
# The test command: installs what the tests need, checks the guide's links, checks the
# dependencies' licences and sources (deny.toml: scripts/check-licences.py, and cargo deny where
# installed), runs the platform checks (macOS type-checks with and without the optional
# features), builds the tests, then runs the whole suite (the `synth` test binary beside the
# others) while, in the background, the SLURM example runs on a private single-node SLURM
# (tests/slurm/run.sh, as root; RIG_SKIP_SLURM=1 skips it), the LeRobot export is checked with
# pyarrow (tests/lerobot/run.sh; RIG_SKIP_LEROBOT=1 skips it) and model-package rewrites are
# checked (tests/export/run.sh; RIG_SKIP_EXPORT=1 skips it); then checks that the API docs build
# without warnings, and smoke-runs every fuzz target for a few seconds (FUZZ_SECONDS, default 5;
# FUZZ_SECONDS=0 skips it). RIG_DOCS_TOUR=1 also runs the demo and then the README tour as
# written after the tests.
#
# The fuzz smoke run installs cargo-fuzz on first use (`cargo install cargo-fuzz --locked`;
# not timed here, it was preinstalled) and builds the fuzz targets once, unoptimised with
# AddressSanitizer (scripts/fuzz-smoke.sh has the times).
set -euo pipefail
cd "$(dirname "$0")/.."
./scripts/setup.sh
export RIG_SHARED="${RIG_SHARED:-$(cd .. && pwd)/shared}"
# The guide (docs/): the checker must catch planted faults, then every relative link and anchor
# of README.md, CHANGELOG.md, TESTING.md and docs/src must resolve. mdBook is optional.
python3 scripts/check-docs.py --self-test
python3 scripts/check-docs.py
# scripts/gpu-check.sh's tables and acceptance verdicts on the H200 run's figures (standard library, < 1 s).
python3 tools/gpu_check_summary.py --self-test
if command -v mdbook >/dev/null 2>&1; then
  book_dir=$(mktemp -d)
  mdbook build docs --dest-dir "$book_dir"
  rm -rf "$book_dir"
fi
# The dependency tree's licences and sources (deny.toml): a crate under a licence not allowed
# there, a git dependency or another registry fails here. scripts/check-licences.py reads
# deny.toml and `cargo metadata` (standard library only, about a second; its self-test plants a
# GPL crate, a git source, another registry, a crate without a licence and a wildcard) and runs
# everywhere. Where cargo-deny is installed, `cargo deny check licenses bans sources` runs too
# (offline; the advisory database, which needs GitHub, is not checked). It is not installed
# here when missing: `cargo install cargo-deny --locked` compiled for 16 min 43 s on a busy
# 2-core machine, over half this suite's time; RIG_INSTALL_CARGO_DENY=1 installs it.
python3 scripts/check-licences.py --self-test
python3 scripts/check-licences.py
if [ "${RIG_INSTALL_CARGO_DENY:-0}" = 1 ] && ! cargo deny --version >/dev/null 2>&1; then
  cargo install cargo-deny --locked
fi
if cargo deny --version >/dev/null 2>&1; then
  cargo deny --locked check licenses bans sources
else
  echo "test: cargo-deny not installed; deny.toml checked by scripts/check-licences.py only"
fi
# A fresh clone builds once: incremental caches would only double target/ on a small disk.
export CARGO_INCREMENTAL="${CARGO_INCREMENTAL:-0}"
free_kib=$(df -Pk . | awk 'NR==2 {print $4}')
echo "test: $((free_kib / 1024)) MiB free on the build disk (a fresh build needs about 3 GiB)"
# The platform checks (docs/src/getting-started.md#features-and-platforms), before the tests,
# both type-checks for macOS (x86_64-apple-darwin; rustup adds the target when missing):
# - with the optional features a Mac builds: not `nokhwa`, whose AVFoundation bindings compile
#   an Objective-C file (objc_exception) that needs Apple's compiler and SDK, which a Linux
#   machine lacks; so this checks everything of the macOS build but nokhwa's backend
#   (camera/nokhwa_backend.rs);
# - without any optional feature (no ONNX Runtime, tokenizer, arrow, parquet or candle), every
#   target: the build without optional features. Checked for macOS rather than for Linux, it
#   reuses the first check's dependencies; what it does not see is Linux-only code (V4L2) built
#   without the features, which the test build below compiles with them.
# On a fresh clone on a 2-core machine: the first 3 min 48 s, the second 1 min 43 s after it (a
# check without the features for Linux took 3 min 7 s on its own, as nothing is shared with
# the test build).
if ! rustup target list --installed | grep -qx x86_64-apple-darwin; then
  rustup target add x86_64-apple-darwin
fi
cargo check --target x86_64-apple-darwin --no-default-features --features synth,lerobot,downstream --all-targets --locked
cargo check --target x86_64-apple-darwin --no-default-features --all-targets --locked
cargo test --all-targets --locked --no-run
# The checks that run the rig binary just built (SLURM, the LeRobot export, package rewrites)
# start now, in the background, one after the other: they mostly wait on apt and pip and on
# simulated hardware, and run beside the tests. Each one's output is printed after the tests.
side_logs=$(mktemp -d)
side=()
start_side() {
  local name=$1
  shift
  ("$@") > "$side_logs/$name.log" 2>&1
  echo $? > "$side_logs/$name.rc"
}
rig_bin="${CARGO_TARGET_DIR:-target}/debug/rig"
(
  set +e
  # examples/slurm end to end on a single-node SLURM it starts and stops (installs slurm-wlm and
  # munge with apt when missing).
  [ "${RIG_SKIP_SLURM:-0}" != 1 ] && start_side slurm env RIG_BIN="$rig_bin" tests/slurm/run.sh
  # The LeRobot export read back by pyarrow and Pillow (a venv in .rig/pycheck), frame by frame
  # against the datasets it came from; RIG_LEROBOT_PYTHON=<python with lerobot> adds LeRobotDataset.
  [ "${RIG_SKIP_LEROBOT:-0}" != 1 ] && start_side lerobot env RIG_BIN="$rig_bin" tests/lerobot/run.sh
  # Package rewrites (tools/repack_package.py: one model.onnx.data per model, float16) checked
  # with rig (a venv in .rig/exportcheck); RIG_EXPORT_PYTHON=<python with tools/requirements.txt>
  # adds the kit checkpoint's export.
  [ "${RIG_SKIP_EXPORT:-0}" != 1 ] && start_side export env RIG_BIN="$rig_bin" tests/export/run.sh
  true
) &
side_pid=$!
trap 'kill "$side_pid" 2>/dev/null || true' EXIT
# The test binaries, the `synth` one on a lane of its own beside the others
# (scripts/lib/run_tests.py; it prints each binary's output when it ends).
python3 scripts/lib/run_tests.py --self-test
tests_rc=0
python3 scripts/lib/run_tests.py --own-lane synth -- --all-targets --locked || tests_rc=$?
wait "$side_pid" || true
trap - EXIT
side_failed=()
for name in slurm lerobot export; do
  [ -f "$side_logs/$name.log" ] || continue
  echo "--- test: $name check (run beside the tests)"
  cat "$side_logs/$name.log"
  [ "$(cat "$side_logs/$name.rc" 2>/dev/null || echo 1)" = 0 ] || side_failed+=("$name")
done
rm -rf "$side_logs"
if [ "$tests_rc" != 0 ] || [ "${#side_failed[@]}" != 0 ]; then
  echo "test: failed: ${side_failed[*]:-} $([ "$tests_rc" != 0 ] && echo "test binaries (exit $tests_rc)")" >&2
  exit 1
fi
# The README tour, run as written with the binary just built (scripts/check-docs.py --tour): every
# step's exit status and key output lines, after scripts/demo.sh has run in the same folder, as
# a new user runs them. It collects and synthesises for minutes (the tour alone took 11 min 44 s
# on a busy 2-core machine; the demo before it adds its own collection and fill), so it runs
# only with RIG_DOCS_TOUR=1.
if [ "${RIG_DOCS_TOUR:-0}" = 1 ]; then
  python3 scripts/check-docs.py --tour "$rig_bin" --after-demo
fi
# The API docs must build without warnings (broken intra-doc links, bad HTML in comments), in
# the smallest build too (links to items it leaves out stay text there: src/lib.rs); the
# default build's last, so target/doc holds it. The smallest build's docs are made for macOS:
# they reuse the type-check above (for Linux they checked every dependency again, 1 min 28 s
# in a fresh clone).
RUSTDOCFLAGS="${RUSTDOCFLAGS:-} -D warnings" cargo doc --no-deps --locked --target x86_64-apple-darwin --no-default-features
RUSTDOCFLAGS="${RUSTDOCFLAGS:-} -D warnings" cargo doc --no-deps --locked
fuzz_seconds="${FUZZ_SECONDS:-5}"
if [ "$fuzz_seconds" != 0 ]; then
  ./scripts/fuzz-smoke.sh "$fuzz_seconds"
fi
