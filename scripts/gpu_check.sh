#!/usr/bin/env bash
# Build + every test (CUDA included) + benchmarks on the GPU machine, in one go.
# Usage there (repo root, .deps carried):  bash scripts/gpu_check.sh [bench|nobench|train|infer]
#   bench: everything; train: skip the decoder/raster benches; nobench: build and tests only;
#   scale: stage-3/4 memory with and without activation checkpointing and 8-bit AdamW;
#   infer: flat_infer's streaming decode of 49- and 201-frame trajectories (peak memory per length).
#   GPU_TRAIN_STAGES="1 2 3" picks the stages flat_bench train times (default 1);
#   GPU_SKIP_TESTS=1 skips ctest; GPU_TARGETS limits the build.
# Logs go to $OUT (or ./gpu_out); a summary table is printed last.
set -uo pipefail
source "$(dirname "$0")/gpu_common.sh"  # ROOT, OUT, BUILD; gpu_card, gpu_configure, gpu_build
MODE="${1:-bench}"
PY="$(command -v python3)"
summary=()
source "$ROOT/scripts/stage_sizes.sh"
gpu_card
t0=$(date +%s)
gpu_configure ${GPU_CMAKE_ARGS:-}
ninja -C "$BUILD" -k 0 ${GPU_TARGETS:-} >"$OUT/build.log" 2>&1; build_rc=$?
summary+=("build rc=$build_rc in $(( $(date +%s) - t0 )) s")
[ $build_rc -ne 0 ] && grep -E "error|FAILED" "$OUT/build.log" | head -30
if [ -z "${GPU_SKIP_TESTS:-}" ]; then
(cd "$BUILD" && ctest --output-on-failure ${GPU_CTEST_ARGS:-} >"$OUT/ctest.log" 2>&1); test_rc=$?
summary+=("ctest rc=$test_rc: $(grep -E 'tests passed|tests failed' "$OUT/ctest.log" | tail -1)")
grep -E "Failed|\*\*\*|FAILED" "$OUT/ctest.log" | head -20
fi
if [ -z "${GPU_SKIP_TESTS:-}" ] && [ -x "$BUILD/tests/flat_test_render" ]; then
  # The CUDA-vs-CPU errors of the rasterizer (docs/rasterizer.md, "Tolerances held").
  "$BUILD/tests/flat_test_render" "*cuda*" -s 2>&1 | grep "cuda-vs-cpu" >"$OUT/cuda_vs_cpu.log"
  summary+=("cuda-vs-cpu rasterizer comparisons: $(wc -l <"$OUT/cuda_vs_cpu.log") lines in cuda_vs_cpu.log")
fi
if [ "$MODE" = "bench" ] && [ -x "$BUILD/flat_bench" ]; then
  # Paper sizes: decoder 13 and 21 latent frames, full and streaming; raster on
  # the anchor's own workload, large and small (see docs/benchmarks.md).
  "$BUILD/flat_bench" decoder >"$OUT/bench_decoder.log" 2>&1; summary+=("bench decoder rc=$?")
  grep -E "median" "$OUT/bench_decoder.log" | tail -8
  "$BUILD/flat_bench" raster --workload anchor-large anchor-small >"$OUT/bench_raster.log" 2>&1; summary+=("bench raster rc=$?")
  tail -12 "$OUT/bench_raster.log"
