#!/usr/bin/env bash
# Configures and builds FLAT-C++ (CPU machine: CUDA compiled, not run).
#   BUILD_DIR (default build), FLAT_JOBS (default: all cores), FLAT_BUILD_TARGETS
#   (default: everything; e.g. "flat_train flat_eval" builds those and what they
#   need), extra cmake args.
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
BUILD_DIR="${BUILD_DIR:-$ROOT/build}"
CACHE="${FLAT_CACHE_DIR:-$HOME/.cache/flat}"
JOBS="${FLAT_JOBS:-$(nproc)}"
cmake -S "$ROOT" -B "$BUILD_DIR" -G Ninja -DCMAKE_BUILD_TYPE=Release \
  -DFLAT_TORCH_PYTHON="$CACHE/venv/bin/python3" "$@"
start=$(date +%s)
if [ -n "${FLAT_BUILD_TARGETS:-}" ]; then
  # shellcheck disable=SC2086
  cmake --build "$BUILD_DIR" -j "$JOBS" --target $FLAT_BUILD_TARGETS
else
  cmake --build "$BUILD_DIR" -j "$JOBS"
fi
echo "[build] built in $(( $(date +%s) - start )) s with $JOBS jobs"
