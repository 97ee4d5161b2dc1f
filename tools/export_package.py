"""Exports a Stable Diffusion + ControlNet model to rig's model-package layout (ONNX).

Two sources, both read from local files only (nothing is downloaded):

1. a diffusers ControlNet pipeline saved with save_pretrained (folders unet/, vae/, text_encoder/,
   tokenizer/, scheduler/, controlnet/), or a diffusers SD 1.5 folder plus --controlnet DIR:

       python tools/export_package.py --diffusers path/to/pipeline [--controlnet path/to/controlnet] --out models/mine

2. an original-ControlNet (cldm) checkpoint such as MultiDiffSense's multidiffsense.ckpt, with its
   config (configs/cldm_v15.yaml from the ControlNet / MultiDiffSense repositories) and a local copy
   of openai/clip-vit-large-patch14 (config, weights and tokenizer; MultiDiffSense keeps CLIP frozen):

       python tools/export_package.py --original-ckpt multidiffsense.ckpt --original-config cldm_v15.yaml \
           --clip-dir clip-vit-large-patch14 --out models/multidiffsense

   The checkpoint is converted with diffusers' own converter (convert_from_ckpt), which builds a
   StableDiffusionControlNetPipeline; the scheduler becomes DDIM with the checkpoint's betas
   (scaled_linear 0.00085..0.012, steps_offset 1), as MultiDiffSense samples.

Writes model.toml, tokenizer/tokenizer.json, {text_encoder,controlnet,unet,vae_decoder}/model.onnx
(float32; models over 2 GB get an external-data file beside model.onnx) and
scheduler/scheduler_config.json. Check the result with `rig synth info --model OUT`.
"""

import argparse
import os
import sys

import torch

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from rig_export import export_models, write_model_toml, write_scheduler_config  # noqa: E402


def load_diffusers(path, controlnet_path):
    from diffusers import ControlNetModel, StableDiffusionControlNetPipeline

    kwargs = {"local_files_only": True, "safety_checker": None, "requires_safety_checker": False}
    if controlnet_path:
        kwargs["controlnet"] = ControlNetModel.from_pretrained(controlnet_path, local_files_only=True)
    return StableDiffusionControlNetPipeline.from_pretrained(path, **kwargs)


def load_original(ckpt, config, clip_dir):
    from diffusers.pipelines.stable_diffusion.convert_from_ckpt import download_from_original_stable_diffusion_ckpt
    from transformers import CLIPTextModel, CLIPTokenizerFast

    return download_from_original_stable_diffusion_ckpt(
        ckpt,
        original_config_file=config,
        scheduler_type="ddim",
        from_safetensors=ckpt.endswith(".safetensors"),
        load_safety_checker=False,
        local_files_only=True,
        text_encoder=CLIPTextModel.from_pretrained(clip_dir, local_files_only=True),
        tokenizer=CLIPTokenizerFast.from_pretrained(clip_dir, local_files_only=True),
        device="cpu",
    )


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    src = ap.add_mutually_exclusive_group(required=True)
    src.add_argument("--diffusers", help="diffusers pipeline folder")
    src.add_argument("--original-ckpt", help="original ControlNet (cldm) checkpoint, .ckpt or .safetensors")
    ap.add_argument("--controlnet", help="diffusers ControlNet folder (with --diffusers)")
    ap.add_argument("--original-config", help="cldm yaml config (with --original-ckpt)")
    ap.add_argument("--clip-dir", help="local openai/clip-vit-large-patch14 folder (with --original-ckpt)")
    ap.add_argument("--out", required=True)
    ap.add_argument("--name", default=None)
    ap.add_argument("--resolution", type=int, default=512, help="square image size in pixels")
    ap.add_argument("--opset", type=int, default=17)
    args = ap.parse_args()

    if args.original_ckpt:
        if not (args.original_config and args.clip_dir):
            ap.error("--original-ckpt needs --original-config and --clip-dir")
        pipe = load_original(args.original_ckpt, args.original_config, args.clip_dir)
    else:
        pipe = load_diffusers(args.diffusers, args.controlnet)
    if getattr(pipe, "controlnet", None) is None:
        sys.exit("the pipeline has no ControlNet")
    pipe.to(torch.float32)

    out = os.path.abspath(args.out)
    os.makedirs(os.path.join(out, "tokenizer"), exist_ok=True)
    tok = pipe.tokenizer
    backend = tok.backend_tokenizer if hasattr(tok, "backend_tokenizer") else None
    if backend is None:
        from transformers import CLIPTokenizerFast

        backend = CLIPTokenizerFast.from_pretrained(args.clip_dir or os.path.join(args.diffusers, "tokenizer")).backend_tokenizer
    backend.no_padding()
    backend.no_truncation()
    backend.save(os.path.join(out, "tokenizer", "tokenizer.json"))

    export_models(out, pipe.text_encoder, pipe.controlnet, pipe.unet, pipe.vae, args.resolution, args.resolution, opset=args.opset)
    name = args.name or os.path.basename(os.path.normpath(args.original_ckpt or args.diffusers))
    write_model_toml(out, name, args.resolution, args.resolution, pipe.vae.config.scaling_factor)
    write_scheduler_config(out, pipe.scheduler.config)
    print(f"wrote {out}; check it with: rig synth info --model {out}")


if __name__ == "__main__":
    main()
