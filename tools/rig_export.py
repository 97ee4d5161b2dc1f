"""Shared export code: wrap diffusers models so their ONNX inputs and outputs carry the names
of rig's model-package contract (docs/src/synthesis.md, "The model package"), and write
the package layout.

    model.toml
    tokenizer/tokenizer.json
    text_encoder/model.onnx   input_ids -> last_hidden_state
    controlnet/model.onnx     sample, timestep, encoder_hidden_states, controlnet_cond,
                              conditioning_scale -> down_block_res_samples_0..N, mid_block_res_sample
    unet/model.onnx           sample, timestep, encoder_hidden_states,
                              down_block_additional_residual_0..N, mid_block_additional_residual
                              -> out_sample
    vae_decoder/model.onnx    latent_sample -> sample
    scheduler/scheduler_config.json

Used by export_package.py (a real pipeline) and make_tiny_package.py (the test package).
"""

import json
import os

import torch


class TextEncoderWrapper(torch.nn.Module):
    def __init__(self, text_encoder):
        super().__init__()
        self.text_encoder = text_encoder

    def forward(self, input_ids):
        return self.text_encoder(input_ids, return_dict=False)[0]


class ControlNetWrapper(torch.nn.Module):
    """The conditioning scale is an input tensor; diffusers multiplies every residual by it,
    which is what this does (with the model's own scale left at 1)."""

    def __init__(self, controlnet):
        super().__init__()
        self.controlnet = controlnet

    def forward(self, sample, timestep, encoder_hidden_states, controlnet_cond, conditioning_scale):
        down, mid = self.controlnet(
            sample,
            timestep,
            encoder_hidden_states=encoder_hidden_states,
            controlnet_cond=controlnet_cond,
            conditioning_scale=1.0,
            return_dict=False,
        )
        down = [d * conditioning_scale for d in down]
        return (*down, mid * conditioning_scale)


class UNetWrapper(torch.nn.Module):
    def __init__(self, unet, n_down):
        super().__init__()
        self.unet = unet
        self.n_down = n_down

    def forward(self, sample, timestep, encoder_hidden_states, *residuals):
        down = list(residuals[: self.n_down])
        mid = residuals[self.n_down]
        return self.unet(
            sample,
            timestep,
            encoder_hidden_states=encoder_hidden_states,
            down_block_additional_residuals=down,
            mid_block_additional_residual=mid,
            return_dict=False,
        )[0]


class VaeDecoderWrapper(torch.nn.Module):
    def __init__(self, vae):
        super().__init__()
        self.vae = vae

    def forward(self, latent_sample):
        return self.vae.decode(latent_sample, return_dict=False)[0]


def _export(module, args, path, input_names, output_names, dynamic_axes, opset):
    os.makedirs(os.path.dirname(path), exist_ok=True)
    torch.onnx.export(
        module,
        args,
        path,
        input_names=input_names,
        output_names=output_names,
        dynamic_axes=dynamic_axes,
        opset_version=opset,
        do_constant_folding=True,
        dynamo=False,
    )


@torch.no_grad()
def export_models(out_dir, text_encoder, controlnet, unet, vae, height, width, opset=17, timestep_dtype=torch.int64,
                  vae_scale_factor=8):
    """Exports the four models into out_dir with the contract's tensor names.

    Batch and spatial sizes are dynamic; the ids are int32 (as diffusers' own ONNX export
    writes them); the timestep is a [1] tensor of timestep_dtype, broadcast over the batch.
    vae_scale_factor: image pixels per latent pixel (the example inputs' latent size).
    """
    text_encoder.eval(), controlnet.eval(), unet.eval(), vae.eval()
    lh, lw = height // vae_scale_factor, width // vae_scale_factor
    latent_channels = unet.config.in_channels
    hidden = text_encoder.config.hidden_size
    seq = text_encoder.config.max_position_embeddings

    ids = torch.zeros((1, seq), dtype=torch.int32)
    _export(
        TextEncoderWrapper(text_encoder),
        (ids,),
        os.path.join(out_dir, "text_encoder", "model.onnx"),
        ["input_ids"],
        ["last_hidden_state"],
        {"input_ids": {0: "batch"}, "last_hidden_state": {0: "batch"}},
        opset,
    )

    sample = torch.randn(2, latent_channels, lh, lw)
    t = torch.tensor([500], dtype=timestep_dtype)
    ehs = torch.randn(2, seq, hidden)
    cond = torch.rand(2, 3, height, width)
    scale = torch.tensor(1.0)
    cn = ControlNetWrapper(controlnet)
    residuals = cn(sample, t, ehs, cond, scale)
    n_down = len(residuals) - 1
    down_names = [f"down_block_res_samples_{i}" for i in range(n_down)]
    spatial = {0: "batch", 2: "height", 3: "width"}
    _export(
        cn,
        (sample, t, ehs, cond, scale),
        os.path.join(out_dir, "controlnet", "model.onnx"),
        ["sample", "timestep", "encoder_hidden_states", "controlnet_cond", "conditioning_scale"],
        down_names + ["mid_block_res_sample"],
        {
            "sample": spatial,
            "encoder_hidden_states": {0: "batch"},
            "controlnet_cond": {0: "batch", 2: "cond_height", 3: "cond_width"},
            **{n: {0: "batch", 2: f"{n}_h", 3: f"{n}_w"} for n in down_names + ["mid_block_res_sample"]},
        },
        opset,
    )

    res_names = [f"down_block_additional_residual_{i}" for i in range(n_down)] + ["mid_block_additional_residual"]
    _export(
        UNetWrapper(unet, n_down),
        (sample, t, ehs, *residuals),
        os.path.join(out_dir, "unet", "model.onnx"),
        ["sample", "timestep", "encoder_hidden_states"] + res_names,
        ["out_sample"],
        {
            "sample": spatial,
            "encoder_hidden_states": {0: "batch"},
            "out_sample": spatial,
            **{n: {0: "batch", 2: f"{n}_h", 3: f"{n}_w"} for n in res_names},
        },
        opset,
    )

    latent = torch.randn(1, vae.config.latent_channels, lh, lw)
    _export(
        VaeDecoderWrapper(vae),
        (latent,),
        os.path.join(out_dir, "vae_decoder", "model.onnx"),
        ["latent_sample"],
        ["sample"],
        {"latent_sample": spatial, "sample": {0: "batch", 2: "image_height", 3: "image_width"}},
        opset,
    )


