"""Reads an original-ControlNet ("cldm") checkpoint, such as the ones MultiDiffSense's train.py
writes, and builds the diffusers / transformers modules rig's exporter turns into ONNX.

The checkpoint's key layout is the one every SD-1.x / original-ControlNet checkpoint has, and
its yaml config (MultiDiffSense's models/cldm_v15.yaml) states the sizes:

    model.diffusion_model.*                  UNet            -> diffusers UNet2DConditionModel
    control_model.*                          ControlNet      -> diffusers ControlNetModel
    first_stage_model.*                      autoencoder     -> diffusers AutoencoderKL
    cond_stage_model.transformer.text_model.*  CLIP text model -> transformers CLIPTextModel
    betas, alphas_cumprod, ..., logvar       noise schedule buffers (checked against the config)

Two checkpoint forms are read, both without running code from the file:

- a plain `{"state_dict": ...}` file (or a bare state dict, or .safetensors);
- the Lightning training checkpoint train.py writes (`state_dict` with `optimizer_states`,
  `callbacks`, `loops`, `epoch`, `global_step`, `pytorch-lightning_version`, ...).

`.ckpt` files are opened with `torch.load(..., weights_only=True)`, which only rebuilds tensors
and plain containers. A few harmless non-tensor types that Lightning checkpoints may hold
(`hyper_parameters` as Lightning's AttributeDict, `argparse.Namespace`, paths) are read through
inert stand-ins registered by name; anything else is refused with the names of the globals.

The UNet, ControlNet and VAE keys are renamed by diffusers' own per-model converters
(`convert_ldm_unet_checkpoint`, `convert_ldm_vae_checkpoint`); the CLIP keys are mapped here
(transformers 5 has no `text_model` submodule). Every module is loaded strictly (no key
missing, none left over), every checkpoint key must belong to a part, and each part's number
of weights must equal its module's, so nothing is dropped or invented silently.

The CLIP weights come from the checkpoint whenever it holds them; `--clip-dir` then gives only
the tokenizer and the text model's architecture (config.json). Only a checkpoint without
`cond_stage_model.transformer.*` keys takes its CLIP weights from `--clip-dir`, and says so.
"""

import argparse
import collections
import os
import pathlib
import pickle

import torch
import yaml

UNET_PREFIX = "model.diffusion_model."
CONTROLNET_PREFIX = "control_model."
VAE_PREFIX = "first_stage_model."
CLIP_PREFIX = "cond_stage_model.transformer."
# Buffers of ldm's DDPM / LatentDiffusion: the noise schedule and the loss weights. Not weights
# of any exported model; `betas` is checked against the config's schedule.
SCHEDULE_BUFFERS = {
    "betas", "alphas_cumprod", "alphas_cumprod_prev", "sqrt_alphas_cumprod", "sqrt_one_minus_alphas_cumprod",
    "log_one_minus_alphas_cumprod", "sqrt_recip_alphas_cumprod", "sqrt_recipm1_alphas_cumprod",
    "posterior_variance", "posterior_log_variance_clipped", "posterior_mean_coef1", "posterior_mean_coef2",
    "logvar", "lvlb_weights",
}


class CheckpointError(Exception):
    """A checkpoint or config this tool cannot turn into a package, with the reason."""


# ---------------------------------------------------------------------------------------------
# Loading the file safely


class _Namespace:
    """Inert stand-in for argparse.Namespace: keeps its fields in __dict__."""


class _PathText(str):
    """Stand-in for pathlib paths: the path's text, nothing else."""

    def __new__(cls, *parts):
        return str.__new__(cls, str(pathlib.PurePosixPath(*(str(p) for p in parts))))


