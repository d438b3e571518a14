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
if [ -x "$BUILD/tests/flat_test_render" ]; then
  # The CUDA-vs-CPU errors of the rasterizer (docs/rasterizer.md, "Tolerances held").
  "$BUILD/tests/flat_test_render" "*cuda*" -s 2>&1 | grep "cuda-vs-cpu" >"$OUT/cuda_vs_cpu.log"
  summary+=("cuda-vs-cpu rasterizer comparisons: $(wc -l <"$OUT/cuda_vs_cpu.log") lines in cuda_vs_cpu.log")
fi
if [ "$MODE" = "bench" ] && [ -x "$BUILD/flat_bench" ]; then
  # Paper sizes: decoder 13 and 21 latent frames, full and streaming; raster at
  # stage-1 and paper scale (see docs/benchmarks.md).
  "$BUILD/flat_bench" decoder >"$OUT/bench_decoder.log" 2>&1; summary+=("bench decoder rc=$?")
  grep -E "median" "$OUT/bench_decoder.log" | tail -8
  "$BUILD/flat_bench" raster --size both >"$OUT/bench_raster.log" 2>&1; summary+=("bench raster rc=$?")
  tail -12 "$OUT/bench_raster.log"
fi
if [ -x "$BUILD/flat_smoke" ]; then
  # The end-to-end smoke run on the GPU: synthetic scenes, random-weight
  # latents, then flat_smoke with the CUDA rasterizer and decoder.
  S="$OUT/smoke"; rm -rf "$S"
  { "$BUILD/flat_synth" --out "$S/scenes" --scenes 2 --seed 7 --family room --frames 17 --size 48x80 --motion mixed &&
    "$BUILD/flat_latents" --scenes "$S/scenes" --random-weights --seed 0 --dim 16 --window 9 --step 4 --device cuda &&
    "$BUILD/flat_smoke" --set run_dir="$S" --set "data.datasets=[{root: $S/scenes, weight: 1.0}]" --set device=cuda; } \
    >"$OUT/smoke.log" 2>&1
  summary+=("smoke (cuda) rc=$?: $(grep -oE 'loss [0-9.]+ -> [0-9.]+' "$OUT/smoke.log" | tail -1)")
  rm -rf "$S/scenes"
fi
echo "==== summary (commit ${FLAT_COMMIT:-$(git -C "$ROOT" rev-parse --short HEAD 2>/dev/null || echo unknown)}, $(date -u +%F))"
printf '%s\n' "${summary[@]}"
