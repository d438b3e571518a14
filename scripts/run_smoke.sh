#!/usr/bin/env bash
# README command 1: install what is missing, build, and run the paper's
# pipeline in miniature on the CPU, on rooms it never trained on:
#   synthetic rooms -> VAE stage (a Wan 2.1 VAE of our own, trained on the
#   training rooms' frames) -> latents from the trained encoder -> stage 1 with
#   the decoder initialised from the trained VAE -> flat_eval on the held-out
#   rooms, every score beside the baselines that ignoring the input reaches.
# No pretrained Wan weights can be had on our machines: the VAE stage is what
# makes the latents carry each room (a random encoder's latents are nearly the
# same for every room). Set FLAT_SMOKE_DIR to put the demo elsewhere (default
# runs/tiny); its data and run folders are its own and rebuilt on every call.
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
# --demo: the build's libraries and libtorch only (not the exports' readers and
# players, which the test suite, README command 2, installs).
bash "$ROOT/scripts/install_deps.sh" --demo
# What the demo runs (the test suite is README command 2; flat_infer for
# README's next commands: cmake --build build --target flat_infer; every tool:
# --target flat_tools). flat_infer's own modules (infer, mesh, export) are
# about 140 s of this machine's 2 cores.
# Without a visible GPU the CUTLASS Hopper convolutions (a decoder speed-up for
# sm_90 only, about 4 minutes of one core to compile) can never run: left out.
# The choice is stored in the build folder's cache: with a GPU it is made again.
cutlass=(-DFLAT_CUTLASS=ON)
if ! nvidia-smi -L >/dev/null 2>&1; then
  cutlass=(-DFLAT_CUTLASS=OFF)
  echo "no GPU visible: building without the CUTLASS Hopper convolutions (scripts/build.sh -DFLAT_CUTLASS=ON adds them)"
fi
# A unity build (each module's sources compiled as a few combined files): the
# four tools in about half the time on 2 cores, the libtorch templates being
# instantiated once per batch instead of once per file. The test suite
# (README command 2) builds file by file again (-DCMAKE_UNITY_BUILD=OFF), so
# each test file stays its own translation unit.
FLAT_BUILD_TARGETS="${FLAT_BUILD_TARGETS:-flat_synth flat_latents flat_train flat_eval}" \
  bash "$ROOT/scripts/build.sh" "${cutlass[@]}" -DCMAKE_UNITY_BUILD=ON -DCMAKE_UNITY_BUILD_BATCH_SIZE=16
B="${BUILD_DIR:-$ROOT/build}"
RUN="${FLAT_SMOKE_DIR:-runs/tiny}"
cd "$ROOT"
PY="${FLAT_CACHE_DIR:-$HOME/.cache/flat}/venv/bin/python3"
T0=$(date +%s)
stamp() { echo "   ($(( $(date +%s) - T0 )) s since the demo started)"; }

echo "== 1/6 synthetic rooms (ray-cast, exact depth and normals): 48 to train on, 8 held out"
rm -rf "$RUN/data"
"$B/flat_synth" --out "$RUN/data/train" --count 48 --seed 7 --family room --frames 17 --size 48x80 --motion mixed
"$B/flat_synth" --out "$RUN/data/val" --count 8 --seed 1001 --family room --frames 17 --size 48x80 --motion mixed
stamp
echo "== 2/6 VAE stage: a dim-8 Wan 2.1 VAE trained on the training rooms' frames, single frames first"
echo "   (configs/tiny/vae_image.yaml), then windows of 5 frames (configs/tiny/vae.yaml)"
"$B/flat_train" --config configs/tiny/vae_image.yaml --overwrite \
  --set "run_dir=$RUN/vae_image" \
  --set "data.datasets=[{root: $RUN/data/train}]" --set "validation.datasets=[{root: $RUN/data/val}]"
"$B/flat_train" --config configs/tiny/vae.yaml --overwrite \
  --set "run_dir=$RUN/vae" --set "init.path=$RUN/vae_image" \
  --set "data.datasets=[{root: $RUN/data/train}]" --set "validation.datasets=[{root: $RUN/data/val}]"
stamp
echo "== 3/6 latents from the trained encoder (windows of 9 frames every 4)"
for split in train val; do
  "$B/flat_latents" --scenes "$RUN/data/$split" --vae "$RUN/vae/vae.safetensors" --window 9 --step 4
done
stamp
echo "== 4/6 stage 1: configs/tiny/stage1.yaml, the scene decoder initialised from the trained VAE's decoder"
"$B/flat_train" --config configs/tiny/stage1.yaml --overwrite \
  --set "run_dir=$RUN/stage1" --set "init.path=$RUN/vae/vae.safetensors" \
  --set "data.datasets=[{root: $RUN/data/train}]" --set "validation.datasets=[{root: $RUN/data/val}]"
stamp
echo "== 5/6 flat_eval on the 8 held-out rooms (every frame), with the baselines"
rm -rf "$RUN/eval"
"$B/flat_eval" --model "$RUN/stage1" --scenes "heldout=$RUN/data/val" --out "$RUN/eval" --device cpu
cat "$RUN/eval/table.md"
stamp
echo "== 6/6 TensorBoard files against metrics/train.jsonl"
if "$PY" -c "import tensorboard" 2>/dev/null; then
  "$PY" scripts/check_tensorboard.py "$RUN/stage1/tensorboard" "$RUN/stage1/metrics/train.jsonl"
else
  echo "(the tensorboard Python package is not installed in $PY: check skipped)"
fi
echo "main job complete in $(( $(date +%s) - T0 )) s: $RUN/vae (vae.safetensors, renders/), $RUN/stage1 (config.yaml,"
echo "  logs/train.log, metrics/*.jsonl, tensorboard/, renders/val_step_*.png, checkpoints/, model.safetensors),"
echo "  $RUN/eval (table.md, results.json, scenes.csv)"
echo "next: cmake --build ${B#"$ROOT"/} --target flat_infer, then README's \"Inference and evaluation\""