def write_model_toml(out_dir, name, width, height, latent_scale, modalities=("TacTip", "ViTac", "ViTacTip"),
                     prompt_template="multidiffsense", hint_encoding="rgb01", vae_scale_factor=None,
                     sampling_steps=None, guidance=None, sampler=None, eta=None, end_token=None,
                     control_colour_map=None):
    """Writes OUT_DIR/model.toml. control_colour_map="viridis" declares MultiDiffSense's control
    image (the depth map colour-mapped with viridis: rig then refuses a grey control image); left
    None, the package reads any 8-bit RGB control image, as diffusers' ControlNet pipelines do."""
    mods = ", ".join(f'"{m}"' for m in modalities)
    text = (
        f"name = {json.dumps(name)}\n"
        f"resolution = [{width}, {height}]  # width, height in pixels\n"
        f"modalities = [{mods}]\n"
        f'prompt_template = "{prompt_template}"\n'
        f"latent_scale = {latent_scale}\n"
        f'hint_encoding = "{hint_encoding}"  # control image RGB scaled to [0, 1]\n'
    )
    if control_colour_map is not None:
        text += (f'control_colour_map = "{control_colour_map}"  # MultiDiffSense\'s control: the depth map colour-mapped '
                 f'with {control_colour_map} (grey refused)\n')
    if vae_scale_factor is not None:
        text += f"vae_scale_factor = {vae_scale_factor}  # image pixels per latent pixel\n"
    if sampling_steps is not None:
        text += f"sampling_steps = {sampling_steps}  # what it was trained to be sampled with\n"
    if guidance is not None:
        text += f"guidance = {float(guidance)}  # classifier-free guidance scale (1: unguided)\n"
    if sampler is not None:
        text += f'sampler = "{sampler}"  # default sampler of rig synth\n'
    if eta is not None:
        text += f"eta = {float(eta)}  # DDIM eta (0: deterministic)\n"
    if end_token is not None:
        text += f"end_token = {json.dumps(end_token)}  # padding token of the tokenizer\n"
    with open(os.path.join(out_dir, "model.toml"), "w") as f:
        f.write(text)


def write_scheduler_config(out_dir, scheduler_config):
    os.makedirs(os.path.join(out_dir, "scheduler"), exist_ok=True)
    cfg = {k: v for k, v in dict(scheduler_config).items() if not k.startswith("_") or k == "_class_name"}
    cfg["_class_name"] = "DDIMScheduler"
    with open(os.path.join(out_dir, "scheduler", "scheduler_config.json"), "w") as f:
        json.dump(cfg, f, indent=2, sort_keys=True)
        f.write("\n")


@torch.no_grad()
def check_onnx(out_dir, text_encoder, controlnet, unet, vae, input_ids, height, width, vae_scale_factor=8):
    """Runs each exported model in onnxruntime on the inputs PyTorch gets; returns
    {model: max |onnx - torch|}. input_ids: int32 [1, 77]."""
    import numpy as np
    import onnxruntime as ort

    gen = torch.Generator().manual_seed(0)
    c = unet.config.in_channels
    lh, lw = height // vae_scale_factor, width // vae_scale_factor
    sample = torch.randn(2, c, lh, lw, generator=gen)
    t = torch.tensor([451], dtype=torch.int64)
    cond = torch.rand(2, 3, height, width, generator=gen)
    ehs = text_encoder(input_ids.long(), return_dict=False)[0].repeat(2, 1, 1)
    res = ControlNetWrapper(controlnet)(sample, t, ehs, cond, torch.tensor(1.0))
    pred = UNetWrapper(unet, len(res) - 1)(sample, t, ehs, *res)
    latent = torch.randn(1, vae.config.latent_channels, lh, lw, generator=gen)
    img = vae.decode(latent, return_dict=False)[0]

    def run(name, feeds):
        s = ort.InferenceSession(os.path.join(out_dir, name, "model.onnx"), providers=["CPUExecutionProvider"])
        return s.run(None, feeds)

    te = run("text_encoder", {"input_ids": input_ids.numpy()})[0]
    cn = run("controlnet", {"sample": sample.numpy(), "timestep": t.numpy(), "encoder_hidden_states": ehs.numpy(),
                            "controlnet_cond": cond.numpy(), "conditioning_scale": np.array(1.0, dtype=np.float32)})
    feeds = {"sample": sample.numpy(), "timestep": t.numpy(), "encoder_hidden_states": ehs.numpy()}
    for i, r in enumerate(cn[:-1]):
        feeds[f"down_block_additional_residual_{i}"] = r
    feeds["mid_block_additional_residual"] = cn[-1]
    un = run("unet", feeds)[0]
    vd = run("vae_decoder", {"latent_sample": latent.numpy()})[0]
    return {
        "text_encoder": float(np.abs(te - ehs[:1].numpy()).max()),
        "controlnet": max(float(np.abs(a - b.numpy()).max()) for a, b in zip(cn, res)),
        "unet": float(np.abs(un - pred.numpy()).max()),
        "vae_decoder": float(np.abs(vd - img.numpy()).max()),
    }
