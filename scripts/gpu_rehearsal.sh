#!/usr/bin/env bash
# Issue #43's rehearsal at the paper's sizes on the GPU machine: the path a
# user takes with their own videos, on clips in the real formats made from
# ray-cast rooms (flat_synth --format), with the wall time of every step.
#   raw clips (RealEstate10K .txt + frames, DL3DV transforms.json + images_4,
#   predictor-style depth .npy / 16-bit PNG and OpenGL normals, corrupt clips)
#   -> flat_import (batch, both formats; the corrupt clips reported)
#   -> flat_latents --configs configs/stage1..4.yaml --overlay (every stage's
#      set; one process per GPU with --shard)
#   -> flat_train stages 1 -> 2 -> 3 -> 4 (configs/stageN.yaml as shipped, an
#      overlay for the data, short schedules, --nproc NPROC)
#   -> flat_eval of every stage on the held-out clips (its three baselines)
#   -> flat_infer and flat_mesh on a held-out clip.
# No Wan 2.1 weights can be had here: the latents come from a random-weight
# dim-96 encoder (recorded as such; the scores are pipeline checks, not
# results), stage 1 starts from scratch, and LPIPS is off (no VGG weights).
#
# Usage (repo root on the device, .deps carried):
#   PHASES="build data import latents train eval mesh" NPROC=2 bash scripts/gpu_rehearsal.sh
# Variables: PHASES (default all), NPROC (GPUs, default: all visible),
#   STEPS ("s1 s2 s3 s4", default "200 100 60 40"), CLIPS ("re10k dl3dv val_re10k
#   val_dl3dv", default "16 8 4 4"), FRAMES (default 57), SIZE (clips' frame size,
#   default 432x768), STAGES (default "1 2 3 4"), W (work folder,
#   default /tmp/rehearsal), BUILD (default build-gpu), GPU_CMAKE_ARGS (e.g.
#   -DFLAT_CUTLASS=OFF: every conv through cuDNN, a shorter build).
# Logs and the summary go to $OUT (or ./gpu_out).
set -uo pipefail
source "$(dirname "$0")/gpu_common.sh"  # ROOT, OUT, BUILD; gpu_card, gpu_configure, gpu_build
W="${W:-/tmp/rehearsal}"
PHASES="${PHASES:-build data import latents train eval mesh}"
NPROC="${NPROC:-$(nvidia-smi -L 2>/dev/null | wc -l)}"
read -r S1 S2 S3 S4 <<<"${STEPS:-200 100 60 40}"
read -r N_RE N_DL N_VRE N_VDL <<<"${CLIPS:-16 8 4 4}"
FRAMES="${FRAMES:-57}"
SIZE="${SIZE:-432x768}"        # the clips' frame size (432x768: every stage's set can be made)
STAGES="${STAGES:-1 2 3 4}"    # the stages whose sets, runs and evaluations are made
UNIT=0.5  # flat_synth writes poses and depth in units of 0.5 m; --scale 0.5 gives metres back
SUMMARY="$OUT/rehearsal_summary.txt"
has() { [[ " $PHASES " == *" $1 "* ]]; }
now() { date +%s.%N; }
note() { echo "$*" | tee -a "$SUMMARY"; }
timed() {  # label, log, command...: runs it, notes its wall time and exit code
  local label=$1 log=$2; shift 2
  local t0; t0=$(now)
  "$@" >"$log" 2>&1; local rc=$?
  note "$(printf '%-44s rc=%-3s %7.1f s' "$label" "$rc" "$(awk -v a="$(now)" -v b="$t0" 'BEGIN{print a-b}')")"
  return $rc
}
nvidia-smi --query-gpu=name,memory.total --format=csv,noheader | tee -a "$SUMMARY"
note "commit ${FLAT_COMMIT:-unknown}, $(date -u +%F), NPROC=$NPROC, steps $S1/$S2/$S3/$S4, clips $N_RE+$N_DL train, $N_VRE+$N_VDL held out, $FRAMES frames"

