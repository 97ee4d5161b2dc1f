"""Exports a train.py checkpoint as a rig model package (default: models/default).

    python tools/train/export.py [--ckpt out/train/diffusion.pt] [--train-dir out/train] \
        [--out models/default] [--name rig-default-<size>]

Takes the exponential-moving-average weights of the checkpoint (diffusion.pt, or one of the
ema-NNNNNN.pt snapshots), the tokenizer and the autoencoder statistics from --train-dir, and
writes the package layout rig reads (docs/src/synthesis.md): model.toml (the resolution the run trained
at, from vae.pt's `size`: 128 x 128 for models/default; vae_scale_factor 4; the latent scale of
the training latents), tokenizer/, text_encoder/, controlnet/, unet/, vae_decoder/ (ONNX) and
scheduler/scheduler_config.json (DDIM, prediction_type "sample"). Then it checks each ONNX model
against PyTorch with onnxruntime.
"""

import argparse
import json
import os
import shutil
import sys

import torch

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))
sys.path.insert(0, HERE)
from model import SCHEDULER_CONFIG, SpaceToDepthAE, ae_image_size, build_text_encoder, build_unet_controlnet  # noqa: E402
from rig_export import export_models, write_model_toml, write_scheduler_config  # noqa: E402



def trained_size(train_dir):
    """Image size (px, square) the run in train_dir trained on (its vae.pt)."""
    return ae_image_size(torch.load(os.path.join(train_dir, "vae.pt"), map_location="cpu", weights_only=False))


def load_trained(train_dir, ckpt):
    """(tokenizer, text_encoder, unet, controlnet, vae, step) from a training directory."""
    from tokenizers import Tokenizer
    args = json.load(open(os.path.join(train_dir, "args.json")))
    tok = Tokenizer.from_file(os.path.join(train_dir, "tokenizer.json"))
    ae = torch.load(os.path.join(train_dir, "vae.pt"), map_location="cpu", weights_only=False)
    vae = SpaceToDepthAE(ae["channel_mean"])
    vae.config["scaling_factor"] = ae["scaling_factor"]
    eos, bos = tok.token_to_id("<|endoftext|>"), tok.token_to_id("<|startoftext|>")
    text_encoder = build_text_encoder(tok.get_vocab_size(), bos, eos)
    unet, controlnet = build_unet_controlnet(args["width"], vae.config.latent_channels)
    modules = torch.nn.ModuleDict({"text_encoder": text_encoder, "unet": unet, "controlnet": controlnet})
    state = torch.load(ckpt, map_location="cpu", weights_only=False)
    modules.load_state_dict(state["ema"])
    for m in (text_encoder, unet, controlnet, vae):
        m.eval()
    return tok, text_encoder, unet, controlnet, vae, state["step"]


def check_onnx(out, text_encoder, controlnet, unet, vae, tok, size):
    """Runs every exported model on the same inputs as PyTorch (rig_export.check_onnx) and
    prints the largest difference of each."""
    from rig_export import check_onnx as compare

    ids = torch.tensor([tok.encode("{'sensor_context': 'x', 'object_pose': {'x': 1.0}}").ids])
    ids = torch.nn.functional.pad(ids, (0, 77 - ids.shape[1]), value=tok.token_to_id("<|endoftext|>")).to(torch.int32)
    diffs = compare(out, text_encoder, controlnet, unet, vae, ids, size, size, vae_scale_factor=4)
    for name, diff in diffs.items():
        print(f"onnx check {name}: max |onnx - torch| = {diff:.2e}")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--train-dir", default="out/train")
    ap.add_argument("--ckpt", default=None, help="default: <train-dir>/diffusion.pt")
    ap.add_argument("--out", default="models/default")
    ap.add_argument("--name", default=None, help="default: rig-default-<size>")
    args = ap.parse_args()
    ckpt = args.ckpt or os.path.join(args.train_dir, "diffusion.pt")
    tok, text_encoder, unet, controlnet, vae, step = load_trained(args.train_dir, ckpt)
    size = trained_size(args.train_dir)
    name = args.name or f"rig-default-{size}"
    out = os.path.abspath(args.out)
    if os.path.isdir(out):
        shutil.rmtree(out)
    os.makedirs(os.path.join(out, "tokenizer"))
    tok.save(os.path.join(out, "tokenizer", "tokenizer.json"))
    export_models(out, text_encoder, controlnet, unet, vae, size, size, vae_scale_factor=4)
    # The exporter writes one file per model; external-data files would appear beside them.
    write_model_toml(out, name, size, size, round(vae.config.scaling_factor, 6),
                     vae_scale_factor=4, sampling_steps=20, guidance=1.0,  # see train.py: INFERENCE_TIMESTEPS
                     sampler="dpm++2m",  # docs/src/evaluation.md: beats DDIM on ViTac contact SSIM
                     control_colour_map="viridis")  # trained on MultiDiffSense's viridis control images
    write_scheduler_config(out, SCHEDULER_CONFIG)
    with open(os.path.join(out, "TRAINING.txt"), "w") as f:
        targs = json.load(open(os.path.join(args.train_dir, "args.json")))
        f.write(f"Trained by tools/train/train.py: EMA weights of {os.path.basename(ckpt)} (step {step} of this run"
                + (f", started from the EMA weights of {targs['init']}" if targs.get("init") else "") + ").\n"
                "This run's arguments:\n" + json.dumps(targs, indent=2) + "\n"
                "docs/src/training.md describes the recipe; tools/train/train_default.sh retrains it.\n")
    check_onnx(out, text_encoder, controlnet, unet, vae, tok, size)
    total = sum(os.path.getsize(os.path.join(d, f)) for d, _, fs in os.walk(out) for f in fs)
    print(f"exported step {step} of {ckpt} to {out} ({total / 1e6:.1f} MB)")


if __name__ == "__main__":
    main()
