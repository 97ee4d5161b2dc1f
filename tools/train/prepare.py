"""Packs a collected training set into one array file for train.py.

    python tools/train/prepare.py --data out/train-data --controls out/train-controls \
        --size 128 --out out/train/data.npz

For every dataset `<data>/<object>/<sensor>/` (manifest.toml + poses.csv + images/) it takes the
rows with source=real, resizes the frame to SIZE x SIZE (PIL bilinear with antialiasing, the
same triangle filter rig uses), reads the control image `<controls>/<object>/<sensor>/<pose_id>.png`
(written by `rig render --controls-of`, i.e. exactly the hint `rig synth --fill-missing` feeds
the model) and the MultiDiffSense prompt of the row (`<controls>/<object>/<sensor>/prompts.csv`,
also written by rig). The reference (no-contact) frame of each dataset is stored too.
"""

import argparse
import csv
import os
from functools import partial
from multiprocessing import Pool

import numpy as np
from PIL import Image

SENSOR_LABELS = {"tactip": "TacTip", "vitac": "ViTac", "vitactip": "ViTacTip"}


def load_rgb(path, size):
    img = Image.open(path).convert("RGB")
    if img.size != (size, size):
        img = img.resize((size, size), Image.BILINEAR)
    return np.asarray(img, dtype=np.uint8)


def read_prompts(path):
    """pose_id -> {sensor label -> prompt} from rig's prompts.csv (pose_id, sensor, prompt)."""
    out = {}
    with open(path, newline="") as f:
        for row in csv.DictReader(f):
            out.setdefault(int(row["pose_id"]), {})[row["sensor"]] = row["prompt"]
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", default="out/train-data")
    ap.add_argument("--controls", default=None, help="default: out/train-controls")
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--out", default="out/train/data.npz")
    ap.add_argument("--workers", type=int, default=os.cpu_count(), help="processes decoding images")
    args = ap.parse_args()
    controls = args.controls or "out/train-controls"

    images, hints, prompts, sensors, objects, pose_ids, poses = [], [], [], [], [], [], []
    references = {}
    for obj in sorted(os.listdir(args.data)):
        if obj == "controls" or not os.path.isdir(os.path.join(args.data, obj)):
            continue
        for sensor in sorted(os.listdir(os.path.join(args.data, obj))):
            ds = os.path.join(args.data, obj, sensor)
            if not os.path.isfile(os.path.join(ds, "manifest.toml")):
                continue
            label = SENSOR_LABELS[sensor]
            cdir = os.path.join(controls, obj, sensor)
            prompt_table = read_prompts(os.path.join(cdir, "prompts.csv"))
            references[sensor] = load_rgb(os.path.join(ds, "reference.png"), args.size)
            with open(os.path.join(ds, "poses.csv"), newline="") as f:
                for row in csv.DictReader(f):
                    if row["source"] != "real":
                        continue
                    pid = int(row["pose_id"])
                    images.append(os.path.join(ds, row["image"]))
                    hints.append(os.path.join(cdir, f"{pid}.png"))
                    prompts.append(prompt_table[pid][label])
                    sensors.append(sensor)
                    objects.append(obj)
                    pose_ids.append(pid)
                    poses.append([float(row[k]) for k in ("x_mm", "y_mm", "z_mm", "yaw_deg")])
            print(f"{obj}/{sensor}: {sum(1 for o, s in zip(objects, sensors) if o == obj and s == sensor)} rows")
    with Pool(max(1, args.workers)) as pool:
        load = partial(load_rgb, size=args.size)
        images = pool.map(load, images, chunksize=16)
        hints = pool.map(load, hints, chunksize=16)
    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    np.savez(
        args.out,
        images=np.stack(images), hints=np.stack(hints), prompts=np.array(prompts),
        sensors=np.array(sensors), objects=np.array(objects), pose_ids=np.array(pose_ids),
        poses=np.array(poses, dtype=np.float64),
        ref_sensors=np.array(sorted(references)), references=np.stack([references[s] for s in sorted(references)]),
    )
    print(f"wrote {args.out}: {len(images)} rows")


if __name__ == "__main__":
    main()
