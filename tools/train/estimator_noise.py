"""How far pixel noise alone moves the contact axis that rig eval's estimator finds.

    python tools/train/estimator_noise.py [--sensor tactip] [--object edge] [--rows 150]

For the first ROWS training rows of that object and sensor in out/train/data.npz (true images,
at the data's size, 128 px for the default) whose contact has a yaw (eigenvalue ratio below 0.5), and for each blur divisor and
region fraction of the grid (the `ContactEstimator` family, ported in quick_eval.py), adds
white Gaussian noise of 1 and 2 8-bit levels and prints how far the estimated axis moves (mean
and median, deg). A synthetic image whose pixels are off by about that much cannot be told from
the true one by its axis below this scale. Seeded: the same data gives the same table.
"""

import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import quick_eval as q  # noqa: E402


def axis_change(true_estimate, estimate):
    """How far the axis moved; a lost estimate counts as 90 deg."""
    return 90.0 if estimate is None else q.axis_difference(true_estimate[2], estimate[2])


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--train-data", default="out/train/data.npz")
    ap.add_argument("--sensor", default="tactip")
    ap.add_argument("--object", default="edge")
    ap.add_argument("--rows", type=int, default=150)
    ap.add_argument("--divisors", default="128,64,32")
    ap.add_argument("--fractions", default="0,0.1,0.2,0.3,0.5")
    args = ap.parse_args()
    d = np.load(args.train_data)
    sel, ref = q.training_rows(d, args.object, args.sensor, args.rows)
    if len(sel) == 0:
        sys.exit(f"no training rows of {args.object}/{args.sensor} in {args.train_data}")
    trues = [d["images"][j].astype(np.float32) / 255 for j in sel]
    rng = np.random.default_rng(1)
    print(f"{args.sensor} {args.object}: axis change under white noise, deg (mean / median)")
    print(f"{'divisor':>7} {'fraction':>8} {'poses':>5} {'1 level':>15} {'2 levels':>15}")
    for div in map(float, args.divisors.split(",")):
        for frac in map(float, args.fractions.split(",")):
            q.ESTIMATORS[args.sensor] = (div, frac)
            moved = {1: [], 2: []}
            for true in trues:
                et = q.contact_estimate(true, ref, args.sensor)
                if et is None or et[3] >= 0.5:
                    continue
                for sigma in moved:
                    noisy = np.clip(true + rng.normal(0, sigma / 255, true.shape).astype(np.float32), 0, 1)
                    moved[sigma].append(axis_change(et, q.contact_estimate(noisy, ref, args.sensor)))
            cells = [f"{np.mean(v):.3f} / {np.median(v):.3f}" if v else "n/a" for v in moved.values()]
            print(f"{div:>7g} {frac:>8g} {len(moved[1]):>5} {cells[0]:>15} {cells[1]:>15}", flush=True)


if __name__ == "__main__":
    main()
