"""A picture of how a checkpoint draws one sensor's contact on its own training poses.

    python tools/train/contact_panel.py --ckpt out/train-3/ema-002145.pt --train-dir out/train-3 \\
        --object edge --sensor tactip --rows 4 --out docs/src/images/tactip-model-vs-true.png

One row per training row of out/train/data.npz (the first ROWS of that object and sensor), six
tiles at the data's size: the true image, the model's image (quick_eval.py's PyTorch DDIM, 20 steps, seed 0),
the hint, then |true - reference|, |model - reference| and |model - true| (largest channel, 3x
brightened). Prints each row's pose and the contact axis rig eval's estimator finds in both.
"""

import argparse
import os
import sys

import numpy as np
import torch
from PIL import Image

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from quick_eval import contact_estimate, sample_model, training_rows  # noqa: E402


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--train-data", default="out/train/data.npz")
    ap.add_argument("--ckpt", required=True)
    ap.add_argument("--train-dir", required=True)
    ap.add_argument("--object", default="edge")
    ap.add_argument("--sensor", default="tactip")
    ap.add_argument("--rows", type=int, default=4)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--out", required=True)
    args = ap.parse_args()
    torch.set_num_threads(2)
    d = np.load(args.train_data)
    sel, ref = training_rows(d, args.object, args.sensor, args.rows)
    if len(sel) == 0:
        sys.exit(f"no training rows of {args.object}/{args.sensor} in {args.train_data}")
    hints = [d["hints"][j].astype(np.float32) / 255 for j in sel]
    model = sample_model(args.ckpt, args.train_dir, hints, [str(d["prompts"][j]) for j in sel],
                         device=args.device, batch=len(sel))

    def diff(a, b):
        return np.repeat(np.abs(a - b).max(2, keepdims=True) * 3, 3, 2)

    rows = []
    for k, j in enumerate(sel):
        true, m = d["images"][j].astype(np.float32) / 255, model[k]
        et, em = contact_estimate(true, ref, args.sensor), contact_estimate(m, ref, args.sensor)
        axis = lambda e: "none" if e is None else f"{e[2]:+.2f}"  # noqa: E731
        print(f"pose {d['poses'][j].tolist()}: axis true {axis(et)} deg, model {axis(em)} deg")
        rows.append(np.concatenate([true, m, hints[k], diff(true, ref), diff(m, ref), diff(m, true)], 1))
    img = np.clip(np.concatenate(rows, 0), 0, 1)
    Image.fromarray((img * 255).round().astype(np.uint8)).save(args.out, optimize=True)


if __name__ == "__main__":
    main()
