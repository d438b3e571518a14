#!/usr/bin/env bash
# Same-run A/B of training-step changes on the GPU machine, in one call
# (issue #30: "each measured side by side with the previous commit"):
#   1. build flat_bench (and flat_synth, flat_latents) from the working tree:
#      variant 0, the base; then apply each patch of AB_PATCHES in turn
#      (cumulatively), rebuilding flat_bench and keeping a copy of each binary;
#   2. per stage of AB_STAGES, make one synthetic room with random-weight dim-96
#      latents at the stage's sizes (as scripts/gpu_check.sh train does);
#   3. time `flat_bench train` on configs/stageN.yaml as shipped by each
#      variant (the patched configs for patched variants), interleaved over
#      AB_ROUNDS rounds, then the extra settings of AB_SETS on the last variant.
# Usage there (repo root; .deps/glm and the patch folder carried):
#   AB_DIR=.ab AB_PATCHES="lpips" AB_STAGES="1 2" \
#   AB_SETS="ckpt17|--set loss.lpips_checkpoint=true --set loss.lpips_chunk=17" bash scripts/gpu_train_ab.sh
# AB_SETS: ';'-separated "label|flat_bench arguments" entries. Each variant's
# configs are snapshotted with its binary, so a patched config counts as part
# of its variant. Output: a summary table (step as trained, it/s, LPIPS alone,
# peak, by part) and every log in $OUT/train_ab_logs.tgz.
set -uo pipefail
source "$(dirname "$0")/gpu_common.sh"  # ROOT, OUT, BUILD; gpu_card, gpu_configure, gpu_build
source "$ROOT/scripts/ab_variants.sh"  # AB_DIR, names; ab_setup, ab_build_bench, ab_patch_variants
ab_setup train_ab 1  # BIN, ROUNDS
DATA="${AB_DATA_DIR:-/tmp/flat_train_ab_data}"
STAGES="${AB_STAGES:-1}"
STEPS="${AB_STEPS:-10}"
gpu_configure ${GPU_CMAKE_ARGS:-}
source "$ROOT/scripts/stage_sizes.sh"
build_variant() {  # $1: index; the rest: extra targets
  ab_build_bench "$@"
  rm -rf "$BIN/configs_$1"; cp -a "$ROOT/configs" "$BIN/configs_$1"
}
build_variant 0 flat_synth flat_latents
cp "$BUILD/flat_synth" "$BUILD/flat_latents" "$BIN/"
ab_patch_variants build_variant
for stage in $STAGES; do
  stage_sizes "$stage" || exit 1
  D="$DATA/stage$stage"
  if [ ! -f "$D/.done" ]; then
    rm -rf "$D"
    { OMP_NUM_THREADS=16 "$BIN/flat_synth" --out "$D" --count 1 --seed "$stage" --family room --frames $frames \
        --size $size --motion mixed &&
      "$BIN/flat_latents" --scenes "$D" --random-weights --seed 0 --dim 96 --window $frames --device cuda \
        --precision bf16 && touch "$D/.done"; } >"$OUT/data_stage$stage.log" 2>&1 ||
      { echo "data for stage $stage failed:"; tail -5 "$OUT/data_stage$stage.log"; exit 1; }
  fi
done
run() {  # $1: label, $2: variant, $3: stage, $4: round, rest: extra arguments
  local label=$1 v=$2 stage=$3 r=$4; shift 4
  local log="$OUT/bench_${label}_stage${stage}_r$r.log"
  "$BIN/flat_bench_$v" train --config "$BIN/configs_$v/stage$stage.yaml" --random-lpips --warmup 3 --steps "$STEPS" \
    --set "data.datasets=[{root: $DATA/stage$stage}]" --set validation.datasets=[] --set data.workers=4 "$@" \
    >"$log" 2>&1 || { echo "$label stage $stage failed:"; tail -5 "$log"; }
  local trained lp peak
  trained=$(grep -E "as trained" "$log" | tail -1 | awk -F'|' '{print $3 "ms," $4}')
  lp=$(grep -E "LPIPS fwd\+bwd alone" "$log" | tail -1 | awk -F'|' '{print $3}')
  peak=$(grep -oE "peak memory[^|]*" "$log" | tail -1)
  printf "%-10s stage %s round %s | step as trained %s | LPIPS alone %s ms | %s\n" \
    "$label" "$stage" "$r" "$trained" "$lp" "$peak" | tr -s ' ' | tee -a "$OUT/summary.log"
}
for stage in $STAGES; do
  for r in $(seq 1 "$ROUNDS"); do
    for v in $(seq 0 $i); do run "${names[$v]}" "$v" "$stage" "$r"; done
  done
  IFS=';' read -ra sets <<<"${AB_SETS:-}"
  for s in "${sets[@]}"; do
    [ -z "$s" ] && continue
    # shellcheck disable=SC2086
    run "${s%%|*}" "$i" "$stage" 1 ${s#*|}
  done
done
echo "== variants: ${names[*]}; by part (first round):"
for f in "$OUT"/bench_*_r1.log; do
  echo "-- $(basename "$f" .log)"; grep -E "^\| " "$f" | grep -vE "^\|---|^\| part" | cut -c1-110
done
