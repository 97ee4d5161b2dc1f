"""Builds the tiny, randomly initialised model package rig's tests run, and a diffusers
reference run of it. Nothing is downloaded: the tokenizer is trained here on a few prompts and
the models are built from small configs with a fixed torch seed.

    .venv/bin/python tools/make_tiny_package.py [--out tests/data/tiny-package]

The tokenizer trainer is not bit-for-bit repeatable between runs, so the package and its
reference are always regenerated together (as this script does).

Writes:
    <out>/                      the package (model.toml, tokenizer/, text_encoder/, controlnet/,
                                unet/, vae_decoder/, scheduler/)
    <out>/../tiny-reference/    control.png, init_latents.npy, prompt.txt, input_ids.npy,
                                ddim_step_latents.npy [steps,1,C,h,w], ddim_raw.npy (NHWC, the
                                decoder output before clamping), ddim.png, and the same for
                                DPM-Solver++ 2M (dpm_*) and for guidance 1 (ddim_g1_*),
                                plus reference.json (settings of the run)
"""

import argparse
import json
import os
import sys

import numpy as np
import torch
from PIL import Image

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from rig_export import export_models, write_model_toml, write_scheduler_config  # noqa: E402

WIDTH = HEIGHT = 64
STEPS = 4
GUIDANCE = 7.5
PROMPT = ("{'sensor_context': 'captured by a high-resolution vision only sensor ViTac.', "
          "'object_pose': {'x': 0.12, 'y': -0.34, 'z': 1.5, 'yaw': 15.0}}")
SCHEDULER_CONFIG = {
    "_class_name": "DDIMScheduler",
    "num_train_timesteps": 1000,
    "beta_start": 0.00085,
    "beta_end": 0.012,
    "beta_schedule": "scaled_linear",
    "clip_sample": False,
    "set_alpha_to_one": False,
    "steps_offset": 1,
    "prediction_type": "epsilon",
    "timestep_spacing": "leading",
    "trained_betas": None,
}


def default_corpus():
    """The tiny package's tokenizer corpus: 150 random prompts and two phrases."""
    corpus = []
    rng = np.random.default_rng(0)
    for sensor, ctx in [("TacTip", "tactile only"), ("ViTac", "vision only"), ("ViTacTip", "visuo-tactile")]:
        for _ in range(50):
            x, y, z, yaw = (round(float(v), 2) for v in rng.uniform([-5, -5, -1, -90], [5, 5, 2, 90]))
            corpus.append(str({"sensor_context": f"captured by a high-resolution {ctx} sensor {sensor}.",
                               "object_pose": {"x": x, "y": y, "z": z, "yaw": yaw}}))
    corpus += ["a photo of a tactile sensor image", "blurry, low quality, distorted"]
    return corpus


def build_tokenizer(corpus=None, vocab_size=300):
    """A CLIP-shaped byte-level BPE (same normaliser, pre-tokeniser, </w> suffix and
    start/end post-processing as openai/clip-vit-large-patch14), trained on `corpus` (default:
    a few random prompts). Digits are single pre-tokens, so any pose value tokenises."""
    from tokenizers import Regex, Tokenizer, decoders, models, normalizers, pre_tokenizers, processors, trainers

    tok = Tokenizer(models.BPE(unk_token="<|endoftext|>", end_of_word_suffix="</w>"))
    tok.normalizer = normalizers.Sequence(
        [normalizers.NFC(), normalizers.Replace(Regex(r"\s+"), " "), normalizers.Lowercase()]
    )
    tok.pre_tokenizer = pre_tokenizers.Sequence([
        pre_tokenizers.Split(
            Regex(r"""<\|startoftext\|>|<\|endoftext\|>|'s|'t|'re|'ve|'m|'ll|'d|[\p{L}]+|[\p{N}]|[^\s\p{L}\p{N}]+"""),
            behavior="removed",
            invert=True,
        ),
        pre_tokenizers.ByteLevel(add_prefix_space=False, use_regex=False),
    ])
    tok.decoder = decoders.ByteLevel()
    if corpus is None:
        corpus = default_corpus()
    trainer = trainers.BpeTrainer(
        vocab_size=vocab_size,
        special_tokens=["<|startoftext|>", "<|endoftext|>"],
        end_of_word_suffix="</w>",
        initial_alphabet=pre_tokenizers.ByteLevel.alphabet(),
        show_progress=False,
    )
    tok.train_from_iterator(corpus, trainer)
    bos, eos = tok.token_to_id("<|startoftext|>"), tok.token_to_id("<|endoftext|>")
    tok.post_processor = processors.TemplateProcessing(
        single="<|startoftext|> $A <|endoftext|>",
        pair="<|startoftext|> $A <|endoftext|> $B <|endoftext|>",
        special_tokens=[("<|startoftext|>", bos), ("<|endoftext|>", eos)],
    )
    return tok


