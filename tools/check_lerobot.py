#!/usr/bin/env python3
"""Checks a `rig dataset export --format lerobot` folder with readers rig does not share code with.

    python3 tools/check_lerobot.py OUT [--datasets DIR] [--lerobot]

Always (needs pyarrow and Pillow):
- every data and episodes file is at most data_files_size_in_mb x 10^6 bytes, and each data file
  is read whole with pyarrow's read_table, one file at a time (its images are dropped before the
  next file is read);
- meta/info.json: codebase_version v3.0, counts, features; every data file's columns are exactly
  the features, with the arrow types LeRobot's loader casts to (fixed-size float32 lists for
  vectors, struct<bytes, path> for images, string, bool, int64, float32);
- row counts: the data files hold total_frames rows, `index` runs 0..N-1, each episode's rows
  are dataset_from_index..dataset_to_index with frame_index 0..length-1, all in the data file
  the episode names;
- every image decodes (Pillow) to the feature's height x width x 3;
- meta/tasks.parquet maps task_index to the task text (its pandas index), meta/stats.json has
  every numeric and image feature.

--datasets DIR: also compares every frame with the rig datasets it was exported from (pose_id,
commanded pose = action, measured pose = observation.state where measured, source, and the
decoded pixels), taking each episode's object from meta/episodes' rig/object.

--lerobot: also loads OUT with the `lerobot` package's LeRobotDataset from the local folder
(HF_HUB_OFFLINE=1: no hub access) and iterates every frame, checking its pose, pose_id, task
and image shapes against the parquet rows. Opt-in: `pip install lerobot` pulls in torch.

Prints one line per check and exits 1 on the first failure.
"""

import argparse
import csv
import io
import json
import os
import sys
from pathlib import Path


def fail(msg):
    print(f"check_lerobot: FAIL: {msg}", file=sys.stderr)
    sys.exit(1)


def ok(msg):
    print(f"check_lerobot: ok: {msg}")


def expected_type(pa, ft):
    dtype, shape = ft["dtype"], tuple(ft["shape"])
    if dtype == "image":
        return pa.struct([("bytes", pa.binary()), ("path", pa.string())])
    scalar = {"float32": pa.float32(), "float64": pa.float64(), "int64": pa.int64(), "bool": pa.bool_(), "string": pa.string()}[dtype]
    if shape == (1,):
        return scalar
    if len(shape) == 1:
        return pa.list_(scalar, shape[0])
    fail(f"feature shape {shape} is not one rig writes")


def hist_stats(hist):
    """min, max, mean, std and the quantiles of the values a 256-bin histogram counts, on [0, 1]
    (numpy's linear quantile method, taken on the counts rather than on the sorted pixels)."""
    import numpy as np

    n = int(hist.sum())
    values = np.arange(256, dtype=np.float64)
    mean = float((values * hist).sum() / n)
    std = float(np.sqrt(((values - mean) ** 2 * hist).sum() / n))
    nonzero = np.nonzero(hist)[0]
    cum = np.cumsum(hist)

    def rank(k):
        return float(np.searchsorted(cum, k, side="right"))

    out = {"min": float(nonzero[0]), "max": float(nonzero[-1]), "mean": mean, "std": std}
    for q in (1, 10, 50, 90, 99):
        pos = q / 100 * (n - 1)
        lo = int(np.floor(pos))
        hi = min(lo + 1, n - 1)
        out[f"q{q:02d}"] = rank(lo) + (rank(hi) - rank(lo)) * (pos - lo)
    return {k: v / 255.0 for k, v in out.items()}


def check_file_sizes(out, info, pattern, what):
    bound = info["data_files_size_in_mb"] * 1_000_000
    files = sorted(out.glob(pattern))
    if not files:
        fail(f"no {pattern}")
    for f in files:
        size = f.stat().st_size
        if size > bound:
            fail(f"{f}: {size} bytes, over data_files_size_in_mb {info['data_files_size_in_mb']} (x 10^6 bytes)")
    largest = max(f.stat().st_size for f in files)
    ok(f"{len(files)} {what} file(s), each at most {info['data_files_size_in_mb']} MB (largest {largest / 1e6:.2f} MB)")
    return files


