#!/usr/bin/env bash
# Sourced first by the GPU scripts (scripts/gpu_*.sh): where they work and how
# they configure and build, written once so that a flag changes in one place.
#   ROOT   the repository;
#   OUT    the folder whose files come back from the device ($OUT, else
#          ROOT/gpu_out), created;
#   BUILD  the build folder: $BUILD, else $GPU_BUILD_DIR, else ROOT/build-gpu.
# Functions (each failure shows the log's tail and ends the script, as a
# build that did not happen leaves nothing to measure):
#   gpu_card                 the card's name, memory and driver into $OUT/gpu.txt
#   gpu_cmake ARGS...        the Release configure (Ninja, no OpenImageIO, glm
#                            from .deps, this python3's torch) plus ARGS
#   gpu_configure ARGS...    gpu_cmake into $OUT/configure.log; a fresh
#                            $OUT/build.log
#   gpu_build TARGET...      ninja, appended to $OUT/build.log (a script
#                            builds in steps: variants, tests)
#   gpu_archive_logs NAME    logs into a scratch folder packed into
#                            $OUT/NAME.tgz at exit (the device tool returns
#                            few files); OUT then names the scratch folder
# sync_mtimes (gpu_sync_mtimes.sh) is sourced too.
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
OUT="${OUT:-$ROOT/gpu_out}"; mkdir -p "$OUT"
BUILD="${BUILD:-${GPU_BUILD_DIR:-$ROOT/build-gpu}}"
source "$ROOT/scripts/gpu_sync_mtimes.sh"

gpu_card() { nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader | tee "$OUT/gpu.txt"; }

gpu_cmake() {
  cmake -S "$ROOT" -B "$BUILD" -G Ninja -DCMAKE_BUILD_TYPE=Release -DFLAT_WITH_OIIO=OFF \
    -DCMAKE_PREFIX_PATH="$ROOT/.deps/glm/usr" -DFLAT_TORCH_PYTHON="$(command -v python3)" "$@"
}

gpu_configure() {
  gpu_cmake "$@" >"$OUT/configure.log" 2>&1 || { tail -40 "$OUT/configure.log"; echo "CONFIGURE FAILED"; exit 1; }
  : >"$OUT/build.log"
}

gpu_build() {
  ninja -C "$BUILD" "$@" >>"$OUT/build.log" 2>&1 || { grep -E "error|FAILED" "$OUT/build.log" | head -30; exit 1; }
}

gpu_archive_logs() {
  GPU_ARCHIVE="$OUT/$1.tgz"
  OUT="/tmp/flat_$1"; rm -rf "$OUT"; mkdir -p "$OUT"
  trap 'tar czf "$GPU_ARCHIVE" -C "$OUT" .' EXIT
}
