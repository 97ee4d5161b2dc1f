#!/usr/bin/env python3
"""The tables and the acceptance check of scripts/gpu-check.sh, from the logs in its work folder.

    tools/gpu_check_summary.py WORK_DIR [--tiny]   print them (gpu-check.sh runs this at its end)
    tools/gpu_check_summary.py --self-test         check this on tests/data/gpu-check-h200

Reads the lines gpu-check.sh keeps in WORK_DIR (VARIANT fp32 or fp16, G the guidance, 1 or 9):

  diffusers.log        tools/diffusers_anchor.py: `diffusers cuda float32 guidance 1: 50 steps in 2.621 s`
  rig-VARIANT-gG.log   `rig synth one`: `wrote ... in 3.09 s (+11.55 s loading): ...`
  fill-VARIANT-gG.log  `rig synth --fill-missing`: `...: synthesised 4 poses in 4.6 s (...)` (one line
                       a dataset) and `timing: load 10.25 s, warm-up 0.618 s (first step), 1.000 s an
                       image steady state (4 images)`
  parity.log           `rig fp32 guidance 1: max level difference 1` (levels of 255 against diffusers fp32)

and prints: the timing table; the fills' split (load, warm-up, steady state an image, and the
guidance 9 / 1 ratios); and the GPU acceptance criteria of the issue text, each `met`, `NOT met`,
or `n/a` where a number is missing. A missing file or a line in another format gives n/a, never
an error. With --tiny a line first says the thresholds are for the 512 px GPU run.
Python 3 standard library only.
"""

import re
import shutil
import sys
import tempfile
from pathlib import Path

VARIANTS = ("fp32", "fp16")
GUIDANCES = ("1", "9")
NUM = r"([0-9]+(?:\.[0-9]+)?)"

# The GPU thresholds (512 x 512, 50 steps).
GUIDED_RATIO_MAX = 1.3
FP16_FILL_MAX_S = 1.0
PARITY_MAX_LEVELS = 2


def lines_of(path):
    try:
        return path.read_text(encoding="utf-8", errors="replace").splitlines()
    except OSError:
        return []


def last_match(pattern, lines):
    found = None
    for line in lines:
        m = re.search(pattern, line)
        if m:
            found = m
    return found


def number(m, group):
    try:
        return float(m.group(group)) if m else None
    except (TypeError, ValueError):
        return None


def read_work(work):
    """Every figure of the work folder: a dict of name -> float (absent where not found)."""
    work = Path(work)
    fig = {}
    for line in lines_of(work / "diffusers.log"):
        m = re.match(r"diffusers \S+ (float32|float16) guidance ([0-9]+): [0-9]+ steps in " + NUM + " s", line)
        if m:
            fig[f"diffusers_{m.group(1)}_g{m.group(2)}"] = float(m.group(3))
    for line in lines_of(work / "parity.log"):
        m = re.match(r"rig (fp32|fp16) guidance ([0-9]+): max level difference ([0-9]+)$", line.strip())
        if m:
            fig[f"levels_{m.group(1)}_g{m.group(2)}"] = float(m.group(3))
    for v in VARIANTS:
        for g in GUIDANCES:
            key, tag = f"{v}_g{g}", f"{v}-g{g}"
            m = last_match(r"^wrote .* in " + NUM + r" s \(\+" + NUM + r" s loading\)", lines_of(work / f"rig-{tag}.log"))
            fig[f"one_{key}"], fig[f"one_load_{key}"] = number(m, 1), number(m, 2)
            fill = lines_of(work / f"fill-{tag}.log")
            poses, seconds = 0, 0.0
            for line in fill:
                m = re.search(r"synthesised ([0-9]+) poses in " + NUM + " s", line)
                if m:
                    poses, seconds = poses + int(m.group(1)), seconds + float(m.group(2))
            fig[f"fill_{key}"] = seconds / poses if poses else None
            fig[f"fill_images_{key}"] = poses or None
            timing = [line for line in fill if line.startswith("timing:")]
            t = timing[-1] if timing else ""
            fig[f"load_{key}"] = number(re.search(r"\bload " + NUM + " s", t), 1)
            fig[f"warmup_{key}"] = number(re.search(r"\bwarm-up " + NUM + " s", t), 1)
            fig[f"steady_{key}"] = number(re.search(NUM + " s an image steady state", t), 1)
    return {k: v for k, v in fig.items() if v is not None}


def s(x, decimals):
    return "n/a" if x is None else f"{x:.{decimals}f} s"


def ratio(a, b):
    return a / b if a is not None and b else None


def r2(x):
    return "n/a" if x is None else f"{x:.2f}"


def verdict(ok):
    return "n/a" if ok is None else ("met" if ok else "NOT met")


def at_most(a, b):
    return None if a is None or b is None else a <= b


