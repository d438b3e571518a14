#!/usr/bin/env bash
# The VAE stage on the GPU (issue #44, docs/training.md "A VAE stage that does
# not fall"): why the shipped recipe's held-out reconstruction fell, and the
# fixed recipe on three room sets, one GPU each.
#   prep   build flat_synth, then (while the other tools build) cast three
#          room sets of SETS_ROOMS training + 16 held-out rooms (49 frames of
#          176x320) on the GPUs, each set its own seeds: A = the recipe's rooms
#          (seeds 7 / 1001, where the fall was seen), B = 41 / 1041, C = 53 /
#          1053 (used by no test or doc before); and the four stages' rooms.
#   start  in the background (setsid: the runs outlive this call on a warm
#          machine):
#            GPU 0: with VAE_AB=1 the A/B that found the fall (session 9: on
#                   set A, single frames, 1,200 steps, validated every 100:
#                   "old" = lr 2e-3, no clipping, bf16; "clip", "lr", "fp32"
#                   change one thing; "new" = configs/recipe/vae_image.yaml);
#                   with GPU_TESTS=1 the CUDA tests of render, gaussians,
#                   surfels, optim and data (built here, -j 6);
#            GPUs 1-3: the fixed recipe (configs/recipe/vae_image.yaml then
#                   configs/recipe/vae.yaml) on sets A, B, C, one set a GPU,
#                   wall time measured from the first step to the VAE file
#                   (the test build of GPU_TESTS shares the CPUs meanwhile);
#            then the recipe's four stages from set A's VAE
#                   (scripts/gpu_four_stages.sh; FOUR_STAGES_AB=1: two
#                   variants, AB_A_NAME/AB_A_SET and AB_B_NAME/AB_B_SET, two
#                   seeds each, one GPU a seed).
#          VAE_SETS=A: set A alone (the four stages need only it);
#          RASTER_BENCH=1: the rasterizer benchmarks on GPUs 2-3 meanwhile
#          (scripts/gpu_gaussians.sh with BENCH_ONLY=1 PROFILE_GPU=3; its
#          gsplat wheels in .deps/wheels, ../shared/bench as shared_bench);
#          AB_B_START_STAGE=4: variant B trains stage 4 alone, from variant
#          A's stage 3 (a stage-4 A/B from one model).
#   wait   wait up to WAIT_SECONDS for the runs, then print each run's
#          validation curve and falls; once all are done, tables and grids
#          go to $OUT.
# Usage on the GPU machine (4 GPUs; repo root, .deps carried):
#   bash scripts/gpu_vae.sh prep && bash scripts/gpu_vae.sh start && WAIT_SECONDS=300 bash scripts/gpu_vae.sh wait
set -uo pipefail
source "$(dirname "$0")/gpu_common.sh"   # ROOT, OUT, BUILD; gpu_cmake
PHASE="${1:-prep}"
R="${VAE_RUNS:-/tmp/flat_vae}"
ROOMS="${SETS_ROOMS:-256}"; FRAMES=49; SIZE=176x320
declare -A TRAIN_SEED=([A]=7 [B]=41 [C]=53) VAL_SEED=([A]=1001 [B]=1041 [C]=1053)
cd "$ROOT"

