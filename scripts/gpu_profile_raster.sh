#!/usr/bin/env bash
# Rasterizer on the anchor workload, on the GPU machine, in one go:
#   1. build flat_bench (and the render and bench tests with RASTER_TESTS=1, run
#      then: the CUDA-vs-CPU errors of docs/rasterizer.md);
#   2. if .anchor/ holds ../shared/bench/*.py (carry it): the anchor's own files
#      (export_workload.py, CUDA) against ours (--write-workload), compared
#      value by value, and our rasterizer timed on the Python file's triangles too;
#   3. flat_bench raster on the workloads: times, per-view load, GPU time per kernel;
#   4. Nsight Compute counters of one launch (middle view) of each kernel.
# Usage there (repo root, .deps and .anchor carried):
#   bash scripts/gpu_profile_raster.sh            RASTER_WORKLOADS="anchor-large anchor-small"
#   RASTER_NCU=0 skips step 4; RASTER_NCU_KERNELS picks the kernels (regexes);
#   RASTER_BENCH=0 skips step 3; RASTER_NCU_SOURCE=1 makes step 4 a stall
#   sampling report per source line instead (built with -lineinfo):
#   $OUT/ncu_source.tgz holds, per kernel, the SASS + CUDA source page as CSV;
#   with it, RASTER_NCU_DETAILS names kernels whose counters step 4 reads too.
#   RASTER_CUTLASS=ON builds the decoder's CUTLASS convs too (off: the raster
#   bench needs none of them, and they take most of the build).
set -uo pipefail
source "$(dirname "$0")/gpu_common.sh"  # ROOT, OUT, BUILD; gpu_card, gpu_configure, gpu_build
WORKLOADS="${RASTER_WORKLOADS:-anchor-large anchor-small}"
W="${RASTER_WORK_DIR:-/tmp/flat_raster_workloads}"
gpu_card
t0=$(date +%s)
targets="flat_bench"
[ "${RASTER_TESTS:-0}" = 1 ] && targets="$targets flat_test_render flat_test_bench"
gpu_configure -DFLAT_CUTLASS="${RASTER_CUTLASS:-OFF}" ${RASTER_NCU_SOURCE:+-DCMAKE_CUDA_FLAGS=-lineinfo}
sync_mtimes "$ROOT" "$BUILD"
gpu_build $targets
echo "== built $targets in $(( $(date +%s) - t0 )) s"
B="$BUILD/flat_bench"
if [ "${RASTER_TESTS:-0}" = 1 ]; then
  (cd "$BUILD" && FLAT_TEST_TMP="$BUILD/test_tmp" ./tests/flat_test_render -s 2>&1 | grep -E "cuda-vs-cpu|passed|failed" \
    >"$OUT/test_render.log"; echo "== render tests rc=${PIPESTATUS[0]}"; tail -3 "$OUT/test_render.log")
  (cd "$BUILD" && FLAT_TEST_TMP="$BUILD/test_tmp" ./tests/flat_test_bench 2>&1 | tail -2)
fi
if [ -f "$ROOT/.anchor/export_workload.py" ]; then
  rm -rf "$W"; mkdir -p "$W"
  for c in large small; do
    if echo "$WORKLOADS" | grep -q "anchor-$c"; then
      python3 "$ROOT/.anchor/export_workload.py" $c "$W/py" --device cuda 2>&1 | tail -1
      "$B" raster --workload anchor-$c --write-workload "$W/cpp" --repeats 1 >"$OUT/write_$c.log" 2>&1
      python3 "$ROOT/scripts/compare_workload.py" "$W/py/$c.ply" "$W/py/${c}_cameras.json" \
        "$W/cpp/anchor-$c.ply" "$W/cpp/anchor-${c}_cameras.json" | tee "$OUT/compare_$c.log" | tail -3
      "$B" raster --triangles "$W/py/$c.ply" --cameras "$W/py/${c}_cameras.json" 2>&1 | tail -1
      rm -rf "$W/cpp"
    fi
  done
fi
if [ "${RASTER_BENCH:-1}" = 1 ]; then
  "$B" raster --workload $WORKLOADS --repeats ${RASTER_REPEATS:-7} --profile >"$OUT/bench_raster.log" 2>&1
  echo "== bench rc=$?"; cat "$OUT/bench_raster.log" | grep -vE "^\[" | head -60
  grep -E "per view" "$OUT/bench_raster.log"
fi
[ "${RASTER_NCU:-1}" = 0 ] && exit 0
command -v ncu >/dev/null || { echo "no ncu"; exit 0; }
first=$(echo $WORKLOADS | awk '{print $1}')
if [ -n "${RASTER_NCU_SOURCE:-}" ]; then
  S=/tmp/ncu_source; rm -rf "$S"; mkdir -p "$S"
  for k in ${RASTER_NCU_KERNELS:-raster_forward_kernel raster_backward_kernel}; do
    timeout 240 ncu --clock-control none -k "regex:$k" --launch-skip 12 --launch-count 1 --import-source yes \
      --section SourceCounters --section WarpStateStats --section LaunchStats --section Occupancy \
      --section SpeedOfLight --section MemoryWorkloadAnalysis \
      -o "$S/$k" "$B" raster --workload $first --repeats 1 >"$S/$k.log" 2>&1
    echo "== $k rc=$?"
    ncu -i "$S/$k.ncu-rep" --page details >"$S/$k.details.txt" 2>&1
    ncu -i "$S/$k.ncu-rep" --page source --csv --print-source cuda,sass >"$S/$k.source.csv" 2>&1
    grep -E "Duration|Warp Cycles Per Issued|Stall|Registers Per|Achieved Occupancy|DRAM Throughput|Memory Throughput|L2 Hit|L1/TEX Hit" "$S/$k.details.txt" | head -20
  done
  tar czf "$OUT/ncu_source.tgz" -C "$S" . ; ls -la "$OUT/ncu_source.tgz"
  [ -z "${RASTER_NCU_DETAILS:-}" ] && exit 0
fi
for k in ${RASTER_NCU_DETAILS:-${RASTER_NCU_KERNELS:-raster_forward_kernel raster_backward_kernel cull_kernel screen_kernel duplicate_kernel chain_kernel Onesweep}}; do
  timeout 240 ncu --clock-control none -k "regex:$k" --launch-skip 12 --launch-count 1 \
    --section SpeedOfLight --section Occupancy --section LaunchStats --section WarpStateStats \
    --section SchedulerStats --section InstructionStats --section MemoryWorkloadAnalysis \
    "$B" raster --workload $first --repeats 1 >"$OUT/ncu_$k.log" 2>&1
  echo "== $k rc=$?"
  grep -E "Duration|Compute \(SM\) Throughput|Memory Throughput|Achieved Occupancy|Theoretical Occupancy|Registers Per|Executed Ipc Active|Issue Slots Busy|No Eligible|Warp Cycles Per Issued|Avg. Active Threads Per Warp|Avg. Not Predicated|L1/TEX Hit|L2 Hit|DRAM Throughput|Block Limit|Dynamic Shared|Static Shared" "$OUT/ncu_$k.log" | head -24
done
