"""Builds a Stable Diffusion 1.5 + ControlNet pipeline with random weights (seed 0) and saves it
with diffusers' save_pretrained: the shape of a MultiDiffSense model, for timing rig against
diffusers and for exporting models over 2 GB (scripts/gpu-check.sh).

    python tools/build_sd15.py OUT --clip-dir CLIP [--tiny]

Full size: the UNet (860 M parameters, 64x64 latents, cross-attention width 768), its ControlNet
(361 M, made from the UNet as diffusers' ControlNetModel.from_unet does), SD 1.5's VAE (84 M)
and a CLIP ViT-L/14-shaped text model (123 M). --tiny: the same blocks, a few thousand times
smaller (64 x 64 px images, 8 x 8 latents), for a dry run on a CPU. CLIP: a folder with CLIP's
BPE files vocab.json and merges.txt (the MultiDiffSense kit's clip/ has them); nothing is
downloaded. A random ControlNet's zero convolutions are zero (it would do nothing): they get
small random weights.
"""

import argparse
import os

import torch
from diffusers import (AutoencoderKL, ControlNetModel, DDIMScheduler, StableDiffusionControlNetPipeline,
                       UNet2DConditionModel)
from transformers import CLIPTextConfig, CLIPTextModel, CLIPTokenizer


def build(tiny):
    if tiny:
        unet = UNet2DConditionModel(sample_size=8, block_out_channels=(32, 64), layers_per_block=1,
                                    down_block_types=("CrossAttnDownBlock2D", "DownBlock2D"),
                                    up_block_types=("UpBlock2D", "CrossAttnUpBlock2D"),
                                    cross_attention_dim=32, attention_head_dim=4, norm_num_groups=8)
        vae = AutoencoderKL(block_out_channels=(8, 16, 16, 16), down_block_types=("DownEncoderBlock2D",) * 4,
                            up_block_types=("UpDecoderBlock2D",) * 4, latent_channels=4, norm_num_groups=8, sample_size=64)
        text = CLIPTextConfig(vocab_size=49408, hidden_size=32, intermediate_size=64, num_hidden_layers=2,
                              num_attention_heads=4, max_position_embeddings=77, hidden_act="quick_gelu", projection_dim=32)
    else:
        unet = UNet2DConditionModel(sample_size=64, cross_attention_dim=768, attention_head_dim=8)
        vae = AutoencoderKL(block_out_channels=(128, 256, 512, 512), down_block_types=("DownEncoderBlock2D",) * 4,
                            up_block_types=("UpDecoderBlock2D",) * 4, latent_channels=4, layers_per_block=2, sample_size=512)
        text = CLIPTextConfig(vocab_size=49408, hidden_size=768, intermediate_size=3072, num_hidden_layers=12,
                              num_attention_heads=12, max_position_embeddings=77, hidden_act="quick_gelu", projection_dim=768)
    return unet, vae, CLIPTextModel(text)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("out", help="folder to save the pipeline in")
    ap.add_argument("--clip-dir", required=True, help="folder with CLIP's vocab.json and merges.txt")
    ap.add_argument("--tiny", action="store_true", help="tiny shapes for a CPU dry run")
    args = ap.parse_args()
    for name in ("vocab.json", "merges.txt"):
        if not os.path.isfile(os.path.join(args.clip_dir, name)):
            raise SystemExit(f"error: {args.clip_dir} has no {name} (CLIP's BPE files)")
    torch.manual_seed(0)
    unet, vae, text_encoder = build(args.tiny)
    controlnet = ControlNetModel.from_unet(unet)
    with torch.no_grad():
        for m in list(controlnet.controlnet_down_blocks) + [controlnet.controlnet_mid_block]:
            m.weight.normal_(0, 0.02)
    tokenizer = CLIPTokenizer(os.path.join(args.clip_dir, "vocab.json"), os.path.join(args.clip_dir, "merges.txt"),
                              model_max_length=77)
    scheduler = DDIMScheduler(beta_start=0.00085, beta_end=0.012, beta_schedule="scaled_linear", clip_sample=False,
                              set_alpha_to_one=False, steps_offset=1)
    pipe = StableDiffusionControlNetPipeline(vae=vae, text_encoder=text_encoder, tokenizer=tokenizer, unet=unet,
                                             controlnet=controlnet, scheduler=scheduler, safety_checker=None,
                                             feature_extractor=None, requires_safety_checker=False)
    pipe.save_pretrained(args.out, safe_serialization=True)
    n = lambda m: sum(p.numel() for p in m.parameters()) / 1e6  # noqa: E731
    print(f"saved {args.out}: unet {n(unet):.1f}M, controlnet {n(controlnet):.1f}M, vae {n(vae):.1f}M, "
          f"text encoder {n(text_encoder):.1f}M parameters")


if __name__ == "__main__":
    main()
