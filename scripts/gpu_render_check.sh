#!/bin/bash
# Rasterizer checks on the GPU machine: build, CUDA-vs-CPU tests, benchmarks.
# Usage (repo root, device machine): scripts/gpu_render_check.sh [bench args]
# Logs go to $OUT (or ./gpu_render_logs).
set -o pipefail
OUT=${OUT:-$PWD/gpu_render_logs}
mkdir -p "$OUT"
export GLM_PREFIX=$PWD/.deps/glm/usr
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv | tee "$OUT/gpu.txt"
cmake -S . -B build-gpu -G Ninja -DCMAKE_BUILD_TYPE=Release -DFLAT_WITH_OIIO=OFF -DCMAKE_PREFIX_PATH="$GLM_PREFIX" \
  -DFLAT_TORCH_PYTHON="$(which python3)" > "$OUT/cmake.log" 2>&1 || { tail -40 "$OUT/cmake.log"; exit 1; }
time ninja -C build-gpu -k 0 flat_test_render flat_bench flat_render_exe > "$OUT/build.log" 2>&1
echo "build rc=$?"; grep -E "error|FAILED" "$OUT/build.log" | head -40
link_without_missing_libs() {  # another module failing to build must not stop the render checks
  local target=$1 cmd
  cmd=$(ninja -C build-gpu -t commands "$target" | tail -1)
  for lib in $(echo "$cmd" | grep -o '[^ ]*libflat_[a-z]*\.a' | sort -u); do
    [ -f "build-gpu/$lib" ] || { echo "linking $target without $lib"; cmd=${cmd//$lib/}; }
  done
  (cd build-gpu && eval "$cmd")
}
[ -x build-gpu/tests/flat_test_render ] || link_without_missing_libs flat_test_render
[ -x build-gpu/flat_bench ] || link_without_missing_libs flat_bench
if [ -x build-gpu/tests/flat_test_render ]; then
  build-gpu/tests/flat_test_render 2>&1 | tee "$OUT/test.log" | tail -60
fi
if [ -x build-gpu/flat_bench ]; then
  build-gpu/flat_bench raster "$@" 2>&1 | tee "$OUT/bench.log"
fi
