"""The same pipeline as rig's, driven from Python onnxruntime: for the benchmark
(benches/synth_vs_python.rs) and for checking rig against an independent implementation.

Same work per image as `rig synth one --sampler ddim`: tokenise (padded to 77 with the end
token), encode the prompt and the negative prompt in one call, then per step one ControlNet call
and one UNet call on the [uncond, cond] batch (only cond at guidance 1), DDIM (eta 0) in numpy,
one VAE decode. The package's `model.toml` gives the resolution, the VAE factor, the latent
scale and the hint encoding; the UNet's input gives the latent channels; the scheduler config
gives the prediction type (epsilon, sample or v_prediction). So any rig package runs, the tiny
test package (4 latent channels at 1/8, epsilon) and `models/default` (1/4, sample) alike.

    python tools/ort_pipeline.py --model tests/data/tiny-package --control control.png \
        --prompt "..." --steps 20 --guidance 7.5 --images 5 [--size 64x64] [--threads N] [--json]
"""

import argparse
import json
import os
import time
import tomllib

import numpy as np
import onnxruntime as ort
from PIL import Image
from tokenizers import Tokenizer


class DDIM:
    def __init__(self, cfg, steps):
        n = cfg.get("num_train_timesteps", 1000)
        if cfg.get("beta_schedule", "linear") == "scaled_linear":
            betas = np.linspace(cfg["beta_start"] ** 0.5, cfg["beta_end"] ** 0.5, n, dtype=np.float64).astype(np.float32) ** 2
        else:
            betas = np.linspace(cfg["beta_start"], cfg["beta_end"], n, dtype=np.float64).astype(np.float32)
        self.ac = np.cumprod(1.0 - betas, dtype=np.float32)
        self.final = np.float32(1.0) if cfg.get("set_alpha_to_one", True) else self.ac[0]
        self.ratio = n // steps
        self.timesteps = (np.arange(0, steps) * self.ratio)[::-1] + cfg.get("steps_offset", 0)
        self.prediction = cfg.get("prediction_type", "epsilon")
        if self.prediction not in ("epsilon", "sample", "v_prediction"):
            raise SystemExit(f"prediction_type {self.prediction!r} is not supported")

    def step(self, out, t, x):
        a = self.ac[t]
        prev = t - self.ratio
        a_prev = self.ac[prev] if prev >= 0 else self.final
        if self.prediction == "epsilon":
            eps = out
            x0 = (x - np.sqrt(1 - a) * eps) / np.sqrt(a)
        elif self.prediction == "sample":
            x0 = out
            eps = (x - np.sqrt(a) * x0) / np.sqrt(1 - a)
        else:  # v_prediction
            x0 = np.sqrt(a) * x - np.sqrt(1 - a) * out
            eps = np.sqrt(a) * out + np.sqrt(1 - a) * x
        return np.sqrt(a_prev) * x0 + np.sqrt(1 - a_prev) * eps


def np_type(ort_type):
    return {"tensor(int32)": np.int32, "tensor(int64)": np.int64, "tensor(float)": np.float32, "tensor(double)": np.float64}[ort_type]


