#!/usr/bin/env bash
# The GPU recipe of "Latents that carry the scene" (docs/training.md): a small
# reproduction of the paper's pipeline on synthetic rooms at 176x320.
#   data   build; ROOMS training + VAL held-out rooms (never trained on);
#          the VAE stage (configs/recipe/vae.yaml); latents of every room from
#          the trained encoder (windows of 17, and of 49 for stage 2) and, for
#          the control, from a random-weight encoder of the same width.
#   train1 stage 1 (configs/recipe/stage1.yaml) and its two controls side by
#          side on the one GPU: random-encoder latents, and a decoder trained
#          from scratch on the trained VAE's latents (and RECIPE_VARIANT_SET's
#          variant, if set);
#   train2 stage 2 from stage 1 (and the variant's); flat_eval of each model on
#          the held-out rooms, with the baselines.
#   ablate the paper's ablations and Table 1 baselines (configs/ablations/*.yaml
#          layered over configs/recipe/stage1.yaml) for the seeds in
#          ABLATE_SEEDS (default "0"), ABLATE_PARALLEL side by side (default 8),
#          each bounded by ABLATE_SECONDS (default 450); scripts/run_ablations.sh
#          trains, evaluates on the held-out rooms and tabulates every seed
#          run so far (runs/recipe/ablations/table.md).
# Runs and builds go under the repo root given; on the device machine copy the
# tree to /tmp first (ignored folders of the repo do not survive between calls;
# /tmp does while the machine stays warm).
# Usage on the GPU machine (repo root, .deps carried): bash scripts/gpu_recipe.sh data|train1|train2
# (train = train1 then train2). Each phase fits one device call; each needs the
# folders the previous one left (the same warm machine). Every training is bounded by `timeout -s TERM`
# (it checkpoints and stops; flat_eval then reads the newest checkpoint).
# Logs and tables go to $OUT; a summary is printed last.
set -uo pipefail
source "$(dirname "$0")/gpu_common.sh"  # ROOT, OUT, BUILD; gpu_card, gpu_configure, gpu_build
PHASE="${1:-data}"
R="$ROOT/runs/recipe"
ROOMS="${RECIPE_ROOMS:-256}"; VAL="${RECIPE_VAL_ROOMS:-16}"; FRAMES="${RECIPE_FRAMES:-49}"; SIZE=176x320
DIM="${RECIPE_DIM:-32}"
# Steps of record (docs/training.md, 2026-11-26); the seconds bound each run
# (it checkpoints and stops on SIGTERM) so that a phase fits one device call.
VAE_IMAGE_STEPS="${RECIPE_VAE_IMAGE_STEPS:-3500}"; VAE_IMAGE_SECONDS="${RECIPE_VAE_IMAGE_SECONDS:-420}"
VAE_STEPS="${RECIPE_VAE_STEPS:-1000}"; VAE_SECONDS="${RECIPE_VAE_SECONDS:-240}"
S1_STEPS="${RECIPE_S1_STEPS:-1100}"; S1_SECONDS="${RECIPE_S1_SECONDS:-330}"
S2_STEPS="${RECIPE_S2_STEPS:-300}"; S2_SECONDS="${RECIPE_S2_SECONDS:-110}"
# Extra --set arguments for every scene-decoder training (stage 1, its controls, stage 2).
read -r -a LOSS_SET <<< "${RECIPE_LOSS_SET:-}"
T0=$(date +%s)
summary=()
note() { summary+=("$(printf '%4d s  %s' $(( $(date +%s) - T0 )) "$1")"); echo "[recipe $(( $(date +%s) - T0 )) s] $1"; }
cd "$ROOT"
gpu_card