def images_label(fig):
    counts = {fig.get(f"fill_images_{v}_g{g}") for v in VARIANTS for g in GUIDANCES} - {None}
    return f"{int(counts.pop())} images" if len(counts) == 1 else "images"


def tables(fig):
    """The timing table and the fills' split, as Markdown lines."""
    f = fig.get
    n = images_label(fig)
    out = ["| | guidance 1 | guidance 9 |", "|---|---|---|"]
    for dtype, name in (("float32", "fp32"), ("float16", "fp16")):
        out.append(f"| diffusers, PyTorch {name} | {s(f(f'diffusers_{dtype}_g1'), 3)} | {s(f(f'diffusers_{dtype}_g9'), 3)} |")
    for v in VARIANTS:
        out.append(f"| rig {v} `synth --fill-missing` ({n}, per image) | {s(f(f'fill_{v}_g1'), 3)} | {s(f(f'fill_{v}_g9'), 3)} |")
        one = [
            "n/a" if f(f"one_{v}_g{g}") is None else f"{s(f(f'one_{v}_g{g}'), 2)} (+{s(f(f'one_load_{v}_g{g}'), 2)} loading)"
            for g in GUIDANCES
        ]
        out.append(f"| rig {v} `synth one` (first image of a process) | {one[0]} | {one[1]} |")
    lv = {k: "n/a" if f(f"levels_{k}") is None else str(int(f(f"levels_{k}"))) for k in ("fp32_g1", "fp16_g1", "fp32_g9", "fp16_g9")}
    out.append(
        f"| parity: max level difference, rig fp32 / fp16 against diffusers fp32 | {lv['fp32_g1']} / {lv['fp16_g1']} | {lv['fp32_g9']} / {lv['fp16_g9']} |"
    )
    out += [
        "",
        "The fills' `timing:` lines: the warm-up is the first step's extra cost, paid once a process; per image is the",
        "fill's time over its images, warm-up included.",
        "",
        f"| fill, {n} | load | warm-up | steady state, an image | per image | guidance 9 / 1, steady state | guidance 9 / 1, per image |",
        "|---|---|---|---|---|---|---|",
    ]
    for v in VARIANTS:
        for g in GUIDANCES:
            k = f"{v}_g{g}"
            ratios = ["", ""]
            if g == "9":
                ratios = [r2(ratio(f(f"steady_{v}_g9"), f(f"steady_{v}_g1"))), r2(ratio(f(f"fill_{v}_g9"), f(f"fill_{v}_g1")))]
            out.append(
                f"| rig {v}, guidance {g} | {s(f(f'load_{k}'), 2)} | {s(f(f'warmup_{k}'), 3)} | {s(f(f'steady_{k}'), 3)} "
                f"| {s(f(f'fill_{k}'), 3)} | {ratios[0]} | {ratios[1]} |"
            )
    return out


def acceptance(fig, tiny=False):
    """The issue's GPU criteria on these figures: Markdown lines, and [(criterion, verdict)]."""
    f = fig.get
    rows = []
    for g in GUIDANCES:
        rig, dif = f(f"fill_fp32_g{g}"), f(f"diffusers_float32_g{g}")
        rows.append((f"rig fp32 fill per image <= diffusers fp32, guidance {g}", f"{s(rig, 3)} against {s(dif, 3)}", at_most(rig, dif)))
    for what, digits, g1, g9 in (
        ("fill per image", 3, f("fill_fp32_g1"), f("fill_fp32_g9")),
        ("fill steady state", 3, f("steady_fp32_g1"), f("steady_fp32_g9")),
        ("`synth one`", 2, f("one_fp32_g1"), f("one_fp32_g9")),
    ):
        q = ratio(g9, g1)
        shown = f"{s(g9, digits)} / {s(g1, digits)}" + ("" if q is None else f" = {q:.2f}x")
        rows.append((f"rig fp32 guidance 9 <= {GUIDED_RATIO_MAX}x guidance 1, {what}", shown, at_most(q, GUIDED_RATIO_MAX)))
    for what, key in (("per image, warm-up included", "fill_fp16_g1"), ("steady state", "steady_fp16_g1")):
        rows.append((f"rig fp16 fill <= {FP16_FILL_MAX_S} s an image, guidance 1, {what}", s(f(key), 3), at_most(f(key), FP16_FILL_MAX_S)))
    for v in VARIANTS:
        for g in GUIDANCES:
            level = f(f"levels_{v}_g{g}")
            shown = "n/a" if level is None else f"{int(level)} level{'' if level == 1 else 's'}"
            rows.append((f"parity <= {PARITY_MAX_LEVELS} levels of 255, rig {v} against diffusers fp32, guidance {g}", shown, at_most(level, PARITY_MAX_LEVELS)))
    out = []
    if tiny:
        out.append("--tiny: these thresholds are for the 512 x 512 GPU run (50 steps); on the tiny model they mean nothing.")
    out += ["| acceptance (issue text) | measured | verdict |", "|---|---|---|"]
    out += [f"| {c} | {m} | {verdict(ok)} |" for c, m, ok in rows]
    return out, [(c, verdict(ok)) for c, _, ok in rows]


