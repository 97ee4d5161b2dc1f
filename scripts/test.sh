#!/usr/bin/env bash
# The test command: installs what the tests need, then runs the whole suite.
set -euo pipefail
cd "$(dirname "$0")/.."
./scripts/setup.sh
export RIG_SHARED="${RIG_SHARED:-$(cd .. && pwd)/shared}"
cargo test --all-targets --locked
