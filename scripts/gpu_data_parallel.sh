#!/usr/bin/env bash
# Data-parallel training over NCCL on a multi-GPU machine (docs/benchmarks.md,
# "Data-parallel training over NCCL"). Run on the GPU machine from the repo
# root, after a build (scripts/gpu_check.sh or GPU_BUILD_DIR):
#
#   bash scripts/gpu_data_parallel.sh
#
# For each stage in DP_STAGES (default 1), on synthetic rooms with random-weight
# dim-96 latents, from scratch weights with random LPIPS weights:
#   1. scaling: flat_train with 1 sample per GPU on 1, 2, ... GPUs (DP_NPROCS,
#      default "1 <all GPUs>"), DP_STEPS steps each: median step time after the
#      first DP_SKIP steps, samples/s, scaling efficiency, peak memory per rank;
#   2. equivalence: one GPU with the combined batch, twice (its run-to-run
#      spread is the noise floor), against the W-GPU run: the losses of the
#      first steps;
#   3. (stage 1 only) a W-rank run with rank 1 SIGKILLed mid-run: seconds until
#      the launcher exits and its message; then --resume on all ranks.
# Knobs: DP_STAGES, DP_NPROCS, DP_STEPS, DP_SKIP, DP_SCENES (synthetic rooms,
# default 8), DP_ROUNDS (scaling repeated, 1 and W GPUs interleaved, then the
# efficiency of the mean steps), DP_PARTS (default "scaling equivalence kill"), DP_SETS (extra
# flat_train overrides for every run, e.g. "precision=fp32"), DP_TAG (log name suffix).
# Everything goes to $OUT (dp_*.log, dp_summary.txt, and each run's metrics in
# dp_metrics_<stage><tag>.tgz). The scaling part also prints the 1-GPU steps'
# spread (what uneven data alone would cost at 2 GPUs); the equivalence part
# the step-0 gradient norms (with precision=fp32 and NVIDIA_TF32_OVERRIDE=0
# they agree to ~1e-6; TF32 convolutions alone leave ~2e-4).
set -uo pipefail
source "$(dirname "$0")/gpu_common.sh"  # ROOT, OUT, BUILD; gpu_card, gpu_configure, gpu_build
NGPU=$(nvidia-smi -L | wc -l)
NPROCS="${DP_NPROCS:-1 $NGPU}"
STEPS="${DP_STEPS:-30}"
SKIP="${DP_SKIP:-5}"
EQ_STEPS="${DP_EQ_STEPS:-10}"  # steps of each equivalence run (fp32 without TF32 is slow)
ROUNDS="${DP_ROUNDS:-1}"      # scaling runs repeated, 1 and W GPUs interleaved
W="${NPROCS##* }"               # the largest count: the equivalence and kill runs
WORK="${DP_WORK:-/tmp/flat_dp}"; mkdir -p "$WORK"   # the data of an earlier call are reused
PARTS="${DP_PARTS:-scaling equivalence kill}"
TAG="${DP_TAG:-}"
SETS=(); for kv in ${DP_SETS:-}; do SETS+=(--set "$kv"); done
SUM="$OUT/dp_summary$TAG.txt"; : >"$SUM"
say() { echo "$*" | tee -a "$SUM"; }
# NVLink multicast stays off on shared hosts (the device notes); inherited by the workers.
export NCCL_NVLS_ENABLE=0 TORCH_SYMM_MEM_DISABLE_MULTICAST=1 NVSHMEM_DISABLE_NVLS=1

say "== data-parallel runs: $(nvidia-smi --query-gpu=name --format=csv,noheader | sort | uniq -c | xargs), commit ${FLAT_COMMIT:-$(git -C "$ROOT" rev-parse --short HEAD 2>/dev/null)}, $(date -u +%F)"

# Median of step_seconds after the first $SKIP steps of a run folder's metrics.
median_step() {
  python3 - "$1/metrics/train.jsonl" "$SKIP" <<'EOF'
import json, statistics, sys
rows = [json.loads(l) for l in open(sys.argv[1]) if l.strip()]
s = [r["step_seconds"] for r in rows if r["step"] >= int(sys.argv[2])]
print(f"{statistics.median(s):.4f}")
EOF
}
# The 1-GPU steps' spread: what the slower of two ranks costs when each draws
# its own sample (the median over all pairs of max(t_i, t_j) against the median),
# an estimate of the data-parallel overhead that uneven data alone explains.
pair_max() {
  python3 - "$1/metrics/train.jsonl" "$SKIP" <<'EOF'
import itertools, json, statistics, sys
rows = [json.loads(l) for l in open(sys.argv[1]) if l.strip()]
s = sorted(r["step_seconds"] for r in rows if r["step"] >= int(sys.argv[2]))
m = statistics.median(s)
pm = statistics.median(max(a, b) for a, b in itertools.combinations(s, 2))
print(f"1-GPU step spread: p10 {1e3*s[len(s)//10]:.1f} ms, median {1e3*m:.1f} ms, p90 {1e3*s[9*len(s)//10]:.1f} ms; "
      f"median of the slower of two: {1e3*pm:.1f} ms (uneven data alone: {100*m/pm:.1f}% at 2 GPUs)")
EOF
}
peaks() { grep -oE "peak GPU memory.*" "$1" | tail -1 | sed 's/.*: //'; }