# Globals a Lightning checkpoint may name outside tensors and containers, each read through a
# stand-in that runs no code of the original class.
# Lightning's AttributeDict (a dict with attribute access) is read as an OrderedDict, the dict
# type torch's weights-only unpickler fills.
STAND_INS = {
    "pytorch_lightning.utilities.parsing.AttributeDict": collections.OrderedDict,
    "lightning.pytorch.utilities.parsing.AttributeDict": collections.OrderedDict,
    "lightning_fabric.utilities.data.AttributeDict": collections.OrderedDict,
    "lightning.fabric.utilities.data.AttributeDict": collections.OrderedDict,
    "argparse.Namespace": _Namespace,
    "pathlib.PosixPath": _PathText,
    "pathlib.WindowsPath": _PathText,
    "pathlib._local.PosixPath": _PathText,
    "pathlib._local.WindowsPath": _PathText,
}


def _torch_load(path):
    """torch.load with weights_only=True; known harmless globals through stand-ins; else refuse."""
    try:
        return torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as first:
        try:
            named = torch.serialization.get_unsafe_globals_in_checkpoint(path)
        except Exception:  # noqa: BLE001 - the first error is the one to show
            named = []
        unknown = [g for g in named if g not in STAND_INS]
        if not named or unknown:
            raise CheckpointError(
                f"{path}: refusing to unpickle {', '.join(unknown) or 'objects'} (only tensors, plain containers "
                f"and {', '.join(sorted(set(STAND_INS)))} are read; nothing in a checkpoint is run). If you trust "
                "the file, save its weights alone in the environment that wrote it: python -c \"import torch; "
                "c = torch.load('IN.ckpt', weights_only=False); torch.save({'state_dict': c['state_dict']}, "
                "'OUT.ckpt')\"" + ("" if named else f" ({str(first).splitlines()[0]})")
            ) from None
        with torch.serialization.safe_globals([(STAND_INS[g], g) for g in named]):
            return torch.load(path, map_location="cpu", weights_only=True)


def load_checkpoint(path):
    """(state_dict, description) of a .ckpt / .pt / .safetensors file."""
    if path.endswith(".safetensors"):
        from safetensors.torch import load_file

        return load_file(path, device="cpu"), "safetensors state dict"
    obj = _torch_load(path)
    if not isinstance(obj, dict):
        raise CheckpointError(f"{path}: holds a {type(obj).__name__}, not a dict with a state_dict")
    description = "bare state dict"
    if "state_dict" in obj:
        lightning = [k for k in ("pytorch-lightning_version", "optimizer_states", "global_step", "epoch") if k in obj]
        if lightning:
            parts = []
            if "pytorch-lightning_version" in obj:
                parts.append(f"Lightning {obj['pytorch-lightning_version']}")
            for k in ("epoch", "global_step"):
                if k in obj:
                    parts.append(f"{k} {obj[k]}")
            others = sorted(k for k in obj if k != "state_dict")
            description = f"Lightning training checkpoint ({', '.join(parts)}; ignored: {', '.join(others)})"
        else:
            description = "{'state_dict'} file"
        obj = obj["state_dict"]
        # MultiDiffSense's load_state_dict unwraps twice; so does this.
        if isinstance(obj, dict) and isinstance(obj.get("state_dict"), dict):
            obj = obj["state_dict"]
    bad = [k for k, v in obj.items() if not isinstance(v, torch.Tensor)]
    if bad:
        raise CheckpointError(f"{path}: the state dict holds non-tensors under {', '.join(bad[:5])}")
    return obj, description


# ---------------------------------------------------------------------------------------------
# The config


def _params(config, *path):
    node = config
    for key in path:
        if not isinstance(node, dict) or key not in node:
            raise CheckpointError(f"the config has no {'.'.join(path)}")
        node = node[key]
    return node


