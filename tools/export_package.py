"""Exports a Stable Diffusion + ControlNet model to rig's model-package layout (ONNX).

Two sources, both read from local files only (nothing is downloaded):

1. an original-ControlNet (cldm) checkpoint such as a MultiDiffSense model: the plain
   `{"state_dict"}` file or the Lightning training checkpoint its train.py writes (.ckpt, read
   without running code from it; or .safetensors), with its yaml config (models/cldm_v15.yaml)
   and a local CLIP folder (openai/clip-vit-large-patch14: tokenizer and config.json):

       python tools/export_package.py --original-ckpt multidiffsense.ckpt --original-config cldm_v15.yaml \\
           --clip-dir clip-vit-large-patch14 --out models/multidiffsense

   The CLIP text weights come from the checkpoint (`cond_stage_model.transformer.*`); --clip-dir
   gives the tokenizer and the text model's architecture, and its weights only when the
   checkpoint has none. The tool prints where each part came from (tools/cldm_checkpoint.py).
   model.toml gets MultiDiffSense's sampling as defaults: DDIM, 50 steps, eta 0, guidance 1
   (what its generate and test scripts save), the config's resolution, and
   control_colour_map = "viridis" (its control image; rig refuses a grey one).

2. a diffusers ControlNet pipeline saved with save_pretrained (folders unet/, vae/, text_encoder/,
   tokenizer/, scheduler/, controlnet/), or a diffusers SD 1.5 folder plus --controlnet DIR:

       python tools/export_package.py --diffusers path/to/pipeline [--controlnet path/to/controlnet] --out models/mine

   model.toml declares no control colour map: the package reads any 8-bit RGB control image,
   grey included, as diffusers' depth and edge ControlNets are given.

Writes model.toml, tokenizer/tokenizer.json, {text_encoder,controlnet,unet,vae_decoder}/model.onnx
and scheduler/scheduler_config.json, then runs each ONNX model in onnxruntime against PyTorch.
A model over 2 GB (the full-size UNet) keeps its weights in one file, model.onnx.data, beside its
model.onnx (--external-data always: every model does). --fp16 writes float16 weights and
activations with float32 inputs and outputs (tools/repack_package.py says what stays float32).
Check the result with `rig synth info --model OUT`.
"""

import argparse
import os
import shutil
import sys
import time
import warnings

import torch

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from repack_package import repack_package  # noqa: E402
from rig_export import check_onnx, export_models, write_model_toml, write_scheduler_config  # noqa: E402

# MultiDiffSense's generate.py and test.py call ControlLDM.log_images with its defaults and save
# log["samples"]: DDIM, 50 steps, eta 0, no guidance (the guidance-9 sample is computed and dropped).
MDS_SAMPLING = {"sampler": "ddim", "sampling_steps": 50, "eta": 0.0, "guidance": 1.0}


def load_diffusers(path, controlnet_path):
    from diffusers import ControlNetModel, StableDiffusionControlNetPipeline

    kwargs = {"local_files_only": True, "safety_checker": None, "requires_safety_checker": False}
    if controlnet_path:
        kwargs["controlnet"] = ControlNetModel.from_pretrained(controlnet_path, local_files_only=True)
    pipe = StableDiffusionControlNetPipeline.from_pretrained(path, **kwargs)
    if getattr(pipe, "controlnet", None) is None:
        sys.exit("the pipeline has no ControlNet")
    pipe.to(torch.float32)
    tok = pipe.tokenizer
    backend = tok.backend_tokenizer if hasattr(tok, "backend_tokenizer") else None
    if backend is None:
        from transformers import CLIPTokenizerFast

        backend = CLIPTokenizerFast.from_pretrained(os.path.join(path, "tokenizer"), local_files_only=True).backend_tokenizer
    return pipe.text_encoder, pipe.controlnet, pipe.unet, pipe.vae, backend, pipe.tokenizer.pad_token, dict(pipe.scheduler.config)


def load_original(ckpt, config_path, clip_dir):
    from cldm_checkpoint import CheckpointError, CldmConfig, convert, load_checkpoint
    from transformers import CLIPTokenizerFast

    try:
        config = CldmConfig(config_path)
        state_dict, description = load_checkpoint(ckpt)
        print(f"checkpoint   {ckpt}: {description}")
        text_encoder, controlnet, unet, vae, report = convert(state_dict, config, clip_dir)
    except CheckpointError as e:
        sys.exit(f"error: {e}")
    for line in report:
        print(line)
    tok = CLIPTokenizerFast.from_pretrained(clip_dir, local_files_only=True)
    print(f"tokenizer    --clip-dir {clip_dir} ({len(tok)} tokens, padded with {tok.pad_token!r})")
    return text_encoder, controlnet, unet, vae, tok.backend_tokenizer, tok.pad_token, config


