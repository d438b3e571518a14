#!/usr/bin/env bash
# CTest `install` (tests/CMakeLists.txt): `cmake --install` of a built tree
# into a scratch prefix, then
#   1. the prefix holds every tool, the configs, the headers and the package;
#   2. a separate project (tests/install/consumer) finds the package with
#      find_package(flat), builds against it, and runs;
#   3. the installed tools run from another folder with only <prefix>/bin
#      (and /usr/bin, /bin for the shell and ffmpeg) on PATH and a bare
#      environment: every --help, then README command 1's chain in miniature
#      (flat_synth -> flat_latents -> flat_train -> flat_eval) and flat_infer.
# Usage: install_test.sh CMAKE SOURCE_DIR BUILD_DIR WORK_DIR GENERATOR CXX
set -euo pipefail
CMAKE="$1" SRC="$2" BUILD="$3" WORK="$4" GEN="$5" CXX="$6"
rm -rf "$WORK"
mkdir -p "$WORK"
PREFIX="$WORK/prefix"
fail() { echo "install test: $*" >&2; exit 1; }

echo "== cmake --install $BUILD --prefix $PREFIX"
"$CMAKE" --install "$BUILD" --prefix "$PREFIX" > "$WORK/install.log" || { cat "$WORK/install.log"; fail "cmake --install failed"; }

echo "== 1. what the prefix holds"
TOOLS=(flat_train flat_eval flat_infer flat_mesh flat_bench flat_import flat_latents flat_pack flat_render flat_synth
       flat_vae)
for t in "${TOOLS[@]}"; do
  [ -x "$PREFIX/bin/$t" ] || fail "$PREFIX/bin/$t missing (every tool of apps/ and data_tools/ is installed)"
done
for f in share/flat/configs/stage1.yaml share/flat/configs/tiny/stage1.yaml share/flat/configs/ablations/3dgs.yaml \
         include/flat/core/config.h include/flat/model/scene_decoder.h \
         lib/cmake/flat/flatConfig.cmake lib/cmake/flat/flatConfigVersion.cmake lib/cmake/flat/flatTargets.cmake; do
  [ -f "$PREFIX/$f" ] || fail "$PREFIX/$f missing"
done
# Nothing in the package may point back into the build or source tree.
if grep -l -e "$BUILD" -e "$SRC/include" "$PREFIX"/lib/cmake/flat/*.cmake; then
  fail "the package above refers to the build or source tree"
fi

echo "== 2. a find_package(flat) consumer"
"$CMAKE" -S "$SRC/tests/install/consumer" -B "$WORK/consumer" -G "$GEN" -DCMAKE_BUILD_TYPE=Release \
  -DCMAKE_CXX_COMPILER="$CXX" -DCMAKE_PREFIX_PATH="$PREFIX" > "$WORK/consumer_configure.log" 2>&1 ||
  { cat "$WORK/consumer_configure.log"; fail "configuring the consumer against $PREFIX failed"; }
"$CMAKE" --build "$WORK/consumer" -j 2 > "$WORK/consumer_build.log" 2>&1 ||
  { cat "$WORK/consumer_build.log"; fail "building the consumer against $PREFIX failed"; }
"$WORK/consumer/flat_consumer" "$PREFIX/share/flat/configs/tiny/stage1.yaml" || fail "the consumer failed"

echo "== 3. the installed tools, from $WORK/elsewhere, PATH=$PREFIX/bin:/usr/bin:/bin"
mkdir -p "$WORK/elsewhere"
cd "$WORK/elsewhere"
env -i HOME="$WORK/home" PATH="$PREFIX/bin:/usr/bin:/bin" OMP_NUM_THREADS=1 PREFIX="$PREFIX" \
  bash -euo pipefail -c '
for t in '"${TOOLS[*]}"'; do
  where=$(command -v "$t") || { echo "$t not on PATH"; exit 1; }
  [ "$where" = "$PREFIX/bin/$t" ] || { echo "$t resolves to $where, not $PREFIX/bin/$t"; exit 1; }
  "$t" --help > "help_$t.txt" || { echo "$t --help failed"; cat "help_$t.txt"; exit 1; }
done
echo "every tool: --help ok"
flat_synth --out scenes --count 1 --frames 5 --size 16x24 --seed 3
flat_latents --scenes scenes --random-weights --dim 4 --window 5
cat > stage.yaml <<EOF
run_dir: run
stage: install-test
steps: 1
device: cpu
precision: fp32
init: {from: scratch}
optim: {warmup_steps: 0}
validation: {datasets: []}
data:
  datasets: [{root: scenes, weight: 1.0}]
  height: 16
  width: 24
  input_frames: 5
  target_views: 2
  workers: 0
  latents: true
pipeline:
  model:
    vae: {dim: 4}
loss: {lambda_perc: 0.0}
EOF
flat_train --config stage.yaml
flat_eval --model run --scenes "synth=scenes" --out eval --device cpu
flat_infer --model run --scene scenes/room_000000 --out infer --device cpu
outputs="run/model.safetensors eval/table.md infer/scene.ply infer/summary.json"
# The viewer copies three.js from Debian libjs-three, wherever the tool runs from.
if [ -f /usr/share/javascript/three/three.min.js ]; then outputs="$outputs infer/viewer/index.html infer/viewer/three.min.js"; fi
for f in $outputs; do
  [ -s "$f" ] || { echo "$f missing or empty"; exit 1; }
done
echo "flat_synth, flat_latents, flat_train, flat_eval, flat_infer: ok"
' > "$WORK/tools.log" 2>&1 || { cat "$WORK/tools.log"; fail "an installed tool failed (log above)"; }
tail -n 2 "$WORK/tools.log"
echo "install test: ok"