class Pipeline:
    def __init__(self, model, threads=None):
        opts = ort.SessionOptions()
        if threads:
            opts.intra_op_num_threads = threads
        load = lambda m: ort.InferenceSession(os.path.join(model, m, "model.onnx"), opts, providers=["CPUExecutionProvider"])
        self.text, self.cn, self.unet, self.vae = load("text_encoder"), load("controlnet"), load("unet"), load("vae_decoder")
        self.tok = Tokenizer.from_file(os.path.join(model, "tokenizer", "tokenizer.json"))
        end = self.tok.token_to_id("<|endoftext|>")
        self.tok.enable_truncation(77)
        self.tok.enable_padding(length=77, pad_id=end, pad_token="<|endoftext|>")
        with open(os.path.join(model, "scheduler", "scheduler_config.json")) as f:
            self.sched_cfg = json.load(f)
        with open(os.path.join(model, "model.toml"), "rb") as f:
            self.config = tomllib.load(f)
        self.resolution = tuple(self.config.get("resolution", (512, 512)))
        self.vae_factor = int(self.config.get("vae_scale_factor", 8))
        self.latent_scale = float(self.config.get("latent_scale", 0.18215))
        self.hint_encoding = self.config.get("hint_encoding", "rgb01")
        self.types = {s: {i.name: i for i in getattr(self, s).get_inputs()} for s in ("text", "cn", "unet")}
        channels = self.types["unet"]["sample"].shape[1]
        self.latent_channels = channels if isinstance(channels, int) else 4
        self.down = [o.name for o in self.cn.get_outputs()]
        self.res = [i.name for i in self.unet.get_inputs()][3:]

    def ts(self, sess, t, batch):
        spec = self.types[sess]["timestep"]
        shape = [] if len(spec.shape) == 0 else ([1] if spec.shape == [1] else [batch])
        return np.full(shape, t, dtype=np_type(spec.type))

    def generate(self, control, prompt, negative, steps, guidance, latents):
        guided = guidance != 1.0
        prompts = [negative, prompt] if guided else [prompt]
        ids = np.array([e.ids for e in self.tok.encode_batch(prompts)], dtype=np_type(self.types["text"]["input_ids"].type))
        ehs = self.text.run(["last_hidden_state"], {"input_ids": ids})[0]
        hint = (np.asarray(control, dtype=np.float32) / 255.0).transpose(2, 0, 1)[None]
        if self.hint_encoding == "rgb11":
            hint = hint * 2.0 - 1.0
        b = 2 if guided else 1
        hint = np.repeat(hint, b, axis=0)
        sched = DDIM(self.sched_cfg, steps)
        x = latents
        for t in sched.timesteps:
            sample = np.concatenate([x] * b)
            res = self.cn.run(self.down, {"sample": sample, "timestep": self.ts("cn", t, b), "encoder_hidden_states": ehs,
                                          "controlnet_cond": hint, "conditioning_scale": np.array(1.0, dtype=np.float32)})
            feed = {"sample": sample, "timestep": self.ts("unet", t, b), "encoder_hidden_states": ehs}
            feed.update(dict(zip(self.res, res)))
            eps = self.unet.run(["out_sample"], feed)[0]
            if guided:
                eps = eps[0:1] + np.float32(guidance) * (eps[1:2] - eps[0:1])
            x = sched.step(eps, int(t), x).astype(np.float32)
        raw = self.vae.run(["sample"], {"latent_sample": (x / np.float32(self.latent_scale)).astype(np.float32)})[0]
        return raw.transpose(0, 2, 3, 1)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--model", required=True)
    ap.add_argument("--control", required=True)
    ap.add_argument("--prompt", required=True)
    ap.add_argument("--negative-prompt", default="")
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--guidance", type=float, default=7.5)
    ap.add_argument("--images", type=int, default=3)
    ap.add_argument("--size", default=None)
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--init-latents", default=None)
    ap.add_argument("--dump-raw", default=None)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()

    t0 = time.perf_counter()
    pipe = Pipeline(args.model, args.threads)
    load_s = time.perf_counter() - t0
    control = Image.open(args.control).convert("RGB")
    w, h = (int(v) for v in args.size.lower().split("x")) if args.size else pipe.resolution
    if control.size != (w, h):
        control = control.resize((w, h), Image.BILINEAR)
    rng = np.random.default_rng(0)
    times = []
    raw = None
    for i in range(args.images + 1):  # the first image warms up and is not timed
        lat = np.load(args.init_latents) if args.init_latents else rng.standard_normal((1, pipe.latent_channels, h // pipe.vae_factor, w // pipe.vae_factor)).astype(np.float32)
        t = time.perf_counter()
        raw = pipe.generate(control, args.prompt, args.negative_prompt, args.steps, args.guidance, lat)
        if i > 0:
            times.append(time.perf_counter() - t)
    if args.dump_raw:
        np.save(args.dump_raw, raw.astype(np.float32))
    result = {"load_s": load_s, "seconds": times, "mean_s": float(np.mean(times)), "min_s": float(np.min(times)),
              "onnxruntime": ort.__version__}
    print(json.dumps(result) if args.json else result)


if __name__ == "__main__":
    main()
