"""Self-check of a trained model on unseen poses of the training objects, against the two
baselines of `rig eval` (pose-blind mean image, nearest-neighbour shifted and rotated).

    python tools/train/quick_eval.py --ckpt out/train/diffusion.pt [--per 4]      # PyTorch sampler
    python tools/train/quick_eval.py --synth out/quick-synth                        # images from rig

Experiments (each adds rows): `--seeds N` samples the model with seeds 1..N-1 too; `--img2img
0.2,0.5` also starts the sampler from the nearest-neighbour image noised to these strengths
(the last round(20 * strength) steps); `--seen` judges training rows of data.npz instead of
unseen test poses (nearest-neighbour then skips the row itself); `--inside-only` also judges
each method's image with everything outside the true contact region (dilated 4 px more)
replaced by the true image, so what error is left comes from inside the contact;
`--one-shot` also judges the clean image the first sampler step predicts from pure noise (the
model as a plain regression from hint and prompt, no sampling scatter).

Test rows: the real rows of out/test-data/<object>/<sensor> (plans/test.toml) whose pose was not
collected for training. Everything is compared at the run's size, 128 x 128 for the default
(PIL bilinear, antialiased).

- contact SSIM: Gaussian-window SSIM (11 px, sigma 1.5, per RGB channel, averaged) over the
  pixels where the true image differs from its dataset's reference frame by more than 12/255
  in any channel, dilated by 1 px;
- position / yaw error: rig eval's per-sensor contact estimator (`eval::ContactEstimator`:
  the change from the reference, box-blurred three times; one contact gate at radius size/64;
  the connected region around the peak above floor + FRAC (peak - floor), weighted) gives a
  centroid and a principal axis; the error is the distance between the estimate from the
  method's image and from the true image of the same pose (rig eval's "vs true" columns; mm
  through the default calibration, 2.125 px/mm at 128 px; yaw mod 180 deg, only where the true
  image's contact is not near-isotropic, eigenvalue ratio below 0.5).

This is a quick proxy for `rig eval`, whose tables are the reference (docs/src/evaluation.md).
"""

import argparse
import csv
import functools
import math
import os
import subprocess
import sys

import numpy as np
import torch
import torch.nn.functional as F
from PIL import Image

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))
sys.path.insert(0, HERE)

SIZE = 128  # the size main() loads and compares at: --size, or the run's image size
THRESH = 12 / 255
SENSORS = ["tactip", "vitac", "vitactip"]
LABELS = {"tactip": "TacTip", "vitac": "ViTac", "vitactip": "ViTacTip"}


def px_per_mm(size):
    """The default calibration's scale at `size` px (8.5 px/mm at 512)."""
    return 8.5 * size / 512


def axis_difference(a_deg, b_deg):
    """Angle between two axes (mod 180), degrees in [0, 90] (eval::axis_difference_deg)."""
    d = abs(a_deg - b_deg) % 180
    return min(d, 180 - d)


def training_rows(train, obj, sensor, n):
    """Indices of the first n rows of obj/sensor in a data.npz (maybe none), and that sensor's
    reference frame in [0, 1]."""
    sel = np.where((train["objects"] == obj) & (train["sensors"] == sensor))[0][:n]
    ref = train["references"][list(train["ref_sensors"]).index(sensor)].astype(np.float32) / 255.0
    return sel, ref


def load_rgb(path):
    img = Image.open(path).convert("RGB")
    if img.size != (SIZE, SIZE):
        img = img.resize((SIZE, SIZE), Image.BILINEAR)
    return np.asarray(img, dtype=np.float32) / 255.0


def rows_of(ds):
    with open(os.path.join(ds, "poses.csv"), newline="") as f:
        return list(csv.DictReader(f))


def gauss_window():
    g = torch.exp(-((torch.arange(11) - 5.0) ** 2) / (2 * 1.5 ** 2))
    g = g / g.sum()
    return (g[:, None] * g[None, :]).view(1, 1, 11, 11).repeat(3, 1, 1, 1)


WIN = gauss_window()


