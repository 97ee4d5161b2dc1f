#!/usr/bin/env python3
"""The dependency tree's licences, sources and wildcards against deny.toml, from `cargo metadata`.

scripts/test.sh runs this on every machine (it needs only Python's standard library and cargo,
and takes about a second), and `cargo deny check licenses bans sources` as well where cargo-deny
is installed. The two read the same deny.toml, so a machine without cargo-deny (a fresh CI
runner, where installing it compiles for a quarter of an hour) still refuses what cargo-deny
refuses for these rules:

- licences: every package outside the workspace must declare an SPDX `license` expression that
  can be satisfied with the licences in `[licenses] allow` (OR picks any side, AND needs both,
  `A WITH B` must be allowed as written; the legacy `/` reads as OR). A package with only a
  `license-file` fails: read it, then allow it in deny.toml (cargo-deny would need a
  clarification too).
- sources: only the registries in `[sources] allow-registry` (crates.io's git index and its
  sparse index are the same registry); a git dependency fails (`unknown-git = "deny"`).
- bans: with `wildcards = "deny"`, a workspace crate's dependency on version `*` fails (path
  dependencies are allowed with `allow-wildcard-paths`).

What this does not do: cargo-deny's licence-text confidence scoring (only the declared expression
is read) and its advisory check (neither runs offline).

    python3 scripts/check-licences.py              # check the tree (exit 1 naming each failure)
    python3 scripts/check-licences.py --self-test  # planted faults must each be caught
"""

import json
import re
import subprocess
import sys
import tomllib
from pathlib import Path

CRATES_IO = {
    "https://github.com/rust-lang/crates.io-index",
    "https://index.crates.io/",
    "https://index.crates.io",
}


class ExpressionError(ValueError):
    pass


def tokens(expr):
    """SPDX expression tokens; `/` (old Cargo manifests) is OR."""
    out = []
    for t in re.findall(r"\(|\)|/|[^\s()/]+", expr):
        out.append("OR" if t == "/" else t)
    return out


def satisfiable(expr, allowed):
    """Whether `expr` can be met using only licences in `allowed` (a set of strings)."""
    toks = tokens(expr)
    pos = 0

    def peek():
        return toks[pos] if pos < len(toks) else None

    def take():
        nonlocal pos
        if pos >= len(toks):
            raise ExpressionError(f"{expr!r}: ends early")
        pos += 1
        return toks[pos - 1]

    def leaf():
        t = take()
        if t == "(":
            v = either()
            if take() != ")":
                raise ExpressionError(f"{expr!r}: unbalanced parentheses")
            return v
        if t in ("AND", "OR", "WITH", ")"):
            raise ExpressionError(f"{expr!r}: {t} where a licence was expected")
        if peek() == "WITH":
            take()
            return f"{t} WITH {take()}" in allowed
        return t in allowed

    def both():
        v = leaf()
        while peek() == "AND":
            take()
            v = leaf() and v
        return v

    def either():
        v = both()
        while peek() == "OR":
            take()
            v = both() or v
        return v

    v = either()
    if pos != len(toks):
        raise ExpressionError(f"{expr!r}: unexpected {toks[pos]!r}")
    return v


def source_registry(source):
    """The registry URL of a package source, or None for a path package."""
    if source is None:
        return None
    kind, _, url = source.partition("+")
    return kind, url


def failures(metadata, deny):
    allowed = set(deny.get("licenses", {}).get("allow", []))
    sources = deny.get("sources", {})
    registries = set(sources.get("allow-registry", []))
    if registries & CRATES_IO:
        registries |= CRATES_IO
    git_allowed = set(sources.get("allow-git", []))
    bans = deny.get("bans", {})
    members = set(metadata["workspace_members"])
    out = []
    for p in sorted(metadata["packages"], key=lambda p: (p["name"], p["version"])):
        name = f'{p["name"]} {p["version"]}'
        if p["id"] in members:
            if bans.get("wildcards") == "deny":
                for d in p["dependencies"]:
                    is_path = d.get("path") is not None
                    if d["req"] == "*" and not (is_path and bans.get("allow-wildcard-paths")):
                        out.append(f"{name}: depends on {d['name']} at version * (wildcards are denied)")
            continue
        lic = p.get("license")
        if not lic:
            out.append(f"{name}: declares no SPDX licence expression (license-file {p.get('license_file')})")
        else:
            try:
                if not satisfiable(lic, allowed):
                    out.append(f"{name}: licence {lic!r} is not met by deny.toml's allow list")
            except ExpressionError as e:
                out.append(f"{name}: unreadable licence expression: {e}")
        src = source_registry(p.get("source"))
        if src is not None:
            kind, url = src
            if kind in ("registry", "sparse"):
                if url not in registries:
                    out.append(f"{name}: from registry {url}, not in deny.toml's allow-registry")
            elif kind == "git":
                base = url.split("?")[0].split("#")[0]
                if base not in git_allowed:
                    out.append(f"{name}: a git dependency ({base}); deny.toml denies unknown git sources")
            else:
                out.append(f"{name}: from an unknown source kind {kind!r}")
    return out


