#!/usr/bin/env bash
# Rasterizer profile on the GPU machine: per-view workload statistics, the
# per-kernel time of one step, and Nsight Compute counters of one launch of
# each kernel (middle view). Usage there: bash scripts/gpu_profile_raster.sh [paper|stage1]
set -uo pipefail
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
OUT="${OUT:-$ROOT/gpu_out}"; mkdir -p "$OUT"
SIZE="${1:-paper}"
BUILD="${GPU_BUILD_DIR:-$ROOT/build-gpu}"
cmake -S "$ROOT" -B "$BUILD" -G Ninja -DCMAKE_BUILD_TYPE=Release -DFLAT_WITH_OIIO=OFF \
  -DCMAKE_PREFIX_PATH="$ROOT/.deps/glm/usr" -DFLAT_TORCH_PYTHON="$(command -v python3)" >"$OUT/configure.log" 2>&1 \
  || { tail -40 "$OUT/configure.log"; exit 1; }
ninja -C "$BUILD" flat_bench >"$OUT/build.log" 2>&1 || { grep -E "error|FAILED" "$OUT/build.log" | head -30; exit 1; }
B="$BUILD/flat_bench"
SPDLOG_LEVEL=debug "$B" raster --workload "$SIZE" --repeats 3 --profile 2>&1 | grep -vE "raster view ([0-9]|1[0-9]|2[0-2]):" \
  | tee "$OUT/profile_$SIZE.log" | tail -40
SPDLOG_LEVEL=debug "$B" raster --workload "$SIZE" --repeats 1 2>&1 | grep "raster view" | sort -u -t: -k1,1 | head -30 >"$OUT/views_$SIZE.log"
head -30 "$OUT/views_$SIZE.log"
command -v ncu >/dev/null || { echo "no ncu"; exit 0; }
for k in preprocess_kernel raster_forward_kernel raster_backward_kernel preprocess_backward_kernel; do
  timeout 240 ncu --clock-control none -k "regex:$k" --launch-skip 12 --launch-count 1 \
    --section SpeedOfLight --section Occupancy --section LaunchStats --section WarpStateStats \
    --section SchedulerStats --section InstructionStats --section MemoryWorkloadAnalysis \
    "$B" raster --workload "$SIZE" --repeats 1 >"$OUT/ncu_$k.log" 2>&1
  echo "== $k rc=$?"
  grep -E "Duration|Compute \(SM\) Throughput|Memory Throughput|Achieved Occupancy|Theoretical Occupancy|Registers Per|Executed Ipc Active|Issue Slots Busy|No Eligible|Warp Cycles Per Issued|Avg. Active Threads Per Warp|Avg. Not Predicated|Executed Instructions  |L1/TEX Hit|L2 Hit|DRAM Throughput|Block Limit" "$OUT/ncu_$k.log" | head -30
done
