#!/usr/bin/env bash
# The GPU machine has neither GLM, nanoflann nor CUTLASS and cannot install
# anything: extract the header-only libraries into .deps (git-ignored) and
# carry it with each device call (carry: [".deps"]); CMake finds them there.
#   .deps/glm        Debian's libglm-dev
#   .deps/nanoflann  Debian's libnanoflann-dev (the mesh stitching's KD-tree)
#   .deps/cutlass  include/ and tools/util/include/ of NVIDIA's nvidia-cutlass wheel
#   .deps/wheels   gsplat's PyPI wheel (CUDA sources, compiled on the device) and
#                  its Python dependencies: the anchor of flat_bench raster
#                  --primitives 3dgs|2dgs (scripts/bench_gsplat.py)
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
CUTLASS_VERSION="${FLAT_CUTLASS_VERSION:-4.2.0.0}"
# A Debian package's files, extracted (not installed) into .deps/NAME.
extract_deb() {  # name, package, a file that proves it is there
  if [ -f "$ROOT/.deps/$1/$3" ]; then
    echo "$1 already in .deps/$1"
    return
  fi
  local tmp; tmp=$(mktemp -d)
  (cd "$tmp" && apt-get download "$2" >/dev/null)
  mkdir -p "$ROOT/.deps/$1"
  dpkg -x "$tmp"/"$2"_*.deb "$ROOT/.deps/$1"
  rm -rf "$tmp"
  echo "$1 extracted to .deps/$1"
}
extract_deb glm libglm-dev usr/share/cmake/glm/glmConfig.cmake
extract_deb nanoflann libnanoflann-dev usr/include/nanoflann.hpp
if [ -f "$ROOT/.deps/cutlass/include/cutlass/cutlass.h" ]; then
  echo "CUTLASS already in .deps/cutlass"
else
  tmp=$(mktemp -d)
  python3 -m pip download -q --no-deps --dest "$tmp" "nvidia-cutlass==$CUTLASS_VERSION"
  python3 -m zipfile -e "$tmp"/nvidia_cutlass-*.whl "$tmp/x"
  mkdir -p "$ROOT/.deps/cutlass/tools/util"
  mv "$tmp/x/cutlass_library/source/include" "$ROOT/.deps/cutlass/include"
  mv "$tmp/x/cutlass_library/source/tools/util/include" "$ROOT/.deps/cutlass/tools/util/include"
  rm -rf "$tmp"
  echo "CUTLASS $CUTLASS_VERSION headers extracted to .deps/cutlass ($(du -sh "$ROOT/.deps/cutlass" | cut -f1))"
fi
if ls "$ROOT/.deps/wheels"/gsplat-*.whl >/dev/null 2>&1; then
  echo "gsplat wheels already in .deps/wheels"
else
  mkdir -p "$ROOT/.deps/wheels"
  python3 -m pip download -q --no-deps --dest "$ROOT/.deps/wheels" "gsplat==${FLAT_GSPLAT_VERSION:-1.5.3}"
  # The device runs Ubuntu 24.04's Python 3.12 and has torch and numpy already.
  python3 -m pip download -q --dest "$ROOT/.deps/wheels" --python-version 3.12 --only-binary=:all: \
    --platform manylinux2014_x86_64 jaxtyping rich ninja
  echo "gsplat and its dependencies in .deps/wheels ($(du -sh "$ROOT/.deps/wheels" | cut -f1))"
fi
