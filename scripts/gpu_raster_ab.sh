#!/usr/bin/env bash
# Same-run A/B of rasterizer changes on the GPU machine, in one call:
#   1. build flat_bench from the working tree (variant 0), then apply each
#      patch of AB_PATCHES in turn (cumulatively: variant i = variant i-1 +
#      patch i), rebuilding flat_bench and keeping a copy of each binary;
#   2. with RASTER_TESTS=1, build the render and bench tests at the last
#      variant and run them (the CUDA-vs-CPU errors of docs/rasterizer.md);
#      RASTER_TESTS=each runs them at every variant;
#   3. time every variant AB_ROUNDS times, interleaved (0 1 2 .. 0 1 2 ..), on
#      the anchor workloads, then one --profile run each (GPU ms per kernel);
#   4. with AB_NCU=1, Nsight Compute's stall sampling per source line of the
#      last variant's forward and backward kernels (one launch, view 12 of
#      the first workload; the build then has -lineinfo), in the archive.
# Usage there (repo root; .deps/glm and the patch folder carried):
#   AB_DIR=.ab AB_PATCHES="fuse prefetch" bash scripts/gpu_raster_ab.sh
# A patch is AB_DIR/NAME.patch (git diff format, applied with patch -p1).
# Output: a summary at the end (times, profiles, test result) and every log
# in $OUT/ab_logs.tgz (the device tool returns at most 8 files).
set -uo pipefail
source "$(dirname "$0")/gpu_common.sh"  # ROOT, OUT, BUILD; gpu_card, gpu_configure, gpu_build
source "$ROOT/scripts/ab_variants.sh"  # AB_DIR, names; ab_setup, ab_build_bench, ab_patch_variants
ab_setup ab 2  # BIN, ROUNDS
WORKLOADS="${RASTER_WORKLOADS:-anchor-large anchor-small}"
gpu_configure -DFLAT_CUTLASS=OFF ${AB_NCU:+-DCMAKE_CUDA_FLAGS=-lineinfo}
run_tests() {  # $1: index
  gpu_build flat_test_render flat_test_bench
  (cd "$BUILD" && FLAT_TEST_TMP="$BUILD/test_tmp" ./tests/flat_test_render -s 2>&1 | grep -E "cuda-vs-cpu|passed|failed|FAILED" \
    >"$OUT/test_render_$1.log"; echo "== render tests (variant $1) rc=${PIPESTATUS[0]}"; tail -1 "$OUT/test_render_$1.log")
  (cd "$BUILD" && FLAT_TEST_TMP="$BUILD/test_tmp" ./tests/flat_test_bench 2>&1 | tail -1)
}
build_variant() {  # $1: index
  ab_build_bench "$1"
  [ "${RASTER_TESTS:-0}" = each ] && run_tests "$1"
}
build_variant 0
ab_patch_variants build_variant
[ "${RASTER_TESTS:-0}" = 1 ] && run_tests "$i"
for r in $(seq 1 "$ROUNDS"); do
  for v in $(seq 0 $i); do
    "$BIN/flat_bench_$v" raster --workload $WORKLOADS --repeats "${RASTER_REPEATS:-5}" >"$OUT/bench_${v}_$r.log" 2>&1 \
      || { echo "variant $v failed:"; tail -5 "$OUT/bench_${v}_$r.log"; }
    grep -E "^\| anchor|^\| paper|^\| stage1" "$OUT/bench_${v}_$r.log" | sed "s/^/v$v r$r /" >>"$OUT/ab.log"
  done
done
for v in $(seq 0 $i); do
  "$BIN/flat_bench_$v" raster --workload $WORKLOADS --repeats 1 --profile 2>&1 | grep -vE "^\[" >"$OUT/profile_$v.log"
done
echo "== variants: ${names[*]}"
grep -h "per view" "$OUT"/bench_0_1.log | cut -c1-220
echo "== fwd / fwd+bwd ms (columns: variant, round, workload, fwd, fwd+bwd, peak)"
awk -F'|' '{split($1, a, " "); printf "%s %s %-13s %7s %7s %5s\n", a[1], a[2], $2, $10, $11, $12}' "$OUT/ab.log"
for v in $(seq 0 $i); do
  echo "== profile variant $v (${names[$v]})"; grep -E "profile|GPU timeline|^  +[0-9.]+  (fwd|bwd) |raster_|chain|radix|screen|cull|gather|rank|duplicate|ordered|Scan|Reduce|Select" "$OUT/profile_$v.log" | head -40
done
for v in $(seq 0 $i); do
  [ -f "$OUT/test_render_$v.log" ] && { echo "== render tests, variant $v:"; grep -E "passed|failed|FAILED" "$OUT/test_render_$v.log" | tail -3; }
done
if [ -n "${AB_NCU:-}" ] && command -v ncu >/dev/null; then
  first=$(echo $WORKLOADS | awk '{print $1}')
  for k in raster_forward_kernel raster_backward_kernel; do
    timeout 240 ncu --clock-control none -k "regex:$k" --launch-skip 12 --launch-count 1 --import-source yes \
      --section SourceCounters --section WarpStateStats --section LaunchStats --section Occupancy \
      --section SpeedOfLight --section MemoryWorkloadAnalysis \
      -o "$OUT/ncu_$k" "$BIN/flat_bench_$i" raster --workload $first --repeats 1 >"$OUT/ncu_$k.log" 2>&1
    ncu -i "$OUT/ncu_$k.ncu-rep" --page details >"$OUT/ncu_$k.details.txt" 2>&1
    ncu -i "$OUT/ncu_$k.ncu-rep" --page source --csv --print-source cuda,sass >"$OUT/ncu_$k.source.csv" 2>&1
    rm -f "$OUT/ncu_$k.ncu-rep"
    echo "== ncu $k (variant $i)"
    grep -E "Duration|Warp Cycles Per Issued|Registers Per|Achieved Occupancy|DRAM Throughput|L2 Hit" "$OUT/ncu_$k.details.txt" | head -8
  done
fi
