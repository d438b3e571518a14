#!/usr/bin/env bash
# The recipe's four stages (issue #44, docs/training.md "The four stages of the
# recipe"): 176x320 with 17 views -> 176x320 with 49 -> 360x640 -> 432x768
# with 8-bit AdamW, pruning and checkpointing (configs/recipe/stage1-4.yaml),
# each stage initialised from the one before, for two training seeds side by
# side; every stage scored by flat_eval on the held-out rooms at its own
# resolution, with the baselines.
#   rooms    ROOMS training + 16 held-out rooms, 49 frames at the largest size
#            (seeds 7 / 1001: the rooms of the VAE's set A, rendered larger)
#   latents  every latent set the four configs need, from VAE_FILE (one
#            flat_latents per GPU, --shard k/N)
#   train    SEEDS (default "0 1") side by side, each on GPUS_PER_SEED GPUs
#            (flat_train --nproc), stage after stage, each bounded by its
#            seconds (it checkpoints and stops on SIGTERM); flat_eval of each
#            stage runs beside the next one
#   all      rooms, latents, train
# Two variants side by side on 4 GPUs, e.g. without and with random backgrounds
# (STAGES_DATA shares the first run's rooms and latents):
#   GPUS_PER_SEED=1 STAGES_RUNS=/tmp/fs_base bash scripts/gpu_four_stages.sh train &
#   GPUS_PER_SEED=1 FIRST_GPU=2 STAGES_RUNS=/tmp/fs_rb STAGES_DATA=/tmp/fs_base/data \
#     EXTRA_SET="--set loss.random_background=true" bash scripts/gpu_four_stages.sh train
# Tables, results and grids go to $OUT. Usage on the GPU machine (repo root,
# .deps carried, tools built in $GPU_BUILD_DIR):
#   VAE_FILE=/tmp/flat_vae/fixed_A/vae.safetensors bash scripts/gpu_four_stages.sh all
# A small CPU rehearsal of the script itself: DEVICE=cpu SETS="48x80 48x80 64x112 80x144" ROOMS=4 VAL=2
#   STEPS="2 2 2 2" EXTRA_SET="--set optim.warmup_steps=0" GPUS_PER_SEED=1 bash scripts/gpu_four_stages.sh all (VAE_FILE from README command 1).
set -uo pipefail
source "$(dirname "$0")/gpu_common.sh"   # ROOT, OUT, BUILD
PHASE="${1:-all}"
S="${STAGES_RUNS:-/tmp/flat_stages}"
D="${STAGES_DATA:-$S/data}"   # rooms and latents (another run's, to share them)
mkdir -p "$S"
DEVICE="${DEVICE:-cuda}"
ROOMS="${ROOMS:-128}"; VAL="${VAL:-16}"; FRAMES=49
# A second held-out set of a seed no run or doc has used before: every stage
# is scored on it too, so a choice made on the first set is rechecked. A new
# seed each device run (8128 on 2026-11-28 chose the depth-normal consistency).
FRESH_SEED="${FRESH_SEED:-9241}"
read -r -a SET <<< "${SETS:-176x320 176x320 360x640 432x768}"     # each stage's HxW
# Each stage's steps are what one H100 a seed gets through in its bound, so
# the cosine schedule reaches its end instead of being cut before it decays. The
# training steps alone took 0.16 / 0.52 / 0.91 / 0.34 s at stages 1-4 (four
# seeds side by side, 2026-11-28); start-up and the two validations take the
# rest (55 / 70 s each at stages 3 / 4 over 16 rooms x 9 views, so the trainer
# validates on VAL_VIEWS views a room unless asked for flat_eval's 9). Stage 4
# needs its minutes: with 600 steps its pruned model recovered only after ~380
# (docs/training.md).
read -r -a STEP <<< "${STEPS:-700 200 120 1000}"                    # each stage's steps
read -r -a LIMIT <<< "${STAGE_SECONDS:-170 150 230 480}"            # each stage's time bound
VAL_VIEWS="${VAL_VIEWS:-3}"   # 9: the trainer's validation scores flat_eval's exact views (compared below)
# The reserved-but-unallocated share of a full GPU (8 GiB in the OOM of one
# stage 3 beside a flat_eval) is what expandable segments give back.
export PYTORCH_CUDA_ALLOC_CONF="${PYTORCH_CUDA_ALLOC_CONF:-expandable_segments:True}"
read -r -a SEED_LIST <<< "${SEEDS:-0 1}"
GPUS_PER_SEED="${GPUS_PER_SEED:-2}"
WINDOW=(17 49 49 49)
VAE_DIM="${VAE_DIM:-32}"
read -r -a EXTRA <<< "${EXTRA_SET:-}"                              # more --set for every stage
read -r -a EXTRA4 <<< "${STAGE4_EXTRA_SET:-}"                      # more --set for stage 4 only
T0=$(date +%s)
note() { echo "[four stages $(( $(date +%s) - T0 )) s] $1" | tee -a "$OUT/four_stages.txt"; }
cd "$ROOT"
gpus=0; [ "$DEVICE" = cuda ] && gpus=$(nvidia-smi -L | wc -l)

