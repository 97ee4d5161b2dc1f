"""Builds small ONNX graphs that break rig's model-package contract in one way each, for the
error tests (tests/synth/synth_errors.rs). Each graph has the right names except for the one fault;
the computation is a placeholder (Identity), as only the interface is under test.

    .venv/bin/python tools/make_broken_models.py   # writes tests/data/broken-models/*.onnx
"""

import os

import onnx
from onnx import TensorProto, helper

OUT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests", "data", "broken-models")


def tensor(name, ty, shape):
    return helper.make_tensor_value_info(name, ty, shape)


def save(name, inputs, outputs, first_input, first_output):
    # outputs[0] = Identity(inputs[0]); other outputs the same, so the graph is valid.
    nodes = [helper.make_node("Identity", [first_input], [o.name]) for o in outputs]
    graph = helper.make_graph(nodes, name, inputs, outputs)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    onnx.checker.check_model(model)
    onnx.save(model, os.path.join(OUT, name))


def main():
    os.makedirs(OUT, exist_ok=True)
    f, i64 = TensorProto.FLOAT, TensorProto.INT64
    lat = ["batch", 4, "h", "w"]
    # A UNet taking 3 down-block residuals where the tiny ControlNet returns 4.
    save(
        "unet_3_residuals.onnx",
        [tensor("sample", f, lat), tensor("timestep", i64, [1]), tensor("encoder_hidden_states", f, ["batch", 77, 32])]
        + [tensor(f"down_block_additional_residual_{i}", f, ["batch", 16, "h", "w"]) for i in range(3)]
        + [tensor("mid_block_additional_residual", f, ["batch", 32, "h", "w"])],
        [tensor("out_sample", f, lat)],
        "sample",
        "out_sample",
    )
    # A ControlNet whose hint input is float16.
    save(
        "controlnet_fp16_cond.onnx",
        [tensor("sample", f, lat), tensor("timestep", i64, [1]), tensor("encoder_hidden_states", f, ["batch", 77, 32]),
         tensor("controlnet_cond", TensorProto.FLOAT16, ["batch", 3, "H", "W"]), tensor("conditioning_scale", f, [])],
        [tensor(f"down_block_res_samples_{i}", f, lat) for i in range(4)] + [tensor("mid_block_res_sample", f, lat)],
        "sample",
        "down_block_res_samples_0",
    )
    # A text encoder whose ids are float and whose output has rank 2.
    save(
        "text_encoder_float_ids.onnx",
        [tensor("input_ids", f, ["batch", 77])],
        [tensor("last_hidden_state", f, ["batch", 77])],
        "input_ids",
        "last_hidden_state",
    )
    # A VAE decoder with an extra input rig does not know how to feed.
    save(
        "vae_decoder_extra_input.onnx",
        [tensor("latent_sample", f, lat), tensor("return_dict", TensorProto.BOOL, [])],
        [tensor("sample", f, ["batch", 3, "H", "W"])],
        "latent_sample",
        "sample",
    )
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
