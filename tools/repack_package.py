"""Rewrites the ONNX models of a rig model package: all weights of a model in one external-data
file `model.onnx.data` beside its `model.onnx` (instead of one file per tensor, as torch writes
models over 2 GB), and optionally in float16.

    python tools/repack_package.py IN --out OUT [--fp16] [--external-data auto|always|never]

Copies package IN to OUT (which must not exist, or be a package: it is replaced) and rewrites
OUT's four models. export_package.py does the same as its last step (--fp16, --external-data).
Needs onnx, onnxruntime and numpy only (no PyTorch).

Float16 (--fp16): weights and activations float16, except the ops in FP32_OPS (GroupNorm's and
LayerNorm's statistics) and the sinusoidal timestep embedding, which stay float32 with casts
around them. Every graph input and output stays float32 (a cast at the boundary), so the package
contract, and rig, are unchanged.
"""

import argparse
import os
import shutil
import sys
# --- Package files: one external-data file per model, float16 -----------------------------------------------

MODEL_DIRS = ("text_encoder", "controlnet", "unet", "vae_decoder")
EXTERNAL_DATA = "model.onnx.data"
# ONNX files are protobufs, which cannot exceed 2 GiB: bigger models keep their weights outside.
PROTOBUF_LIMIT_BYTES = 2**31 - 1
# Kept float32 in a float16 package: the statistics of GroupNorm (exported as InstanceNormalization)
# and LayerNorm are sums of squares over whole feature maps, which overflow float16's 65504.
FP32_OPS = ("InstanceNormalization", "LayerNormalization")


def save_model(model, path, external):
    """Writes `model` (an onnx ModelProto, external weights already loaded) to `path`, replacing
    whatever its folder held: with external, every weight goes to one file `model.onnx.data`
    beside it (size_threshold 0), else everything stays in model.onnx."""
    import onnx

    folder = os.path.dirname(path)
    for name in os.listdir(folder):
        full = os.path.join(folder, name)
        if os.path.isdir(full):
            shutil.rmtree(full)
        else:
            os.remove(full)
    if external:
        onnx.save_model(model, path, save_as_external_data=True, all_tensors_to_one_file=True, location=EXTERNAL_DATA,
                        size_threshold=0, convert_attribute=False)
    else:
        onnx.save_model(model, path)


def is_large(path):
    """Whether the model at `path` is over the protobuf limit: torch wrote its weights outside
    (files beside model.onnx), or model.onnx itself is over 2 GB."""
    folder = os.path.dirname(path)
    return os.listdir(folder) != ["model.onnx"] or os.path.getsize(path) > PROTOBUF_LIMIT_BYTES


def timestep_embedding_nodes(graph, input_name="timestep"):
    """Names of the nodes between the timestep input and the first linear layer after it: the
    sinusoidal embedding, which diffusers computes in float32 in its float16 pipelines too (in
    float16, t x frequency at t near 1000 is off by up to 0.5, a quarter turn of sine)."""
    consumers = {}
    for node in graph.node:
        for name in node.input:
            consumers.setdefault(name, []).append(node)
    names, front = set(), [input_name]
    while front:
        for node in consumers.get(front.pop(), []):
            if node.op_type in ("Gemm", "MatMul") or node.name in names:
                continue
            names.add(node.name)
            front.extend(node.output)
    # and the constants only they read (the frequencies), else rounded to float16 on the way
    for node in graph.node:
        if node.op_type == "Constant" and all(c.name in names for out in node.output for c in consumers.get(out, [])):
            if any(consumers.get(out) for out in node.output):
                names.add(node.name)
    return names


def to_float16(path):
    """A float16 copy of the model at `path` (an onnx ModelProto, weights loaded): weights and
    activations float16, except FP32_OPS and the timestep embedding, which stay float32 with casts
    around them. Inputs and outputs stay float32 (casts at the boundary), so the package contract
    is unchanged. The converter needs every tensor's type: they are inferred from the file
    (infer_shapes_path, which also works over 2 GB), next to it so external data resolves."""
    import onnx
    from onnx.shape_inference import infer_shapes_path
    from onnxruntime.transformers.float16 import DEFAULT_OP_BLOCK_LIST, convert_float_to_float16

    inferred = os.path.join(os.path.dirname(path), "model.inferred.onnx")
    try:
        infer_shapes_path(path, inferred)
        model = onnx.load(inferred, load_external_data=True)
    finally:
        if os.path.exists(inferred):
            os.remove(inferred)
    for i, node in enumerate(model.graph.node):
        if not node.name:
            node.name = f"node_{i}_{node.op_type}"
    blocked = timestep_embedding_nodes(model.graph)
    model = convert_float_to_float16(model, keep_io_types=True, disable_shape_infer=True,
                                     op_block_list=list(DEFAULT_OP_BLOCK_LIST) + list(FP32_OPS),
                                     node_block_list=sorted(blocked))
    _join_float32_runs(model.graph)
    return model