# The stage's config with this script's data, size and steps, into ARGS: stage (1-4), seed, run dir, init path.
stage_args() {
  local st=$1 seed=$2 run=$3 init=$4 i=$(( $1 - 1 ))
  ARGS=(--config "configs/recipe/stage$st.yaml" --set run_dir="$run" --set seed="$seed" --set device="$DEVICE" \
    --set "data.datasets=[{root: $D/train}]" --set "validation.datasets=[{root: $D/val}]" \
    --set data.height="${SET[$i]%x*}" --set data.width="${SET[$i]#*x}" --set steps="${STEP[$i]}" \
    --set init.path="$init" --set pipeline.model.vae.dim="$VAE_DIM" \
    --set validation.scenes="$VAL" --set validation.max_views="$VAL_VIEWS" --set validation.every="${STEP[$i]}" "${EXTRA[@]}")
  [ "$st" = 4 ] && ARGS+=("${EXTRA4[@]}")
  # validation: all held-out rooms at the start and the end, VAL_VIEWS views each.
}

if [ "$PHASE" = rooms ] || [ "$PHASE" = all ]; then
  rm -rf "$D"; mkdir -p "$D"
  big="${SET[3]}"
  # SYNTH_DEVICE=cuda: the rays are cast on the GPUs (one process each), else 16 CPU processes.
  synth_dev="${SYNTH_DEVICE:-cpu}"; [ "$gpus" -eq 0 ] && synth_dev=cpu
  if [ "$synth_dev" = cuda ]; then P=$gpus; else P=$(( gpus > 0 ? 16 : 2 )); fi
  per=$(( (ROOMS + P - 1) / P ))
  for k in $(seq 0 $((P - 1))); do
    n=$(( ROOMS - k * per < per ? ROOMS - k * per : per )); [ "$n" -le 0 ] && continue
    CUDA_VISIBLE_DEVICES=$(( gpus > 0 ? k % gpus : 0 )) "$BUILD/flat_synth" --device "$synth_dev" --threads 2 \
      --out "$D/train" --count $n --first-index $((k * per)) --seed 7 --family room \
      --frames $FRAMES --size "$big" --motion mixed --log-level warn >"$S/synth_$k.log" 2>&1 &
  done
  CUDA_VISIBLE_DEVICES=$(( gpus > 0 ? (gpus - 1) : 0 )) "$BUILD/flat_synth" --device "$synth_dev" --threads 2 \
    --out "$D/val" --count "$VAL" --seed 1001 --family room --frames $FRAMES \
    --size "$big" --motion mixed --log-level warn >"$S/synth_val.log" 2>&1 &
  CUDA_VISIBLE_DEVICES=$(( gpus > 1 ? (gpus - 2) : 0 )) "$BUILD/flat_synth" --device "$synth_dev" --threads 2 \
    --out "$D/fresh" --count "$VAL" --seed "$FRESH_SEED" --family room --frames $FRAMES \
    --size "$big" --motion mixed --log-level warn >"$S/synth_fresh.log" 2>&1 &
  wait
  note "rooms: $(ls "$D/train" | grep -c room) training, $(ls "$D/val" | grep -c room) held-out, $(ls "$D/fresh" | grep -c room) fresh, $FRAMES frames of $big"
fi

if [ "$PHASE" = latents ] || [ "$PHASE" = all ]; then
  [ -f "${VAE_FILE:-}" ] || { echo "VAE_FILE=${VAE_FILE:-} is not a file (the trained VAE stage's vae.safetensors)"; exit 1; }
  shards=$(( gpus > 0 ? gpus : 1 ))
  for k in $(seq 0 $((shards - 1))); do
    for st in 1 2 3 4; do
      i=$((st - 1))
      # One flat_latents per stage config: each sets its own size and window.
      CUDA_VISIBLE_DEVICES=$k OMP_NUM_THREADS=4 "$BUILD/flat_latents" --configs "configs/recipe/stage$st.yaml" \
        --set "data.datasets=[{root: $D/train}]" --set "validation.datasets=[{root: $D/val}, {root: $D/fresh}]" \
        --set data.height="${SET[$i]%x*}" --set data.width="${SET[$i]#*x}" \
        --vae "$VAE_FILE" --device "$DEVICE" --threads 4 --shard "$k/$shards" >"$S/latents_s${st}_$k.log" 2>&1 \
        || { echo "flat_latents stage $st shard $k failed:"; tail -5 "$S/latents_s${st}_$k.log"; }
    done &
  done
  wait
  note "latents: $(cd "$D/val/$(ls "$D/val" | grep -v log | head -1)" && ls latents_* | tr "\n" " ")"
