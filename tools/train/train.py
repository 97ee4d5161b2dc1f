"""Trains the default synthesis model: a small ControlNet-on-latent-diffusion model with
MultiDiffSense's structure and conditioning (depth-map control image; the structured prompt
naming sensor and pose), from scratch, on a CPU.

    python tools/train/train.py --data out/train/data.npz --out out/train [--device cpu]

Stages (each checkpoints into --out and resumes from its last checkpoint when rerun):
  1. tokenizer: a CLIP-shaped byte-level BPE trained on the prompts of the training set;
  2. autoencoder: a fixed, lossless space-to-depth map (f=4: 128x128x3 images <-> 32x32x48
     latents, see model.SpaceToDepthAE); only its channel mean and latent scale (unit variance
     of the training latents) are computed from the data;
  3. diffusion: CLIP text encoder + `UNet2DConditionModel` + `ControlNetModel.from_unet`,
     trained jointly from scratch (there is no pretrained base at this size) to predict the
     clean latent (`prediction_type = "sample"`) under the scaled-linear DDPM noise schedule;
     half of the timesteps are drawn from the 20 that rig's default DDIM sampler visits, and
     the contact region (pixels differing from the sensor's reference frame) weighs more.
     An exponential moving average of the weights is what gets exported.

Deterministic for a given --seed, data file, thread count and torch build on the CPU (the
tokenizer trainer is not bit-for-bit repeatable, so the tokenizer is saved in --out and reused
by a resumed run).
"""

import argparse
import copy
import json
import math
import os
import sys
import time

import numpy as np
import torch
import torch.nn.functional as F

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))
sys.path.insert(0, HERE)
from model import SCHEDULER_CONFIG, SpaceToDepthAE, ae_image_size, build_text_encoder, build_unet_controlnet  # noqa: E402

# rig's default sampler: DDIM, 20 steps, "leading" spacing, steps_offset 1.
INFERENCE_TIMESTEPS = list(range(1, 1000, 50))
CONTACT_THRESHOLD = 12 / 255  # a pixel is "contact" when it differs from the reference by this much


def parse_args(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default="out/train/data.npz")
    ap.add_argument("--out", default="out/train")
    ap.add_argument("--device", default="cpu", help="cpu or cuda")
    ap.add_argument("--threads", type=int, default=2, help="torch CPU threads")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--steps", type=int, default=1200, help="diffusion training steps")
    ap.add_argument("--batch", type=int, default=8)
    ap.add_argument("--lr", type=float, default=8e-4)
    ap.add_argument("--ema", type=float, default=0.995)
    ap.add_argument("--contact-weight", type=float, default=4.0,
                    help="extra loss weight of the contact region (pixels differing from the reference)")
    ap.add_argument("--ckpt-every", type=int, default=100)
    ap.add_argument("--log-every", type=int, default=10)
    ap.add_argument("--width", type=int, default=32, help="UNet base channels")
    ap.add_argument("--polish-steps", type=int, default=0,
                    help="after the run: this many more steps at --polish-lr, the text encoder at 4x (diffusion-polish.pt)")
    ap.add_argument("--polish-lr", type=float, default=3e-4)
    ap.add_argument("--bench", type=int, default=0, help="time this many steps of each stage and exit")
    ap.add_argument("--minutes", type=float, default=0,
                    help="train for about this long instead of --steps: the step count (and so the learning-rate "
                         "schedule) is set from the speed of the first steps")
    ap.add_argument("--amp", action="store_true", help="bfloat16 autocast of the forward passes (CUDA)")
    ap.add_argument("--pure-noise-from", type=int, default=INFERENCE_TIMESTEPS[-1],
                    help="timesteps from this one up are trained on pure noise, as the sampler's first step sees it")
    ap.add_argument("--init", default=None,
                    help="start from the EMA weights of this checkpoint (same --width; put its tokenizer.json and "
                         "vae.pt in --out first)")
    return ap.parse_args(argv)


# --- data ---------------------------------------------------------------------------------