def ssim_map(a, b):
    """Per-pixel SSIM (mean over RGB) of two HxWx3 images in [0, 1]."""
    x = torch.from_numpy(a).permute(2, 0, 1)[None]
    y = torch.from_numpy(b).permute(2, 0, 1)[None]
    f = lambda z: F.conv2d(F.pad(z, (5, 5, 5, 5), mode="reflect"), WIN, groups=3)  # noqa: E731
    mx, my = f(x), f(y)
    sxx, syy, sxy = f(x * x) - mx * mx, f(y * y) - my * my, f(x * y) - mx * my
    c1, c2 = 0.01 ** 2, 0.03 ** 2
    s = ((2 * mx * my + c1) * (2 * sxy + c2)) / ((mx * mx + my * my + c1) * (sxx + syy + c2))
    return s[0].mean(0).numpy()


def contact_mask(true, ref):
    m = (np.abs(true - ref).max(-1) > THRESH).astype(np.float32)
    return F.max_pool2d(torch.from_numpy(m)[None, None], 3, 1, 1)[0, 0].numpy() > 0.5


# rig eval's contact estimator per sensor (eval::ContactEstimator): blur divisor, region fraction.
ESTIMATORS = {"tactip": (32.0, 0.0), "vitac": (128.0, 0.4), "vitactip": (128.0, 0.3)}


def box_blur(a, r):
    """Mean over a (2r+1)-square window clipped at the border, as rig's calibration::detect::box_blur."""
    for axis in (0, 1):
        n = a.shape[axis]
        c = np.concatenate([np.zeros_like(a.take([0], axis)), np.cumsum(a, axis)], axis)
        i = np.arange(n)
        lo, hi = np.maximum(i - r, 0), np.minimum(i + r, n - 1)
        shape = [1, 1]
        shape[axis] = n
        a = (c.take(hi + 1, axis) - c.take(lo, axis)) / (hi - lo + 1).reshape(shape)
    return a


def smoothed(change, r):
    for _ in range(3):
        change = box_blur(change, r)
    return change


def noise_floor(change):
    median = np.median(change)
    return median + 4.0 * np.median(np.abs(change - median))