if has build; then
  timed "configure" "$OUT/configure.log" gpu_cmake -DFLAT_BUILD_TESTS=OFF ${GPU_CMAKE_ARGS:-} ||
    { tail -30 "$OUT/configure.log"; exit 1; }
  timed "build" "$OUT/build.log" ninja -C "$BUILD" flat_synth flat_import flat_latents flat_train flat_eval flat_infer \
    flat_mesh || { grep -E "error|FAILED" "$OUT/build.log" | head -30; exit 1; }
fi
B="$BUILD"
RAW="$W/raw"; DATA="$W/data"; RUNS="$W/runs"

if has data; then
  rm -rf "$W"; mkdir -p "$RAW"
  # Training clips with two corrupt ones of each format; held-out clips of other seeds.
  timed "flat_synth re10k x$N_RE (2 corrupt)" "$OUT/synth_re10k.log" "$B/flat_synth" --format re10k --out "$RAW/re10k" \
    --count "$N_RE" --corrupt 2 --seed 11 --frames "$FRAMES" --size "$SIZE" --unit $UNIT --no-truth --motion mixed
  timed "flat_synth dl3dv x$N_DL (2 corrupt)" "$OUT/synth_dl3dv.log" "$B/flat_synth" --format dl3dv --out "$RAW/dl3dv" \
    --count "$N_DL" --corrupt 2 --seed 12 --frames "$FRAMES" --size "$SIZE" --unit $UNIT --no-truth --motion mixed
  timed "flat_synth held-out re10k x$N_VRE" "$OUT/synth_val_re10k.log" "$B/flat_synth" --format re10k \
    --out "$RAW/val_re10k" --count "$N_VRE" --seed 21 --frames "$FRAMES" --size "$SIZE" --unit $UNIT --no-truth --motion mixed
  timed "flat_synth held-out dl3dv x$N_VDL" "$OUT/synth_val_dl3dv.log" "$B/flat_synth" --format dl3dv \
    --out "$RAW/val_dl3dv" --count "$N_VDL" --seed 22 --frames "$FRAMES" --size "$SIZE" --unit $UNIT --no-truth --motion mixed
fi

if has import; then
  J=$(( $(nproc) / 2 ))
  for split in re10k val_re10k; do
    timed "flat_import re10k $split" "$OUT/import_$split.log" "$B/flat_import" re10k --in "$RAW/$split/cameras" \
      --frames-dir "$RAW/$split/frames" --out "$DATA/$split" --depth "$RAW/$split/depth" \
      --normals "$RAW/$split/normals" --normals-convention opengl --scale $UNIT --jobs $J
    python3 -c "import json,sys; s=json.load(open(sys.argv[1])); print('  imported', s['imported'], 'failed', s['failed'], [f['name'] + ': ' + f['reason'][:90] for f in s['failures']])" \
      "$DATA/$split/import_summary.json" | tee -a "$SUMMARY"
  done
  for split in dl3dv val_dl3dv; do
    timed "flat_import transforms $split" "$OUT/import_$split.log" "$B/flat_import" transforms --in "$RAW/$split" \
      --out "$DATA/$split" --depth "$RAW/$split/{clip}/depth" --depth-png-scale 0.001 \
      --normals "$RAW/$split/{clip}/normals" --normals-convention opengl --scale $UNIT --jobs $J
    python3 -c "import json,sys; s=json.load(open(sys.argv[1])); print('  imported', s['imported'], 'failed', s['failed'], [f['name'][:12] + ': ' + f['reason'][:90] for f in s['failures']])" \
      "$DATA/$split/import_summary.json" | tee -a "$SUMMARY"
  done
fi

# The data overlay every stage and flat_latents read (the paper configs as shipped otherwise).
cat >"$W/my_data.yaml" <<EOF
data:
  datasets: [{root: $DATA/re10k, weight: 0.5}, {root: $DATA/dl3dv, weight: 0.5}]
  workers: 4
validation:
  datasets: [{root: $DATA/val_re10k}, {root: $DATA/val_dl3dv}]
  scenes: 8
loss:
  lambda_perc: 0.0
  lpips_weights: ""
EOF
CONFIGS=(configs/stage1.yaml configs/stage2.yaml configs/stage3.yaml configs/stage4.yaml)