def build_models(vocab_size, eos_id, bos_id):
    from diffusers import AutoencoderKL, ControlNetModel, UNet2DConditionModel
    from transformers import CLIPTextConfig, CLIPTextModel

    torch.manual_seed(0)
    text_encoder = CLIPTextModel(CLIPTextConfig(
        vocab_size=vocab_size, hidden_size=32, intermediate_size=37, num_hidden_layers=2,
        num_attention_heads=4, max_position_embeddings=77, bos_token_id=bos_id, eos_token_id=eos_id,
        pad_token_id=eos_id, projection_dim=32,
    ))
    common = dict(
        block_out_channels=(16, 32), layers_per_block=1, in_channels=4,
        down_block_types=("CrossAttnDownBlock2D", "DownBlock2D"), cross_attention_dim=32,
        norm_num_groups=8, attention_head_dim=8,
    )
    unet = UNet2DConditionModel(sample_size=8, out_channels=4,
                                up_block_types=("UpBlock2D", "CrossAttnUpBlock2D"), **common)
    controlnet = ControlNetModel(conditioning_embedding_out_channels=(8, 8, 16, 16), **common)
    # ControlNet's zero convolutions start at zero, which would make the control image have
    # no effect; give them small random weights so the tests see the control path.
    with torch.no_grad():
        for p in controlnet.parameters():
            if torch.count_nonzero(p) == 0:
                p.normal_(0.0, 0.2)
    vae = AutoencoderKL(
        block_out_channels=(8, 16, 16, 16), layers_per_block=1, in_channels=3, out_channels=3,
        latent_channels=4, down_block_types=["DownEncoderBlock2D"] * 4,
        up_block_types=["UpDecoderBlock2D"] * 4, norm_num_groups=4, sample_size=WIDTH,
        scaling_factor=0.18215,
    )
    for m in (text_encoder, unet, controlnet, vae):
        m.eval()
    return text_encoder, unet, controlnet, vae


def control_image():
    """A 64x64 depth-like hint: a viridis-ish ramp with a disc pressed in the middle."""
    yy, xx = np.mgrid[0:HEIGHT, 0:WIDTH].astype(np.float32)
    r = np.hypot(xx - 30, yy - 34) / 20
    depth = np.clip(1 - r, 0, 1)
    rgb = np.stack([0.27 + 0.7 * depth * depth, 0.0 + 0.9 * depth, 0.33 + 0.3 * (1 - depth) * (xx / WIDTH)], -1)
    return Image.fromarray((np.clip(rgb, 0, 1) * 255).round().astype(np.uint8), "RGB")


@torch.no_grad()
def reference_run(pipe, scheduler, control, init_latents, guidance, ref_dir, tag):
    pipe.scheduler = scheduler
    steps = []

    def record(_pipe, _i, _t, kwargs):
        steps.append(kwargs["latents"].detach().clone().numpy())
        return kwargs

    out = pipe(
        prompt=PROMPT, negative_prompt="", image=control, height=HEIGHT, width=WIDTH,
        num_inference_steps=STEPS, guidance_scale=guidance, eta=0.0, latents=init_latents.clone(),
        output_type="latent", callback_on_step_end=record, controlnet_conditioning_scale=1.0,
    )
    latents = out.images
    raw = pipe.vae.decode(latents / pipe.vae.config.scaling_factor, return_dict=False)[0]
    raw_nhwc = raw.permute(0, 2, 3, 1).contiguous().numpy().astype(np.float32)
    np.save(os.path.join(ref_dir, f"{tag}_step_latents.npy"), np.stack(steps).astype(np.float32))
    np.save(os.path.join(ref_dir, f"{tag}_raw.npy"), raw_nhwc)
    img = (np.clip(raw_nhwc[0] / 2 + 0.5, 0, 1) * 255).round().astype(np.uint8)
    Image.fromarray(img, "RGB").save(os.path.join(ref_dir, f"{tag}.png"))
    return [int(t) for t in pipe.scheduler.timesteps]


