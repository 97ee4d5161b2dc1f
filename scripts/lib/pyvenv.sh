# Sourced by the test scripts that check rig's output with Python (tests/export, tests/lerobot).
# pyvenv DIR IMPORTS PACKAGE...: makes the venv DIR with the pinned PACKAGEs from PyPI unless it
# is there and `import IMPORTS` works in it; says so with the caller's `say`, silent when kept.
pyvenv() {
  local venv=$1 imports=$2
  shift 2
  if [ ! -x "$venv/bin/python" ] || ! "$venv/bin/python" -c "import $imports" 2>/dev/null; then
    say "making $venv ($*, from PyPI)"
    python3 -m venv "$venv"
    "$venv/bin/pip" install --quiet --disable-pip-version-check "$@"
  fi
}