if [ "$PHASE" = "prep" ]; then
  nvidia-smi --query-gpu=name,memory.total --format=csv,noheader
  t0=$(date +%s); mkdir -p "$R"
  gpus=$(nvidia-smi -L | wc -l)
  # Logs stay under $R: the device returns few files. Tests are configured
  # (built later on GPU 0 by "start" with GPU_TESTS=1).
  gpu_cmake -DFLAT_BUILD_TESTS=ON -DFLAT_CUTLASS=OFF >"$R/configure.log" 2>&1 || { tail -30 "$R/configure.log"; exit 1; }
  # flat_synth first: the rooms are cast on the GPUs while the other tools build.
  ninja -C "$BUILD" flat_synth >"$R/build.log" 2>&1 || { grep -E "error|FAILED" "$R/build.log" | head -30; exit 1; }
  echo "flat_synth built in $(( $(date +%s) - t0 )) s"
  bench=""; [ "${RASTER_BENCH:-0}" = 1 ] && bench=flat_bench
  ( ninja -C "$BUILD" flat_train flat_latents flat_eval flat_infer flat_mesh $bench >"$R/build_tools.log" 2>&1 || echo "BUILD FAILED" >>"$R/build_tools.log" ) &
  builder=$!
  rm -rf "$R"/set* "$R"/ab_* "$R"/fixed_*
  [ "$gpus" -gt 0 ] || { echo "no GPU visible (nvidia-smi -L)"; exit 1; }
  P=$gpus; per=$(( (ROOMS + P - 1) / P )); g=0; synths=()
  # The GPU is chosen before the job forks: `CUDA_VISIBLE_DEVICES=$((g++)) cmd &`
  # would expand in the child and put every job on GPU 0.
  synth() {  # log name, then flat_synth's arguments
    local log=$1 dev=$(( g % gpus )); shift; g=$((g + 1))
    CUDA_VISIBLE_DEVICES=$dev "$BUILD/flat_synth" --device cuda --family room --frames $FRAMES --size $SIZE \
      --motion mixed --log-level warn "$@" >"$R/$log.log" 2>&1 &
    synths+=($!)
  }
  for s in ${VAE_SETS:-A B C}; do   # VAE_SETS: fewer sets (one GPU)
    for k in $(seq 0 $((P - 1))); do
      n=$(( ROOMS - k * per < per ? ROOMS - k * per : per )); [ "$n" -le 0 ] && continue
      synth "synth_${s}_$k" --out "$R/set$s/train" --count $n --first-index $((k * per)) --seed "${TRAIN_SEED[$s]}"
    done
    synth "synth_${s}_val" --out "$R/set$s/val" --count 16 --seed "${VAL_SEED[$s]}"
  done
  # The four stages' rooms (scripts/gpu_four_stages.sh) at the same time.
  [ "${FOUR_STAGES:-1}" = 1 ] && OUT="$R/out" SYNTH_DEVICE=cuda bash "$ROOT/scripts/gpu_four_stages.sh" rooms >"$R/stage_rooms.log" 2>&1 &
  failed=0
  for p in "${synths[@]}"; do wait "$p" || failed=$((failed + 1)); done
  wait
  [ "$failed" -eq 0 ] || { echo "$failed flat_synth run(s) failed:"; grep -h "error" "$R"/synth_*.log | head -5; exit 1; }
  grep -q "BUILD FAILED" "$R/build_tools.log" && { grep -E "error|FAILED" "$R/build_tools.log" | head -30; exit 1; }
  for s in ${VAE_SETS:-A B C}; do echo "set $s: $(ls "$R/set$s/train" | grep -c room) training, $(ls "$R/set$s/val" | grep -c room) held-out rooms"; done
  tail -2 "$R/out/four_stages.txt" 2>/dev/null
  echo "prep done in $(( $(date +%s) - t0 )) s"
fi

# One VAE training: name, GPU, set, config, extra flat_train arguments...
# TRAIN_SECONDS bounds it (SIGTERM: it checkpoints and stops; 0 = no bound).
train_vae() {
  local name=$1 gpu=$2 set=$3 config=$4; shift 4
  CUDA_VISIBLE_DEVICES=$gpu OMP_NUM_THREADS=4 timeout -s TERM "${TRAIN_SECONDS:-0}" \
    "$BUILD/flat_train" --config "$config" --set run_dir="$R/$name" \
    --set "data.datasets=[{root: $R/set$set/train}]" --set "validation.datasets=[{root: $R/set$set/val}]" \
    --set threads=4 --set data.workers=4 "$@" >"$R/$name.log" 2>&1
}

if [ "$PHASE" = "start" ]; then
  first_set=$(echo ${VAE_SETS:-A B C} | cut -d' ' -f1)
  [ -d "$R/set$first_set/val" ] || { echo "no room set $first_set under $R: run prep first (same warm machine)"; exit 1; }
  rm -f "$R/ALL_DONE"
  setsid bash "$0" runs >"$R/runs.log" 2>&1 </dev/null &
  echo "started the GPU-0 work and the VAE recipe on set(s) ${VAE_SETS:-A B C} under $R"
fi

