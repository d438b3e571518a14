#!/usr/bin/env bash
# Installs what FLAT-C++ needs on a Debian 12 machine (run as root), skipping
# what is already there:
#   - Debian -dev packages (yaml-cpp, spdlog, CLI11, OpenImageIO, nlohmann-json,
#     GLM, Catch2, clang's libFuzzer runtime, ninja; libpng and libjpeg for
#     PNG/JPEG in builds without OpenImageIO, src/core/png_jpeg_io.cpp);
#   - libtorch as shipped in PyTorch's `torch` wheel (pinned to the GPU
#     machine's version), in a virtual environment outside the checkout. The
#     wheels are downloaded once into a cache folder and reused afterwards;
#   - CUTLASS's headers (NVIDIA's `nvidia-cutlass` wheel, header-only for us:
#     the Hopper convs of src/model/cuda_sm90), into the same environment;
#   - the tensorboard package there, to check flat_train's event files;
#   - the export module's tools: tinygltf (GLB), three.js (viewer), ffmpeg
#     (MP4), and the readers that check our files (chromium for the viewer's
#     screenshot test; assimp, Blender and the trimesh package for
#     scripts/check_interop.py; Blender's glTF importer needs python3-numpy,
#     which Debian's blender package does not pull in);
#   - the gloo headers (libgloo-dev libnanoflann-dev): the torch wheel holds c10d's Gloo code
#     but not the headers its ProcessGroupGloo.hpp includes (src/distributed).
# Python is only the installer of libtorch; nothing in the product runs it.
#
# `install_deps.sh --demo` (README command 1, scripts/run_smoke.sh) installs
# only what building and running the demo needs: the build's libraries and
# libtorch, without the readers and players that check our exports (Blender,
# chromium, assimp, ffmpeg, trimesh, tensorboard), libFuzzer, and, without a
# visible GPU, CUTLASS. The torch wheels download while apt-get installs. The
# test suite (README command 2) installs the rest.
set -euo pipefail
DEMO=0
[ "${1:-}" = "--demo" ] && DEMO=1

TORCH_VERSION="${FLAT_TORCH_VERSION:-2.11.0}"
CUTLASS_VERSION="${FLAT_CUTLASS_VERSION:-4.2.0.0}"
CACHE="${FLAT_CACHE_DIR:-$HOME/.cache/flat}"
VENV="$CACHE/venv"
WHEELS="$CACHE/wheels-torch-$TORCH_VERSION"

APT_PACKAGES=(cmake ninja-build g++ clang libclang-rt-14-dev
  libyaml-cpp-dev libspdlog-dev libcli11-dev nlohmann-json3-dev libglm-dev catch2
  libopenimageio-dev openimageio-tools libopencv-core-dev python3-venv python3-pip
  libtinygltf-dev libjs-three ffmpeg chromium assimp-utils blender python3-numpy
  libgloo-dev libnanoflann-dev libpng-dev libjpeg62-turbo-dev)

# Not needed to build or run the demo: the fuzzer's runtime, the exports' readers and players.
DEMO_SKIPS=" clang libclang-rt-14-dev openimageio-tools libjs-three ffmpeg chromium assimp-utils blender python3-numpy "

# The torch wheels (several GB) download in the background while apt-get runs,
# where pip is already there; otherwise after it.
PY="${FLAT_PYTHON:-python3}"
need_torch=1
if [ -x "$VENV/bin/python3" ] && "$VENV/bin/python3" -c "import torch,sys; sys.exit(torch.__version__.split('+')[0] != '$TORCH_VERSION')" 2>/dev/null; then
  need_torch=0
fi
download_torch() {
  mkdir -p "$WHEELS"
  if ! ls "$WHEELS"/torch-"$TORCH_VERSION"-*.whl >/dev/null 2>&1; then
    echo "[install_deps] downloading the torch $TORCH_VERSION wheel and its CUDA runtime wheels into $WHEELS (once; several GB)"
    "$PY" -m pip download -q --dest "$WHEELS" "torch==$TORCH_VERSION"
  fi
}
download_pid=""
if [ "$need_torch" = 1 ] && "$PY" -m pip --version >/dev/null 2>&1; then
  download_torch &
  download_pid=$!
fi

missing=()
for p in "${APT_PACKAGES[@]}"; do
  [ "$DEMO" = 1 ] && [[ "$DEMO_SKIPS" == *" $p "* ]] && continue
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if ((${#missing[@]})); then
  echo "[install_deps] apt-get install ${missing[*]}"
  export DEBIAN_FRONTEND=noninteractive
  apt-get update -qq
  apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
else
  echo "[install_deps] Debian packages: all present"
fi

if [ "$need_torch" = 0 ]; then
  echo "[install_deps] libtorch $TORCH_VERSION: present in $VENV"
else
  if [ -n "$download_pid" ]; then
    wait "$download_pid" || { echo "[install_deps] downloading the torch $TORCH_VERSION wheels into $WHEELS failed"; exit 1; }
  else
    download_torch
  fi
  echo "[install_deps] installing libtorch $TORCH_VERSION into $VENV from the cached wheels"
  "$PY" -m venv "$VENV"
  "$VENV/bin/python3" -m pip install -q --no-index --find-links "$WHEELS" "torch==$TORCH_VERSION"
fi
echo "[install_deps] libtorch cmake prefix: $("$VENV/bin/python3" -c 'import torch.utils; print(torch.utils.cmake_prefix_path)' 2>/dev/null)"
if [ "$DEMO" = 1 ] && ! nvidia-smi -L >/dev/null 2>&1; then
  echo "[install_deps] demo without a visible GPU: CUTLASS, tensorboard and trimesh skipped (README command 2 installs them)"
  exit 0
fi
if "$VENV/bin/python3" -c "import importlib.metadata as m, sys; sys.exit(m.version('nvidia-cutlass') != '$CUTLASS_VERSION')" 2>/dev/null; then
  echo "[install_deps] CUTLASS $CUTLASS_VERSION: present in $VENV"
else
  # --no-deps: only the headers are used (the wheel's Python tooling is not).
  echo "[install_deps] installing the CUTLASS $CUTLASS_VERSION headers (nvidia-cutlass wheel) into $VENV"
  "$VENV/bin/python3" -m pip install -q --no-deps "nvidia-cutlass==$CUTLASS_VERSION"
fi
# TensorBoard (Python): only to check, from scripts and tests, that the event
# files flat_train writes are read by the real package. Not used by the product.
if "$VENV/bin/python3" -c "import tensorboard" 2>/dev/null; then
  echo "[install_deps] tensorboard (for the event-file check): present in $VENV"
else
  echo "[install_deps] installing tensorboard into $VENV (only for scripts/check_tensorboard.py)"
  "$VENV/bin/python3" -m pip install -q tensorboard || echo "[install_deps] tensorboard could not be installed: the event-file check will be skipped"
fi
# trimesh (Python): one of the three readers of scripts/check_interop.py (our
# PLY and GLB read by other programs). Not used by the product.
if "$VENV/bin/python3" -c "import trimesh" 2>/dev/null; then
  echo "[install_deps] trimesh (for the interop check): present in $VENV"
else
  echo "[install_deps] installing trimesh into $VENV (only for scripts/check_interop.py)"
  "$VENV/bin/python3" -m pip install -q trimesh || echo "[install_deps] trimesh could not be installed: its interop check will say UNAVAILABLE"
fi