class CldmConfig:
    """What the yaml config says about the model, checked for what the package can express."""

    def __init__(self, path):
        with open(path, encoding="utf-8") as f:
            self.raw = yaml.safe_load(f)
        p = _params(self.raw, "model", "params")
        target = self.raw["model"].get("target", "")
        if not target.endswith("ControlLDM"):
            raise CheckpointError(f"{path}: model.target is {target!r}; expected cldm.cldm.ControlLDM (original ControlNet)")
        cond = _params(self.raw, "model", "params", "cond_stage_config")
        if not str(cond.get("target", "")).endswith("FrozenCLIPEmbedder"):
            raise CheckpointError(f"{path}: cond_stage_config.target is {cond.get('target')!r}; only FrozenCLIPEmbedder (SD 1.x CLIP) is supported")
        layer = (cond.get("params") or {}).get("layer", "last")
        if layer != "last":
            raise CheckpointError(f"{path}: FrozenCLIPEmbedder layer {layer!r}; only 'last' (last_hidden_state) is supported")
        if p.get("only_mid_control", False):
            raise CheckpointError(f"{path}: only_mid_control is true; rig feeds every ControlNet residual")
        if p.get("global_average_pooling", False):
            raise CheckpointError(f"{path}: global_average_pooling is true; not supported")
        if p.get("use_ema", False):
            raise CheckpointError(f"{path}: use_ema is true; this tool exports the non-EMA weights only")
        schedule = p.get("beta_schedule", "linear")
        if schedule != "linear":
            raise CheckpointError(f"{path}: beta_schedule {schedule!r}; only ldm's 'linear' (diffusers' scaled_linear) is supported")
        self.parameterization = p.get("parameterization", "eps")
        if self.parameterization not in ("eps", "v"):
            raise CheckpointError(f"{path}: parameterization {self.parameterization!r}; eps or v only")
        unet = _params(self.raw, "model", "params", "unet_config", "params")
        if unet.get("num_head_channels", -1) != -1 or unet.get("use_linear_in_transformer", False):
            raise CheckpointError(f"{path}: num_head_channels / use_linear_in_transformer are SD 2.x settings; SD 1.x only")
        self.timesteps = int(p.get("timesteps", 1000))
        self.linear_start = float(p.get("linear_start", 0.00085))
        self.linear_end = float(p.get("linear_end", 0.012))
        self.scale_factor = float(p.get("scale_factor", 1.0))
        self.scale_by_std = bool(p.get("scale_by_std", False))
        dd = _params(self.raw, "model", "params", "first_stage_config", "params", "ddconfig")
        self.ddconfig = dd
        self.vae_scale_factor = 2 ** (len(dd["ch_mult"]) - 1)
        self.latent_size = int(p.get("image_size", 64))
        self.resolution = self.latent_size * self.vae_scale_factor
        self.hint_channels = int(_params(self.raw, "model", "params", "control_stage_config", "params").get("hint_channels", 3))
        if self.hint_channels != 3:
            raise CheckpointError(f"{path}: hint_channels {self.hint_channels}; rig feeds RGB control images (3)")

    def scheduler_config(self):
        """diffusers DDIMScheduler config equal to ldm's DDIMSampler on this schedule: timesteps
        `range(0, T, T // S) + 1` ("leading" spacing, offset 1), alphas_cumprod[0] before the first."""
        return {
            "_class_name": "DDIMScheduler",
            "num_train_timesteps": self.timesteps,
            "beta_start": self.linear_start,
            "beta_end": self.linear_end,
            "beta_schedule": "scaled_linear",
            "clip_sample": False,
            "set_alpha_to_one": False,
            "steps_offset": 1,
            "prediction_type": "epsilon" if self.parameterization == "eps" else "v_prediction",
            "timestep_spacing": "leading",
            "trained_betas": None,
        }


# ---------------------------------------------------------------------------------------------
# Conversion


def _split(state_dict):
    """The checkpoint's keys by part; unknown keys are an error."""
    parts = {"unet": {}, "controlnet": {}, "vae": {}, "clip": {}, "schedule": {}}
    unknown = []
    for key, value in state_dict.items():
        if key.startswith(UNET_PREFIX):
            parts["unet"][key] = value
        elif key.startswith(CONTROLNET_PREFIX):
            parts["controlnet"][key] = value
        elif key.startswith(VAE_PREFIX):
            parts["vae"][key] = value
        elif key.startswith(CLIP_PREFIX):
            parts["clip"][key] = value
        elif key in SCHEDULE_BUFFERS or key == "scale_factor":
            parts["schedule"][key] = value
        else:
            unknown.append(key)
    if unknown:
        raise CheckpointError(f"the checkpoint holds {len(unknown)} keys this tool does not know: {', '.join(sorted(unknown)[:8])}")
    for part, prefix in (("unet", UNET_PREFIX), ("controlnet", CONTROLNET_PREFIX), ("vae", VAE_PREFIX)):
        if not parts[part]:
            raise CheckpointError(f"the checkpoint has no {prefix}* keys: not an original-ControlNet (cldm) checkpoint")
    return parts