if [ "$PHASE" = "runs" ]; then  # started by "start", in its own process session
  if [ "${VAE_AB:-0}" = 1 ]; then  # the A/B that found the fall (session 9); 5ffc29e fixed its cause
    old=(--set optim.lr=2e-3 --set optim.grad_clip=0 --set optim.warmup_steps=100)
    ab=(--set steps=1200 --set validation.every=100 --set checkpoint.every=600)
    train_vae ab_old 0 A configs/recipe/vae_image.yaml "${old[@]}" "${ab[@]}" &
    train_vae ab_clip 0 A configs/recipe/vae_image.yaml "${old[@]}" "${ab[@]}" --set optim.grad_clip=1 &
    train_vae ab_lr 0 A configs/recipe/vae_image.yaml "${old[@]}" "${ab[@]}" --set optim.lr=5e-4 &
    train_vae ab_fp32 0 A configs/recipe/vae_image.yaml "${old[@]}" "${ab[@]}" --set precision=fp32 &
    train_vae ab_new 0 A configs/recipe/vae_image.yaml "${ab[@]}" &
  fi
  if [ "${GPU_TESTS:-0}" = 1 ]; then  # GPU 0: the CUDA tests of the modules changed since the last device run
    ( ninja -C "$BUILD" -j 6 -k 0 ${GPU_TEST_TARGETS:-flat_test_render flat_test_gaussians flat_test_surfels flat_test_optim flat_test_data} \
        >"$R/build_tests.log" 2>&1
      cd "$BUILD" && CUDA_VISIBLE_DEVICES=0 OMP_NUM_THREADS=4 ctest --output-on-failure -R "${GPU_CTEST_REGEX:-render|gaussians|surfels|optim|data}" \
        >"$R/ctest.log" 2>&1
      echo "rc $?" >>"$R/ctest.log"
      CUDA_VISIBLE_DEVICES=0 "$BUILD/tests/flat_test_render" "*cuda*" -s 2>&1 | grep "cuda-vs-cpu" >"$R/cuda_vs_cpu.log"
      for t in ${GPU_CUDA_TESTS:-render gaussians surfels optim data}; do
        [ -x "$BUILD/tests/flat_test_$t" ] && CUDA_VISIBLE_DEVICES=0 "$BUILD/tests/flat_test_$t" "[cuda]" 2>&1 | tail -2 | sed "s/^/[cuda] $t: /"
      done >"$R/cuda_only.log"
      touch "$R/TESTS_DONE" ) &
  fi
  # RASTER_BENCH=1 (issue #46): the rasterizer timings beside gsplat on GPU 2
  # and the per-kernel profile on GPU 3, while those GPUs are free (no VAE
  # sets B, C: VAE_SETS=A; variant B from stage 4: AB_B_START_STAGE=4).
  [ "${RASTER_BENCH:-0}" = 1 ] && ( mkdir -p "$R/raster"
    CUDA_VISIBLE_DEVICES=2 BENCH_ONLY=1 PROFILE_GPU=3 OUT="$R/raster" bash "$ROOT/scripts/gpu_gaussians.sh" \
      >"$R/raster/raster_bench.log" 2>&1; touch "$R/RASTER_DONE" ) &
  g=1
  for s in ${VAE_SETS:-A B C}; do
    ( t0=$(date +%s)
      train_vae "fixed_${s}_image" $g $s configs/recipe/vae_image.yaml
      train_vae "fixed_$s" $g $s configs/recipe/vae.yaml --set init.path="$R/fixed_${s}_image"
      echo $(( $(date +%s) - t0 )) >"$R/fixed_$s.seconds" ) &
    [ "$s" = A ] && vae_a=$!
    g=$((g + 1))
  done
  wait "$vae_a"   # the four stages need set A's VAE only
  # Then the recipe's four stages from set A's VAE, as soon as it is written
  # (sets B and C may still train on GPUs 2-3 for a few seconds): two seeds on
  # two GPUs each, or with FOUR_STAGES_AB=1 two variants (AB_A_* on GPUs 0-1,
  # AB_B_* on GPUs 2-3; by default the configs as shipped, which take random
  # backgrounds at stage 4 only, against random backgrounds at every stage),
  # one GPU a seed, sharing rooms and latents.
  if [ "${FOUR_STAGES:-1}" = 1 ]; then
    export VAE_FILE="$R/fixed_A/vae.safetensors"
    OUT="$R/out" bash "$ROOT/scripts/gpu_four_stages.sh" latents
    if [ "${FOUR_STAGES_AB:-0}" = 1 ]; then
      # AB_A / AB_B: each variant's name and its --set arguments for every stage.
      OUT="$R/out/${AB_A_NAME:-as_shipped}" GPUS_PER_SEED=1 EXTRA_SET="${AB_A_SET:-}" MESH_ROOMS="${MESH_ROOMS:-8}" \
        bash "$ROOT/scripts/gpu_four_stages.sh" train &
      # AB_B_STAGE4_SET: --set arguments for variant B's stage 4 only.
      # AB_B_START_STAGE=4: variant B trains stage 4 alone, from variant A's
      # stage 3 of each seed (its GPUs idle until then: RASTER_BENCH uses them).
      OUT="$R/out/${AB_B_NAME:-random_background_everywhere}" GPUS_PER_SEED=1 FIRST_GPU=2 STAGES_RUNS=/tmp/flat_stages_b \
        STAGES_DATA=/tmp/flat_stages/data EXTRA_SET="${AB_B_SET:---set loss.random_background=true}" \
        STAGE4_EXTRA_SET="${AB_B_STAGE4_SET:-}" START_STAGE="${AB_B_START_STAGE:-1}" INIT_RUNS=/tmp/flat_stages \
        MESH_ROOMS="${AB_B_MESH_ROOMS:-0}" \
        bash "$ROOT/scripts/gpu_four_stages.sh" train &
      wait
    else
      OUT="$R/out" MESH_ROOMS="${MESH_ROOMS:-8}" bash "$ROOT/scripts/gpu_four_stages.sh" train
    fi
  fi
  wait   # sets B and C, the tests
  touch "$R/ALL_DONE"
