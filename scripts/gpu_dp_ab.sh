#!/usr/bin/env bash
# Same-call A/B of data-parallel changes on a multi-GPU machine (issue #30's
# "measured side by side with the previous commit"): build the working tree
# (the base), run scripts/gpu_data_parallel.sh with DP_TAG=_base, then apply
# each patch of AB_PATCHES (from AB_DIR, cumulatively), rebuild flat_train and
# run it again with DP_TAG=_<patch>; DP_* knobs pass through (DP_PARTS for the
# base, DP_PARTS_AB for the patched runs, default the same). Before the runs,
# the [cuda] test cases of AB_TESTS (test binaries, e.g. "model loss") run
# on the base build. Usage there (repo root; .deps/glm and the patches carried):
#   AB_DIR=.ab AB_PATCHES=sync DP_PARTS=scaling DP_STEPS=60 DP_SKIP=10 bash scripts/gpu_dp_ab.sh
set -uo pipefail
source "$(dirname "$0")/gpu_common.sh"  # ROOT, OUT, BUILD; gpu_card, gpu_configure, gpu_build
AB_DIR="${AB_DIR:-$ROOT/.ab}"
t0=$(date +%s)
gpu_configure ${GPU_CMAKE_ARGS:-}
tests=(); for t in ${AB_TESTS:-}; do tests+=("tests/flat_test_$t"); done
sync_mtimes "$ROOT" "$BUILD"
gpu_build flat_train flat_synth flat_latents flat_bench "${tests[@]}"
echo "== base built in $(( $(date +%s) - t0 )) s"
for t in ${AB_TESTS:-}; do
  "$BUILD/tests/flat_test_$t" "[cuda]" >"$OUT/test_cuda_$t.log" 2>&1
  echo "== flat_test_$t [cuda] rc=$?: $(tail -2 "$OUT/test_cuda_$t.log" | xargs)"
done
export OUT GPU_BUILD_DIR="$BUILD"
DP_TAG=_base bash "$ROOT/scripts/gpu_data_parallel.sh" | grep -vE "^== end"
for p in ${AB_PATCHES:-}; do
  (cd "$ROOT" && patch -p1 -s <"$AB_DIR/$p.patch") || { echo "patch $p does not apply"; exit 1; }
  sync_mtimes "$ROOT" "$BUILD"
  gpu_build flat_train
  DP_TAG=_$p DP_PARTS="${DP_PARTS_AB:-${DP_PARTS:-scaling equivalence kill}}" bash "$ROOT/scripts/gpu_data_parallel.sh" |
    grep -vE "^== (end|data-parallel)"
done
