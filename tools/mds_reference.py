"""MultiDiffSense's own sampler on a cldm checkpoint: the references rig's parity tests compare
against, and the small random checkpoint behind tests/data/mds-small-package/.

Runs MultiDiffSense's code (its public repository, commit d58ce6a, checked out at --mds-repo;
nothing of it is copied here) in an environment that reads its checkpoints: transformers 4.x
(its FrozenCLIPEmbedder loads CLIP with the `text_model` submodule that transformers 5 dropped),
pytorch-lightning, omegaconf, einops. That is not tools/requirements.txt; a separate venv:

    python3 -m venv /tmp/mds-venv
    echo "$PWD/.venv/lib/python3.11/site-packages" > /tmp/mds-venv/lib/python3.11/site-packages/zz_rig.pth  # torch, numpy, PIL
    /tmp/mds-venv/bin/pip install --no-deps transformers==4.57.6 tokenizers==0.22.1 huggingface_hub==0.36.0 \\
        pytorch-lightning==2.6.6 lightning-utilities torchmetrics einops omegaconf antlr4-python3-runtime==4.9.3 fsspec \\
        torchvision==0.29.2

Three commands:

    # a small CLIP folder: BPE trained on MultiDiffSense prompts, random 1-layer text model
    /tmp/mds-venv/bin/python tools/mds_reference.py clip --out CLIP_DIR [--prompt PROMPT.txt]

    # a random ControlLDM built with MultiDiffSense's classes from CONFIG, saved as {"state_dict"}
    /tmp/mds-venv/bin/python tools/mds_reference.py checkpoint --mds-repo MDS --config CONFIG --out CKPT [--seed 0]

    # what MultiDiffSense's sampler makes of CKPT: ControlLDM.log_images(batch, sample=True, N=1,
    # ddim_steps=S) for S in 4 and 50, with X_T injected as the starting noise
    /tmp/mds-venv/bin/python tools/mds_reference.py references --mds-repo MDS --config CONFIG --ckpt CKPT \\
        --hint HINT.png --prompt PROMPT.txt --x-t X_T.npy --out REF_DIR

References: samples_S{4,50}.npy (guidance 1, what MultiDiffSense's scripts save),
samples_cfg9_S{4,50}.npy (guidance 9, negative prompt ""), text_embedding_{cond,uncond}.npy and
meta.json; all NCHW float32 before any clamping, as the MultiDiffSense kit in
$RIG_SHARED/multidiffsense-cldm-kit holds them. The hint goes in as MultiDiffSense's data loader
makes it: RGB / 255 (the hint is given at the model's size, so its resize is the identity).
"""

import argparse
import importlib.machinery
import json
import os
import sys
import types

import numpy as np
import torch
from PIL import Image


def import_mds(repo):
    """Puts MultiDiffSense on the path. Two imports its modules make are not needed for sampling
    and are stubbed when absent: open_clip (other encoders) and torchvision.utils.make_grid
    (plots); its log_txt_as_img (a Windows font) is replaced by a blank image."""
    sys.path.insert(0, os.path.abspath(repo))
    try:
        import open_clip  # noqa: F401
    except ImportError:
        sys.modules["open_clip"] = types.ModuleType("open_clip")
        sys.modules["open_clip"].__spec__ = importlib.machinery.ModuleSpec("open_clip", None)
    try:
        import torchvision.utils  # noqa: F401
    except ImportError:
        tv = types.ModuleType("torchvision")
        tv_utils = types.ModuleType("torchvision.utils")

        def make_grid(*_a, **_k):
            raise RuntimeError("make_grid stub: not used for sampling")

        tv_utils.make_grid = make_grid
        tv.__spec__ = importlib.machinery.ModuleSpec("torchvision", None)
        tv_utils.__spec__ = importlib.machinery.ModuleSpec("torchvision.utils", None)
        tv.utils = tv_utils
        sys.modules["torchvision"], sys.modules["torchvision.utils"] = tv, tv_utils
    import cldm.cldm
    import ldm.util

    def blank(wh, xc, size=10):
        return torch.zeros(len(xc), 3, wh[1], wh[0])

    cldm.cldm.log_txt_as_img = blank
    ldm.util.log_txt_as_img = blank


