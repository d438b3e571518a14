#!/usr/bin/env bash
# Post-optimisation and mesh conversion on the GPU (issue #33, docs/inference.md):
#   chain  the triangle chain alone, decoder aside: a 96x160 synthetic room,
#          a dim-8 decoder trained 60 steps on random-encoder latents (its
#          soup is a blurry wash), then flat_mesh --refine 2000 from that soup,
#          photometric only (the paper's objective) and with the depth and
#          normal terms; every 4th frame held out;
#   paper  timing at the paper's size: 49 frames of 432x768 (4.06M
#          triangles decoded), flat_mesh with the defaults (250 refine steps,
#          then the conversion), seconds and peak memory.
# Usage on the GPU machine (repo root, .deps carried): bash scripts/gpu_mesh.sh chain|paper|all
# Logs, metrics and PNG grids go to $OUT.
set -uo pipefail
source "$(dirname "$0")/gpu_common.sh"  # ROOT, OUT, BUILD; gpu_card, gpu_configure, gpu_build
PHASE="${1:-all}"
D="$ROOT/runs/mesh"
CHAIN_STEPS="${MESH_CHAIN_STEPS:-2000}"
T0=$(date +%s)
note() { echo "[mesh $(( $(date +%s) - T0 )) s] $1" | tee -a "$OUT/notes.txt"; }
cd "$ROOT"
gpu_card

if [ ! -x "$BUILD/flat_mesh" ]; then
  gpu_configure -DFLAT_BUILD_TESTS=OFF -DFLAT_CUTLASS=OFF
  gpu_build flat_synth flat_latents flat_train flat_infer flat_mesh
  note "built"
fi
grid_png() { python3 "$ROOT/scripts/safetensors_to_png.py" "$1/renders/compare.safetensors" "$OUT/$2.png" ${3:-} >/dev/null; }
keep() {  # run folder, name[, PNG stride]: small outputs into $OUT
  for f in metrics.json summary.json mesh_stats.json mesh.log; do [ -f "$1/$f" ] && cp "$1/$f" "$OUT/$2_$f"; done
  # A build with libpng writes the grid as PNG; one without any image library as safetensors.
  if [ -f "$1/renders/compare.png" ]; then cp "$1/renders/compare.png" "$OUT/$2_compare.png"
  elif [ -f "$1/renders/compare.safetensors" ]; then grid_png "$1" "$2_compare" "${3:-}"; fi
}

if [ "$PHASE" = "chain" ] || [ "$PHASE" = "all" ]; then
  C="$D/chain"; rm -rf "$C"; mkdir -p "$C"
  "$BUILD/flat_synth" --out "$C/data" --count 1 --seed 11 --family room --frames 17 --size 96x160 --motion mixed \
    --log-level warn >"$OUT/chain_synth.log" 2>&1
  "$BUILD/flat_latents" --scenes "$C/data" --random-weights --dim 8 --window 17 --device cuda >"$OUT/chain_latents.log" 2>&1
  "$BUILD/flat_train" --config configs/tiny/stage1.yaml --set run_dir="$C/model" --set steps=60 --set device=cuda \
    --set init.from=scratch --set "init.path=''" --set optim.warmup_steps=5 --set checkpoint.every=60 \
    --set "data.datasets=[{root: $C/data}]" --set "validation.datasets=[{root: $C/data}]" --set validation.every=60 \
    --set validation.scenes=1 --set data.height=96 --set data.width=160 --set data.input_frames=17 \
    >"$OUT/chain_train.log" 2>&1
  note "chain model: rc=$? $(grep -oE 'held-out PSNR.*' "$OUT/chain_train.log" | tail -1 | cut -c1-160)"
  "$BUILD/flat_infer" --model "$C/model" --scene "$C/data/room_000000" --out "$C/infer" --no-video --novel none \
    --device cuda >"$OUT/chain_infer.log" 2>&1
  note "chain infer rc=$?: $(grep -E 'triangles' "$OUT/chain_infer.log" | tail -1)"
  "$BUILD/flat_mesh" --from "$C/infer" --out "$C/photometric" --refine "$CHAIN_STEPS" --device cuda \
    >"$OUT/chain_photometric.txt" 2>&1
  note "chain photometric rc=$?"; keep "$C/photometric" chain_photometric
  cp "$C/photometric/mesh.glb" "$C/photometric/mesh.ply" "$C/photometric/mesh.obj" "$OUT/" 2>/dev/null
  "$BUILD/flat_mesh" --from "$C/infer" --out "$C/geometric" --refine "$CHAIN_STEPS" --device cuda \
    --lambda-depth 0.1 --lambda-normal 0.1 >"$OUT/chain_geometric.txt" 2>&1
  note "chain with depth+normal terms rc=$?"; keep "$C/geometric" chain_geometric
  tail -12 "$OUT/chain_photometric.txt" "$OUT/chain_geometric.txt"
fi

if [ "$PHASE" = "paper" ] || [ "$PHASE" = "all" ]; then
  P="$D/paper"; rm -rf "$P"; mkdir -p "$P"
  [ -d "$D/chain/model" ] || { echo "paper: needs the chain model (run chain first on this machine)"; exit 1; }
  "$BUILD/flat_synth" --out "$P/data" --count 1 --seed 12 --family room --frames 49 --size 432x768 --motion mixed \
    --log-level warn >"$OUT/paper_synth.log" 2>&1
  note "paper data rc=$?"
  "$BUILD/flat_latents" --scenes "$P/data" --random-weights --dim 8 --window 49 --device cuda >"$OUT/paper_latents.log" 2>&1
  "$BUILD/flat_infer" --model "$D/chain/model" --scene "$P/data/room_000000" --out "$P/infer" --no-video --novel none \
    --no-renders --no-viewer --prune-opacity 0 --device cuda >"$OUT/paper_infer.log" 2>&1
  note "paper infer rc=$?: $(grep -E 'triangles' "$OUT/paper_infer.log" | tail -1)"
  "$BUILD/flat_mesh" --from "$P/infer" --out "$P/mesh" --device cuda --no-viewer >"$OUT/paper_mesh.txt" 2>&1
  note "paper mesh rc=$?"; keep "$P/mesh" paper 2  # the full-size grid is 17 MB
  tail -14 "$OUT/paper_mesh.txt"
fi
cat "$OUT/notes.txt"
