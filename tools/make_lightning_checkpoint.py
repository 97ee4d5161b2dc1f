"""Wraps a cldm state dict in a Lightning training checkpoint, as MultiDiffSense's train.py
writes one (trainer.fit with ModelCheckpoint, EarlyStopping on val/loss, AdamW over the
ControlNet's parameters, precision 32), for testing tools/export_package.py on that form:

    .venv/bin/python tools/make_lightning_checkpoint.py IN.ckpt OUT.ckpt [--hparams] [--code MARKER]

OUT holds `state_dict` (IN's), `optimizer_states` (AdamW after one step over control_model.*,
as ControlLDM.configure_optimizers with sd_locked), `lr_schedulers` ([]), `epoch`,
`global_step`, `pytorch-lightning_version`, `loops` and `callbacks` (the EarlyStopping and
ModelCheckpoint states). Without Lightning installed, its classes are not needed: Lightning
writes these as plain containers and tensors.

--hparams adds `hyper_parameters` as Lightning's AttributeDict (what a LightningModule calling
save_hyperparameters() writes), pickled under Lightning's class name, to test that the exporter
reads it through its stand-in. --code adds an object whose unpickling would run
`touch MARKER`, to test that the exporter refuses such a file (and MARKER never appears).
"""

import argparse
import os
import sys
import types

import torch


def lightning_attribute_dict():
    """A dict subclass pickled as pytorch_lightning.utilities.parsing.AttributeDict."""
    names = ["pytorch_lightning", "pytorch_lightning.utilities", "pytorch_lightning.utilities.parsing"]
    for name in names:
        sys.modules.setdefault(name, types.ModuleType(name))

    class AttributeDict(dict):
        pass

    AttributeDict.__module__ = names[-1]
    AttributeDict.__qualname__ = "AttributeDict"
    sys.modules[names[-1]].AttributeDict = AttributeDict
    return AttributeDict


class RunsCode:
    """Unpickling this runs `touch MARKER` (through os.system)."""

    def __init__(self, marker):
        self.marker = marker

    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("input")
    ap.add_argument("output")
    ap.add_argument("--hparams", action="store_true")
    ap.add_argument("--code", metavar="MARKER")
    args = ap.parse_args()

    plain = torch.load(args.input, map_location="cpu", weights_only=True)
    state_dict = plain.get("state_dict", plain)
    params = [torch.nn.Parameter(v.clone()) for k, v in state_dict.items() if k.startswith("control_model.")]
    opt = torch.optim.AdamW(params, lr=1e-5)
    for p in params:
        p.grad = torch.randn_like(p) * 1e-3
    opt.step()

    steps, epoch = 78840, 119
    ckpt = {
        "epoch": epoch,
        "global_step": steps,
        "pytorch-lightning_version": "2.6.6",
        "state_dict": state_dict,
        "loops": {
            "fit_loop": {
                "state_dict": {},
                "epoch_loop.state_dict": {"_batches_that_stepped": steps},
                "epoch_loop.batch_progress": {
                    "total": {"ready": steps, "completed": steps, "started": steps, "processed": steps},
                    "current": {"ready": 657, "completed": 657, "started": 657, "processed": 657},
                    "is_last_batch": True,
                },
                "epoch_progress": {"total": {"ready": epoch + 1, "completed": epoch, "started": epoch + 1,
                                             "processed": epoch + 1}},
            },
        },
        "callbacks": {
            "EarlyStopping{'monitor': 'val/loss', 'mode': 'min'}": {
                "wait_count": 3, "stopped_epoch": 0, "best_score": torch.tensor(0.0712), "patience": 10,
            },
            "ModelCheckpoint{'monitor': None, 'mode': 'min', 'every_n_train_steps': 0, 'every_n_epochs': 1, "
            "'train_time_interval': None}": {
                "monitor": None, "best_model_score": None, "best_model_path": "", "current_score": None,
                "dirpath": "results/lightning_logs/version_0/checkpoints", "best_k_models": {},
                "kth_best_model_path": "", "kth_value": torch.tensor(float("inf")), "last_model_path": "",
            },
        },
        "optimizer_states": [opt.state_dict()],
        "lr_schedulers": [],
    }
    if args.hparams:
        ckpt["hparams_name"] = "kwargs"
        ckpt["hyper_parameters"] = lightning_attribute_dict()(learning_rate=1e-5, sd_locked=True, only_mid_control=False)
    if args.code:
        ckpt["extra"] = RunsCode(args.code)
    torch.save(ckpt, args.output)
    print(f"wrote {args.output} ({os.path.getsize(args.output) / 1e6:.1f} MB): {len(state_dict)} weights, "
          f"AdamW state for {len(params)} tensors" + (", hyper_parameters" if args.hparams else "")
          + (", an object that runs code" if args.code else ""))


if __name__ == "__main__":
    main()