def self_test(deny):
    allowed = set(deny["licenses"]["allow"])
    assert satisfiable("MIT OR Apache-2.0", allowed)
    assert satisfiable("MIT/Apache-2.0", allowed)
    assert satisfiable("(MIT OR Apache-2.0) AND Unicode-3.0", allowed)
    assert satisfiable("MIT OR GPL-3.0-only", allowed)
    assert satisfiable("Apache-2.0 WITH LLVM-exception", allowed)
    assert not satisfiable("GPL-3.0-only", allowed)
    assert not satisfiable("MIT AND GPL-2.0-only", allowed)
    assert not satisfiable("GPL-2.0-only WITH Classpath-exception-2.0", allowed)
    for bad in ("MIT OR", "(MIT", "MIT Apache-2.0", "AND MIT"):
        try:
            satisfiable(bad, allowed)
        except ExpressionError:
            continue
        raise AssertionError(f"{bad!r} was read as an expression")

    def pkg(name, lic, source="registry+https://github.com/rust-lang/crates.io-index", deps=()):
        return {"id": name, "name": name, "version": "1.0.0", "license": lic, "license_file": None,
                "source": source, "dependencies": list(deps)}

    good = {"workspace_members": ["rig"], "packages": [
        pkg("rig", "MIT OR Apache-2.0", source=None, deps=[{"name": "serde", "req": "^1", "path": None}]),
        pkg("serde", "MIT OR Apache-2.0"),
        pkg("sparse", "MIT", source="sparse+https://index.crates.io/"),
    ]}
    assert failures(good, deny) == [], failures(good, deny)
    planted = {
        "copyleft": pkg("copyleft", "GPL-3.0-only"),
        "nolicence": pkg("nolicence", None),
        "gitdep": pkg("gitdep", "MIT", source="git+https://example.invalid/x.git#abc"),
        "otherreg": pkg("otherreg", "MIT", source="registry+https://example.invalid/index"),
    }
    for name, p in planted.items():
        tree = {"workspace_members": ["rig"], "packages": good["packages"] + [p]}
        found = failures(tree, deny)
        assert len(found) == 1 and found[0].startswith(name), (name, found)
    wild = {"workspace_members": ["rig"], "packages": [
        pkg("rig", "MIT", source=None, deps=[{"name": "serde", "req": "*", "path": None},
                                             {"name": "local", "req": "*", "path": "/x"}]),
        pkg("serde", "MIT"),
    ]}
    found = failures(wild, deny)
    assert len(found) == 1 and "serde at version *" in found[0], found
    print("check-licences: self-test passed (4 planted packages and a wildcard caught)")


def main():
    root = Path(__file__).resolve().parent.parent
    deny = tomllib.loads((root / "deny.toml").read_text())
    if sys.argv[1:] == ["--self-test"]:
        self_test(deny)
        return 0
    if sys.argv[1:]:
        print(__doc__, file=sys.stderr)
        return 2
    args = ["cargo", "metadata", "--format-version", "1", "--locked"]
    if deny.get("graph", {}).get("all-features"):
        args.append("--all-features")
    metadata = json.loads(subprocess.run(args, cwd=root, check=True, capture_output=True, text=True).stdout)
    found = failures(metadata, deny)
    for f in found:
        print(f"check-licences: {f}", file=sys.stderr)
    external = len(metadata["packages"]) - len(metadata["workspace_members"])
    if found:
        print(f"check-licences: {len(found)} of {external} packages fail deny.toml", file=sys.stderr)
        return 1
    print(f"check-licences: {external} packages meet deny.toml's licences, sources and wildcard rule")
    return 0


if __name__ == "__main__":
    sys.exit(main())
