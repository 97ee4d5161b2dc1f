#!/usr/bin/env python3
"""Runs the test binaries `cargo test` would run, in lanes side by side (standard library only).

`cargo test` runs its test binaries one after the other, and holds the build folder's lock
while they run, so a second `cargo test` waits for the first. On a 2-core machine the two
longest binaries, `rig` and `synth`, each leave much of the machine idle when run alone (run
side by side, they used 84% and 115% of a core; docs/src/testing.md has the times). This asks
cargo for the binaries (`cargo test --no-run
--message-format=json`, which builds them when needed), then runs every binary named with
`--own-lane` on its own lane and the others one after the other on the first, each from its
package's folder as cargo does. Each binary's output is printed whole when it ends, under the
line cargo would print; the exit status is 1 when any binary failed (all lanes run to the end),
and the failures are listed last.

usage: run_tests.py [--own-lane NAME]... [--self-test] -- CARGO_TEST_ARGS...
  e.g. run_tests.py --own-lane synth -- --all-targets --locked
"""

import argparse
import io
import json
import os
import subprocess
import sys
import tempfile
import threading
import time

# The order cargo runs them in: the library's unit tests, the binaries', the integration tests,
# then the benchmarks (as smoke tests), each kind by name.
KIND_ORDER = {"lib": 0, "bin": 1, "test": 2, "bench": 3}


def test_binaries(cargo_args):
    """The test executables of `cargo test CARGO_ARGS`, built when needed: (kind, name, source,
    executable, package folder) in cargo's running order."""
    cmd = ["cargo", "test", "--no-run", "--message-format=json-render-diagnostics", *cargo_args]
    proc = subprocess.run(cmd, stdout=subprocess.PIPE, text=True)
    if proc.returncode != 0:
        sys.exit(proc.returncode)
    found = []
    for line in proc.stdout.splitlines():
        try:
            msg = json.loads(line)
        except json.JSONDecodeError:
            continue
        if msg.get("reason") != "compiler-artifact" or not msg.get("executable"):
            continue
        if not msg.get("profile", {}).get("test"):
            continue
        target = msg["target"]
        kind = next((k for k in target["kind"] if k in KIND_ORDER), None)
        if kind is None:
            continue
        found.append((kind, target["name"], target["src_path"], msg["executable"], os.path.dirname(msg["manifest_path"])))
    found.sort(key=lambda b: (KIND_ORDER[b[0]], b[1]))
    return found


def lanes_of(binaries, own_lane):
    """The first lane holds every binary not named in `own_lane`; each named one gets its own."""
    first = [b for b in binaries if b[1] not in own_lane or b[0] not in ("test", "bench")]
    own = [[b] for b in binaries if b[1] in own_lane and b[0] in ("test", "bench")]
    return [first, *own] if first else own


class Runner:
    def __init__(self, out=None):
        self.lock = threading.Lock()
        self.failed = []
        self.out = out or sys.stdout

    def run_lane(self, lane):
        for kind, name, src, exe, folder in lane:
            env = dict(os.environ, CARGO_MANIFEST_DIR=folder)
            start = time.monotonic()
            with tempfile.TemporaryFile(mode="w+b") as out:
                rc = subprocess.run([exe], cwd=folder, env=env, stdout=out, stderr=subprocess.STDOUT).returncode
                out.seek(0)
                text = out.read().decode("utf-8", "replace")
            took = time.monotonic() - start
            label = "unittests " + os.path.relpath(src, folder) if kind in ("lib", "bin") else os.path.relpath(src, folder)
            with self.lock:
                self.out.write(f"     Running {label} ({os.path.relpath(exe, folder)}), {took:.1f} s\n")
                self.out.write(text)
                self.out.flush()
                if rc != 0:
                    self.failed.append(f"{label} (exit {rc})")


def self_test():
    binaries = [
        ("bench", "raster", "b", "e", "f"),
        ("test", "synth", "s", "e", "f"),
        ("lib", "rig", "l", "e", "f"),
        ("test", "rig", "r", "e", "f"),
    ]
    lanes = lanes_of(binaries, {"synth"})
    assert [[b[1] for b in lane] for lane in lanes] == [["raster", "rig", "rig"], ["synth"]], lanes
    # The library's unit tests share the package's name with a test target: only a test or a
    # benchmark target gets a lane of its own.
    lanes = lanes_of(binaries, {"rig"})
    assert [[b[0] for b in lane] for lane in lanes] == [["bench", "test", "lib"], ["test"]], lanes
    assert lanes_of([], {"synth"}) == []
    printed = io.StringIO()
    runner = Runner(printed)
    with tempfile.TemporaryDirectory() as tmp:
        ok, bad = os.path.join(tmp, "ok"), os.path.join(tmp, "bad")
        for path, status in ((ok, 0), (bad, 3)):
            with open(path, "w") as f:
                f.write(f"#!/bin/sh\necho ran in \"$PWD\"\nexit {status}\n")
            os.chmod(path, 0o755)
        lanes = [[("test", "a", os.path.join(tmp, "a.rs"), ok, tmp)], [("test", "b", os.path.join(tmp, "b.rs"), bad, tmp)]]
        threads = [threading.Thread(target=runner.run_lane, args=(lane,)) for lane in lanes]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    assert runner.failed == ["b.rs (exit 3)"], runner.failed
    # Each binary's output whole, under its line, run from its package's folder.
    for name in ("a.rs (ok)", "b.rs (bad)"):
        assert f"     Running {name}, " in printed.getvalue(), printed.getvalue()
    assert printed.getvalue().count(f"ran in {os.path.realpath(tmp)}\n") == 2, printed.getvalue()
    print("run_tests: self-test ok")


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--own-lane", action="append", default=[], metavar="NAME", help="run this test or bench target on a lane of its own")
    parser.add_argument("--self-test", action="store_true", help="check the lanes and the failure report, then exit")
    parser.add_argument("cargo_args", nargs="*", help="arguments of `cargo test` (after --)")
    args = parser.parse_args()
    if args.self_test:
        self_test()
        return 0
    binaries = test_binaries(args.cargo_args)
    missing = set(args.own_lane) - {b[1] for b in binaries}
    if missing:
        print(f"run_tests: no test target named {', '.join(sorted(missing))}", file=sys.stderr)
        return 2
    lanes = lanes_of(binaries, set(args.own_lane))
    start = time.monotonic()
    runner = Runner()
    threads = [threading.Thread(target=runner.run_lane, args=(lane,)) for lane in lanes]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    print(f"run_tests: {len(binaries)} test binaries in {len(lanes)} lanes, {time.monotonic() - start:.1f} s")
    if runner.failed:
        print("run_tests: failed: " + "; ".join(runner.failed), file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
