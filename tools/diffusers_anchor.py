"""diffusers' StableDiffusionControlNetPipeline on the same weights, control image, prompt and
initial latents as rig: its time per image and its images (scripts/gpu-check.sh).

    python tools/diffusers_anchor.py PIPELINE --control PNG --prompt TEXT --latents X_T.npy \\
        --out-prefix PREFIX [--steps 50] [--guidance 1,9] [--device auto|cpu|cuda] [--fp16]

DDIM as the pipeline's scheduler config says, eta 0, negative prompt "" (diffusers' default).
One untimed warm-up image per guidance scale, then one timed image per scale (CUDA synchronised around
it). Prints `diffusers DEVICE DTYPE guidance G: S steps in T s` per scale and saves
PREFIX_gG.png (float32 only; 8-bit, rounded as rig rounds). --fp16 also times float16 (CUDA).
"""

import argparse
import time

import numpy as np
import torch
from diffusers import StableDiffusionControlNetPipeline
from PIL import Image


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("pipeline")
    ap.add_argument("--control", required=True)
    ap.add_argument("--prompt", required=True)
    ap.add_argument("--latents", required=True)
    ap.add_argument("--out-prefix", required=True)
    ap.add_argument("--steps", type=int, default=50)
    ap.add_argument("--guidance", default="1,9", help="comma-separated guidance scales")
    ap.add_argument("--device", default="auto", choices=["auto", "cpu", "cuda"])
    ap.add_argument("--fp16", action="store_true", help="also time float16 (CUDA only)")
    args = ap.parse_args()
    device = ("cuda" if torch.cuda.is_available() else "cpu") if args.device == "auto" else args.device
    pipe = StableDiffusionControlNetPipeline.from_pretrained(args.pipeline, local_files_only=True, safety_checker=None,
                                                             requires_safety_checker=False).to(device)
    pipe.set_progress_bar_config(disable=True)
    control = Image.open(args.control).convert("RGB")
    latents = torch.from_numpy(np.load(args.latents)).to(device)
    height, width = control.height, control.width
    scales = [float(g) for g in args.guidance.split(",")]

    def run(guidance, dtype):
        if device == "cuda":
            torch.cuda.synchronize()
        t = time.perf_counter()
        r = pipe(args.prompt, image=control, height=height, width=width, num_inference_steps=args.steps,
                 guidance_scale=guidance, latents=latents.to(dtype), eta=0.0, output_type="np")
        if device == "cuda":
            torch.cuda.synchronize()
        return time.perf_counter() - t, r.images[0]

    dtypes = [torch.float32] + ([torch.float16] if args.fp16 and device == "cuda" else [])
    for dtype in dtypes:
        pipe.to(dtype=dtype)
        for g in scales:
            run(g, dtype)  # warm-up at each batch size (1 unguided, 2 guided): kernels, allocator
        for g in scales:
            seconds, image = run(g, dtype)
            print(f"diffusers {device} {str(dtype).removeprefix('torch.')} guidance {g:g}: {args.steps} steps in {seconds:.3f} s",
                  flush=True)
            if dtype == torch.float32:
                level = np.rint(np.clip(image, 0.0, 1.0) * 255.0).astype(np.uint8)  # half to even, as rig
                Image.fromarray(level).save(f"{args.out_prefix}_g{g:g}.png")


if __name__ == "__main__":
    main()