def main():
    ap = argparse.ArgumentParser()
    here = os.path.dirname(os.path.abspath(__file__))
    ap.add_argument("--out", default=os.path.join(here, "..", "tests", "data", "tiny-package"))
    args = ap.parse_args()
    out = os.path.abspath(args.out)
    ref_dir = os.path.join(os.path.dirname(out), "tiny-reference")
    os.makedirs(out, exist_ok=True)
    os.makedirs(ref_dir, exist_ok=True)

    from diffusers import DDIMScheduler, DPMSolverMultistepScheduler, StableDiffusionControlNetPipeline
    from transformers import PreTrainedTokenizerFast

    tok = build_tokenizer()
    os.makedirs(os.path.join(out, "tokenizer"), exist_ok=True)
    tok.save(os.path.join(out, "tokenizer", "tokenizer.json"))
    eos, bos = tok.token_to_id("<|endoftext|>"), tok.token_to_id("<|startoftext|>")
    fast = PreTrainedTokenizerFast(
        tokenizer_object=tok, bos_token="<|startoftext|>", eos_token="<|endoftext|>",
        pad_token="<|endoftext|>", unk_token="<|endoftext|>", model_max_length=77,
    )

    text_encoder, unet, controlnet, vae = build_models(tok.get_vocab_size(), eos, bos)
    export_models(out, text_encoder, controlnet, unet, vae, HEIGHT, WIDTH)
    write_model_toml(out, "tiny-random-multidiffsense", WIDTH, HEIGHT, 0.18215, control_colour_map="viridis")
    write_scheduler_config(out, SCHEDULER_CONFIG)

    ddim = DDIMScheduler.from_config(SCHEDULER_CONFIG)
    pipe = StableDiffusionControlNetPipeline(
        vae=vae, text_encoder=text_encoder, tokenizer=fast, unet=unet, controlnet=controlnet,
        scheduler=ddim, safety_checker=None, feature_extractor=None, requires_safety_checker=False,
    )
    pipe.set_progress_bar_config(disable=True)
    control = control_image()
    control.save(os.path.join(ref_dir, "control.png"))
    init = torch.randn((1, 4, HEIGHT // 8, WIDTH // 8), generator=torch.Generator().manual_seed(1234))
    np.save(os.path.join(ref_dir, "init_latents.npy"), init.numpy().astype(np.float32))
    ids = fast(PROMPT, padding="max_length", max_length=77, truncation=True).input_ids
    np.save(os.path.join(ref_dir, "input_ids.npy"), np.array([ids], dtype=np.float32))
    with open(os.path.join(ref_dir, "prompt.txt"), "w") as f:
        f.write(PROMPT)

    runs = {
        "ddim": reference_run(pipe, DDIMScheduler.from_config(SCHEDULER_CONFIG), control, init, GUIDANCE, ref_dir, "ddim"),
        "ddim_g1": reference_run(pipe, DDIMScheduler.from_config(SCHEDULER_CONFIG), control, init, 1.0, ref_dir, "ddim_g1"),
        "dpm": reference_run(
            pipe,
            DPMSolverMultistepScheduler.from_config(SCHEDULER_CONFIG, algorithm_type="dpmsolver++", solver_order=2),
            control, init, GUIDANCE, ref_dir, "dpm"),
    }
    import diffusers
    import transformers
    with open(os.path.join(ref_dir, "reference.json"), "w") as f:
        json.dump({
            "prompt": PROMPT, "negative_prompt": "", "steps": STEPS, "guidance": GUIDANCE, "eta": 0.0,
            "width": WIDTH, "height": HEIGHT, "conditioning_scale": 1.0, "timesteps": runs,
            "torch": torch.__version__, "diffusers": diffusers.__version__, "transformers": transformers.__version__,
        }, f, indent=2)
        f.write("\n")
    print(f"package: {out}\nreference: {ref_dir}\ntimesteps: {runs}")


if __name__ == "__main__":
    main()
