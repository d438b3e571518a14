#!/usr/bin/env bash
# README command 1: install what is missing, build, and run the main job on
# its tiny default: make synthetic rooms, encode their latents, train the tiny
# stage-1 config on the CPU for a few minutes, and show held-out PSNR before
# and after (flat_train prints it) and where the outputs are.
#
# The latents come from a RANDOM-weight Wan VAE encoder: no pretrained VAE can
# be downloaded on our machines (every output says so). Set FLAT_SMOKE_DIR to
# put the demo elsewhere (default runs/tiny); the demo's data and run folders
# are its own and are rebuilt on every call.
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
bash "$ROOT/scripts/install_deps.sh"
bash "$ROOT/scripts/build.sh"
B="${BUILD_DIR:-$ROOT/build}"
RUN="${FLAT_SMOKE_DIR:-runs/tiny}"
cd "$ROOT"
PY="${FLAT_CACHE_DIR:-$HOME/.cache/flat}/venv/bin/python3"

echo "== 1/4 synthetic rooms (ray-cast, exact depth and normals): 8 to train on, 2 held out"
rm -rf "$RUN/data"
"$B/flat_synth" --out "$RUN/data/train" --scenes 8 --seed 7 --family room --frames 17 --size 48x80 --motion mixed
"$B/flat_synth" --out "$RUN/data/val" --scenes 2 --seed 1001 --family room --frames 17 --size 48x80 --motion mixed
echo "== 2/4 latents: random-weight Wan VAE encoder (dim 16), windows of 9 frames every 4"
for split in train val; do
  "$B/flat_latents" --scenes "$RUN/data/$split" --random-weights --seed 0 --dim 16 --window 9 --step 4
done
echo "== 3/4 flat_train: configs/tiny/stage1.yaml on the CPU"
"$B/flat_train" --config configs/tiny/stage1.yaml --overwrite \
  --set "run_dir=$RUN/stage1" \
  --set "data.datasets=[{root: $RUN/data/train}]" --set "validation.datasets=[{root: $RUN/data/val}]"
echo "== 4/4 TensorBoard files against metrics/train.jsonl"
if "$PY" -c "import tensorboard" 2>/dev/null; then
  "$PY" scripts/check_tensorboard.py "$RUN/stage1/tensorboard" "$RUN/stage1/metrics/train.jsonl"
else
  echo "(the tensorboard Python package is not installed in $PY: check skipped)"
fi
echo "main job complete: $RUN/stage1 (config.yaml, logs/train.log, metrics/train.jsonl and val.jsonl,"
echo "  tensorboard/, renders/val_step_*.png, checkpoints/, model.safetensors)"
