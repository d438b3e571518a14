#!/usr/bin/env bash
# Build + every test (CUDA included) + benchmarks on the GPU machine, in one go.
# Usage there (repo root, .deps carried):  bash scripts/gpu_check.sh [bench|nobench]
# Logs go to $OUT (or ./gpu_out); a summary table is printed last.
set -uo pipefail
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
OUT="${OUT:-$ROOT/gpu_out}"; mkdir -p "$OUT"
MODE="${1:-bench}"
BUILD="${GPU_BUILD_DIR:-$ROOT/build-gpu}"
PY="$(command -v python3)"
summary=()
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader | tee "$OUT/gpu.txt"
t0=$(date +%s)
cmake -S "$ROOT" -B "$BUILD" -G Ninja -DCMAKE_BUILD_TYPE=Release -DFLAT_WITH_OIIO=OFF \
  -DCMAKE_PREFIX_PATH="$ROOT/.deps/glm/usr" -DFLAT_TORCH_PYTHON="$PY" ${GPU_CMAKE_ARGS:-} >"$OUT/configure.log" 2>&1 \
  || { tail -40 "$OUT/configure.log"; echo "CONFIGURE FAILED"; exit 1; }
ninja -C "$BUILD" -k 0 ${GPU_TARGETS:-} >"$OUT/build.log" 2>&1; build_rc=$?
summary+=("build rc=$build_rc in $(( $(date +%s) - t0 )) s")
[ $build_rc -ne 0 ] && grep -E "error|FAILED" "$OUT/build.log" | head -30
(cd "$BUILD" && ctest --output-on-failure ${GPU_CTEST_ARGS:-} >"$OUT/ctest.log" 2>&1); test_rc=$?
summary+=("ctest rc=$test_rc: $(grep -E 'tests passed|tests failed' "$OUT/ctest.log" | tail -1)")
grep -E "Failed|\*\*\*|FAILED" "$OUT/ctest.log" | head -20
if [ "$MODE" = "bench" ] && [ -x "$BUILD/flat_bench" ]; then
  for sub in ${GPU_BENCHES:-decoder raster}; do
    if "$BUILD/flat_bench" "$sub" --help >/dev/null 2>&1; then
      "$BUILD/flat_bench" "$sub" --device cuda >"$OUT/bench_$sub.log" 2>&1; rc=$?
      summary+=("bench $sub rc=$rc")
      tail -25 "$OUT/bench_$sub.log"
    fi
  done
fi
echo "==== summary ($(git -C "$ROOT" rev-parse --short HEAD 2>/dev/null || echo no-git), $(date -u +%F))"
printf '%s\n' "${summary[@]}"
