#!/usr/bin/env bash
# Sourced by the A/B scripts (gpu_raster_ab.sh, gpu_train_ab.sh) after
# gpu_common.sh: their variants, built one after the other from the working
# tree. Variant 0 is the tree as it is, variant i the tree with the first i
# patches of AB_PATCHES applied (cumulatively; AB_DIR/NAME.patch, git diff
# format, patch -p1).
#   ab_setup NAME ROUNDS        the logs archived into $OUT/NAME_logs.tgz; BIN,
#                               the variants' binaries ($AB_BIN_DIR, else
#                               /tmp/flat_NAME), emptied; ROUNDS, the timing
#                               rounds ($AB_ROUNDS, else ROUNDS); the card
#   names                       the variants' names: base, then the patches'
#   ab_build_bench I [TARGET..] builds flat_bench (and the TARGETs) at the tree
#                               as it is now; the binary kept as $BIN/flat_bench_I
#   ab_patch_variants FN        applies each patch in turn and calls FN I after
#                               each; sets i to the last variant's index
AB_DIR="${AB_DIR:-$ROOT/.ab}"
names=(base)
ab_setup() {
  gpu_archive_logs "$1_logs"
  BIN="${AB_BIN_DIR:-/tmp/flat_$1}"; rm -rf "$BIN"; mkdir -p "$BIN"
  ROUNDS="${AB_ROUNDS:-$2}"
  gpu_card
}
ab_build_bench() {
  local v=$1 t0; t0=$(date +%s); shift
  sync_mtimes "$ROOT" "$BUILD"
  gpu_build flat_bench "$@"
  cp "$BUILD/flat_bench" "$BIN/flat_bench_$v"
  echo "== variant $v (${names[$v]}) built in $(( $(date +%s) - t0 )) s"
}
ab_patch_variants() {
  i=0
  for p in ${AB_PATCHES:-}; do
    i=$((i + 1)); names+=("$p")
    patch -p1 -s -d "$ROOT" <"$AB_DIR/$p.patch" || { echo "patch $p does not apply"; exit 1; }
    "$1" "$i"
  done
}