def _join_float32_runs(graph):
    """The converter puts a float32->float16 cast after every float32 node and a float16->float32
    cast before every float32 consumer, even between two float32 nodes (a float16 rounding in the
    middle of the float32 timestep embedding), and writes the same cast twice for a tensor that
    two float32 nodes read (an invalid graph). Joins such runs: a float32 consumer reads the
    float32 tensor itself, and casts nobody reads are dropped."""
    producer = {out: node for node in graph.node for out in node.output}
    rename, nodes, seen = {}, [], set()
    for node in graph.node:
        if node.op_type == "Cast" and node.name.endswith("_cast_to_fp32_node"):
            if node.name in seen:
                continue  # the same cast, written once per float32 consumer
            seen.add(node.name)
            source = producer.get(node.input[0])
            if source is not None and source.op_type == "Cast" and source.name.endswith("_cast_to_fp16_node"):
                rename[node.output[0]] = source.input[0]
                continue
        nodes.append(node)
    for node in nodes:
        for i, name in enumerate(node.input):
            node.input[i] = rename.get(name, name)
    read = {name for node in nodes for name in node.input} | {o.name for o in graph.output}
    nodes = [n for n in nodes if not (n.op_type == "Cast" and n.name.endswith("_cast_to_fp16_node") and n.output[0] not in read)]
    live = {out for node in nodes for out in node.output}
    del graph.node[:]
    graph.node.extend(nodes)
    infos, names = [], set()
    for info in graph.value_info:
        if info.name in live and info.name not in names:
            names.add(info.name)
            infos.append(info)
    del graph.value_info[:]
    graph.value_info.extend(infos)


def repack_package(out_dir, fp16=False, external="auto"):
    """Rewrites each model of the package in out_dir: weights in one model.onnx.data per model
    where `external` says (torch writes one file per tensor for models over 2 GB), and in
    float16 when fp16. Returns {model: (bytes of its folder, whether external)}."""
    import onnx

    if external not in ("auto", "always", "never"):
        raise ValueError(f"external must be auto, always or never, not {external!r}")
    report = {}
    for name in MODEL_DIRS:
        path = os.path.join(out_dir, name, "model.onnx")
        folder = os.path.dirname(path)
        large = is_large(path)
        outside = external == "always" or (external == "auto" and large)
        if large and external == "never" and not fp16:
            raise ValueError(f"{path} is over 2 GB: it cannot be written without external data")
        if not fp16 and not large and not outside:
            report[name] = (os.path.getsize(path), False)  # nothing to change: left as written
            continue
        model = to_float16(path) if fp16 else onnx.load(path, load_external_data=True)
        save_model(model, path, outside)
        report[name] = (sum(os.path.getsize(os.path.join(folder, f)) for f in os.listdir(folder)), outside)
    return report


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("package", help="model package folder to read")
    ap.add_argument("--out", required=True, help="package folder to write (replaced if it is a package)")
    ap.add_argument("--fp16", action="store_true", help="float16 weights and activations (float32 inputs and outputs)")
    ap.add_argument("--external-data", choices=["auto", "always", "never"], default="auto",
                    help="weights in one model.onnx.data per model: auto (only over 2 GB), always, never")
    args = ap.parse_args()
    src, out = os.path.abspath(args.package), os.path.abspath(args.out)
    if not os.path.isfile(os.path.join(src, "model.toml")):
        sys.exit(f"error: {src} is not a model package (no model.toml)")
    if src == out:
        sys.exit("error: --out must be another folder than the package read")
    if os.path.isdir(out) and os.listdir(out):
        if not os.path.isfile(os.path.join(out, "model.toml")):
            sys.exit(f"error: {out} exists and is not a model package; refusing to replace it")
        shutil.rmtree(out)
    shutil.copytree(src, out)
    try:
        report = repack_package(out, fp16=args.fp16, external=args.external_data)
    except ValueError as e:
        sys.exit(f"error: {e}")
    for name, (size, outside) in report.items():
        print(f"{name:13}{size / 1e6:8.1f} MB{'  (weights in model.onnx.data)' if outside else ''}")
    print(f"wrote {out}{' (float16)' if args.fp16 else ''}")


if __name__ == "__main__":
    main()
