#!/usr/bin/env bash
# One device call for the 3DGS / 2DGS rasterizers (issue #34): build, their
# CUDA-vs-CPU tests, flat_bench raster on the anchor workloads with the three
# primitives (triangles, 3dgs, 2dgs: the same scene, primitives/triangle_gaussians.h),
# and the anchor gsplat on the same Gaussians (scripts/bench_gsplat.py), built
# from its PyPI wheel in the background while ours compiles.
# Usage on the GPU machine (repo root; .deps carried, .deps/wheels holding the
# gsplat wheel and its pure-Python dependencies): bash scripts/gpu_gaussians.sh
# A failed install of those wheels, or a gsplat that does not build, exits 1
# with the log's tail (SKIP_GSPLAT=1: ours only).
# Logs and tables go to $OUT; GPU_BUILD_DIR is shared with scripts/gpu_recipe.sh.
set -uo pipefail
source "$(dirname "$0")/gpu_common.sh"  # ROOT, OUT, BUILD; gpu_card, gpu_configure, gpu_build
T0=$(date +%s)
say() { echo "[gaussians $(( $(date +%s) - T0 )) s] $*"; }
cd "$ROOT"
gpu_card

GS_PID=""
if [ -d "$ROOT/.deps/wheels" ] && [ "${SKIP_GSPLAT:-0}" != 1 ]; then
  # The carried wheels are gsplat and its pure-Python dependencies; numpy and
  # torch are the machine's. A resolving install fails where numpy is not among
  # the wheels, so they go in as they are (--no-deps). In the foreground: a
  # failed install stops the script here, loudly, not after the GPU work.
  shopt -s nullglob
  WHEELS=("$ROOT"/.deps/wheels/*.whl)
  shopt -u nullglob
  if [ "${#WHEELS[@]}" -eq 0 ]; then
    echo "gpu_gaussians: no .whl files in $ROOT/.deps/wheels (SKIP_GSPLAT=1 runs without the gsplat anchor)" >&2
    exit 1
  fi
  if ! pip install --no-deps --no-index --target /tmp/gsplat_py "${WHEELS[@]}" >"$OUT/gsplat_install.log" 2>&1; then
    echo "gpu_gaussians: installing the ${#WHEELS[@]} carried wheels failed (pip install --no-deps; log:" \
      "$OUT/gsplat_install.log); SKIP_GSPLAT=1 runs without the gsplat anchor:" >&2
    tail -20 "$OUT/gsplat_install.log" >&2
    exit 1
  fi
  say "gsplat wheels installed (${#WHEELS[@]})"
  # gsplat compiles its CUDA extension on first import: in the background while ours builds.
  (
    export PATH=/tmp/gsplat_py/bin:$PATH PYTHONPATH=/tmp/gsplat_py MAX_JOBS=${GSPLAT_JOBS:-6} TORCH_CUDA_ARCH_LIST=9.0
    python3 -c "import sys, gsplat; from gsplat.cuda._backend import _C
print('gsplat', gsplat.__version__, 'built:', _C is not None); sys.exit(0 if _C is not None else 1)"
  ) >"$OUT/gsplat_build.log" 2>&1 &
  GS_PID=$!
fi

# BENCH_ONLY=1: flat_bench is built already (scripts/gpu_vae.sh prep with
# RASTER_BENCH=1), the tests run elsewhere: the benchmarks alone.
if [ "${BENCH_ONLY:-0}" != 1 ]; then
  gpu_configure -DFLAT_BUILD_TESTS=ON -DFLAT_CUTLASS=OFF
  # GPU_TESTS: the suites whose [cuda] cases run (default: the two Gaussian rasterizers).
  read -r -a SUITES <<< "${GPU_TESTS:-flat_test_gaussians flat_test_surfels}"
  gpu_build -j "${BUILD_JOBS:-12}" "${SUITES[@]}" flat_bench
  say "built"
  for n in "${SUITES[@]}"; do
    t="$(find "$BUILD" -name "$n" -type f | head -1)"
    timeout 240 "$t" "[cuda]" >"$OUT/$n.log" 2>&1; echo "$n [cuda]: rc=$? $(grep -E 'passed|failed' "$OUT/$n.log" | tail -1)"
    grep -E -A6 "FAILED" "$OUT/$n.log" | head -40
  done
  say "tests done"
fi
# SPLAT_TILE_AB=8: the 3DGS / 2DGS kernels with 8 x 8 tiles (-DFLAT_SPLAT_TILE_SIZE=8,
# a second build folder, built in the background from here), their [cuda]
# tests and timings after the shipped ones, on the same GPU.
AB_PID=""; AB_BUILD="$BUILD-tile${SPLAT_TILE_AB:-}"
if [ -n "${SPLAT_TILE_AB:-}" ]; then
  ( BUILD="$AB_BUILD" gpu_cmake -DFLAT_BUILD_TESTS=ON -DFLAT_CUTLASS=OFF -DFLAT_SPLAT_TILE_SIZE="$SPLAT_TILE_AB" &&
      ninja -C "$AB_BUILD" -j "${BUILD_JOBS:-12}" flat_bench flat_test_gaussians flat_test_surfels ) \
    >"$OUT/build_tile$SPLAT_TILE_AB.log" 2>&1 &
  AB_PID=$!
fi
# PROFILE_GPU=k: GPU time per kernel of one forward+backward step of each
# primitive (flat_bench raster --profile) on GPU k, beside the timings.
PROF_PID=""
if [ -n "${PROFILE_GPU:-}" ]; then
  CUDA_VISIBLE_DEVICES=$PROFILE_GPU timeout "${BENCH_SECONDS:-200}" "$BUILD/flat_bench" raster --device cuda \
    --workload ${WORKLOADS:-anchor-large anchor-small} --primitives triangles 3dgs 2dgs --repeats 1 --profile \
    >"$OUT/bench_profile.log" 2>&1 &
  PROF_PID=$!
fi
timeout "${BENCH_SECONDS:-200}" "$BUILD/flat_bench" raster --device cuda --workload ${WORKLOADS:-anchor-large anchor-small} \
  --primitives triangles 3dgs 2dgs --repeats "${RASTER_REPEATS:-5}" >"$OUT/bench_raster.log" 2>&1
echo "flat_bench raster rc=$?"; grep -E "^\|" "$OUT/bench_raster.log"; grep -E "error" "$OUT/bench_raster.log" | head -5
say "ours timed"
[ -n "$PROF_PID" ] && { wait "$PROF_PID"; echo "flat_bench raster --profile rc=$?"; }
if [ -n "$AB_PID" ]; then
  if wait "$AB_PID"; then
    say "tile-$SPLAT_TILE_AB variant built"
    for n in flat_test_gaussians flat_test_surfels; do
      timeout 240 "$AB_BUILD/tests/$n" "[cuda]" >"$OUT/${n}_tile$SPLAT_TILE_AB.log" 2>&1
      echo "$n [cuda], tiles of $SPLAT_TILE_AB: rc=$? $(grep -E 'passed|failed' "$OUT/${n}_tile$SPLAT_TILE_AB.log" | tail -1)"
    done
    timeout "${BENCH_SECONDS:-200}" "$AB_BUILD/flat_bench" raster --device cuda --workload ${WORKLOADS:-anchor-large anchor-small} \
      --primitives 3dgs 2dgs --repeats "${RASTER_REPEATS:-5}" >"$OUT/bench_raster_tile$SPLAT_TILE_AB.log" 2>&1
    echo "flat_bench raster, tiles of $SPLAT_TILE_AB: rc=$?"; grep -E "^\|" "$OUT/bench_raster_tile$SPLAT_TILE_AB.log"
    # The shipped build once more after it: both variants timed in the same minutes.
    timeout "${BENCH_SECONDS:-200}" "$BUILD/flat_bench" raster --device cuda --workload ${WORKLOADS:-anchor-large anchor-small} \
      --primitives 3dgs 2dgs --repeats "${RASTER_REPEATS:-5}" >"$OUT/bench_raster_again.log" 2>&1
    echo "flat_bench raster, shipped again: rc=$?"; grep -E "^\|" "$OUT/bench_raster_again.log"
  else
    echo "the tile-$SPLAT_TILE_AB variant did not build:"; grep -E "error|FAILED" "$OUT/build_tile$SPLAT_TILE_AB.log" | head -20
  fi
fi
if [ -n "$GS_PID" ]; then
  if ! wait "$GS_PID"; then
    echo "gpu_gaussians: gsplat did not build or import (log: $OUT/gsplat_build.log); the anchor did not run:" >&2
    tail -20 "$OUT/gsplat_build.log" >&2
    exit 1
  fi
  tail -3 "$OUT/gsplat_build.log"
  say "gsplat built"
  PATH=/tmp/gsplat_py/bin:$PATH PYTHONPATH=/tmp/gsplat_py FLAT_SHARED_BENCH="$ROOT/shared_bench" \
    timeout "${GSPLAT_SECONDS:-150}" python3 scripts/bench_gsplat.py --repeats "${RASTER_REPEATS:-5}" >"$OUT/bench_gsplat.log" 2>&1
  echo "bench_gsplat rc=$?"; grep -E "^\||gsplat|Error|error" "$OUT/bench_gsplat.log" | head -12
fi
say "done"