source "$ROOT/scripts/stage_sizes.sh"
LPIPS="$WORK/random_lpips.safetensors"
for stage in ${DP_STAGES:-1}; do
  stage_sizes "$stage" || continue
  D="$WORK/data${stage}_${DP_SCENES:-8}"
  [ -e "$D/.ready" ] || { rm -rf "$D" && "$BUILD/flat_synth" --out "$D" --count ${DP_SCENES:-8} --seed $stage --family room --frames $frames --size $size --motion mixed &&
    "$BUILD/flat_latents" --scenes "$D" --random-weights --seed 0 --dim 96 --window $frames --device cuda --precision bf16 &&
    # The random LPIPS file (flat_bench train writes it; 1 timed step).
    "$BUILD/flat_bench" train --config configs/stage$stage.yaml --random-lpips --warmup 1 --steps 1 \
      --set "data.datasets=[{root: $D}]" --set validation.datasets=[] "${SETS[@]}" && cp /tmp/flat_bench_random_lpips.safetensors "$LPIPS" && touch "$D/.ready"; } \
    >"$OUT/dp_data_$stage$TAG.log" 2>&1 || { say "stage $stage: data preparation failed"; tail -20 "$OUT/dp_data_$stage$TAG.log"; continue; }
  # One flat_train run: name, ranks, global batch, steps, extra --set args.
  train() {
    local name=$1 n=$2 batch=$3 steps=$4; shift 4
    local nproc=(); [ "$n" -gt 1 ] && nproc=(--nproc "$n")
    rm -rf "$WORK/$name"
    "$BUILD/flat_train" --config configs/stage$stage.yaml "${nproc[@]}" --set run_dir="$WORK/$name" \
      --set steps=$steps --set data.batch_size=$batch --set init.from=scratch --set "init.path=''" \
      --set loss.lpips_weights="$LPIPS" --set "data.datasets=[{root: $D}]" --set validation.datasets=[] \
      --set optim.warmup_steps=0 --set checkpoint.every=1000000 --set log.progress_seconds=30 "${SETS[@]}" "$@" \
      >"$OUT/dp_${name}$TAG.log" 2>&1
  }
  say "-- stage $stage ($size, $frames frames${DP_SETS:+, $DP_SETS})"
  declare -A sps=() all=()
  [[ " $PARTS " == *" scaling "* ]] && say "scaling: $STEPS steps, median step time after step $SKIP, $ROUNDS round(s)"
  for r in $(seq 1 "$ROUNDS"); do
  for n in $NPROCS; do
    [[ " $PARTS " == *" scaling "* ]] || break 2
    name=s${stage}_w$n; [ "$r" -gt 1 ] && name=${name}_r$r
    train $name $n $n $STEPS; rc=$?
    t=$(median_step "$WORK/$name" 2>/dev/null)
    sps[$n]=""; [ -n "$t" ] && sps[$n]=$(python3 -c "print(f'{$n/$t:.3f}')") && all[$n]="${all[$n]:-} $t"
    eff=""; [ -n "${sps[1]:-}" ] && [ -n "${sps[$n]:-}" ] && eff=$(python3 -c "print(f'{100*${sps[$n]}/($n*${sps[1]}):.1f}%')")
    prefix=""; [ "$ROUNDS" -gt 1 ] && prefix="round $r: "
    say "$prefix$n GPU(s), batch $n (1 per GPU) rc=$rc: step ${t:-?} s, ${sps[$n]:-?} samples/s, ${sps[$n]:+$(python3 -c "print(f'{${sps[$n]}/$n:.3f}')")} it/s per GPU, scaling efficiency ${eff:-n/a}, peak GiB per rank: $(peaks "$OUT/dp_$name$TAG.log")"
    [ "$n" = 1 ] && [ -n "$t" ] && say "  $(pair_max "$WORK/$name")"
  done
  done
  # Over the rounds (each run's 1-GPU reference interleaved with it): the
  # efficiency of the mean step times, against the spread of the rounds.
  if [ "$ROUNDS" -gt 1 ] && [ -n "${all[1]:-}" ]; then
    for n in $NPROCS; do
      [ "$n" = 1 ] || [ -z "${all[$n]:-}" ] && continue
      say "pooled over $ROUNDS rounds: $(python3 -c "