def create(args):
    import_mds(args.mds_repo)
    from cldm.model import create_model

    return create_model(args.config).cpu()


def cmd_clip(args):
    """A small CLIP folder in transformers' layout (as MultiDiffSense's FrozenCLIPEmbedder loads
    it): a CLIP-shaped BPE trained on MultiDiffSense prompts (vocab.json, merges.txt) and a random
    1-layer text model of width 32."""
    from transformers import CLIPTextConfig, CLIPTextModel, CLIPTokenizer

    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    from make_tiny_package import build_tokenizer, default_corpus

    os.makedirs(args.out, exist_ok=True)
    corpus = default_corpus() + [open(p, encoding="utf-8").read() for p in args.prompt]
    tok = build_tokenizer(corpus, vocab_size=args.vocab_size)
    tok.model.save(args.out)
    special = {"bos_token": "<|startoftext|>", "eos_token": "<|endoftext|>", "pad_token": "<|endoftext|>",
               "unk_token": "<|endoftext|>"}
    with open(os.path.join(args.out, "special_tokens_map.json"), "w") as f:
        json.dump(special, f, indent=2)
    with open(os.path.join(args.out, "tokenizer_config.json"), "w") as f:
        json.dump({"tokenizer_class": "CLIPTokenizer", "model_max_length": 77, **special}, f, indent=2)
    slow = CLIPTokenizer.from_pretrained(args.out)
    for text in corpus:
        want = tok.encode(text).ids
        got = slow(text).input_ids
        if want != got:
            sys.exit(f"the slow CLIPTokenizer and tokenizers disagree on {text!r}: {got} vs {want}")
    torch.manual_seed(args.seed)
    eos, bos = tok.token_to_id("<|endoftext|>"), tok.token_to_id("<|startoftext|>")
    model = CLIPTextModel(CLIPTextConfig(
        vocab_size=tok.get_vocab_size(), hidden_size=32, intermediate_size=37, num_hidden_layers=1,
        num_attention_heads=4, max_position_embeddings=77, bos_token_id=bos, eos_token_id=eos, pad_token_id=eos,
        projection_dim=32))
    model.save_pretrained(args.out)
    longest = max(len(slow(p).input_ids) for p in corpus)
    print(f"wrote {args.out}: {tok.get_vocab_size()} tokens (longest prompt {longest} tokens), CLIP width 32, 1 layer")


def cmd_checkpoint(args):
    torch.manual_seed(args.seed)
    model = create(args)
    # ControlNet's zero convolutions and ldm's zero-initialised output layers start at zero, which
    # would hide the control path and the text; random values instead (std --zero-init-std). The
    # hint block's convolutions get He initialisation (PyTorch's default init shrinks the hint
    # through its 8 layers), so that the control image changes the output as much as the text.
    with torch.no_grad():
        for name, p in model.named_parameters():
            if torch.count_nonzero(p) == 0:
                p.normal_(0.0, args.zero_init_std)
            elif name.startswith("control_model.input_hint_block.") and p.dim() == 4:
                torch.nn.init.kaiming_normal_(p)
    sd = model.state_dict()
    torch.save({"state_dict": sd}, args.out)
    n = sum(v.numel() for k, v in sd.items())
    print(f"wrote {args.out}: {len(sd)} tensors, {n:,} values")