fi

# One seed's four stages on the GPUs given (comma list), flat_eval of each
# beside the next. START_STAGE=k (with INIT_RUNS, another run's $S): start at
# stage k from that run's stage k-1 of the same seed, once it is written
# (its .done marker): an A/B of stage k alone, from one shared model.
chain() {
  local seed=$1 devs=$2 prev="$VAE_FILE" n ARGS=() first=${START_STAGE:-1}
  n=$(echo "$devs" | tr ',' '\n' | wc -l)
  if [ "$first" -gt 1 ]; then
    prev="${INIT_RUNS:?START_STAGE needs INIT_RUNS}/seed$seed/stage$((first - 1))"
    while [ ! -f "$prev.done" ]; do sleep 5; done
    note "seed $seed: stage $first from $prev"
  fi
  for st in $(seq "$first" 4); do
    local i=$((st - 1)) run="$S/seed$seed/stage$st" t0
    t0=$(date +%s)
    stage_args $st "$seed" "$run" "$prev"
    CUDA_VISIBLE_DEVICES=$devs timeout -s TERM "${LIMIT[$i]}" "$BUILD/flat_train" --nproc "$n" \
      "${ARGS[@]}" --set threads=4 --set data.workers=3 >"$S/seed${seed}_stage$st.log" 2>&1
    local rc=$?
    touch "$run.done"   # for a run that starts its own chain here (START_STAGE)
    echo "seed $seed stage $st: rc $rc in $(( $(date +%s) - t0 )) s, $(grep -oE 'validation @ step [0-9]+: PSNR [0-9.]+ dB' "$S/seed${seed}_stage$st.log" | tail -1)" \
      | tee -a "$OUT/four_stages.txt"
    (for set in val fresh; do
      CUDA_VISIBLE_DEVICES=${devs%%,*} OMP_NUM_THREADS=4 "$BUILD/flat_eval" --model "$run" --scenes "heldout=$D/$set" \
        --out "$S/eval_${set}_seed${seed}_stage$st" --name "seed$seed stage$st ${SET[$i]} $set" \
        --latent-set "${SET[$i]}_f${WINDOW[$i]}" --max-views 9 --device "$DEVICE" --threads 4 \
        >"$S/eval_${set}_seed${seed}_stage$st.log" 2>&1
    done
    # One held-out number: the trainer's last validation and flat_eval on the same rooms and views.
    [ "$VAL_VIEWS" = 9 ] && echo "seed $seed stage $st: trainer's $(grep -oE 'validation @ step [0-9]+: PSNR [0-9.]+' "$S/seed${seed}_stage$st.log" | tail -1) dB," \
      "flat_eval $(python3 -c 'import json,sys; r=json.load(open(sys.argv[1])); print("%.2f dB (model %s)" % (r["means"][-1]["psnr"], r["model"]))' \
        "$S/eval_val_seed${seed}_stage$st/results.json" 2>/dev/null)" \
      | tee -a "$OUT/four_stages.txt") &
    prev="$run"
  done
  wait
}

