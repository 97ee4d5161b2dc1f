#!/usr/bin/env bash
# The test command: installs what the tests need, checks the guide's links, runs the platform
# checks (the build without optional features, the macOS type-check), checks the dependencies'
# licences and sources (deny.toml: scripts/check-licences.py, and cargo deny where installed), runs the whole suite,
# runs the SLURM example on a private single-node SLURM (tests/slurm/run.sh, as root;
# RIG_SKIP_SLURM=1 skips it), checks the LeRobot export with pyarrow (tests/lerobot/run.sh;
# RIG_SKIP_LEROBOT=1 skips it), checks model-package rewrites (tests/export/run.sh;
# RIG_SKIP_EXPORT=1 skips it), checks that the API docs build without warnings, then smoke-runs
# every fuzz target for a few seconds (FUZZ_SECONDS, default 5; FUZZ_SECONDS=0 skips it).
# RIG_DOCS_TOUR=1 also runs the demo and then the README tour as written after the test build.
#
# The fuzz smoke run installs cargo-fuzz on first use (`cargo install cargo-fuzz --locked`;
# not timed here, it was preinstalled) and builds the fuzz crate with sanitizer instrumentation
# (about a minute cold on a quiet 2-core machine, seconds once fuzz/target is warm).
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
# The platform checks (docs/src/getting-started.md#features-and-platforms), before the tests:
# - every target of the build without the optional features (no ONNX Runtime, tokenizer, arrow
#   or parquet) type-checked (a type-check, not a build: building it compiled about 57 crates
#   and rig a second time, with other features than the test build's, for the link step alone);
# - macOS, type-checked from here for x86_64-apple-darwin (rustup adds the target when missing).
#   Not with the `nokhwa` feature: nokhwa's AVFoundation bindings compile an Objective-C file
#   (objc_exception) that needs Apple's compiler and SDK, which a Linux machine lacks; so this
#   checks everything of the macOS build but nokhwa's backend (camera/nokhwa_backend.rs).
# Added time with target/ warm from an earlier test run: seconds. On a fresh clone on a quiet
# 2-core machine: the type-check 3 min 7 s (building first, as this once did, took 6 min 43 s and
# the type-check after it 1 min 2 s), the macOS check 3 min 50 s.
cargo check --no-default-features --all-targets --locked
if ! rustup target list --installed | grep -qx x86_64-apple-darwin; then
  rustup target add x86_64-apple-darwin
fi
cargo check --target x86_64-apple-darwin --no-default-features --features synth,lerobot,downstream --all-targets --locked
cargo test --all-targets --locked
# The README tour, run as written with the binary just built (scripts/check-docs.py --tour): every
# step's exit status and key output lines, after scripts/demo.sh has run in the same folder, as
# a new user runs them. It collects and synthesises for minutes (the tour alone took 11 min 44 s
# on a busy 2-core machine; the demo before it adds its own collection and fill), so it runs
# only with RIG_DOCS_TOUR=1.
if [ "${RIG_DOCS_TOUR:-0}" = 1 ]; then
  python3 scripts/check-docs.py --tour "${CARGO_TARGET_DIR:-target}/debug/rig" --after-demo
fi
# examples/slurm end to end on a single-node SLURM it starts and stops (installs slurm-wlm and
# munge with apt when missing), with the rig binary the tests above just built.
if [ "${RIG_SKIP_SLURM:-0}" != 1 ]; then
  RIG_BIN="${CARGO_TARGET_DIR:-target}/debug/rig" tests/slurm/run.sh
fi
# The LeRobot export read back by pyarrow and Pillow (a venv in .rig/pycheck), frame by frame
# against the datasets it came from; RIG_LEROBOT_PYTHON=<python with lerobot> adds LeRobotDataset.
if [ "${RIG_SKIP_LEROBOT:-0}" != 1 ]; then
  RIG_BIN="${CARGO_TARGET_DIR:-target}/debug/rig" tests/lerobot/run.sh
fi
# Package rewrites (tools/repack_package.py: one model.onnx.data per model, float16) checked with
# rig (a venv in .rig/exportcheck); RIG_EXPORT_PYTHON=<python with tools/requirements.txt> adds the
# kit checkpoint's export. RIG_SKIP_EXPORT=1 skips it.
if [ "${RIG_SKIP_EXPORT:-0}" != 1 ]; then
  RIG_BIN="${CARGO_TARGET_DIR:-target}/debug/rig" tests/export/run.sh
fi
# The API docs must build without warnings (broken intra-doc links, bad HTML in comments), in
# the smallest build too (links to items it leaves out stay text there: src/lib.rs); the
# default build's last, so target/doc holds it.
RUSTDOCFLAGS="${RUSTDOCFLAGS:-} -D warnings" cargo doc --no-deps --locked --no-default-features
RUSTDOCFLAGS="${RUSTDOCFLAGS:-} -D warnings" cargo doc --no-deps --locked
fuzz_seconds="${FUZZ_SECONDS:-5}"
if [ "$fuzz_seconds" != 0 ]; then
  ./scripts/fuzz-smoke.sh "$fuzz_seconds"
fi
