"""The default model's parts, shared by train.py, export.py and quick_eval.py."""

import torch
import torch.nn.functional as F

from make_tiny_package import SCHEDULER_CONFIG as _SD15_SCHEDULER  # tools/ is on sys.path

# Stable Diffusion 1.5's DDIM schedule (as the tiny test package), predicting the clean latent.
SCHEDULER_CONFIG = {**_SD15_SCHEDULER, "prediction_type": "sample"}
FACTOR = 4  # image pixels per latent pixel
SEQ_LEN = 77


def ae_image_size(ae_state):
    """The image size (px, square) a run's vae.pt was made for; runs from before it was recorded
    trained on 128 px."""
    return int(ae_state.get("size", 128))


class _Config(dict):
    __getattr__ = dict.__getitem__


class SpaceToDepthAE(torch.nn.Module):
    """A fixed, lossless f=4 autoencoder: the latent of an image in [-1, 1] is its 4x4 pixel
    blocks stacked as 48 channels (space-to-depth), minus a per-channel mean; the decoder is the
    inverse (depth-to-space). Nothing is learned, so reconstruction is exact and the whole
    training budget goes to the diffusion model (a learned AutoencoderKL at this budget blurs
    the TacTip pins, which are 1-2 px at 128 px)."""

    def __init__(self, channel_mean):
        super().__init__()
        self.register_buffer("channel_mean", torch.as_tensor(channel_mean, dtype=torch.float32).view(1, -1, 1, 1))
        self.config = _Config(latent_channels=3 * FACTOR * FACTOR, scaling_factor=1.0)

    def encode(self, image):
        return F.pixel_unshuffle(image, FACTOR) - self.channel_mean

    def decode(self, latent_sample, return_dict=False):
        image = F.pixel_shuffle(latent_sample + self.channel_mean, FACTOR)
        return (image,)


def build_text_encoder(vocab_size, bos_id, eos_id, hidden=64):
    from transformers import CLIPTextConfig, CLIPTextModel
    return CLIPTextModel(CLIPTextConfig(
        vocab_size=vocab_size, hidden_size=hidden, intermediate_size=2 * hidden, num_hidden_layers=2,
        num_attention_heads=4, max_position_embeddings=SEQ_LEN, bos_token_id=bos_id, eos_token_id=eos_id,
        pad_token_id=eos_id, projection_dim=hidden,
    ))


def build_unet_controlnet(width, latent_channels, cross_dim=64):
    from diffusers import ControlNetModel, UNet2DConditionModel
    unet = UNet2DConditionModel(
        sample_size=32, in_channels=latent_channels, out_channels=latent_channels,
        block_out_channels=(width, 2 * width, 2 * width), layers_per_block=1,
        down_block_types=("DownBlock2D", "CrossAttnDownBlock2D", "CrossAttnDownBlock2D"),
        up_block_types=("CrossAttnUpBlock2D", "CrossAttnUpBlock2D", "UpBlock2D"),
        cross_attention_dim=cross_dim, attention_head_dim=32, norm_num_groups=16,
    )
    # The hint is 128 px, the latent 32: three embedding stages give the 4x downsample.
    controlnet = ControlNetModel.from_unet(unet, conditioning_embedding_out_channels=(8, 16, 32))
    return unet, controlnet