import statistics as st
one = [float(x) for x in '${all[1]}'.split()]; many = [float(x) for x in '${all[$n]}'.split()]
per = ', '.join(f'{100*a/b:.1f}%' for a, b in zip(one, many))
print(f'1 GPU {1e3*st.mean(one):.1f} ms, $n GPUs {1e3*st.mean(many):.1f} ms: scaling efficiency {100*st.mean(one)/st.mean(many):.1f}% (rounds: {per})')")"
    done
  fi
  if [ "$W" -gt 1 ] && [[ " $PARTS " == *" equivalence "* ]]; then
    [[ " $PARTS " == *" scaling "* ]] || train s${stage}_w$W $W $W $EQ_STEPS
    train s${stage}_one_a 1 $W $EQ_STEPS
    train s${stage}_one_b 1 $W $EQ_STEPS
    python3 - "$WORK/s${stage}_one_a" "$WORK/s${stage}_one_b" "$WORK/s${stage}_w$W" "$W" <<'EOF' | tee -a "$SUM"
import json, sys
def losses(d, key="loss"):
    return {json.loads(l)["step"]: json.loads(l)[key] for l in open(d + "/metrics/train.jsonl") if l.strip()}
a, b, w = (losses(d) for d in sys.argv[1:4])
# Step 0 starts from the same weights on the same batch: its gradient norm
# compares the averaged gradient itself, before the runs drift apart.
ga, gb, gw = (losses(d, "grad_norm")[0] for d in sys.argv[1:4])
print(f"step 0 gradient norm: 1 GPU {ga:.6e} / {gb:.6e}, {sys.argv[4]} GPUs {gw:.6e}; rel. gaps a-b {abs(ga-gb)/ga:.1e}, a-W {abs(ga-gw)/ga:.1e}")
print(f"losses of the first steps, global batch {sys.argv[4]}: 1 GPU (run a), 1 GPU (run b), {sys.argv[4]} GPUs; rel. gaps")
for s in sorted(a)[:10]:
    if s in b and s in w:
        print(f"  step {s:2d}: {a[s]:.6f} {b[s]:.6f} {w[s]:.6f}   a-b {abs(a[s]-b[s])/abs(a[s]):.2e}   a-W {abs(a[s]-w[s])/abs(a[s]):.2e}")
EOF
  fi
  if [ "$W" -gt 1 ] && [[ " $PARTS " == *" kill "* ]]; then
    # Kill rank 1 once the run has checkpointed twice and gone on.
    every=${DP_KILL_EVERY:-10}
    name=s${stage}_kill; rm -rf "$WORK/$name"
    train $name $W $W 100000 --set checkpoint.every=$every &
    launcher=$!
    for i in $(seq 1 1200); do
      n=$(cat "$WORK/$name/metrics/train.jsonl" 2>/dev/null | wc -l)
      [ "$n" -ge $((2 * every + 5)) ] && break; sleep 0.5
    done
    victim=""
    for p in $(pgrep -f "run_dir=$WORK/$name"); do
      tr '\0' '\n' <"/proc/$p/environ" 2>/dev/null | grep -qx "RANK=1" && victim=$p
    done
    t0=$(date +%s.%N); kill -9 "$victim"; wait $launcher; rc=$?; t1=$(date +%s.%N)
    say "kill: rank 1 (pid $victim) SIGKILLed after $(wc -l <"$WORK/$name/metrics/train.jsonl") logged steps; launcher exit $rc after $(python3 -c "print(f'{$t1-$t0:.1f}')") s"
    grep -E "rank 1|error|killed" "$OUT/dp_$name$TAG.log" | tail -4 | sed 's/^/  /' | tee -a "$SUM"
    ls "$WORK/$name/checkpoints" | sed 's/^/  checkpoint: /' | tee -a "$SUM"
    last=$(ls "$WORK/$name/checkpoints" | grep -oE '[0-9]+' | sort -n | tail -1); last=$((10#$last))
    "$BUILD/flat_train" --resume "$WORK/$name" --nproc $W --set steps=$((last + every)) >"$OUT/dp_${name}_resume$TAG.log" 2>&1
    say "resume --nproc $W rc=$?: $(grep -oE 'resume: .*' "$OUT/dp_${name}_resume$TAG.log" | head -1); $(grep -oE "finished: .*" "$OUT/dp_${name}_resume$TAG.log" | tail -1)"
  fi
  unset sps
  # Every run's metrics, for a closer look.
  (cd "$WORK" && tar czf "$OUT/dp_metrics_$stage$TAG.tgz" $(ls -d s${stage}_*/metrics 2>/dev/null))
done
say "== end"