class Data:
    """The packed training set as uint8 tensors (N,3,H,W), on `device` (a GPU holds all of it)."""

    def __init__(self, path, device="cpu"):
        d = np.load(path)
        nchw = lambda a: torch.from_numpy(a).permute(0, 3, 1, 2).to(device)  # noqa: E731
        self.images = nchw(d["images"])
        self.hints = nchw(d["hints"])
        self.prompts = [str(p) for p in d["prompts"]]
        self.sensors = [str(s) for s in d["sensors"]]
        ref_sensors = [str(s) for s in d["ref_sensors"]]
        self.references = nchw(d["references"])
        self.sensor_index = torch.tensor([ref_sensors.index(s) for s in self.sensors], device=device)
        self.n = len(self.prompts)
        self.shape = tuple(d["images"].shape[1:3])

    def batch(self, idx):
        """(image in [-1, 1], hint in [0, 1], reference in [-1, 1]) of the rows idx, as float."""
        idx = torch.as_tensor(idx, device=self.images.device)
        img = self.images[idx].float() / 127.5 - 1
        hint = self.hints[idx].float() / 255.0
        ref = self.references[self.sensor_index[idx]].float() / 127.5 - 1
        return img, hint, ref


def contact_mask(img, ref):
    """1 where the image differs from its sensor's no-contact reference (any channel)."""
    return ((img - ref).abs().amax(1, keepdim=True) > 2 * CONTACT_THRESHOLD).float()


# --- checkpoints --------------------------------------------------------------------------

def save(path, **state):
    tmp = path + ".tmp"
    torch.save(state, tmp)
    os.replace(tmp, path)


def load(path):
    return torch.load(path, map_location="cpu", weights_only=False) if os.path.isfile(path) else None


def log(out, text):
    line = f"{time.strftime('%H:%M:%S')} {text}"
    print(line, flush=True)
    with open(os.path.join(out, "train.log"), "a") as f:
        f.write(line + "\n")


# --- stages -------------------------------------------------------------------------------

def tokenizer_stage(args, data):
    path = os.path.join(args.out, "tokenizer.json")
    from tokenizers import Tokenizer
    if os.path.isfile(path):
        return Tokenizer.from_file(path)
    from make_tiny_package import build_tokenizer
    tok = build_tokenizer(corpus=sorted(set(data.prompts)), vocab_size=400)
    tok.save(path)
    log(args.out, f"tokenizer: {tok.get_vocab_size()} tokens, e.g. {len(tok.encode(data.prompts[0]).ids)} for {data.prompts[0]!r}")
    return tok


def encode_prompts(tok, prompts, eos_id):
    """rig's tokenisation: truncate to 77 keeping start/end, pad with the end token."""
    out = np.full((len(prompts), 77), eos_id, dtype=np.int64)
    for i, p in enumerate(prompts):
        ids = tok.encode(p).ids
        if len(ids) > 77:
            ids = ids[:76] + [eos_id]
        out[i, :len(ids)] = ids
    return torch.from_numpy(out)


def ae_stage(args, data, device):
    """The fixed space-to-depth autoencoder; its channel mean and latent scale come from the
    training images (scale: unit variance of the latents)."""
    path = os.path.join(args.out, "vae.pt")
    ck = load(path)
    if ck is None:
        x = torch.cat([data.batch(np.arange(i, min(i + 256, data.n)))[0].cpu() for i in range(0, data.n, 256)])
        z = torch.nn.functional.pixel_unshuffle(x, 4)
        mean = z.mean((0, 2, 3))
        scale = float(1.0 / (z - mean.view(1, -1, 1, 1)).std())
        ck = {"channel_mean": mean, "scaling_factor": scale, "size": data.shape[0]}
        save(path, **ck)
        log(args.out, f"autoencoder: space-to-depth f=4, 48 latent channels, latent_scale {scale:.5f}, "
                      f"{data.shape[0]} px images")
    elif ae_image_size(ck) != data.shape[0]:
        sys.exit(f"{path} was made for {ae_image_size(ck)} px images, --data has {data.shape[0]} px")
    vae = SpaceToDepthAE(ck["channel_mean"]).to(device)
    vae.config["scaling_factor"] = ck["scaling_factor"]
    return vae