fi

# Each run's held-out reconstruction PSNR at every validation, the best, the last and the falls.
curves() {
  for log in "$R"/ab_*.log "$R"/fixed_*.log "$R"/one_*.log; do
    [ -f "$log" ] || continue
    local name; name=$(basename "$log" .log)
    local v; v=$(grep -oE 'validation @ step [0-9]+: reconstruction PSNR [0-9.]+' "$log" | sed -E 's/validation @ step ([0-9]+): reconstruction PSNR /\1:/' | tr '\n' ' ')
    local falls; falls=$(grep -c "FELL" "$log")
    local last; last=$(grep -oE 'step [0-9]+/[0-9]+' "$log" | tail -1)
    echo "$name [$last] falls=$falls | $v"
    grep -m2 -E "error|Error|FAILED" "$log" | cut -c1-240
  done
}

# One set's single-frame part on GPU 0 with ONE_ARGS (a recipe change tried
# alone, e.g. ONE_ARGS="--set optim.warmup_steps=500"), the CUDA tests beside
# it with GPU_TESTS=1; in the foreground (one GPU, one call).
if [ "$PHASE" = "one" ]; then
  set_name="${ONE_SET:-A}"
  if [ "${GPU_TESTS:-0}" = 1 ]; then
    ( timeout "${TEST_SECONDS:-420}" ninja -C "$BUILD" -j 8 -k 0 ${GPU_TEST_TARGETS:-flat_test_render flat_test_gaussians flat_test_surfels flat_test_optim flat_test_data} \
        >"$R/build_tests.log" 2>&1
      cd "$BUILD" && OMP_NUM_THREADS=4 ctest --output-on-failure -R "${GPU_CTEST_REGEX:-render|gaussians|surfels|optim|data}" \
        >"$R/ctest.log" 2>&1
      echo "rc $?" >>"$R/ctest.log"
      for t in ${GPU_CUDA_TESTS:-render gaussians surfels optim data}; do
        [ -x "$BUILD/tests/flat_test_$t" ] && "$BUILD/tests/flat_test_$t" "[cuda]" 2>&1 | tail -2 | sed "s/^/[cuda] $t: /"
      done >"$R/cuda_only.log" ) &
  fi
  t0=$(date +%s)
  # Bounded (ONE_SECONDS): it checkpoints and stops on SIGTERM, and what it
  # validated so far still comes back. The tests beside it share the cores.
  # shellcheck disable=SC2086
  TRAIN_SECONDS="${ONE_SECONDS:-300}" train_vae "one_${set_name}_image" 0 "$set_name" configs/recipe/vae_image.yaml ${ONE_ARGS:-}
  echo "one_${set_name}_image: rc $? after $(( $(date +%s) - t0 )) s (the test build beside it)"
  wait
  curves | grep one_ | tee "$OUT/vae_curves.txt"
  if [ -f "$R/ctest.log" ]; then
    grep -E "tests passed|tests failed|^rc " "$R/ctest.log"; grep -E "\*\*\*Failed|FAILED" -A3 "$R/ctest.log" | head -30
    cat "$R/cuda_only.log"
    tar czf "$OUT/tests.tgz" -C "$R" $(cd "$R" && ls ctest.log cuda_only.log build_tests.log 2>/dev/null)
  fi
  tar czf "$OUT/vae_one.tgz" -C "$R" "one_${set_name}_image/metrics" "one_${set_name}_image.log" \
    $(cd "$R" && ls one_"${set_name}"_image/renders/*.png | sed -n '1p;$p')
fi

if [ "$PHASE" = "wait" ]; then
  limit=${WAIT_SECONDS:-300}; t0=$(date +%s)
  while [ ! -f "$R/ALL_DONE" ] && [ $(( $(date +%s) - t0 )) -lt "$limit" ]; do sleep 10; done
  nvidia-smi --query-gpu=index,utilization.gpu,memory.used --format=csv,noheader
  curves | tee "$OUT/vae_curves.txt"
  if [ -f "$R/ctest.log" ]; then
    grep -E "tests passed|tests failed|^rc " "$R/ctest.log"; grep -E "\*\*\*Failed|FAILED" "$R/ctest.log" | head -10
    cat "$R/cuda_only.log" 2>/dev/null
    tar czf "$OUT/tests.tgz" -C "$R" $(cd "$R" && ls ctest.log cuda_vs_cpu.log cuda_only.log build_tests.log 2>/dev/null)
  fi
  tail -12 "$R/out/four_stages.txt" 2>/dev/null
  if [ -f "$R/RASTER_DONE" ]; then   # RASTER_BENCH: the tables, into raster.tgz
    tail -25 "$R/raster/raster_bench.log"; grep -E "^\|" "$R/raster/bench_raster.log" "$R/raster/bench_gsplat.log" 2>/dev/null
    tar czf "$OUT/raster.tgz" -C "$R" raster
  fi
  for v in "$R"/out/*/; do [ -f "$v/four_stages.txt" ] && { echo "== $(basename "$v")"; tail -10 "$v/four_stages.txt"; }; done
  for s in A B C; do [ -f "$R/fixed_$s.seconds" ] && echo "fixed recipe on set $s: $(cat "$R/fixed_$s.seconds") s from launch to the VAE file"; done | tee -a "$OUT/vae_curves.txt"
  if [ -f "$R/ALL_DONE" ]; then
    echo "all runs done"
    # The four stages' tables, results, logs and grids: one archive per
    # variant (FOUR_STAGES_AB) or one for the single run (the device returns 8 files).
    variants=0
    for v in "$R"/out/*/; do
      [ -d "$v" ] || continue
      v=$(basename "$v"); variants=$((variants + 1)); tar czf "$OUT/four_stages_$v.tgz" -C "$R/out/$v" .
    done
    [ "$variants" -eq 0 ] && [ -d "$R/out" ] && tar czf "$OUT/four_stages.tgz" -C "$R/out" .
    tar czf "$OUT/vae_metrics.tgz" -C "$R" $(cd "$R" && ls -d */metrics */logs *.log 2>/dev/null) 2>/dev/null
    # The first and the last grid of each run (all of them exceed the device's 16 MiB a file).
    tar czf "$OUT/vae_grids.tgz" -C "$R" $(cd "$R" && for d in */renders; do ls "$d"/*.png 2>/dev/null | sed -n '1p;$p'; done) 2>/dev/null
  else
    echo "still running after ${limit} s: call wait again"
  fi
fi
