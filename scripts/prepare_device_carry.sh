#!/usr/bin/env bash
# The GPU machine has no GLM and cannot install anything: extract Debian's
# header-only libglm-dev into .deps/glm (git-ignored) and carry it with each
# device call (carry: [".deps"]). scripts/gpu_check.sh finds it there.
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
if [ -f "$ROOT/.deps/glm/usr/share/cmake/glm/glmConfig.cmake" ]; then
  echo "GLM already in .deps/glm"; exit 0
fi
tmp=$(mktemp -d)
(cd "$tmp" && apt-get download libglm-dev >/dev/null)
mkdir -p "$ROOT/.deps/glm"
dpkg -x "$tmp"/libglm-dev_*.deb "$ROOT/.deps/glm"
rm -rf "$tmp"
echo "GLM extracted to .deps/glm"
