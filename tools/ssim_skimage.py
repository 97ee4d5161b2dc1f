#!/usr/bin/env python3
"""SSIM of two images with scikit-image, timed: the peer of rig's SSIM in benches/ssim_vs_skimage.rs.

    python3 tools/ssim_skimage.py A.png B.png [--repeats N] [--json]

Computes skimage.metrics.structural_similarity(a, b, gaussian_weights=True, sigma=1.5,
use_sample_covariance=False, data_range=255, channel_axis=2) -- the definition rig's
metrics::ssim follows -- N times (default 5) on arrays already in memory, and prints the value
and the mean and fastest seconds per call (one JSON line with --json).
"""

import argparse
import json
import time

import numpy as np
from PIL import Image
from skimage.metrics import structural_similarity


def main():
    p = argparse.ArgumentParser()
    p.add_argument("a")
    p.add_argument("b")
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--json", action="store_true")
    args = p.parse_args()
    a = np.asarray(Image.open(args.a).convert("RGB"))
    b = np.asarray(Image.open(args.b).convert("RGB"))
    times = []
    value = None
    for _ in range(max(1, args.repeats)):
        t = time.perf_counter()
        value = structural_similarity(a, b, gaussian_weights=True, sigma=1.5, use_sample_covariance=False, data_range=255, channel_axis=2)
        times.append(time.perf_counter() - t)
    out = {"ssim": float(value), "mean_s": sum(times) / len(times), "min_s": min(times)}
    print(json.dumps(out) if args.json else f"ssim {out['ssim']:.12f}  mean {out['mean_s'] * 1e3:.2f} ms  fastest {out['min_s'] * 1e3:.2f} ms")


if __name__ == "__main__":
    main()