if has latents; then
  # Every stage's set, one stage at a time so each gets its own wall time;
  # one process per GPU, each a shard of the scenes.
  for n in $STAGES; do
    t0=$(now); pids=()
    for k in $(seq 0 $((NPROC - 1))); do
      CUDA_VISIBLE_DEVICES=$k OMP_NUM_THREADS=4 "$B/flat_latents" --configs "${CONFIGS[$((n - 1))]}" \
        --overlay "$W/my_data.yaml" --random-weights --seed 0 --dim 96 --device cuda --precision bf16 --store bf16 \
        --shard "$k/$NPROC" >"$OUT/latents_s${n}_$k.log" 2>&1 &
      pids+=($!)
    done
    rc=0; for p in "${pids[@]}"; do wait "$p" || rc=$?; done
    note "$(printf '%-44s rc=%-3s %7.1f s' "flat_latents stage $n set, $NPROC shard(s)" "$rc" "$(awk -v a="$(now)" -v b="$t0" 'BEGIN{print a-b}')")"
    grep -hE "set\(s\) encoded|set [0-9]+x" "$OUT"/latents_s${n}_*.log | sed 's/^\[[^]]*\] \[info\] /  /' | sort -u | tee -a "$SUMMARY"
  done
fi

stage_steps() { case $1 in 1) echo $S1 ;; 2) echo $S2 ;; 3) echo $S3 ;; 4) echo $S4 ;; esac; }
stage_set() { case $1 in 1) echo 176x320_f17 ;; 2) echo 176x320_f49 ;; 3) echo 360x640_f49 ;; 4) echo 432x768_f49 ;; esac; }

if has train; then
  for n in $STAGES; do
    s=$(stage_steps $n)
    init=(--set "init.path=$RUNS/stage$((n - 1))")
    [ $n -eq 1 ] && init=(--set init.from=scratch --set 'init.path=""')
    timed "flat_train stage $n ($s steps, --nproc $NPROC)" "$OUT/stage$n.log" "$B/flat_train" \
      --config "${CONFIGS[$((n - 1))]}" --config "$W/my_data.yaml" --nproc "$NPROC" --set "run_dir=$RUNS/stage$n" \
      "${init[@]}" --set "steps=$s" --set "optim.warmup_steps=$((s / 10))" --set "checkpoint.every=$s" \
      --set "validation.every=$s" --overwrite || { tail -20 "$OUT/stage$n.log"; break; }
    grep -hE "^.*(data: [0-9]+ training|data parallel:|held-out PSNR:|it/s  done)" "$OUT/stage$n.log" |
      sed 's/^\[[^]]*\] \[info\] /  /' | tee -a "$SUMMARY"
    cp "$RUNS/stage$n/data_report.json" "$OUT/stage${n}_data_report.json" 2>/dev/null
  done
fi

if has eval; then
  for n in $STAGES; do
    [ -f "$RUNS/stage$n/model.safetensors" ] || continue
    timed "flat_eval stage $n ($(stage_set $n))" "$OUT/eval_stage$n.log" "$B/flat_eval" --model "$RUNS/stage$n" \
      --scenes "re10k=$DATA/val_re10k" "dl3dv=$DATA/val_dl3dv" --latent-set "$(stage_set $n)" --max-views 16 \
      --device cuda --precision bf16 --out "$W/eval/stage$n"
    [ -f "$W/eval/stage$n/table.md" ] && cp "$W/eval/stage$n/table.md" "$OUT/eval_stage$n.md"
  done
  if [ -f "$RUNS/stage4/model.safetensors" ]; then
    first=$(ls -d "$DATA"/val_re10k/*/ | head -1)
    timed "flat_infer stage 4, $(basename "$first")" "$OUT/infer.log" "$B/flat_infer" --model "$RUNS/stage4" \
      --scene "$first" --latent-set 432x768_f49 --device cuda --out "$W/infer"
  fi
fi
if has mesh; then
  timed "flat_mesh (defaults)" "$OUT/mesh.log" timeout 240 "$B/flat_mesh" --from "$W/infer" --out "$W/mesh" --device cuda
  [ -f "$W/mesh/mesh_stats.json" ] && cp "$W/mesh/mesh_stats.json" "$OUT/"
fi
note "done"