@torch.no_grad()
def cmd_references(args):
    import_mds(args.mds_repo)
    import ldm.models.diffusion.ddim as ddim
    from cldm.model import create_model, load_state_dict

    model = create_model(args.config).cpu()
    model.load_state_dict(load_state_dict(args.ckpt, location="cpu"))
    model.eval()
    x_t = torch.from_numpy(np.load(args.x_t))
    hint = np.asarray(Image.open(args.hint).convert("RGB"), dtype=np.float32) / 255.0
    prompt = open(args.prompt, encoding="utf-8").read()
    side = model.image_size * 2 ** (len(model.first_stage_model.decoder.up) - 1)
    if hint.shape[:2] != (side, side):
        sys.exit(f"the hint is {hint.shape[1]}x{hint.shape[0]}; give it at the model's size, {side}x{side}")
    batch = {"jpg": torch.zeros(1, side, side, 3), "hint": torch.from_numpy(hint)[None], "txt": [prompt]}

    timesteps = {}
    original_sample = ddim.DDIMSampler.sample

    def sample_from_x_t(self, S, batch_size, shape, conditioning=None, **kwargs):
        kwargs["x_T"] = x_t.clone()
        out = original_sample(self, S, batch_size, shape, conditioning, **kwargs)
        timesteps[S] = [int(t) for t in self.ddim_timesteps]
        return out

    ddim.DDIMSampler.sample = sample_from_x_t
    os.makedirs(args.out, exist_ok=True)
    meta = {"prompt": prompt, "hint_file": os.path.basename(args.hint),
            "hint_layout": "NHWC [0,1] in the batch; ControlLDM.get_input rearranges to NCHW", "runs": {}}
    for steps in args.steps:
        log = model.log_images(batch, sample=True, N=1, ddim_steps=steps)
        run = {"ddim_timesteps": timesteps[steps], "eta": 0.0}
        for key, name in (("samples", f"samples_S{steps}"), ("samples_cfg_scale_9.00", f"samples_cfg9_S{steps}")):
            a = log[key].float().numpy()
            np.save(os.path.join(args.out, name + ".npy"), a)
            run[key] = {"shape": list(a.shape), "min": float(a.min()), "max": float(a.max())}
        meta["runs"][str(steps)] = run
    np.save(os.path.join(args.out, "text_embedding_cond.npy"), model.get_learned_conditioning([prompt]).float().numpy())
    np.save(os.path.join(args.out, "text_embedding_uncond.npy"), model.get_learned_conditioning([""]).float().numpy())
    import transformers

    meta["versions"] = {"torch": torch.__version__, "transformers": transformers.__version__}
    with open(os.path.join(args.out, "meta.json"), "w") as f:
        json.dump(meta, f, indent=1)
        f.write("\n")
    print(f"wrote {args.out}: steps {args.steps}, timesteps {timesteps}")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    k = sub.add_parser("clip")
    k.add_argument("--out", required=True)
    k.add_argument("--prompt", nargs="*", default=[], help="prompt files to add to the tokenizer's corpus")
    k.add_argument("--vocab-size", type=int, default=600)
    k.add_argument("--seed", type=int, default=0)
    c = sub.add_parser("checkpoint")
    r = sub.add_parser("references")
    for p in (c, r):
        p.add_argument("--mds-repo", required=True, help="a checkout of MultiDiffSense (commit d58ce6a)")
        p.add_argument("--config", required=True, help="its cldm yaml (cond_stage_config.params.version: the CLIP folder)")
    c.add_argument("--out", required=True)
    c.add_argument("--seed", type=int, default=0)
    c.add_argument("--zero-init-std", type=float, default=0.2)
    r.add_argument("--ckpt", required=True)
    r.add_argument("--hint", required=True)
    r.add_argument("--prompt", required=True)
    r.add_argument("--x-t", required=True)
    r.add_argument("--steps", type=int, nargs="+", default=[4, 50])
    r.add_argument("--out", required=True)
    args = ap.parse_args()
    {"clip": cmd_clip, "checkpoint": cmd_checkpoint, "references": cmd_references}[args.cmd](args)


if __name__ == "__main__":
    main()
