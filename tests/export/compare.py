"""Compares two `rig synth one` results: raw decoder outputs (--dump-raw .npy) and PNGs.

    compare.py LABEL A.npy B.npy A.png B.png [--max-abs X] [--max-levels N] [--identical]

Prints the largest absolute difference of the raw outputs and of the 8-bit PNG levels; exits 1
when a bound is exceeded (or, with --identical, when anything differs at all).
"""

import argparse
import sys

import numpy as np
from PIL import Image

ap = argparse.ArgumentParser()
ap.add_argument("label")
ap.add_argument("raw_a")
ap.add_argument("raw_b")
ap.add_argument("png_a")
ap.add_argument("png_b")
ap.add_argument("--max-abs", type=float, default=None)
ap.add_argument("--max-levels", type=int, default=None)
ap.add_argument("--identical", action="store_true")
args = ap.parse_args()

a, b = np.load(args.raw_a), np.load(args.raw_b)
if a.shape != b.shape:
    sys.exit(f"{args.label}: raw shapes differ: {a.shape} and {b.shape}")
if not (np.isfinite(a).all() and np.isfinite(b).all()):
    sys.exit(f"{args.label}: a raw output holds NaN or infinity")
raw = float(np.abs(a.astype(np.float64) - b.astype(np.float64)).max())
pa = np.asarray(Image.open(args.png_a).convert("RGB"), dtype=np.int16)
pb = np.asarray(Image.open(args.png_b).convert("RGB"), dtype=np.int16)
levels = int(np.abs(pa - pb).max())
spread = float(np.abs(a).max())
print(f"{args.label}: max |raw difference| {raw:.2e} (raw values up to {spread:.2f}), max PNG level difference {levels} of 255")
failed = []
if args.identical and (raw != 0.0 or levels != 0):
    failed.append("the outputs are not identical")
if args.max_abs is not None and not raw <= args.max_abs:
    failed.append(f"raw difference {raw:.2e} over {args.max_abs:g}")
if args.max_levels is not None and not levels <= args.max_levels:
    failed.append(f"level difference {levels} over {args.max_levels}")
if failed:
    sys.exit(f"{args.label}: FAIL: " + "; ".join(failed))