def contact_estimate(img, ref, sensor):
    """(u_px, v_px, axis_deg, isotropy) of the contact as rig eval estimates it, or None
    without one; isotropy is the smaller over the larger eigenvalue of its second moments."""
    raw = np.abs(img - ref).max(-1).astype(np.float64) * 255.0
    size = img.shape[1]  # radii follow the image width, as in rig
    gate_r = max(size // 64, 1)
    gate = smoothed(raw, gate_r)
    if not gate.max() - noise_floor(gate) >= 3.0:
        return None
    divisor, fraction = ESTIMATORS[sensor]
    r = max(int(size / divisor), 1)
    change = gate if r == gate_r else smoothed(raw, r)
    floor = noise_floor(change)
    peak_i = np.unravel_index(np.argmax(change), change.shape)
    threshold = floor + fraction * (change[peak_i] - floor)
    above = change > threshold
    # The 4-connected region around the peak: grow it inside `above` until it stops.
    region = np.zeros_like(above)
    region[peak_i] = True
    while True:
        grown = region.copy()
        grown[1:] |= region[:-1]
        grown[:-1] |= region[1:]
        grown[:, 1:] |= region[:, :-1]
        grown[:, :-1] |= region[:, 1:]
        grown &= above
        grown[peak_i] = True
        if (grown == region).all():
            break
        region = grown
    w = np.where(region, change - threshold, 0.0)
    w[w < 0] = 0.0
    s = w.sum()
    if not s > 0:
        w = np.zeros_like(change)
        w[peak_i] = 1.0
        s = 1.0
    v, u = np.mgrid[0:change.shape[0], 0:change.shape[1]].astype(np.float64) + 0.5
    cu, cv = (w * u).sum() / s, (w * v).sum() / s
    cuu, cvv, cuv = (w * (u - cu) ** 2).sum() / s, (w * (v - cv) ** 2).sum() / s, (w * (u - cu) * (v - cv)).sum() / s
    axis = 0.5 * math.degrees(math.atan2(2 * cuv, cuu - cvv))
    mean, half = (cuu + cvv) / 2, math.hypot((cuu - cvv) / 2, cuv)
    isotropy = min(max((mean - half) / (mean + half), 0.0), 1.0) if mean + half > 0 else 1.0
    return cu, cv, axis, isotropy


def warp(img, ref, src_pose, dst_pose):
    """The image of src_pose moved to dst_pose: translation and yaw of the object in the image
    (raster.rs: object point p appears at c + S R(-yaw) (p - t)); outside: the reference."""
    x1, y1, _, yaw1 = src_pose
    x2, y2, _, yaw2 = dst_pose
    size = img.shape[1]
    scale = px_per_mm(size)
    c = (size / 2, size / 2)
    v, u = np.mgrid[0:size, 0:size].astype(np.float64)
    # destination pixel -> object point -> source pixel
    a2 = math.radians(yaw2)
    du, dv = (u + 0.5 - c[0]) / scale, (v + 0.5 - c[1]) / scale  # pixel centres
    px = math.cos(a2) * du - math.sin(a2) * dv + x2
    py = math.sin(a2) * du + math.cos(a2) * dv + y2
    a1 = -math.radians(yaw1)
    qx, qy = px - x1, py - y1
    su = c[0] + scale * (math.cos(a1) * qx - math.sin(a1) * qy)
    sv = c[1] + scale * (math.sin(a1) * qx + math.cos(a1) * qy)
    grid = torch.from_numpy(np.stack([su / size * 2 - 1, sv / size * 2 - 1], -1)).float()[None]
    src = torch.from_numpy(img - ref).permute(2, 0, 1)[None]
    out = F.grid_sample(src, grid, mode="bilinear", padding_mode="zeros", align_corners=False)
    return np.clip(out[0].permute(1, 2, 0).numpy() + ref, 0, 1)


@functools.lru_cache(maxsize=None)
def trained_models(train_dir, ckpt):
    """The checkpoint's models, loaded once however many samplings (seeds, one-shot, img2img) use them."""
    from export import load_trained
    return load_trained(train_dir, ckpt)


@torch.no_grad()
def sample_model(ckpt, train_dir, hints, prompts, steps=20, seed=0, device="cpu", batch=8, init=None, strength=1.0,
                 one_shot=False):
    """DDIM (eta 0, rig's timesteps) with the PyTorch models of a checkpoint; images in [0, 1].
    With `init` (images in [0, 1]), starts from them noised to the timestep of `strength`
    (img2img: the last round(steps * strength) steps are run). `one_shot`: the clean image the
    first step predicts from pure noise, the sampler's other steps skipped."""
    from train import alphas_cumprod, encode_prompts
    tok, te, unet, cn, vae, _ = trained_models(train_dir, ckpt)
    te, unet, cn, vae = te.to(device), unet.to(device), cn.to(device), vae.to(device)
    eos = tok.token_to_id("<|endoftext|>")
    ac = alphas_cumprod().double()
    ts = list(range(1, 1000, 1000 // steps))[::-1]
    if init is not None:
        ts = ts[steps - max(1, round(steps * strength)):]
    g = torch.Generator().manual_seed(seed)
    out = []
    for i in range(0, len(hints), batch):
        h = torch.from_numpy(np.stack(hints[i:i + batch])).permute(0, 3, 1, 2).float().to(device)
        ehs = te(encode_prompts(tok, prompts[i:i + batch], eos).to(device))[0]
        x = torch.randn(len(h), vae.config.latent_channels, h.shape[2] // 4, h.shape[3] // 4, generator=g).to(device)
        if init is not None:
            im = torch.from_numpy(np.stack(init[i:i + batch])).permute(0, 3, 1, 2).float().to(device)
            a0 = ac[ts[0]].float()
            x = a0.sqrt() * vae.encode(im * 2 - 1) * vae.config.scaling_factor + (1 - a0).sqrt() * x
        for t in ts:
            tt = torch.tensor([t], device=device)
            down, mid = cn(x, tt, encoder_hidden_states=ehs, controlnet_cond=h, return_dict=False)
            x0 = unet(x, tt, encoder_hidden_states=ehs, down_block_additional_residuals=down,
                      mid_block_additional_residual=mid).sample
            if one_shot:
                x = x0
                break
            a = ac[t].float()
            a_prev = ac[t - 1000 // steps].float() if t - 1000 // steps >= 0 else ac[0].float()
            eps = (x - a.sqrt() * x0) / (1 - a).sqrt()
            x = a_prev.sqrt() * x0 + (1 - a_prev).sqrt() * eps
        img = vae.decode(x / vae.config.scaling_factor)[0]
        out.extend(((img.clamp(-1, 1) + 1) / 2).permute(0, 2, 3, 1).cpu().numpy())
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--train-data", default="out/train/data.npz")
    ap.add_argument("--test", default="out/test-data")
    ap.add_argument("--controls", default=None, help="default: out/test-controls (128 px), else out/test-controls-<size>")
    ap.add_argument("--size", type=int, default=None,
                    help="image size, px (default: the --train-dir run's, with --ckpt; else 128)")
    ap.add_argument("--rig", default="target/release/rig")
    ap.add_argument("--ckpt", default=None)
    ap.add_argument("--train-dir", default="out/train")
    ap.add_argument("--synth", default=None, help="<dir>/<object>/<sensor>/images/<pose_id>.png from rig")
    ap.add_argument("--objects", default="edge cuboid sphere pacman cross")
    ap.add_argument("--per", type=int, default=4, help="test poses per object and sensor")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--device", default="cpu", help="where the PyTorch sampler runs (cpu or cuda)")
    ap.add_argument("--img2img", default="", help="also sample from the nearest-neighbour image at these strengths, e.g. 0.3,0.5")
    ap.add_argument("--seen", action="store_true",
                    help="judge training rows (seen poses) instead of unseen test poses; nearest-neighbour skips the row itself")
    ap.add_argument("--inside-only", action="store_true",
                    help="also judge each method's image with the true image outside the contact region (dilated 4 px)")
    ap.add_argument("--seeds", type=int, default=1, help="also sample the model with seeds 1..N-1")
    ap.add_argument("--one-shot", action="store_true",
                    help="also judge the first sampler step's prediction alone (from pure noise, every seed)")
    args = ap.parse_args()
    if args.seen and args.synth:
        sys.exit("--seen judges training rows, which rig's synthetic images (--synth) are not named by")
    if args.img2img and not args.ckpt:
        sys.exit("--img2img samples the model: it needs --ckpt")
    torch.set_num_threads(args.threads)
    global SIZE
    if args.size is None and args.ckpt:
        from export import trained_size
        args.size = trained_size(args.train_dir)
    SIZE = args.size or 128
    if args.controls is None:
        args.controls = "out/test-controls" if SIZE == 128 else f"out/test-controls-{SIZE}"

    train = np.load(args.train_data)
    t_img = train["images"].astype(np.float32) / 255.0
    if t_img.shape[1] != SIZE:
        sys.exit(f"{args.train_data} holds {t_img.shape[1]} px images, this evaluation is at {SIZE} px (--size)")
    t_sensors, t_objects, t_poses = train["sensors"], train["objects"], train["poses"]

    # (object, sensor, id, pose, true, ref, hint, prompt): id is the test row's pose_id, or with
    # --seen the training row's index in data.npz.
    cases = []
    if args.seen:
        for obj in args.objects.split():
            for s in SENSORS:
                sel, ref = training_rows(train, obj, s, args.per)
                for j in sel:
                    cases.append((obj, s, int(j), tuple(t_poses[j]), t_img[j], ref,
                                  train["hints"][j].astype(np.float32) / 255.0, str(train["prompts"][j])))
    else:
        for obj in args.objects.split():
            for s in SENSORS:
                ds = os.path.join(args.test, obj, s)
                cdir = os.path.join(args.controls, obj, s)
                if not os.path.isfile(os.path.join(cdir, "prompts.csv")):
                    subprocess.run([args.rig, "render", "--controls-of", ds, "--size", f"{SIZE}x{SIZE}", "--out", cdir],
                                   check=True, stdout=subprocess.DEVNULL)
                prompts = {int(r["pose_id"]): r["prompt"] for r in csv.DictReader(open(os.path.join(cdir, "prompts.csv")))}
                seen = {tuple(p) for p, o, ss in zip(t_poses, t_objects, t_sensors) if o == obj and ss == s}
                ref = load_rgb(os.path.join(ds, "reference.png"))
                n = 0
                for r in rows_of(ds):
                    pose = tuple(float(r[k]) for k in ("x_mm", "y_mm", "z_mm", "yaw_deg"))
                    if r["source"] != "real" or pose in seen:
                        continue
                    pid = int(r["pose_id"])
                    cases.append((obj, s, pid, pose, load_rgb(os.path.join(ds, r["image"])), ref,
                                  load_rgb(os.path.join(cdir, f"{pid}.png")), prompts[pid]))
                    n += 1
                    if n >= args.per:
                        break

    methods = {}
    batch = 64 if args.device != "cpu" else 8
    if args.ckpt:
        for seed in range(args.seeds):
            methods["model" + (f" seed {seed}" if seed else "")] = sample_model(
                args.ckpt, args.train_dir, [c[6] for c in cases], [c[7] for c in cases],
                device=args.device, batch=batch, seed=seed)
            if args.one_shot:
                methods["model one-shot" + (f" seed {seed}" if seed else "")] = sample_model(
                    args.ckpt, args.train_dir, [c[6] for c in cases], [c[7] for c in cases],
                    device=args.device, batch=batch, seed=seed, one_shot=True)
    if args.synth:
        methods["model"] = [load_rgb(os.path.join(args.synth, c[0], c[1], "images", f"{c[2]}.png")) for c in cases]
    means = {s: t_img[t_sensors == s].mean(0) for s in SENSORS}
    methods["pose-blind"] = [means[c[1]] for c in cases]
    nn = []
    for obj, s, row_id, pose, _true, ref, _hint, _prompt in cases:
        sel = np.where((t_objects == obj) & (t_sensors == s))[0]
        if args.seen:
            sel = sel[sel != row_id]
        d = t_poses[sel] - np.array(pose)
        dist = np.sqrt((d[:, :3] ** 2).sum(1)) + np.abs(d[:, 3]) / 15.0
        j = sel[int(np.argmin(dist))]
        nn.append(warp(t_img[j], ref, t_poses[j], pose))
    methods["nearest-neighbour"] = nn
    for st in filter(None, args.img2img.split(",")):
        methods[f"img2img {st}"] = sample_model(args.ckpt, args.train_dir, [c[6] for c in cases], [c[7] for c in cases],
                                                device=args.device, batch=batch, init=nn, strength=float(st))
    # Each true image's contact region and contact estimate, once for every method.
    masks = [contact_mask(c[4], c[5]) for c in cases]
    truths = [contact_estimate(c[4], c[5], c[1]) for c in cases]
    if args.inside_only:
        # Each method's image with everything outside the true contact region (dilated 4 px more)
        # replaced by the true image: what is left of its error comes from inside the contact.
        wide = [F.max_pool2d(torch.from_numpy(m.astype(np.float32))[None, None], 9, 1, 4)[0, 0].numpy()[..., None] > 0.5
                for m in masks]
        for name in list(methods):
            methods[f"{name}, inside only"] = [np.where(m, img, c[4]) for m, img, c in zip(wide, methods[name], cases)]

    print(f"{len(cases)} {'seen training' if args.seen else 'unseen test'} poses ({args.per} per object and sensor), {SIZE} px")
    print(f"{'sensor':9} {'method':32} {'contact SSIM':>12} {'pos err mm':>15} {'yaw err deg':>15}")
    for s in SENSORS:
        idx = [i for i, c in enumerate(cases) if c[1] == s]
        for name, imgs in [("true image", [cases[i][4] for i in range(len(cases))])] + list(methods.items()):
            ssims, pos, yaw = [], [], []
            pos_tries = yaw_tries = 0
            for i in idx:
                true, ref, m, et = cases[i][4], cases[i][5], masks[i], truths[i]
                if m.sum() > 0:
                    ssims.append(ssim_map(imgs[i], true)[m].mean())
                if et is None:
                    continue
                # Yaw only where the true contact has one (rig eval's ISOTROPY_RATIO, 0.5).
                has_yaw = et[3] < 0.5
                pos_tries += 1
                yaw_tries += has_yaw
                # An image without an estimate is left out and counted, as in rig eval.
                em = contact_estimate(imgs[i], ref, s)
                if em is None:
                    continue
                pos.append(math.hypot(em[0] - et[0], em[1] - et[1]) / px_per_mm(SIZE))
                if has_yaw:
                    yaw.append(axis_difference(em[2], et[2]))

            def f(v, tries=None):
                text = f"{np.mean(v):.3f}" if v else "n/a"
                return f"{text} ({len(v)}/{tries})" if tries is not None and len(v) < tries else text

            print(f"{s:9} {name:32} {f(ssims):>12} {f(pos, pos_tries):>15} {f(yaw, yaw_tries):>15}")


if __name__ == "__main__":
    main()