def check_arrow(out, datasets=None):
    """Reads each data file whole (pyarrow read_table), one at a time: its images are decoded,
    counted into per-channel histograms and, with `datasets`, compared with the rig datasets'
    rows, then dropped. Returns info and the frames without their images."""
    import numpy as np
    import pyarrow as pa
    import pyarrow.parquet as pq
    from PIL import Image

    info = json.loads((out / "meta/info.json").read_text())
    if info["codebase_version"] != "v3.0":
        fail(f"codebase_version {info['codebase_version']}")
    features = info["features"]
    image_keys = [k for k, ft in features.items() if ft["dtype"] == "image"]
    data_files = check_file_sizes(out, info, "data/*/*.parquet", "data")
    check_file_sizes(out, info, "meta/episodes/*/*.parquet", "episodes")
    sources = load_datasets(datasets) if datasets else None
    episodes = pa.concat_tables([pq.read_table(f) for f in sorted((out / "meta/episodes").glob("*/*.parquet"))]).to_pylist()
    object_of = {ep["episode_index"]: ep["rig/object"] for ep in episodes}
    slim = []
    file_of_index = {}
    hists = {k: np.zeros((3, 256), dtype=np.int64) for k in image_keys}
    decoded = 0
    compared = 0
    for f in data_files:
        t = pq.read_table(f)  # the whole file at once
        names = set(t.schema.names)
        if names != set(features):
            fail(f"{f}: columns {sorted(names)} but features {sorted(features)}")
        for key, ft in features.items():
            want = expected_type(pa, ft)
            got = t.schema.field(key).type
            if got != want:
                fail(f"{f}: column {key} is {got}, LeRobot's loader wants {want}")
        rel = str(f.relative_to(out))
        for i in t.column("index").to_pylist():
            file_of_index[i] = rel
        for key in image_keys:
            h, w, c = features[key]["shape"]
            for cell in t.column(key).to_pylist():
                img = Image.open(io.BytesIO(cell["bytes"]))
                img.load()
                if img.size != (w, h) or len(img.getbands()) != c:
                    fail(f"{key}: an image is {img.size} {img.mode}, the feature says {w}x{h}x{c}")
                pixels = np.asarray(img.convert("RGB")).reshape(-1, 3)
                for ch in range(3):
                    hists[key][ch] += np.bincount(pixels[:, ch], minlength=256)
                decoded += 1
        if sources is not None:
            compared += check_against_datasets(t, info, sources, object_of)
        slim.append(t.drop_columns(image_keys))
    ok(f"{len(data_files)} data files read whole, columns and types match the {len(features)} features")
    ok(f"{decoded} images decode to their features' shapes")
    if sources is not None:
        total = sum(len(rows) for per_sensor in sources.values() for _, rows in per_sensor.values())
        if compared != total:
            fail(f"compared {compared} sensor frames but the datasets hold {total} rows")
        ok(f"every one of the {compared} sensor frames equals its dataset row (pose, source, pixels)")

    table = pa.concat_tables(slim)
    n = table.num_rows
    if n != info["total_frames"]:
        fail(f"{n} rows but total_frames {info['total_frames']}")
    index = table.column("index").to_pylist()
    if index != list(range(n)):
        fail("index is not 0..N-1 in file order")
    if len(episodes) != info["total_episodes"]:
        fail(f"{len(episodes)} episode rows but total_episodes {info['total_episodes']}")
    ep_col = table.column("episode_index").to_pylist()
    fi_col = table.column("frame_index").to_pylist()
    for ep in episodes:
        a, b = ep["dataset_from_index"], ep["dataset_to_index"]
        if b - a != ep["length"] or ep_col[a:b] != [ep["episode_index"]] * ep["length"] or fi_col[a:b] != list(range(ep["length"])):
            fail(f"episode {ep['episode_index']}: rows {a}..{b} do not hold it frame by frame")
        named = info["data_path"].format(chunk_index=ep["data/chunk_index"], file_index=ep["data/file_index"])
        if {file_of_index[i] for i in range(a, b)} != {named}:
            fail(f"episode {ep['episode_index']}: its rows are not all in {named}, the data file it names")
        for key in image_keys:
            if ep[f"stats/{key}/count"] != [ep["length"]]:
                fail(f"episode {ep['episode_index']}: stats/{key}/count {ep[f'stats/{key}/count']}, length {ep['length']}")
    if sum(ep["length"] for ep in episodes) != n:
        fail("episode lengths do not add up to the rows")
    ok(f"{n} rows, {len(episodes)} episodes, index and frame ranges consistent, each episode whole in the data file it names")
    tasks = pq.read_table(out / "meta/tasks.parquet")
    meta = json.loads(tasks.schema.metadata[b"pandas"])
    if meta["index_columns"] != ["task"]:
        fail(f"tasks.parquet pandas index {meta['index_columns']}")
    task_of = dict(zip(tasks.column("task_index").to_pylist(), tasks.column("task").to_pylist()))
    if len(task_of) != info["total_tasks"] or set(table.column("task_index").to_pylist()) - set(task_of):
        fail("task_index values without a task")
    for ep in episodes:
        if ep["tasks"] != [task_of[table.column("task_index")[ep["dataset_from_index"]].as_py()]]:
            fail(f"episode {ep['episode_index']} tasks {ep['tasks']}")
    ok(f"{len(task_of)} tasks: {list(task_of.values())}")
    stats = json.loads((out / "meta/stats.json").read_text())
    for key, ft in features.items():
        if ft["dtype"] in ("string", "bool"):
            continue
        for stat in ("min", "max", "mean", "std", "count", "q01", "q50", "q99"):
            if stat not in stats.get(key, {}):
                fail(f"stats.json lacks {key}/{stat}")
    for key, ft in features.items():
        if ft["dtype"] in ("string", "bool"):
            continue
        if ft["dtype"] == "image":
            per_channel = [hist_stats(hists[key][ch]) for ch in range(3)]
            want = {stat: np.asarray([c[stat] for c in per_channel]) for stat in per_channel[0]}
            shape = (3, 1, 1)
        else:
            values = np.asarray(table.column(key).to_pylist(), dtype=np.float64).reshape(n, -1)
            shape = (values.shape[1],)
            want = {"min": values.min(axis=0), "max": values.max(axis=0), "mean": values.mean(axis=0), "std": values.std(axis=0)}
            for q in (1, 10, 50, 90, 99):
                want[f"q{q:02d}"] = np.quantile(values, q / 100, axis=0)
        for stat, w in want.items():
            got = np.asarray(stats[key][stat], dtype=np.float64)
            if got.shape != shape or not np.allclose(got.reshape(-1), w, rtol=0, atol=1e-9):
                fail(f"stats.json {key}/{stat} is {got.tolist()}, numpy says {w.tolist()}")
    ok("stats.json covers every numeric and image feature and equals numpy's min, max, mean, std and quantiles of the rows")
    return info, table