def _numel(tensors):
    return sum(t.numel() for t in tensors.values())


def _load_strict(module, converted, source_numel, what):
    """Loads `converted` into `module`: no key missing, none unexpected, shapes equal, and as
    many weights as the checkpoint part had."""
    own = module.state_dict()
    missing = sorted(set(own) - set(converted))
    extra = sorted(set(converted) - set(own))
    if missing or extra:
        raise CheckpointError(f"{what}: the converted weights do not fit the model built from the config: "
                              f"missing {missing[:5]}, unexpected {extra[:5]}")
    wrong = [k for k in own if tuple(own[k].shape) != tuple(converted[k].shape)]
    if wrong:
        k = wrong[0]
        raise CheckpointError(f"{what}: {k} has shape {tuple(converted[k].shape)} in the checkpoint and "
                              f"{tuple(own[k].shape)} in the model built from the config")
    if _numel(converted) != source_numel:
        raise CheckpointError(f"{what}: {_numel(converted)} weights converted from {source_numel} in the checkpoint")
    module.load_state_dict({k: v.to(torch.float32) for k, v in converted.items()}, strict=True)
    module.eval()


def _check_schedule(config, schedule):
    betas = schedule.get("betas")
    if betas is None:
        return "not stored in the checkpoint; from the config"
    want = torch.linspace(config.linear_start ** 0.5, config.linear_end ** 0.5, config.timesteps, dtype=torch.float64) ** 2
    if betas.shape != want.shape or (betas.double() - want).abs().max().item() > 1e-7:
        raise CheckpointError(
            f"the checkpoint's betas do not match the config's schedule (linear_start {config.linear_start}, "
            f"linear_end {config.linear_end}, {config.timesteps} steps): wrong config for this checkpoint?")
    return f"betas in the checkpoint match the config ({config.linear_start}..{config.linear_end}, {config.timesteps} steps)"


