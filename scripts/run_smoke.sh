#!/usr/bin/env bash
# README command 1: install what is missing, build, and run the main job on
# the tiny embedded default. Until the staged trainer exists the main job is
# flat_smoke: a few AdamW steps through the whole pipeline (loader -> scene
# decoder -> ray-centred triangles -> rasterizer -> losses), on synthetic
# scenes made here, with random-weight latents (no pretrained VAE can be
# downloaded on our machines; every output says so).
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
bash "$ROOT/scripts/install_deps.sh"
bash "$ROOT/scripts/build.sh"
B="${BUILD_DIR:-$ROOT/build}"
RUN="${FLAT_SMOKE_DIR:-$ROOT/runs/smoke}"
cd "$ROOT"

echo "== 1/4 synthetic scenes (ray-cast rooms with exact depth and normals)"
"$B/flat_synth" --out "$RUN/scenes" --scenes 2 --seed 7 --family room --frames 17 --size 48x80 --motion mixed
echo "== 2/4 latents: random-weight Wan VAE encoder (dim 16), windows of 9 frames every 4"
"$B/flat_latents" --scenes "$RUN/scenes" --random-weights --seed 0 --dim 16 --window 9 --step 4
echo "== 3/4 flat_smoke: optimisation steps through the whole pipeline"
"$B/flat_smoke" --set run_dir="$RUN" --set "data.datasets=[{root: $RUN/scenes, weight: 1.0}]"
echo "== 4/4 flat_render: re-render the exported triangle soup into the same views"
"$B/flat_render" --triangles "$RUN/triangles.ply" --cameras "$RUN/cameras.json" --out "$RUN/rerender" --format safetensors
echo "smoke run complete: $RUN (config.yaml, logs/, metrics/smoke.json, renders/, triangles.ply, rerender/)"
