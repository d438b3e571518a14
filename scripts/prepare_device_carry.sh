#!/usr/bin/env bash
# The GPU machine has neither GLM, nanoflann nor CUTLASS and cannot install
# anything: extract the header-only libraries into .deps (git-ignored) and
# carry it with each device call (carry: [".deps"]); CMake finds them there.
#   .deps/glm        Debian's libglm-dev
#   .deps/nanoflann  Debian's libnanoflann-dev (the mesh stitching's KD-tree)
#   .deps/cutlass  include/ and tools/util/include/ of NVIDIA's nvidia-cutlass wheel
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
CUTLASS_VERSION="${FLAT_CUTLASS_VERSION:-4.2.0.0}"
if [ -f "$ROOT/.deps/glm/usr/share/cmake/glm/glmConfig.cmake" ]; then
  echo "GLM already in .deps/glm"
else
  tmp=$(mktemp -d)
  (cd "$tmp" && apt-get download libglm-dev >/dev/null)
  mkdir -p "$ROOT/.deps/glm"
  dpkg -x "$tmp"/libglm-dev_*.deb "$ROOT/.deps/glm"
  rm -rf "$tmp"
  echo "GLM extracted to .deps/glm"
fi
if [ -f "$ROOT/.deps/nanoflann/usr/include/nanoflann.hpp" ]; then
  echo "nanoflann already in .deps/nanoflann"
else
  tmp=$(mktemp -d)
  (cd "$tmp" && apt-get download libnanoflann-dev >/dev/null)
  mkdir -p "$ROOT/.deps/nanoflann"
  dpkg -x "$tmp"/libnanoflann-dev_*.deb "$ROOT/.deps/nanoflann"
  rm -rf "$tmp"
  echo "nanoflann extracted to .deps/nanoflann"
fi
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