fi
if { [ "$MODE" = "bench" ] || [ "$MODE" = "train" ]; } && [ -x "$BUILD/flat_train" ]; then
  # flat_train on the GPU: the tiny config on synthetic rooms with CUDA (loss
  # and held-out PSNR), then flat_bench train at the paper's stage sizes on
  # synthetic scenes with random-weight dim-96 latents (random LPIPS weights).
  S="$OUT/train"; rm -rf "$S"
  { "$BUILD/flat_synth" --out "$S/tiny/train" --count 4 --seed 7 --family room --frames 17 --size 48x80 --motion mixed &&
    "$BUILD/flat_synth" --out "$S/tiny/val" --count 1 --seed 1001 --family room --frames 17 --size 48x80 --motion mixed &&
    "$BUILD/flat_latents" --scenes "$S/tiny/train" --random-weights --seed 0 --dim 16 --window 9 --step 4 --device cuda &&
    "$BUILD/flat_latents" --scenes "$S/tiny/val" --random-weights --seed 0 --dim 16 --window 9 --step 4 --device cuda &&
    "$BUILD/flat_train" --config configs/tiny/stage1.yaml --set run_dir="$S/tiny/run" --set device=cuda --set steps=60 --set init.from=scratch --set "init.path=''" \
      --set "data.datasets=[{root: $S/tiny/train}]" --set "validation.datasets=[{root: $S/tiny/val}]" --set validation.every=60; } \
    >"$OUT/train_tiny.log" 2>&1
  summary+=("flat_train tiny (cuda) rc=$?: $(grep -oE 'held-out PSNR.*' "$OUT/train_tiny.log" | tail -1)")
  for stage in ${GPU_TRAIN_STAGES:-1}; do
    stage_sizes "$stage" || continue
    win=$frames
    D="$S/stage$stage"
    { "$BUILD/flat_synth" --out "$D" --count 1 --seed $stage --family room --frames $frames --size $size --motion mixed &&
      "$BUILD/flat_latents" --scenes "$D" --random-weights --seed 0 --dim 96 --window $win --device cuda --precision bf16 &&
      "$BUILD/flat_bench" train --config configs/stage$stage.yaml --random-lpips --warmup 3 --steps ${GPU_TRAIN_STEPS:-10} \
        --set "data.datasets=[{root: $D}]" --set validation.datasets=[] --set data.workers=4; } \
      >"$OUT/bench_train_stage$stage.log" 2>&1
    summary+=("bench train stage $stage rc=$?: $(grep -E 'as trained' "$OUT/bench_train_stage$stage.log" | tail -1) $(grep -E 'peak memory' "$OUT/bench_train_stage$stage.log" | tail -1)")
    tail -16 "$OUT/bench_train_stage$stage.log"
    # GPU_TRAIN_RUN_STEPS="200 200 60": a real flat_train run of stage i's config
    # for the i-th count of steps (scratch weights, the bench's random LPIPS file).
    run_steps=$(echo "${GPU_TRAIN_RUN_STEPS:-}" | awk -v i=$stage '{print $i}')
    if [ -n "$run_steps" ]; then
      "$BUILD/flat_train" --config configs/stage$stage.yaml --set run_dir="$D-run" --set steps=$run_steps \
        --set init.from=scratch --set "init.path=''" --set loss.lpips_weights=/tmp/flat_bench_random_lpips.safetensors \
        --set "data.datasets=[{root: $D}]" --set validation.datasets=[] --set checkpoint.every=$run_steps \
        --set optim.warmup_steps=0 --set log.progress_seconds=20 >"$OUT/train_stage$stage.log" 2>&1
      summary+=("flat_train stage $stage, $run_steps steps rc=$?: $(grep -E 'done in' "$OUT/train_stage$stage.log" | tail -1 | sed 's/.*info\] //')")
      rm -rf "$D-run"
    fi
    rm -rf "$D"
  done