if [ "$PHASE" = "data" ]; then
  gpu_configure -DFLAT_BUILD_TESTS=OFF -DFLAT_CUTLASS=OFF
  gpu_build flat_synth flat_latents flat_train flat_eval
  note "built"
  rm -rf "$R"; mkdir -p "$R/data"
  # Rooms in parallel batches (each process 2 threads: unbounded ones starve each other).
  P=8; per=$(( (ROOMS + P - 1) / P ))
  for k in $(seq 0 $((P - 1))); do
    n=$(( ROOMS - k * per < per ? ROOMS - k * per : per )); [ "$n" -le 0 ] && continue
    "$BUILD/flat_synth" --threads 2 --out "$R/data/train" --count $n --first-index $((k * per)) --seed 7 \
      --family room --frames "$FRAMES" --size $SIZE --motion mixed --log-level warn >"$OUT/synth_$k.log" 2>&1 &
  done
  "$BUILD/flat_synth" --threads 2 --out "$R/data/val" --count "$VAL" --seed 1001 --family room \
    --frames "$FRAMES" --size $SIZE --motion mixed --log-level warn >"$OUT/synth_val.log" 2>&1 &
  wait
  note "rooms: $(ls "$R/data/train" | wc -l) training, $(ls "$R/data/val" | wc -l) held-out, $FRAMES frames of $SIZE"
  # The VAE: single frames first, then windows (as Wan trained its VAE).
  timeout -s TERM "$VAE_IMAGE_SECONDS" "$BUILD/flat_train" --config configs/recipe/vae_image.yaml \
    --set steps="$VAE_IMAGE_STEPS" --set pipeline.model.vae.dim="$DIM" >"$OUT/vae_image.log" 2>&1
  note "VAE stage, single frames, rc=$?: $(grep -oE 'validation @ step [0-9]+: reconstruction PSNR [0-9.]+ dB' "$OUT/vae_image.log" | tail -1)"
  timeout -s TERM "$VAE_SECONDS" "$BUILD/flat_train" --config configs/recipe/vae.yaml --set steps="$VAE_STEPS" \
    --set pipeline.model.vae.dim="$DIM" >"$OUT/vae.log" 2>&1
  note "VAE stage, windows of 9, rc=$?: $(grep -oE 'validation @ step [0-9]+: reconstruction PSNR .*correlate [0-9.-]+' "$OUT/vae.log" | tail -1 | cut -c1-200)"
  if [ ! -f "$R/vae/vae.safetensors" ]; then
    # Stopped by the time bound: a resume at the newest checkpoint's step trains
    # no more and writes the file (statistics measured and folded in).
    "$BUILD/flat_train" --resume "$R/vae" --set steps="$(ls "$R/vae/checkpoints" | tail -1 | sed 's/step_0*//')" \
      --set optim.warmup_steps=0 >>"$OUT/vae.log" 2>&1
    note "VAE file from the newest checkpoint: $(ls "$R/vae/vae.safetensors" 2>&1)"
  fi
  # Windows of 49 for stage 2 and random-encoder latents for the control: the
  # same rooms hard-linked (flat_latents replaces files by renaming them).
  # Two processes at a time, threads bounded: six unbounded ones on 16 cores
  # took over 10 minutes (2026-11-25); two of 8 threads take 40 s a set.
  cp -al "$R/data" "$R/data49"; cp -al "$R/data" "$R/data_random"
  latents() {  # folder, log, flat_latents arguments...
    local d=$1 log=$2; shift 2
    for split in train val; do
      OMP_NUM_THREADS=8 "$BUILD/flat_latents" --scenes "$d/$split" "$@" --device cuda >"$OUT/${log}_$split.log" 2>&1 &
    done
    wait
  }
  # Windows of 17 also carry Plucker camera latents (the conditioning ablation).
  latents "$R/data" latents --vae "$R/vae/vae.safetensors" --window 17 --step 32 --camera-rays rppc,plucker
  latents "$R/data49" latents49 --vae "$R/vae/vae.safetensors" --window 49
  latents "$R/data_random" latents_random --random-weights --seed 0 --dim "$DIM" --window 17 --step 32
  note "latents: trained encoder $(grep -oE 'correlate [0-9.-]+ on average' "$OUT/latents_train.log" | tail -1); random encoder $(grep -oE 'correlate [0-9.-]+ on average' "$OUT/latents_random_train.log" | tail -1)"
  grep -hE "correlate|error" "$OUT"/latents*.log | cut -c1-220
