#!/usr/bin/env python3
"""Compares two triangle workloads written as PLY + cameras JSON: the anchor's
own files (../shared/bench/export_workload.py CASE DIR) and ours
(flat_bench raster --workload anchor-CASE --write-workload DIR). Prints the
largest differences of vertices, colours, opacities, sigmas and cameras; exits
1 when a difference exceeds --tol (default 0: bit-identical).

usage: compare_workload.py THEIRS.ply THEIRS_cameras.json OURS.ply OURS_cameras.json [--tol X]
"""
import argparse
import json
import sys

import numpy as np

TYPES = {"float": "<f4", "float32": "<f4", "double": "<f8", "uchar": "u1", "uint8": "u1", "int": "<i4",
         "int32": "<i4", "uint": "<u4"}


def read_ply(path):
    """Binary little-endian triangle soup -> dict of numpy arrays (face lists of exactly 3)."""
    with open(path, "rb") as f:
        data = f.read()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    elements, current = [], None
    for line in data[:end].decode().splitlines():
        w = line.split()
        if w[0] == "element":
            current = (w[1], int(w[2]), [])
            elements.append(current)
        elif w[0] == "property":
            if w[1] == "list":  # list uchar int vertex_indices: fixed count 3 in these files
                current[2].append((w[4] + "_n", TYPES[w[2]]))
                current[2].append((w[4], TYPES[w[3]], (3,)))
            else:
                current[2].append((w[2], TYPES[w[1]]))
    out, offset = {}, end
    for name, count, props in elements:
        arr = np.frombuffer(data, dtype=np.dtype(props), count=count, offset=offset)
        offset += arr.nbytes
        out[name] = arr
    v = np.stack([out["vertex"]["x"], out["vertex"]["y"], out["vertex"]["z"]], 1)
    face = out["face"]
    tris = v[face["vertex_indices"].astype(np.int64)]
    return dict(vertices=tris, colors=np.stack([face["red"], face["green"], face["blue"]], 1),
                opacity=face["opacity"], sigma=face["sigma"])


def read_cameras(path):
    cams = json.load(open(path))["cameras"]
    return dict(intrinsics=np.array([c["intrinsics"] for c in cams], np.float64),
                c2w=np.array([c["c2w"] for c in cams], np.float64),
                size=np.array([[c["width"], c["height"]] for c in cams], np.float64))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("theirs_ply")
    ap.add_argument("theirs_cams")
    ap.add_argument("ours_ply")
    ap.add_argument("ours_cams")
    ap.add_argument("--tol", type=float, default=0.0)
    a = ap.parse_args()
    t, o = read_ply(a.theirs_ply), read_ply(a.ours_ply)
    tc, oc = read_cameras(a.theirs_cams), read_cameras(a.ours_cams)
    worst = 0.0
    for name, x, y in [(k, t[k], o[k]) for k in t] + [("cameras." + k, tc[k], oc[k]) for k in tc]:
        if x.shape != y.shape:
            print(f"{name}: shapes differ {x.shape} vs {y.shape}")
            return 1
        d = np.abs(x.astype(np.float64) - y.astype(np.float64))
        differing = int((d > 0).sum())
        print(f"{name}: {x.shape}, max |difference| {d.max():.3g}, {differing} of {d.size} values differ")
        if not name.startswith("cameras."):  # float32 vs the JSON's doubles: rounding only
            worst = max(worst, float(d.max()))
    print(f"largest difference of the triangles {worst:.3g} (tolerance {a.tol:g})")
    return 0 if worst <= a.tol else 1


if __name__ == "__main__":
    sys.exit(main())
