#!/usr/bin/env bash
# CPU tools side by side on the GPU machine (16 cores), before and after, in
# one call (issue #30): builds flat_synth, flat_latents and flat_train from the
# working tree (variant "base"), then with each patch of AB_PATCHES applied in
# turn, and runs scripts/bench_concurrency.sh synth and train for every variant.
# Usage there (repo root; .deps carried):
#   AB_DIR=.ab AB_PATCHES="threads" bash scripts/gpu_concurrency.sh
# CONC_SYNTH="16 96x160" (rooms, size), CONC_TRAIN_STEPS=40, CONC_GPU_TRAIN=1
# also runs two small flat_train on the GPU side by side (device=cuda).
set -uo pipefail
source "$(dirname "$0")/gpu_common.sh"  # ROOT, OUT, BUILD; gpu_card, gpu_configure, gpu_build
AB_DIR="${AB_DIR:-$ROOT/.ab}"
BIN="${CONC_BIN_DIR:-/tmp/flat_conc}"; rm -rf "$BIN"
nproc; nvidia-smi --query-gpu=name --format=csv,noheader
gpu_configure ${GPU_CMAKE_ARGS:--DFLAT_CUTLASS=OFF}
names=(base)
build_variant() {  # $1: name
  local t0; t0=$(date +%s)
  sync_mtimes "$ROOT" "$BUILD"
  gpu_build flat_synth flat_latents flat_train
  mkdir -p "$BIN/$1"; cp "$BUILD/flat_synth" "$BUILD/flat_latents" "$BUILD/flat_train" "$BIN/$1/"
  echo "== variant $1 built in $(( $(date +%s) - t0 )) s"
}
build_variant base
for p in ${AB_PATCHES:-}; do
  names+=("$p")
  patch -p1 -s -d "$ROOT" <"$AB_DIR/$p.patch" || { echo "patch $p does not apply"; exit 1; }
  build_variant "$p"
done
read -r rooms size <<<"${CONC_SYNTH:-16 96x160}"
for v in "${names[@]}"; do
  echo "== $v"
  timeout 200 bash "$ROOT/scripts/bench_concurrency.sh" synth "$BIN/$v" "$rooms" "$size" 2>&1 | tail -1
  timeout 200 bash "$ROOT/scripts/bench_concurrency.sh" latents "$BIN/$v" 2>&1 | tail -1
  timeout 200 bash "$ROOT/scripts/bench_concurrency.sh" train "$BIN/$v" "${CONC_TRAIN_STEPS:-40}" 2>&1 | tail -1
  if [ -n "${CONC_GPU_TRAIN:-}" ]; then
    DEVICE=cuda timeout 200 bash "$ROOT/scripts/bench_concurrency.sh" train "$BIN/$v" "${CONC_TRAIN_STEPS:-40}" 2>&1 | tail -1
  fi
done