def main():
    warnings.filterwarnings("ignore", category=torch.jit.TracerWarning)
    try:
        from transformers.utils import logging as hf_logging

        hf_logging.set_verbosity_error()
    except ImportError:
        pass
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    src = ap.add_mutually_exclusive_group(required=True)
    src.add_argument("--diffusers", help="diffusers pipeline folder")
    src.add_argument("--original-ckpt", help="original ControlNet (cldm) checkpoint: .ckpt (plain or Lightning) or .safetensors")
    ap.add_argument("--controlnet", help="diffusers ControlNet folder (with --diffusers)")
    ap.add_argument("--original-config", help="cldm yaml config (with --original-ckpt)")
    ap.add_argument("--clip-dir", help="local CLIP folder: tokenizer and config.json (with --original-ckpt)")
    ap.add_argument("--out", required=True, help="package folder (replaced if it exists)")
    ap.add_argument("--name", default=None, help="default: the checkpoint's or folder's name")
    ap.add_argument("--resolution", type=int, default=None,
                    help="square image size in pixels (default: the config's, image_size x the VAE's scale, "
                         "for --original-ckpt; 512 for --diffusers)")
    ap.add_argument("--opset", type=int, default=17)
    ap.add_argument("--sampler", choices=["ddim", "dpm++2m"], default=None,
                    help="model.toml sampling defaults (--original-ckpt: ddim, 50 steps, eta 0, guidance 1, as "
                         "MultiDiffSense's scripts sample; --diffusers: none)")
    ap.add_argument("--sampling-steps", type=int, default=None)
    ap.add_argument("--eta", type=float, default=None)
    ap.add_argument("--guidance", type=float, default=None)
    ap.add_argument("--fp16", action="store_true",
                    help="float16 weights and activations (inputs and outputs stay float32; GroupNorm and LayerNorm "
                         "statistics and the timestep embedding stay float32)")
    ap.add_argument("--external-data", choices=["auto", "always", "never"], default="auto",
                    help="weights in one model.onnx.data per model: auto (models over 2 GB), always, never")
    args = ap.parse_args()

    t0 = time.time()
    sampling = {}
    if args.original_ckpt:
        if not (args.original_config and args.clip_dir):
            ap.error("--original-ckpt needs --original-config and --clip-dir")
        text_encoder, controlnet, unet, vae, backend, pad_token, config = load_original(
            args.original_ckpt, args.original_config, args.clip_dir)
        resolution = args.resolution or config.resolution
        vae_scale_factor = config.vae_scale_factor
        scheduler_config = config.scheduler_config()
        sampling = dict(MDS_SAMPLING)
        # MultiDiffSense's control: the depth map colour-mapped with viridis (rig refuses grey).
        control_colour_map = "viridis"
    else:
        text_encoder, controlnet, unet, vae, backend, pad_token, scheduler_config = load_diffusers(args.diffusers, args.controlnet)
        resolution = args.resolution or 512
        vae_scale_factor = 2 ** (len(vae.config.block_out_channels) - 1)
        # A diffusers ControlNet reads whatever its pipeline is given (depth and edge ones: grey).
        control_colour_map = None
    for key, value in (("sampler", args.sampler), ("sampling_steps", args.sampling_steps), ("eta", args.eta),
                       ("guidance", args.guidance)):
        if value is not None:
            sampling[key] = value
    t_load = time.time() - t0

    out = os.path.abspath(args.out)
    if os.path.isdir(out) and os.listdir(out):
        if not os.path.isfile(os.path.join(out, "model.toml")):
            sys.exit(f"error: {out} exists and is not a model package; refusing to replace it")
        shutil.rmtree(out)
    os.makedirs(os.path.join(out, "tokenizer"), exist_ok=True)
    backend.no_padding()
    backend.no_truncation()
    backend.save(os.path.join(out, "tokenizer", "tokenizer.json"))

    export_models(out, text_encoder, controlnet, unet, vae, resolution, resolution, opset=args.opset,
                  vae_scale_factor=vae_scale_factor)
    name = args.name or os.path.splitext(os.path.basename(os.path.normpath(args.original_ckpt or args.diffusers)))[0]
    write_model_toml(out, name, resolution, resolution, vae.config.scaling_factor, vae_scale_factor=vae_scale_factor,
                     end_token=pad_token, control_colour_map=control_colour_map, **sampling)
    write_scheduler_config(out, scheduler_config)
    t_export = time.time() - t0 - t_load

    ids = backend.encode("a tactile image").ids[:77]
    pad_id = backend.token_to_id(pad_token)
    ids = torch.tensor([ids + [pad_id] * (77 - len(ids))], dtype=torch.int32)
    diffs = check_onnx(out, text_encoder, controlnet, unet, vae, ids, resolution, resolution, vae_scale_factor)
    print("onnx check   max |onnxruntime - torch|: " + ", ".join(f"{k} {v:.1e}" for k, v in diffs.items()))
    worst = max(diffs.values())
    if not worst < 1e-3:
        sys.exit(f"error: an exported model differs from PyTorch by {worst:.2e}")
    # torch writes a model over 2 GB as one file per tensor: one model.onnx.data per model instead,
    # and float16 if asked (checked against PyTorch's float32 below, for information).
    for name, (size, outside) in repack_package(out, fp16=args.fp16, external=args.external_data).items():
        print(f"{name:13}{size / 1e6:9.1f} MB{' float16' if args.fp16 else ''}"
              f"{', weights in model.onnx.data' if outside else ''}")
    if args.fp16:
        diffs = check_onnx(out, text_encoder, controlnet, unet, vae, ids, resolution, resolution, vae_scale_factor)
        print("fp16 check   max |onnxruntime float16 - torch float32|: " + ", ".join(f"{k} {v:.1e}" for k, v in diffs.items()))
    total = sum(os.path.getsize(os.path.join(d, f)) for d, _, fs in os.walk(out) for f in fs)
    print(f"wrote {out} ({total / 1e6:.1f} MB) in {time.time() - t0:.0f} s (load and convert {t_load:.0f} s, "
          f"export {t_export:.0f} s); check it with: rig synth info --model {out}")


if __name__ == "__main__":
    main()