def summary(work, tiny=False):
    fig = read_work(work)
    lines, _ = acceptance(fig, tiny)
    return "\n".join(tables(fig) + [""] + lines)


def self_test():
    """The H200 figures of docs/src/benchmarks.md give the verdicts the guide states, and the block
    the guide shows; figures equal to a threshold meet it; odd or missing logs give n/a and no error."""
    fixture = Path(__file__).resolve().parent.parent / "tests" / "data" / "gpu-check-h200"
    fails = []
    fig = read_work(fixture)
    text = summary(fixture)
    _, verdicts = acceptance(fig)
    want = ["met", "met", "NOT met", "NOT met", "met", "NOT met", "met", "met", "met", "met", "met"]
    if [v for _, v in verdicts] != want:
        fails.append(f"H200 verdicts {verdicts}, want {want}")
    for row in (
        "| rig fp32 `synth --fill-missing` (4 images, per image) | 1.150 s | 1.950 s |",
        "| rig fp16 `synth one` (first image of a process) | 5.04 s (+7.14 s loading) | 3.73 s (+7.05 s loading) |",
        "| rig fp32, guidance 9 | 10.83 s | 1.061 s | 1.679 s | 1.950 s | 1.68 | 1.70 |",
        "| rig fp16, guidance 9 | 7.89 s | 1.220 s | 1.190 s | 1.500 s | 1.48 | 1.28 |",
        "| rig fp32 guidance 9 <= 1.3x guidance 1, `synth one` | 3.58 s / 3.09 s = 1.16x | met |",
        "| parity <= 2 levels of 255, rig fp16 against diffusers fp32, guidance 9 | 1 level | met |",
        "| rig fp16 fill <= 1.0 s an image, guidance 1, steady state | 0.805 s | met |",
    ):
        if row not in text.splitlines():
            fails.append(f"H200 summary lacks {row!r}")
    # "At most": a figure equal to its threshold meets it.
    edge = {"fill_fp32_g1": 2.0, "diffusers_float32_g1": 2.0, "steady_fp32_g1": 1.0, "steady_fp32_g9": 1.3,
            "steady_fp16_g1": 1.0, "levels_fp32_g1": 2.0}
    _, verdicts = acceptance(edge)
    met = [c for c, v in verdicts if v == "met"]
    if len(met) != 4 or any(v not in ("met", "n/a") for _, v in verdicts):
        fails.append(f"figures equal to their thresholds: {verdicts}, want 4 met and the rest n/a")
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp) / "work"
        shutil.copytree(fixture, work)
        (work / "diffusers.log").unlink()
        (work / "parity.log").write_text("rig fp32 guidance 1: max level difference\n\x00\xff garbage\n")
        (work / "fill-fp16-g1.log").write_text("timing: load x s, warm-up (first step), no image yet\n")
        (work / "rig-fp32-g9.log").write_bytes(b"wrote \xff\xfe in s (+ s loading)\n")
        (work / "fill-fp32-g9.log").unlink()
        try:
            text = summary(work, tiny=True)
            _, verdicts = acceptance(read_work(work))
        except Exception as e:  # the point of the test: nothing in the logs raises
            fails.append(f"odd logs raised {e!r}")
        else:
            # Each criterion has lost at least one of its numbers.
            if [v for _, v in verdicts] != ["n/a"] * len(want):
                fails.append(f"odd logs: verdicts {verdicts}, want n/a throughout")
            if not text.startswith("--tiny: ") and "\n--tiny: " not in text:
                fails.append("--tiny printed no line about the thresholds")
            if "| rig fp16, guidance 1 | n/a | n/a | n/a | n/a |  |  |" not in text:
                fails.append("a timing line without numbers did not give n/a in the split")
    # The guide shows this block as the H200 figures give it.
    guide = (fixture.parent.parent.parent / "docs" / "src" / "benchmarks.md").read_text(encoding="utf-8").splitlines()
    block, _ = acceptance(fig)
    if any(row not in guide for row in block):
        fails.append("docs/src/benchmarks.md does not show the acceptance block the H200 figures give")
    if fails:
        print("gpu_check_summary self-test FAILED:\n  " + "\n  ".join(fails), file=sys.stderr)
        return 1
    print(f"gpu_check_summary self-test: ok ({len(want)} verdicts on the H200 figures; odd logs give n/a)")
    return 0


def main(argv):
    args = argv[1:]
    if args == ["--self-test"]:
        return self_test()
    tiny = "--tiny" in args
    rest = [a for a in args if a != "--tiny"]
    if len(rest) != 1 or rest[0].startswith("-"):
        print("usage: tools/gpu_check_summary.py WORK_DIR [--tiny] | --self-test", file=sys.stderr)
        return 2
    print(summary(rest[0], tiny))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
