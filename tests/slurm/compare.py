#!/usr/bin/env python3
"""Compares two rig datasets pose by pose: the same pose ids, each once, the same poses.csv
row, and the same decoded pixels (PNG decoded here with the standard library only).

    compare.py EXPECTED ACTUAL     exit 0 when equal, 1 with the differences listed
"""
import csv
import struct
import sys
import zlib
from pathlib import Path


def png_parts(path):
    """IHDR fields and the inflated image data (filtered scanlines) of a PNG."""
    data = Path(path).read_bytes()
    if data[:8] != b"\x89PNG\r\n\x1a\n":
        raise ValueError(f"{path}: not a PNG")
    pos, idat, header = 8, [], None
    while pos < len(data):
        (length,) = struct.unpack(">I", data[pos : pos + 4])
        kind = data[pos + 4 : pos + 8]
        body = data[pos + 8 : pos + 8 + length]
        if zlib.crc32(kind + body) != struct.unpack(">I", data[pos + 8 + length : pos + 12 + length])[0]:
            raise ValueError(f"{path}: bad CRC in {kind!r}")
        if kind == b"IHDR":
            header = struct.unpack(">IIBBBBB", body)
        elif kind == b"IDAT":
            idat.append(body)
        elif kind == b"IEND":
            break
        pos += 12 + length
    return header, zlib.decompress(b"".join(idat))


def same_pixels(path_a, path_b):
    """Whether two PNGs hold the same pixels: the same header and filtered scanlines mean the
    same pixels; otherwise both are decoded and compared."""
    a, b = png_parts(path_a), png_parts(path_b)
    if a == b:
        return True
    return decode(path_a, *a) == decode(path_b, *b)


def decode(path, header, raw):
    """(width, height, channels, pixel bytes) of an 8-bit, non-interlaced PNG."""
    width, height, depth, colour, _, _, interlace = header
    channels = {0: 1, 2: 3, 4: 2, 6: 4}.get(colour)
    if depth != 8 or channels is None or interlace != 0:
        raise ValueError(f"{path}: unsupported PNG (depth {depth}, colour type {colour}, interlace {interlace})")
    stride = width * channels
    out = bytearray(height * stride)
    prev = bytearray(stride)
    for y in range(height):
        f = raw[y * (stride + 1)]
        line = bytearray(raw[y * (stride + 1) + 1 : (y + 1) * (stride + 1)])
        for x in range(stride):
            a = line[x - channels] if x >= channels else 0
            b = prev[x]
            c = prev[x - channels] if x >= channels else 0
            if f == 1:
                line[x] = (line[x] + a) & 255
            elif f == 2:
                line[x] = (line[x] + b) & 255
            elif f == 3:
                line[x] = (line[x] + (a + b) // 2) & 255
            elif f == 4:
                p = a + b - c
                pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
                line[x] = (line[x] + (a if pa <= pb and pa <= pc else b if pb <= pc else c)) & 255
            elif f != 0:
                raise ValueError(f"{path}: bad filter {f}")
        out[y * stride : (y + 1) * stride] = line
        prev = line
    return width, height, channels, bytes(out)


def rows(dataset):
    """header, {pose_id: row} and the ids seen more than once."""
    with open(Path(dataset) / "poses.csv", newline="") as f:
        reader = csv.reader(f)
        header = next(reader)
        by_id, dups = {}, []
        for row in reader:
            pid = int(row[header.index("pose_id")])
            if pid in by_id:
                dups.append(pid)
            by_id[pid] = row
    return header, by_id, dups


def main():
    expected, actual = Path(sys.argv[1]), Path(sys.argv[2])
    problems = []
    h1, a, d1 = rows(expected)
    h2, b, d2 = rows(actual)
    if h1 != h2:
        problems.append(f"headers differ: {h1} / {h2}")
    for name, dups in ((expected, d1), (actual, d2)):
        if dups:
            problems.append(f"{name}: pose ids more than once: {sorted(set(dups))}")
    if a.keys() != b.keys():
        problems.append(f"pose ids differ: only in {expected}: {sorted(a.keys() - b.keys())}; only in {actual}: {sorted(b.keys() - a.keys())}")
    image = h1.index("image")
    for pid in sorted(a.keys() & b.keys()):
        if a[pid] != b[pid]:
            problems.append(f"pose {pid}: rows differ: {a[pid]} / {b[pid]}")
        if not same_pixels(expected / a[pid][image], actual / b[pid][image]):
            problems.append(f"pose {pid}: pixels differ")
    if problems:
        print(f"compare: {expected} and {actual} differ:")
        for p in problems:
            print(f"  {p}")
        return 1
    print(f"compare: {len(a)} poses, the same rows and pixels in {expected} and {actual}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
