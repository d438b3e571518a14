#!/usr/bin/env python3
"""The anchor of `flat_bench raster --primitives 3dgs|2dgs`: gsplat's own
rasterizers (gsplat.rasterization, gsplat.rasterization_2dgs) timed on the
same scene, in the same process layout as flat_bench (all target views in one
call, 2 warm-ups, median of N).

The scene: the anchor's triangles (../shared/bench/raster_workload.py, the
file flat_bench's anchor workloads reproduce), each turned into one Gaussian
by the rule of src/primitives/triangle_gaussians.cpp (centroid; axes e1 =
normalize(v1 - v0), e2 = n x e1, n; standard deviation = inradius in-plane,
0.1 inradius along n for 3DGS). Forward: rgb + alpha + accumulated depth
(gsplat "RGB+D"; 2DGS also normals and distortion); backward of
sum(rgb * w) + sum(alpha) + 0.1 sum(depth) (+ normals + distortion for 2DGS),
the loss flat_bench uses.

This is a benchmark script for the device, not part of the product.
Usage: python3 scripts/bench_gsplat.py [--case large small] [--kind 3dgs 2dgs] [--repeats 5]
"""
import argparse
import math
import os
import sys
import time

import torch

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.environ.get("FLAT_SHARED_BENCH", os.path.join(HERE, "..", "..", "shared", "bench")))
from raster_workload import make_case  # noqa: E402


def matrix_to_quaternion(R):
    """(N,3,3) rotations -> (N,4) unit (w,x,y,z), w >= 0 (as src/primitives/ray_anchors.cpp)."""
    half = lambda t: 0.5 * torch.sqrt(t.clamp_min(0))
    r = lambda i, j: R[:, i, j]
    w = half(1 + r(0, 0) + r(1, 1) + r(2, 2))
    x = torch.copysign(half(1 + r(0, 0) - r(1, 1) - r(2, 2)), r(2, 1) - r(1, 2))
    y = torch.copysign(half(1 - r(0, 0) + r(1, 1) - r(2, 2)), r(0, 2) - r(2, 0))
    z = torch.copysign(half(1 - r(0, 0) - r(1, 1) + r(2, 2)), r(1, 0) - r(0, 1))
    q = torch.stack([w, x, y, z], -1)
    return q / q.norm(dim=-1, keepdim=True).clamp_min(1e-12)


def gaussians_from_triangles(verts):
    v0, v1, v2 = verts.unbind(1)
    a, b = v1 - v0, v2 - v0
    cr = torch.linalg.cross(a, b)
    twice_area = cr.norm(dim=-1)
    inradius = twice_area / (a.norm(dim=-1) + b.norm(dim=-1) + (v2 - v1).norm(dim=-1))
    e1 = a / a.norm(dim=-1, keepdim=True)
    n = cr / twice_area[:, None]
    e2 = torch.linalg.cross(n, e1)
    quats = matrix_to_quaternion(torch.stack([e1, e2, n], -1))
    scales = torch.stack([inradius, inradius, 0.1 * inradius], -1)
    return verts.mean(1), quats, scales


def cameras(w):
    cams, H, W = w["cams"], None, None
    R = cams["R_c2w"][w["targets"]]
    C = cams["C"][w["targets"]]
    V = R.shape[0]
    viewmats = torch.eye(4, device=R.device).repeat(V, 1, 1)
    viewmats[:, :3, :3] = R.transpose(1, 2)
    viewmats[:, :3, 3] = -(R.transpose(1, 2) @ C[:, :, None])[:, :, 0]
    return viewmats


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--case", nargs="+", default=["large", "small"])
    ap.add_argument("--kind", nargs="+", default=["3dgs", "2dgs"])
    ap.add_argument("--repeats", type=int, default=5)
    a = ap.parse_args()
    import gsplat

    dev = "cuda"
    print(f"gsplat {gsplat.__version__}, torch {torch.__version__}, {torch.cuda.get_device_name()}")
    print("| workload | primitives | count | views | HxW | rasterizer | forward ms | fwd+bwd ms | peak GiB |")
    print("|---|---|---|---|---|---|---|---|---|")
    from raster_workload import CASES
    for case in a.case:
        w = make_case(case, dev)
        H, Wd = CASES[case]["height"], CASES[case]["width"]
        f = w["cams"]["f"]
        means, quats, scales = gaussians_from_triangles(w["verts"])
        colors, opac = w["colors"], w["opacity"][:, 0]
        viewmats = cameras(w)
        V = viewmats.shape[0]
        # The anchor's pixel centres are integers (principal point (W-1)/2);
        # gsplat's are at +0.5: the same rays need cx = W/2.
        K = torch.tensor([[f, 0, Wd / 2.0], [0, f, H / 2.0], [0, 0, 1]], device=dev).repeat(V, 1, 1)
        wrgb = torch.rand(V, H, Wd, 3, device=dev)
        for kind in a.kind:
            def render(m, q, s, c, o):
                if kind == "3dgs":
                    img, alpha, _ = gsplat.rasterization(m, q, s, o, c, viewmats, K, Wd, H, near_plane=0.01,
                                                         render_mode="RGB+D")
                    return (img[..., :3] * wrgb).sum() + alpha.sum() + 0.1 * img[..., 3].sum()
                # Its "RGB+D" mode appends per-camera depths: colours per camera too.
                out = gsplat.rasterization_2dgs(m, q, s, o, c.expand(V, -1, -1), viewmats, K, Wd, H,
                                                near_plane=0.01, render_mode="RGB+D")
                img, alpha, normals, _, distort = out[0], out[1], out[2], out[3], out[4]
                return ((img[..., :3] * wrgb).sum() + alpha.sum() + 0.1 * img[..., 3].sum() + normals.sum()
                        + distort.sum())
            fwd, both, peak = [], [], 0.0
            for it in range(a.repeats + 2):
                torch.cuda.synchronize()
                torch.cuda.reset_peak_memory_stats()
                t0 = time.perf_counter()
                with torch.no_grad():
                    render(means, quats, scales, colors, opac)
                torch.cuda.synchronize()
                t1 = time.perf_counter()
                leaves = [x.detach().requires_grad_(True) for x in (means, quats, scales, colors, opac)]
                torch.cuda.synchronize()
                t2 = time.perf_counter()
                render(*leaves).backward()
                torch.cuda.synchronize()
                t3 = time.perf_counter()
                peak = max(peak, torch.cuda.max_memory_allocated() / 2**30)
                if it >= 2:
                    fwd.append((t1 - t0) * 1e3)
                    both.append((t3 - t2) * 1e3)
            med = lambda v: sorted(v)[len(v) // 2]
            print(f"| anchor-{case} | {kind} | {means.shape[0]} | {V} | {H}x{Wd} | gsplat {gsplat.__version__} | "
                  f"{med(fwd):.2f} | {med(both):.2f} | {peak:.2f} |", flush=True)


if __name__ == "__main__":
    main()
