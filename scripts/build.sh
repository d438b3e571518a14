#!/usr/bin/env bash
# Configures and builds FLAT-C++ (CPU machine: CUDA compiled, not run).
#   BUILD_DIR (default build), FLAT_JOBS (default: all cores), extra cmake args.
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
BUILD_DIR="${BUILD_DIR:-$ROOT/build}"
CACHE="${FLAT_CACHE_DIR:-$HOME/.cache/flat}"
JOBS="${FLAT_JOBS:-$(nproc)}"
cmake -S "$ROOT" -B "$BUILD_DIR" -G Ninja -DCMAKE_BUILD_TYPE=Release \
  -DFLAT_TORCH_PYTHON="$CACHE/venv/bin/python3" "$@"
start=$(date +%s)
cmake --build "$BUILD_DIR" -j "$JOBS"
echo "[build] built in $(( $(date +%s) - start )) s with $JOBS jobs"