fi

# A variant of stage 1 and 2 trained beside the main runs (same data and
# schedule), e.g. RECIPE_VARIANT_SET="--set loss.lambda_normal=0.1"; empty: none.
read -r -a VARIANT_SET <<< "${RECIPE_VARIANT_SET:-}"
s1_runs=(stage1 control_scratch control_random); [ ${#VARIANT_SET[@]} -gt 0 ] && s1_runs+=(variant1)
last_line() { grep -oE 'held-out PSNR.*|validation @ step [0-9]+: PSNR [0-9.]+ dB[^|]*\| baselines[^|]*' "$1" | tail -1 | cut -c1-200; }

if [ "$PHASE" = "train" ] || [ "$PHASE" = "train1" ]; then
  [ -f "$R/vae/vae.safetensors" ] || { echo "no $R/vae/vae.safetensors: run the data phase first (same warm machine)"; exit 1; }
  export OMP_NUM_THREADS=3  # up to four trainings side by side on 16 cores
  common=(--set pipeline.model.vae.dim="$DIM" --set steps="$S1_STEPS" --set threads=3 --set data.workers=3 "${LOSS_SET[@]}")
  timeout -s TERM "$S1_SECONDS" "$BUILD/flat_train" --config configs/recipe/stage1.yaml "${common[@]}" \
    >"$OUT/stage1.log" 2>&1 &
  timeout -s TERM "$S1_SECONDS" "$BUILD/flat_train" --config configs/recipe/stage1.yaml "${common[@]}" \
    --set run_dir="$R/control_scratch" --set init.from=scratch --set "init.path=''" >"$OUT/control_scratch.log" 2>&1 &
  timeout -s TERM "$S1_SECONDS" "$BUILD/flat_train" --config configs/recipe/stage1.yaml "${common[@]}" \
    --set run_dir="$R/control_random" --set "data.datasets=[{root: $R/data_random/train}]" \
    --set "validation.datasets=[{root: $R/data_random/val}]" >"$OUT/control_random.log" 2>&1 &
  if [ ${#VARIANT_SET[@]} -gt 0 ]; then
    timeout -s TERM "$S1_SECONDS" "$BUILD/flat_train" --config configs/recipe/stage1.yaml "${common[@]}" \
      --set run_dir="$R/variant1" "${VARIANT_SET[@]}" >"$OUT/variant1.log" 2>&1 &
  fi
  wait
  for r in "${s1_runs[@]}"; do note "$r: $(last_line "$OUT/$r.log")"; done
fi

if [ "$PHASE" = "train" ] || [ "$PHASE" = "train2" ]; then
  [ -f "$R/stage1/model.safetensors" ] || ls "$R/stage1/checkpoints" >/dev/null \
    || { echo "no $R/stage1: run train1 first (same warm machine)"; exit 1; }
  export OMP_NUM_THREADS=6
  s2=(--set pipeline.model.vae.dim="$DIM" --set steps="$S2_STEPS" --set threads=6 --set data.unseen_fraction=0 "${LOSS_SET[@]}")
  timeout -s TERM "$S2_SECONDS" "$BUILD/flat_train" --config configs/recipe/stage2.yaml "${s2[@]}" >"$OUT/stage2.log" 2>&1 &
  s2_runs=(stage2)
  if [ ${#VARIANT_SET[@]} -gt 0 ]; then
    timeout -s TERM "$S2_SECONDS" "$BUILD/flat_train" --config configs/recipe/stage2.yaml "${s2[@]}" \
      --set run_dir="$R/variant2" --set init.path="$R/variant1" "${VARIANT_SET[@]}" >"$OUT/variant2.log" 2>&1 &
    s2_runs+=(variant2)
  fi
  wait
  for r in "${s2_runs[@]}"; do note "$r: $(last_line "$OUT/$r.log")"; done
  # Held-out rooms: 9 views of each spread over its 49 frames (stage 2: its
  # 49-frame window); stage 1 also on every frame, to compare with its
  # trainer validation (17 views, half outside the window).
  export OMP_NUM_THREADS=2
  evals=("${s1_runs[@]}" "${s2_runs[@]}")
  for r in "${evals[@]}"; do
    data="$R/data/val"; [ "$r" = control_random ] && data="$R/data_random/val"
    case "$r" in stage2|variant2) data="$R/data49/val" ;; esac
    "$BUILD/flat_eval" --model "$R/$r" --scenes "heldout=$data" --out "$R/eval_$r" --name "$r" --max-views 9 \
      --device cuda >"$OUT/eval_$r.log" 2>&1 &
  done
  "$BUILD/flat_eval" --model "$R/stage1" --scenes "heldout=$R/data/val" --out "$R/eval_stage1_all" --name stage1_all_views \
    --device cuda >"$OUT/eval_stage1_all.log" 2>&1 &
  wait
  "$BUILD/flat_eval" --compare $(for r in "${evals[@]}"; do echo "$R/eval_$r"; done) "$R/eval_stage1_all" \
    > "$OUT/table.md" 2>&1
  cat "$OUT/table.md" | head -20
  for r in "${evals[@]}" stage1_all; do cp "$R/eval_$r/results.json" "$OUT/results_$r.json" 2>/dev/null; done
  tar czf "$OUT/renders.tgz" -C "$R" $(cd "$R" && ls -d */renders */metrics 2>/dev/null) 2>/dev/null
  tar czf "$OUT/logs.tgz" -C "$OUT" $(cd "$OUT" && ls *.log) 2>/dev/null
fi
if [ "$PHASE" = "ablate" ]; then
  [ -f "$R/vae/vae.safetensors" ] || { echo "no $R/vae/vae.safetensors: run the data phase first (same warm machine)"; exit 1; }
  ninja -C "$BUILD" flat_train flat_eval >"$OUT/build_ablate.log" 2>&1 || { tail -20 "$OUT/build_ablate.log"; exit 1; }
  A="$R/ablations"
  bash "$ROOT/scripts/run_ablations.sh" --base configs/recipe/stage1.yaml --out "$A" --build "$BUILD" --device cuda \
    --seeds "${ABLATE_SEEDS:-0}" --parallel "${ABLATE_PARALLEL:-8}" --seconds "${ABLATE_SECONDS:-450}" \
    --set steps="${ABLATE_STEPS:-700}" --set data.workers=2 --set pipeline.model.vae.dim="$DIM" \
    --set validation.every=250 --set validation.scenes=8 --set checkpoint.every=250 \
    ${ABLATE_ROWS:-configs/ablations/*.yaml} 2>&1 | tee "$OUT/ablate.log" | grep -vE "^\|" | tail -30
  nvidia-smi --query-gpu=memory.used,memory.total --format=csv >>"$OUT/ablate.log" 2>&1
  # The table over every seed evaluated so far (this call's and earlier ones').
  "$BUILD/flat_eval" --compare "$A"/eval_* --out-table "$A/table_all.md" --overwrite >/dev/null 2>&1
  cp "$A/table_all.md" "$OUT/ablation_table.md" 2>/dev/null
  for e in "$A"/eval_*; do cp "$e/results.json" "$OUT/results_$(basename "$e").json" 2>/dev/null; done
  tar czf "$OUT/ablate_logs.tgz" -C "$A" logs 2>/dev/null
  tar czf "$OUT/ablate_renders.tgz" -C "$A" $(cd "$A" && ls -d *_s*/renders 2>/dev/null) 2>/dev/null
  note "ablations (seeds ${ABLATE_SEEDS:-0}): $(grep -c . "$A/table_all.md" 2>/dev/null) table lines"
fi

echo "==== recipe summary ($PHASE) ===="
for s in "${summary[@]}"; do echo "$s"; done
