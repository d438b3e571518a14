#!/usr/bin/env python3
"""A preview grid that a build without OpenImageIO wrote as safetensors
(core/image_io.h, write_preview_image: tensor "grid", (3,H,W) float32 in
[0,1]) as an 8-bit PNG, with the standard library and numpy only.

    python3 scripts/safetensors_to_png.py GRID.safetensors [OUT.png [STRIDE]]

STRIDE > 1 keeps every STRIDE-th row and column (a smaller file).
"""
import json
import struct
import sys
import zlib

import numpy as np


def read_grid(path):
    with open(path, "rb") as f:
        n = struct.unpack("<Q", f.read(8))[0]
        header = json.loads(f.read(n))
        data = f.read()
    info = header["grid"]
    if info["dtype"] != "F32":
        raise SystemExit(f"{path}: grid is {info['dtype']}, expected F32")
    a, b = info["data_offsets"]
    return np.frombuffer(data[a:b], dtype="<f4").reshape(info["shape"])


def write_png(path, chw):
    img = (np.clip(chw, 0, 1) * 255 + 0.5).astype(np.uint8).transpose(1, 2, 0)
    h, w, _ = img.shape
    raw = b"".join(b"\x00" + img[y].tobytes() for y in range(h))

    def chunk(kind, body):
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body) & 0xFFFFFFFF)

    png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
    png += chunk(b"IDAT", zlib.compress(raw, 9)) + chunk(b"IEND", b"")
    with open(path, "wb") as f:
        f.write(png)


if __name__ == "__main__":
    src = sys.argv[1]
    dst = sys.argv[2] if len(sys.argv) > 2 else src.rsplit(".", 1)[0] + ".png"
    stride = int(sys.argv[3]) if len(sys.argv) > 3 else 1
    write_png(dst, read_grid(src)[:, ::stride, ::stride])
    print(dst)