def convert(state_dict, config, clip_dir):
    """Builds (text_encoder, controlnet, unet, vae) from a cldm state dict, and a report of where
    each part came from (list of lines)."""
    from diffusers import AutoencoderKL, ControlNetModel, UNet2DConditionModel
    from diffusers.pipelines.stable_diffusion.convert_from_ckpt import (
        convert_ldm_unet_checkpoint,
        convert_ldm_vae_checkpoint,
        create_unet_diffusers_config,
        create_vae_diffusers_config,
    )
    from transformers import CLIPTextConfig, CLIPTextModel

    parts = _split(state_dict)
    report = []
    raw = config.raw

    unet_cfg = create_unet_diffusers_config(raw, image_size=config.resolution)
    unet = UNet2DConditionModel(**unet_cfg)
    converted = convert_ldm_unet_checkpoint(dict(parts["unet"]), unet_cfg)
    _load_strict(unet, converted, _numel(parts["unet"]), "UNet")
    report.append(f"unet         checkpoint {UNET_PREFIX}* ({len(parts['unet'])} tensors, {_numel(parts['unet']):,} weights)")

    cn_cfg = create_unet_diffusers_config(raw, image_size=config.resolution, controlnet=True)
    cn_cfg.pop("sample_size")
    controlnet = ControlNetModel(**cn_cfg)
    converted = convert_ldm_unet_checkpoint(dict(parts["controlnet"]), cn_cfg, controlnet=True)
    _load_strict(controlnet, converted, _numel(parts["controlnet"]), "ControlNet")
    report.append(f"controlnet   checkpoint {CONTROLNET_PREFIX}* ({len(parts['controlnet'])} tensors, "
                  f"{_numel(parts['controlnet']):,} weights)")

    vae_cfg = create_vae_diffusers_config(raw, image_size=int(config.ddconfig.get("resolution", config.resolution)))
    latent_scale = config.scale_factor
    if "scale_factor" in parts["schedule"]:
        latent_scale = float(parts["schedule"]["scale_factor"])
    vae = AutoencoderKL(**vae_cfg, scaling_factor=latent_scale)
    converted = convert_ldm_vae_checkpoint(dict(parts["vae"]), vae_cfg)
    _load_strict(vae, converted, _numel(parts["vae"]), "VAE")
    report.append(f"vae          checkpoint {VAE_PREFIX}* ({len(parts['vae'])} tensors, {_numel(parts['vae']):,} weights; "
                  f"the decoder is exported)")
    report.append(f"latent scale {latent_scale} (" + ("the checkpoint's scale_factor" if "scale_factor" in parts["schedule"]
                                                      else "config scale_factor") + ")")

    text_config = CLIPTextConfig.from_pretrained(clip_dir, local_files_only=True)
    text_encoder = CLIPTextModel(text_config)
    clip = parts["clip"]
    if clip:
        converted = {}
        for key, value in clip.items():
            name = key[len(CLIP_PREFIX):]
            if not name.startswith("text_model."):
                raise CheckpointError(f"unexpected CLIP key {key} (expected {CLIP_PREFIX}text_model.*)")
            name = name[len("text_model."):]
            if name == "embeddings.position_ids":
                continue  # a buffer older transformers saved: arange(77), not a weight
            converted[name] = value
        source = _numel(clip) - (clip[CLIP_PREFIX + "text_model.embeddings.position_ids"].numel()
                                 if CLIP_PREFIX + "text_model.embeddings.position_ids" in clip else 0)
        _load_strict(text_encoder, converted, source, "CLIP text model")
        line = f"text encoder checkpoint {CLIP_PREFIX}* ({len(converted)} tensors, {source:,} weights)"
        other = _clip_dir_weights(clip_dir)
        if other is not None:
            diffs = [(converted[k] - other[k]).abs().max().item() for k in converted if k in other and other[k].shape == converted[k].shape]
            same = len(diffs) == len(converted) and max(diffs, default=0.0) == 0.0
            line += ("; --clip-dir holds the same weights" if same
                     else "; --clip-dir's weights differ and are not used")
        report.append(line + f"; architecture from {os.path.join(clip_dir, 'config.json')}")
    else:
        other = _clip_dir_weights(clip_dir)
        if other is None:
            raise CheckpointError(f"the checkpoint has no {CLIP_PREFIX}* keys and {clip_dir} has no CLIP weights")
        _load_strict(text_encoder, other, _numel(other), f"CLIP text model from {clip_dir}")
        report.append(f"text encoder --clip-dir {clip_dir} (the checkpoint holds no {CLIP_PREFIX}* keys)")
    report.append(f"schedule     {_check_schedule(config, parts['schedule'])}")
    return text_encoder, controlnet, unet, vae, report


def _clip_dir_weights(clip_dir):
    """The text model weights in a transformers CLIP folder (keys without `text_model.`), or None."""
    from safetensors.torch import load_file

    for name in ("model.safetensors", "pytorch_model.bin"):
        path = os.path.join(clip_dir, name)
        if not os.path.isfile(path):
            continue
        weights = load_file(path) if name.endswith(".safetensors") else torch.load(path, map_location="cpu", weights_only=True)
        out = {}
        for key, value in weights.items():
            if key.startswith("text_model."):
                key = key[len("text_model."):]
            elif key.startswith(("vision_model.", "visual_projection.", "text_projection.", "logit_scale")):
                continue
            if key == "embeddings.position_ids":
                continue
            out[key] = value
        return out
    return None


def main():
    """Prints what a checkpoint holds and where each part would come from."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("ckpt")
    ap.add_argument("config")
    ap.add_argument("--clip-dir", required=True)
    args = ap.parse_args()
    state_dict, description = load_checkpoint(args.ckpt)
    print(f"{args.ckpt}: {description}")
    for line in convert(state_dict, CldmConfig(args.config), args.clip_dir)[4]:
        print(line)


if __name__ == "__main__":
    main()
