#!/usr/bin/env python3
"""Table-2-style summary of flat_mesh runs (docs/inference.md): the mean over
scenes of PSNR / SSIM / LPIPS / normal cosine of the feedforward soup, the
refined soup and the opaque mesh, on the fitted and the held-out views, beside
the mean-colour oracle, and the mean mesh statistics. Standard library only.

    python3 scripts/mesh_table.py RUN_DIR [RUN_DIR ...]   (each holds metrics.json)
"""
import json
import math
import sys


def mean(values):
    values = [v for v in values if v is not None and not math.isnan(v)]
    return sum(values) / len(values) if values else float("nan")


def main(dirs):
    runs = [json.load(open(f"{d}/metrics.json")) for d in dirs]
    print(f"{len(runs)} scenes: {', '.join(r['scene'] for r in runs)}")
    print("| stage | views | triangles | PSNR | SSIM | LPIPS | normal cos | mean-colour oracle | dataset mean | swap |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for stage in ("feedforward", "refined", "mesh"):
        for split in ("fitted", "held_out"):
            rows = [r["scores"][stage][split] for r in runs if stage in r["scores"]]
            if not rows or rows[0]["views"] == 0:
                continue
            f = lambda k: mean([row.get(k) for row in rows])
            print(f"| {stage} | {split} ({rows[0]['views']}/scene) | {f('triangles'):.0f} | {f('psnr'):.2f} | "
                  f"{f('ssim'):.3f} | {f('lpips'):.3f} | {f('normal_cosine'):.3f} | {f('mean_colour_psnr'):.2f} | "
                  f"{f('dataset_mean_psnr'):.2f} | {f('swap_psnr'):.2f} |")
    stats = [r["mesh_statistics"] for r in runs if r.get("mesh_statistics")]
    if stats:
        keys = ["vertices", "faces", "degenerate_faces_pct", "isolated_faces_pct", "mean_face_neighbours",
                "non_manifold_edges_pct", "boundary_edges_pct", "connected_components"]
        print("\nmesh statistics, mean over scenes:")
        print(", ".join(f"{k} {mean([s[k] for s in stats]):.2f}" for k in keys))
    # Per scene, so that one scene's failure cannot hide in the mean.
    print("\nper scene (held-out views, or fitted when none): PSNR feedforward -> refined -> mesh")
    for r in runs:
        split = "held_out" if r["scores"]["feedforward"]["held_out"]["views"] else "fitted"
        p = [r["scores"][s][split]["psnr"] for s in ("feedforward", "refined", "mesh") if s in r["scores"]]
        print(f"  {r['scene']}: " + " -> ".join(f"{x:.2f}" for x in p))


if __name__ == "__main__":
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    main(sys.argv[1:])