if [ "$PHASE" = train ] || [ "$PHASE" = all ]; then
  VAE_FILE="${VAE_FILE:-}"
  [ -f "$VAE_FILE" ] || { echo "VAE_FILE=$VAE_FILE is not a file"; exit 1; }
  g=${FIRST_GPU:-0}   # the first GPU of this run (two runs side by side)
  for seed in "${SEED_LIST[@]}"; do
    devs=""
    for _ in $(seq 1 "$GPUS_PER_SEED"); do devs="$devs${devs:+,}$(( gpus > 0 ? g % gpus : 0 ))"; g=$((g + 1)); done
    chain "$seed" "$devs" &
  done
  # The mesh phase as soon as the first seed's stage 4 is written (beside the
  # flat_evals of both seeds' last stage).
  mesh_pid=""
  if [ "${MESH_ROOMS:-0}" -gt 0 ]; then
    ( while [ ! -f "$S/seed${SEED_LIST[0]}/stage4.done" ]; do sleep 5; done; bash "$0" mesh ) &
    mesh_pid=$!
  fi
  wait
  for set in val fresh; do
    evals=$(ls -d "$S"/eval_${set}_seed*/ 2>/dev/null)
    # shellcheck disable=SC2086
    "$BUILD/flat_eval" --compare $evals --out-table "$OUT/four_stages_table_$set.md" --overwrite >/dev/null 2>&1
    cat "$OUT/four_stages_table_$set.md" 2>/dev/null | head -30
  done
  tar czf "$OUT/four_stages_results.tgz" -C "$S" $(cd "$S" && ls -d eval_*/results.json eval_*/*.md eval_*/*.csv 2>/dev/null) 2>/dev/null
  tar czf "$OUT/four_stages_logs.tgz" -C "$S" $(cd "$S" && ls *.log seed*/stage*/metrics/*.jsonl 2>/dev/null) 2>/dev/null
  tar czf "$OUT/four_stages_grids.tgz" -C "$S" $(cd "$S" && ls seed0/stage*/renders/*.png 2>/dev/null | sort | awk -F/ '{k=$1"/"$2; last[k]=$0} END {for (k in last) print last[k]}') 2>/dev/null
  note "four stages done"
fi

# flat_mesh on the recipe's held-out rooms (issue #44): the first MESH_ROOMS
# rooms of the held-out set, decoded by seed 0's stage 4 (flat_infer's soup,
# pruned as the model says), refined and converted with flat_mesh's defaults
# (every 4th frame held out), two rooms at a time on each GPU.
if [ "$PHASE" = mesh ]; then
  model="$S/seed${SEED_LIST[0]}/stage4"; M="$S/mesh"; rm -rf "$M"; mkdir -p "$M"
  [ -f "$model/model.safetensors" ] || { note "mesh: no stage-4 model in $model"; exit 1; }
  # Every GPU of the machine, two rooms each at once (the other variant's
  # stage 4 ends about when this starts); flat_mesh's conversion is CPU work
  # (204 s of a 263 s room at 432x768 on 2026-11-28), so the cores are shared out.
  ngpu=$(( gpus > 0 ? gpus : 1 )); slots=$(( ngpu * 2 ))
  threads=$(( $(nproc) / slots )); [ "$threads" -lt 1 ] && threads=1
  rooms=$(ls "$D/val" | grep room | head -"${MESH_ROOMS:-8}")
  k=0
  for room in $rooms; do
    dev=$(( k % ngpu ))
    # The rooms hold every stage's latent set: stage 4's is named.
    ( CUDA_VISIBLE_DEVICES=$dev "$BUILD/flat_infer" --model "$model" --scene "$D/val/$room" --out "$M/infer_$room" \
        --latent-set "${MESH_LATENT_SET:-${SET[3]}_f${WINDOW[3]}}" \
        --device "$DEVICE" --no-video --no-viewer --no-renders --novel none >"$M/infer_$room.log" 2>&1 &&
      CUDA_VISIBLE_DEVICES=$dev OMP_NUM_THREADS=$threads "$BUILD/flat_mesh" --from "$M/infer_$room" --out "$M/mesh_$room" \
        --device "$DEVICE" --no-viewer >"$M/mesh_$room.log" 2>&1
      echo "mesh $room: rc $?" >>"$M/rc.txt" ) &
    k=$((k + 1)); [ $(( k % slots )) -eq 0 ] && wait
  done
  wait
  cat "$M/rc.txt"
  python3 "$ROOT/scripts/mesh_table.py" "$M"/mesh_room_*/ >"$OUT/mesh_table.md" 2>&1
  for d in "$M"/mesh_room_*/; do
    python3 -c 'import json,sys; m=json.load(open(sys.argv[1]+"/metrics.json")); s=json.load(open(sys.argv[1]+"/mesh_stats.json")); sc=m["scores"]
print(m["scene"], *["%s %.2f dB cos %.3f" % (k, sc[k]["held_out"]["psnr"], sc[k]["held_out"]["normal_cosine"]) for k in ("feedforward","refined","mesh") if k in sc], "edge pieces %d / %d faces" % (s["edge_connected_pieces"], s["faces"]))' "$d" 2>&1
  done >>"$OUT/mesh_table.md"
  cat "$OUT/mesh_table.md"
  tar czf "$OUT/mesh_results.tgz" -C "$M" $(cd "$M" && ls mesh_room_*/metrics.json mesh_room_*/mesh_stats.json *.log rc.txt 2>/dev/null) \
    $(cd "$M" && ls mesh_room_*/renders/compare.png 2>/dev/null | head -1) 2>/dev/null
  note "mesh: $(wc -l <"$M/rc.txt") rooms"
fi