def load_datasets(datasets):
    """object -> sensor -> (dataset folder, pose_id -> poses.csv row)."""
    by_object = {}
    for manifest in sorted(datasets.rglob("manifest.toml")):
        d = manifest.parent
        with open(d / "poses.csv", newline="") as f:
            by_object.setdefault(d.parent.name, {})[d.name] = (d, {int(r["pose_id"]): r for r in csv.DictReader(f)})
    return by_object


def check_against_datasets(table, info, by_object, object_of):
    """Compares the rows of one data file with the rig datasets (`object_of`: episode_index ->
    the episode's object, meta/episodes' rig/object); returns the sensor frames compared."""
    import numpy as np
    from PIL import Image

    sensors = [k.removeprefix("observation.images.") for k, ft in info["features"].items() if ft["dtype"] == "image"]
    checked = 0
    for r in table.to_pylist():
        obj = object_of[r["episode_index"]]
        for s in sensors:
            d, rows = by_object[obj][s]
            src = rows[r["pose_id"]]
            cmd = [float(src[k]) for k in ("x_mm", "y_mm", "z_mm", "yaw_deg")]
            if not np.allclose(r["action"], np.float32(cmd), rtol=0, atol=0):
                fail(f"{obj} pose {r['pose_id']}: action {r['action']} but commanded {cmd}")
            if src["meas_x_mm"]:
                meas = [float(src[k]) for k in ("meas_x_mm", "meas_y_mm", "meas_z_mm", "meas_yaw_deg")]
                if not r["state_measured"] or not np.allclose(r["observation.state"], np.float32(meas), rtol=0, atol=0):
                    fail(f"{obj} pose {r['pose_id']}: state {r['observation.state']} but measured {meas}")
            if r[f"source.{s}"] != src["source"]:
                fail(f"{obj} pose {r['pose_id']} {s}: source {r[f'source.{s}']} but {src['source']}")
            ours = np.asarray(Image.open(io.BytesIO(r[f"observation.images.{s}"]["bytes"])).convert("RGB"))
            theirs = np.asarray(Image.open(d / src["image"]).convert("RGB"))
            if not np.array_equal(ours, theirs):
                fail(f"{obj} pose {r['pose_id']} {s}: pixels differ from {d / src['image']}")
            checked += 1
    return checked


def check_lerobot(out, table, info):
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    import numpy as np
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    ds = LeRobotDataset("rig/export", root=out)
    if len(ds) != table.num_rows:
        fail(f"LeRobotDataset has {len(ds)} frames, the parquet {table.num_rows}")
    image_keys = [k for k, ft in info["features"].items() if ft["dtype"] == "image"]
    rows = table.to_pylist()
    for i in range(len(ds)):
        item = ds[i]
        r = rows[i]
        if int(item["pose_id"]) != r["pose_id"] or int(item["index"]) != i:
            fail(f"frame {i}: pose_id {item['pose_id']} index {item['index']}")
        if not np.array_equal(item["observation.state"].numpy(), np.float32(r["observation.state"])):
            fail(f"frame {i}: observation.state {item['observation.state']}")
        if not np.array_equal(item["action"].numpy(), np.float32(r["action"])):
            fail(f"frame {i}: action {item['action']}")
        for k in image_keys:
            h, w, c = info["features"][k]["shape"]
            if tuple(item[k].shape) != (c, h, w):
                fail(f"frame {i}: {k} has shape {tuple(item[k].shape)}")
        if not isinstance(item["task"], str) or not item["task"]:
            fail(f"frame {i}: task {item['task']!r}")
    ok(f"LeRobotDataset loaded {out} offline and yielded all {len(ds)} frames with their poses, tasks and {len(image_keys)} images each")


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("out", type=Path)
    p.add_argument("--datasets", type=Path, help="the rig datasets the export was made from")
    p.add_argument("--lerobot", action="store_true", help="also load it with lerobot's LeRobotDataset")
    a = p.parse_args()
    info, table = check_arrow(a.out, a.datasets)
    if a.lerobot:
        check_lerobot(a.out, table, info)


if __name__ == "__main__":
    main()
