#!/usr/bin/env python3
"""How far the TacTip pins move from the no-contact look, real against simulated.

Reads the panels `rig compare-real --sensor tactip --out DIR` writes (each `1_tactip_<i>.png`
is real | baseline | footprint | contact region | simulator, 512 px each, and
`1_tactip_no_contact.png` the measured no-contact look). Pins are the connected regions
brighter than 80 (15-400 px in area), located by their intensity-weighted centre; each pin at
rest is matched to the nearest pin of the pressed frame, and matches further than 10 px away
are dropped (a pin the contact hid). Prints, per frame, the median and 90th-percentile travel
(px) of the real and the simulated pins, and the mean absolute difference from the no-contact
look after both are resized to 64 x 64 (grey levels).

With `--pair REST PRESSED` it measures two frames instead (e.g. `rig render --sensor tactip`
at a pose short of contact and at a press): the median and 90th-percentile travel, px.

Usage: python3 tools/pin_travel.py DIR
       python3 tools/pin_travel.py --pair REST.png PRESSED.png
(numpy and Pillow: tools/requirements.txt)
"""
import sys

from collections import deque

import numpy as np
from PIL import Image

# The MultiDiffSense example's TacTip frames with their indentation, mm (1.5 mm minus the
# logged z: the depth convention of `rig compare-real`), shallowest first.
FRAMES = [(1, 1.10), (5, 1.22), (4, 1.44), (2, 2.27), (3, 2.43)]


def panel(path, k):
    image = np.asarray(Image.open(path).convert("L")).astype(float)
    return image[:, 512 * k:512 * (k + 1)]


def pins(grey):
    """Intensity-weighted centres (row, column) of the 4-connected regions brighter than 80
    whose area is 15-400 px."""
    mask = grey > 80
    seen = np.zeros_like(mask)
    h, w = mask.shape
    centres = []
    for y0, x0 in zip(*np.nonzero(mask)):
        if seen[y0, x0]:
            continue
        seen[y0, x0] = True
        queue, region = deque([(y0, x0)]), []
        while queue:
            y, x = queue.popleft()
            region.append((y, x))
            for ny, nx in ((y - 1, x), (y + 1, x), (y, x - 1), (y, x + 1)):
                if 0 <= ny < h and 0 <= nx < w and mask[ny, nx] and not seen[ny, nx]:
                    seen[ny, nx] = True
                    queue.append((ny, nx))
        if 15 < len(region) < 400:
            ys, xs = np.array(region).T
            weight = grey[ys, xs]
            centres.append(((ys * weight).sum() / weight.sum(), (xs * weight).sum() / weight.sum()))
    return np.array(centres).reshape(-1, 2)


def small(grey):
    return np.asarray(Image.fromarray(grey.astype("uint8")).resize((64, 64), Image.BILINEAR)).astype(float)


def travel_between(rest, pressed):
    """Each rest pin's distance to the nearest pressed pin, px, those under 10 px."""
    at_rest, moved = pins(rest), pins(pressed)
    if len(at_rest) == 0 or len(moved) == 0:
        sys.exit("no pins found")
    travel = np.sqrt(((at_rest[:, None, :] - moved[None, :, :]) ** 2).sum(-1)).min(1)
    return travel[travel < 10]


def grey(path):
    return np.asarray(Image.open(path).convert("L")).astype(float)


def main(folder):
    rest = np.asarray(Image.open(f"{folder}/1_tactip_no_contact.png").convert("L")).astype(float)
    at_rest = pins(rest)
    if len(at_rest) == 0:
        sys.exit(f"no pins found in {folder}/1_tactip_no_contact.png")
    print("frame  press   real median/90%/64px   sim median/90%/64px")
    for index, press in FRAMES:
        cells = []
        for k in (0, 4):
            grey = panel(f"{folder}/1_tactip_{index}.png", k)
            moved = pins(grey)
            if len(moved) == 0:
                cells.append("no pins")
                continue
            travel = np.sqrt(((at_rest[:, None, :] - moved[None, :, :]) ** 2).sum(-1)).min(1)
            travel = travel[travel < 10]
            diff = np.abs(small(grey) - small(rest)).mean()
            cells.append(f"{np.median(travel):.2f}/{np.percentile(travel, 90):.2f}/{diff:.2f}")
        print(f"{index:>5}  {press:.2f} mm  {cells[0]:>20}   {cells[1]:>20}")


if __name__ == "__main__":
    if len(sys.argv) == 4 and sys.argv[1] == "--pair":
        t = travel_between(grey(sys.argv[2]), grey(sys.argv[3]))
        print(f"pins matched {len(t)}: median travel {np.median(t):.2f} px, 90th percentile {np.percentile(t, 90):.2f} px")
    elif len(sys.argv) == 2:
        main(sys.argv[1])
    else:
        sys.exit(__doc__)
