#!/usr/bin/env bash
# Installs what rig needs on a fresh Debian 12 machine: libclang for the v4l bindings and
# the ONNX Runtime shared library (from the PyPI onnxruntime wheel) into .rig/onnxruntime/.
# Idempotent: each step is skipped when its result is already there.
set -euo pipefail
cd "$(dirname "$0")/.."

ORT_VERSION=1.31.1
ORT_DIR=.rig/onnxruntime
ORT_LIB="$ORT_DIR/libonnxruntime.so.$ORT_VERSION"

as_root() { if [ "$(id -u)" = 0 ]; then "$@"; else sudo "$@"; fi; }

if ! ldconfig -p 2>/dev/null | grep -q 'libclang-14.so\|libclang.so.1'; then
  if ! ls /usr/lib/x86_64-linux-gnu/libclang-14.so* >/dev/null 2>&1 && ! ls /usr/lib/*/libclang-14.so* >/dev/null 2>&1; then
    echo "setup: installing libclang1-14 (needed by the v4l bindings)"
    as_root apt-get update -qq
    as_root env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libclang1-14 >/dev/null
  fi
fi

if [ ! -f "$ORT_LIB" ]; then
  echo "setup: fetching ONNX Runtime $ORT_VERSION from the PyPI wheel"
  tmp=$(mktemp -d)
  python3 -m pip download --quiet --no-deps "onnxruntime==$ORT_VERSION" -d "$tmp"
  mkdir -p "$ORT_DIR"
  python3 - "$tmp" "$ORT_DIR" "$ORT_VERSION" <<'PY'
import glob, sys, zipfile, os
tmp, dest, ver = sys.argv[1:]
whl = glob.glob(os.path.join(tmp, "onnxruntime-*.whl"))[0]
with zipfile.ZipFile(whl) as z:
    for name in z.namelist():
        base = os.path.basename(name)
        if name.startswith("onnxruntime/capi/") and base.startswith("libonnxruntime"):
            with z.open(name) as src, open(os.path.join(dest, base), "wb") as dst:
                dst.write(src.read())
PY
  rm -rf "$tmp"
fi
echo "setup: ONNX Runtime at $ORT_LIB"

# Headless Chromium for the daemon's page test (tests/rig/daemon_browser.rs); Debian's package.
# The demo does not need it: scripts/demo.sh sets RIG_SETUP_BROWSER=0.
if [ "${RIG_SETUP_BROWSER:-1}" = "0" ]; then
  :
elif [ ! -x /usr/bin/chromium ]; then
  echo "setup: installing chromium (the daemon page's browser test)"
  as_root apt-get update -qq
  as_root env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null
fi
if [ -x /usr/bin/chromium ]; then
  echo "setup: chromium at /usr/bin/chromium"
fi