@torch.no_grad()
def encode_all(vae, data, device, out):
    path = os.path.join(out, "latents.pt")
    ck = load(path)
    if ck is not None and ck["n"] == data.n:
        return ck["latents"].to(device)
    lat = []
    for i in range(0, data.n, 64):
        img = data.batch(np.arange(i, min(i + 64, data.n)))[0].to(device)
        lat.append(vae.encode(img) * vae.config.scaling_factor)
    lat = torch.cat(lat)
    save(path, latents=lat.cpu(), n=data.n)
    return lat


def alphas_cumprod():
    betas = torch.linspace(SCHEDULER_CONFIG["beta_start"] ** 0.5, SCHEDULER_CONFIG["beta_end"] ** 0.5, 1000,
                           dtype=torch.float64) ** 2
    return torch.cumprod(1 - betas, 0).float()


def diffusion_stage(args, data, tok, latents, device, polish=False):
    path = os.path.join(args.out, "diffusion-polish.pt" if polish else "diffusion.pt")
    eos, bos = tok.token_to_id("<|endoftext|>"), tok.token_to_id("<|startoftext|>")
    torch.manual_seed(args.seed + 2)
    text_encoder = build_text_encoder(tok.get_vocab_size(), bos, eos).to(device)
    unet, controlnet = build_unet_controlnet(args.width, latents.shape[1])
    unet, controlnet = unet.to(device), controlnet.to(device)
    modules = torch.nn.ModuleDict({"text_encoder": text_encoder, "unet": unet, "controlnet": controlnet})
    ema = copy.deepcopy(modules).requires_grad_(False)
    text_params = list(text_encoder.parameters())
    other = [p for k, m in modules.items() if k != "text_encoder" for p in m.parameters()]
    opt = torch.optim.AdamW([{"params": other, "k": 1.0}, {"params": text_params, "k": 4.0 if polish else 1.0}],
                            lr=args.lr, weight_decay=0.01)
    step, n_steps_saved = 0, None
    ck = load(path)
    if polish and ck is None:
        # Start from the finished main run's weights (its EMA goes on as the EMA).
        base = load(os.path.join(args.out, "diffusion.pt"))
        modules.load_state_dict(base["model"]), ema.load_state_dict(base["ema"])
    if ck is None and not polish and args.init:
        init = load(args.init)
        if init is None:
            sys.exit(f"--init {args.init}: no such checkpoint")
        modules.load_state_dict(init["ema"]), ema.load_state_dict(init["ema"])
        log(args.out, f"initialised from the EMA weights of {args.init} (step {init.get('step')})")
    if ck is not None:
        modules.load_state_dict(ck["model"]), ema.load_state_dict(ck["ema"])
        step = ck["step"]
        n_steps_saved = ck.get("n_steps")
        if ck.get("done"):
            return ema
        opt.load_state_dict(ck["opt"])
    n_params = {k: sum(p.numel() for p in m.parameters()) for k, m in modules.items()}
    log(args.out, f"diffusion params: {n_params}")
    ids_all = encode_prompts(tok, data.prompts, eos)
    ac = alphas_cumprod().to(device)
    rng = np.random.default_rng(args.seed + 3 + step)
    torch.manual_seed(args.seed + 3 + step)
    n_steps = n_steps_saved or args.bench or (args.polish_steps if polish else args.steps)
    timed = bool(args.minutes) and not polish and not args.bench and n_steps_saved is None
    t0, seen, run_loss = time.time(), 0, 0.0
    ema_params, model_params = list(ema.parameters()), list(modules.parameters())
    t_start = t0
    amp = torch.autocast(device.type, dtype=torch.bfloat16, enabled=args.amp)
    modules.train()
    while step < n_steps:
        if timed and seen == 10:
            t_start = time.time()  # after the warm-up steps
        if timed and seen == 60:
            per_step = (time.time() - t_start) / 50
            n_steps = max(step + 1, int(args.minutes * 60 / per_step))
            log(args.out, f"--minutes {args.minutes}: {per_step * 1000:.1f} ms/step, training {n_steps} steps")
        if polish:
            lr = args.polish_lr
        else:
            lr = args.lr * min(1.0, (step + 1) / 50) * (0.5 * (1 + math.cos(math.pi * step / n_steps)) * 0.9 + 0.1)
        for g in opt.param_groups:
            g["lr"] = lr * g["k"]
        idx = rng.integers(0, data.n, args.batch)
        img, hint, ref = data.batch(idx)
        x0 = latents[torch.as_tensor(idx, device=latents.device)].to(device)
        hint, ids = hint.to(device), ids_all[idx].to(device)
        # Half the batch at the sampler's own timesteps, half anywhere.
        t_inf = torch.tensor(INFERENCE_TIMESTEPS)[torch.from_numpy(rng.integers(0, len(INFERENCE_TIMESTEPS), args.batch))]
        t_any = torch.from_numpy(rng.integers(0, 1000, args.batch))
        t = torch.where(torch.from_numpy(rng.random(args.batch) < 0.5), t_inf, t_any).to(device)
        noise = torch.randn_like(x0)
        a = ac[t].view(-1, 1, 1, 1)
        # The sampler starts from pure noise at its first timestep (951), where this schedule
        # (terminal SNR > 0) would still leave 0.09 x the image in x_t. Trained on that leak, the
        # model reads the sensor from x_t rather than from the prompt, and then draws any sensor
        # from pure noise. From --pure-noise-from up it sees what the sampler gives it.
        a = torch.where((t >= args.pure_noise_from).view(-1, 1, 1, 1), torch.zeros_like(a), a)
        xt = a.sqrt() * x0 + (1 - a).sqrt() * noise
        with amp:
            ehs = text_encoder(ids)[0]
            down, mid = controlnet(xt, t, encoder_hidden_states=ehs, controlnet_cond=hint, return_dict=False)
            pred = unet(xt, t, encoder_hidden_states=ehs, down_block_additional_residuals=down,
                        mid_block_additional_residual=mid).sample.float()
        # Contact pixels weigh more: the static background is easy, the contact is the point.
        w = 1 + args.contact_weight * F.max_pool2d(contact_mask(img, ref), 4).to(device)
        loss = (w * (pred - x0) ** 2).mean()
        opt.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(modules.parameters(), 1.0)
        opt.step()
        step += 1
        seen += 1
        with torch.no_grad():
            d = min(args.ema, (1 + step) / (10 + step))
            torch._foreach_lerp_(ema_params, model_params, 1 - d)
        run_loss += loss.detach()
        if step % args.log_every == 0 or step == n_steps:
            log(args.out, f"diffusion step {step}/{n_steps} loss {float(run_loss) / args.log_every:.4f} lr {lr:.2e} "
                          f"{(time.time() - t0) / seen:.2f} s/step")
            run_loss = 0.0
        if args.bench and step >= args.bench:
            log(args.out, f"bench diffusion: {(time.time() - t0) / seen:.2f} s/step at batch {args.batch}")
            return None
        if step % args.ckpt_every == 0 or step == n_steps:
            save(path, model=modules.state_dict(), ema=ema.state_dict(), opt=opt.state_dict(), step=step,
                 n_steps=n_steps, done=step == n_steps)
            save(os.path.join(args.out, f"ema-{'polish-' if polish else ''}{step:06d}.pt"), ema=ema.state_dict(), step=step)
            for old in sorted(f for f in os.listdir(args.out) if f.startswith("ema-0"))[:-3]:
                os.remove(os.path.join(args.out, old))
    return ema


def main(argv=None):
    args = parse_args(argv)
    torch.set_num_threads(args.threads)
    torch.manual_seed(args.seed)
    os.makedirs(args.out, exist_ok=True)
    device = torch.device(args.device)
    torch.backends.cuda.matmul.allow_tf32 = True
    torch.backends.cudnn.allow_tf32 = True
    with open(os.path.join(args.out, "args.json"), "w") as f:
        json.dump(vars(args), f, indent=2)
    data = Data(args.data, device)
    log(args.out, f"data: {data.n} rows, {data.shape[0]}x{data.shape[1]}, on {device}")
    tok = tokenizer_stage(args, data)
    vae = ae_stage(args, data, device)
    latents = encode_all(vae, data, device, args.out)
    log(args.out, f"latents: {tuple(latents.shape)} std {latents.std():.3f}")
    diffusion_stage(args, data, tok, latents, device)
    if args.polish_steps:
        diffusion_stage(args, data, tok, latents, device, polish=True)
    log(args.out, "done")


if __name__ == "__main__":
    main()