fi
if [ "$MODE" = "infer" ] && [ -x "$BUILD/flat_infer" ]; then
  # flat_infer on long trajectories: a dim-96 stage-1 decoder (2 steps from
  # scratch: random weights in effect), then one 49-frame and one 201-frame
  # window (13 and 51 latent frames, 176x320) decoded on CUDA in bf16, streaming
  # and full-sequence; summary.json holds the peak memory of decoding and rendering.
  I="$OUT/infer"; rm -rf "$I"
  { "$BUILD/flat_synth" --out "$I/train" --count 1 --seed 3 --family room --frames 17 --size 176x320 --motion pan &&
    "$BUILD/flat_latents" --scenes "$I/train" --random-weights --seed 0 --dim 96 --window 17 --device cuda --precision bf16 &&
    "$BUILD/flat_train" --config configs/stage1.yaml --set run_dir="$I/run" --set steps=2 --set init.from=scratch \
      --set "init.path=''" --set loss.lambda_perc=0 --set "data.datasets=[{root: $I/train}]" --set validation.datasets=[] \
      --set optim.warmup_steps=0; } >"$OUT/infer_model.log" 2>&1
  summary+=("infer: model rc=$?")
  for T in 49 201; do
    { "$BUILD/flat_synth" --out "$I/long$T" --count 1 --seed 5 --family room --frames $T --size 176x320 --motion orbit &&
      "$BUILD/flat_latents" --scenes "$I/long$T" --random-weights --seed 0 --dim 96 --window $T --device cuda --precision bf16; } \
      >"$OUT/infer_data_$T.log" 2>&1
    for mode in streaming full; do
      flag=""; [ $mode = full ] && flag="--full-sequence"
      "$BUILD/flat_infer" --model "$I/run" --scene "$I/long$T/room_000000" --out "$I/out_${T}_$mode" --device cuda \
        --no-video --novel-frames 24 $flag >"$OUT/infer_${T}_$mode.log" 2>&1
      rc=$?
      peaks=$(python3 -c "import json,sys; j=json.load(open(sys.argv[1])); print('triangles', j['triangles_decoded'], 'decode', round(j['seconds']['decode'],2), 's, peak GiB decode', round(j['peak_memory_gib']['decode'],2), 'render', round(j['peak_memory_gib']['render'],2))" "$I/out_${T}_$mode/summary.json" 2>/dev/null)
      summary+=("flat_infer $T frames $mode rc=$rc: $peaks")
      tail -9 "$OUT/infer_${T}_$mode.log"
      cp "$I/out_${T}_$mode/summary.json" "$OUT/infer_summary_${T}_$mode.json" 2>/dev/null
    done
  done
  rm -rf "$I"
fi
if [ "$MODE" = "scale" ] && [ -x "$BUILD/flat_bench" ]; then
  # Memory savers of stage 4 (8-bit AdamW, activation checkpointing), timed with
  # flat_bench train at the paper's stage-3 and stage-4 sizes (random weights,
  # random LPIPS, synthetic rooms with random-weight dim-96 latents).
  for stage in ${GPU_SCALE_STAGES:-3 4}; do
    case $stage in 3) size=360x640 ;; 4) size=432x768 ;; esac
    D="$OUT/scale$stage"; rm -rf "$D"
    { "$BUILD/flat_synth" --out "$D" --count 1 --seed $stage --family room --frames 49 --size $size --motion mixed &&
      "$BUILD/flat_latents" --scenes "$D" --random-weights --seed 0 --dim 96 --window 49 --device cuda --precision bf16; } \
      >"$OUT/scale_data_$stage.log" 2>&1
    for variant in "plain:--set optim.name=adamw --set pipeline.model.activation_checkpointing=false" \
                   "ckpt:--set optim.name=adamw --set pipeline.model.activation_checkpointing=true" \
                   "ckpt+8bit:--set optim.name=adamw8bit --set pipeline.model.activation_checkpointing=true"; do
      name=${variant%%:*}; sets=${variant#*:}
      "$BUILD/flat_bench" train --config configs/stage$stage.yaml --random-lpips --warmup 2 --steps ${GPU_TRAIN_STEPS:-5} \
        --set "data.datasets=[{root: $D}]" --set validation.datasets=[] --set data.workers=4 $sets \
        >"$OUT/scale_${stage}_$name.log" 2>&1
      summary+=("stage $stage $name rc=$?: $(grep -E 'as trained' "$OUT/scale_${stage}_$name.log" | tail -1) $(grep -E 'peak memory' "$OUT/scale_${stage}_$name.log" | tail -1)")
    done
    rm -rf "$D"
  done
fi
echo "==== summary (commit ${FLAT_COMMIT:-$(git -C "$ROOT" rev-parse --short HEAD 2>/dev/null || echo unknown)}, $(date -u +%F))"
printf '%s\n' "${summary[@]}"
