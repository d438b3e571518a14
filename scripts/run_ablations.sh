#!/usr/bin/env bash
# The paper's ablations and Table 1 baselines, one command: trains every row
# (a configs/ablations/ overlay layered over one base stage config) on the same
# data for each seed, evaluates each run on held-out scenes with flat_eval (its
# baselines beside every row), and tabulates them with flat_eval --compare (one
# row per run, then the rows over seeds: mean ± spread). docs/research.md.
#
# Usage: scripts/run_ablations.sh [options] ROW.yaml...
#   --base FILE       base stage config (default configs/recipe/stage1.yaml)
#   --seeds "0 1"     seeds per row (default "0 1")
#   --out DIR         runs, evaluations and table.md go here (default runs/ablations)
#   --eval DIR        held-out scene folders for flat_eval (default: the base's validation root)
#   --max-views N     views per held-out scene (default 9)
#   --parallel N      trainings side by side (default 1; threads are split between them)
#   --seconds S       bound each training: SIGTERM after S s (it checkpoints; flat_eval reads the newest)
#   --set KEY=VALUE   an override for every training (repeatable)
#   --build DIR       the flat_* binaries (default build, or build/bin when that exists)
#   --device D        cuda | cpu (default cuda when nvidia-smi works)
# A finished run (model.safetensors present) is not trained again: rerunning
# the command after a stop continues where it stopped.
set -uo pipefail
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
BASE="$ROOT/configs/recipe/stage1.yaml"; SEEDS="0 1"; OUT="runs/ablations"; EVAL=""; MAX_VIEWS=9
PARALLEL=1; SECONDS_BOUND=""; SETS=(); BUILD=""; DEVICE=""; ROWS=()
while [ $# -gt 0 ]; do
  case "$1" in
    --base) BASE=$2; shift 2 ;;
    --seeds) SEEDS=$2; shift 2 ;;
    --out) OUT=$2; shift 2 ;;
    --eval) EVAL=$2; shift 2 ;;
    --max-views) MAX_VIEWS=$2; shift 2 ;;
    --parallel) PARALLEL=$2; shift 2 ;;
    --seconds) SECONDS_BOUND=$2; shift 2 ;;
    --set) SETS+=(--set "$2"); shift 2 ;;
    --build) BUILD=$2; shift 2 ;;
    --device) DEVICE=$2; shift 2 ;;
    -h|--help) sed -n '2,20p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
    -*) echo "run_ablations.sh: unknown option $1 (see --help)" >&2; exit 2 ;;
    *) ROWS+=("$1"); shift ;;
  esac
done
[ ${#ROWS[@]} -gt 0 ] || { echo "run_ablations.sh: name at least one row, e.g. configs/ablations/*.yaml" >&2; exit 2; }
[ -f "$BASE" ] || { echo "run_ablations.sh: base config $BASE not found" >&2; exit 2; }
for r in "${ROWS[@]}"; do [ -f "$r" ] || { echo "run_ablations.sh: row $r not found" >&2; exit 2; }; done
if [ -z "$BUILD" ]; then BUILD="$ROOT/build"; [ -x "$BUILD/bin/flat_train" ] && BUILD="$BUILD/bin"; fi
[ -x "$BUILD/flat_train" ] && [ -x "$BUILD/flat_eval" ] || { echo "run_ablations.sh: no flat_train/flat_eval in $BUILD (--build)" >&2; exit 2; }
if [ -z "$DEVICE" ]; then DEVICE=cpu; nvidia-smi >/dev/null 2>&1 && DEVICE=cuda; fi
if [ -z "$EVAL" ]; then
  EVAL=$("$BUILD/flat_train" --config "$BASE" --print-config | awk '/^validation:/{v=1} v && /root:/{print $NF; exit}' | tr -d '}')
fi
[ -d "$EVAL" ] || { echo "run_ablations.sh: held-out scenes '$EVAL' not found (--eval)" >&2; exit 2; }
THREADS=$(( $(nproc) / PARALLEL )); [ "$THREADS" -ge 1 ] || THREADS=1
mkdir -p "$OUT/logs"
echo "run_ablations: ${#ROWS[@]} rows x seeds [$SEEDS] over $BASE, $PARALLEL side by side, $THREADS threads each; held-out: $EVAL"

train_one() {  # row-file seed
  local row=$1 seed=$2 name; name="$(basename "$row" .yaml)_s$seed"
  local run="$OUT/$name" log="$OUT/logs/$name.log"
  if [ -f "$run/model.safetensors" ]; then echo "  $name: trained already"; return 0; fi
  local start=(--config "$BASE" --config "$row" --set run_dir="$run" --set seed="$seed")
  [ -d "$run/checkpoints" ] && start=(--resume "$run")
  local bound=(); [ -n "$SECONDS_BOUND" ] && bound=(timeout -s TERM "$SECONDS_BOUND")
  OMP_NUM_THREADS=$THREADS "${bound[@]}" "$BUILD/flat_train" "${start[@]}" --device "$DEVICE" \
    --set threads="$THREADS" "${SETS[@]}" >"$log" 2>&1
  local rc=$?
  echo "  $name: flat_train rc=$rc ($(grep -oE 'step [0-9]+/[0-9]+' "$log" | tail -1)); log $log"
}

jobs_running() { jobs -rp | wc -l; }
for seed in $SEEDS; do
  for row in "${ROWS[@]}"; do
    while [ "$(jobs_running)" -ge "$PARALLEL" ]; do sleep 2; done
    train_one "$row" "$seed" &
  done
done
wait

evals=()
for seed in $SEEDS; do
  for row in "${ROWS[@]}"; do
    name="$(basename "$row" .yaml)_s$seed"; run="$OUT/$name"
    [ -d "$run" ] || continue
    while [ "$(jobs_running)" -ge "$PARALLEL" ]; do sleep 2; done
    OMP_NUM_THREADS=$THREADS "$BUILD/flat_eval" --model "$run" --scenes "heldout=$EVAL" --out "$OUT/eval_$name" \
      --name "$(basename "$row" .yaml) seed $seed" --max-views "$MAX_VIEWS" --device "$DEVICE" \
      >"$OUT/logs/eval_$name.log" 2>&1 &
    evals+=("$OUT/eval_$name")
  done
done
wait
present=(); for e in "${evals[@]}"; do [ -f "$e/results.json" ] && present+=("$e"); done
[ ${#present[@]} -gt 0 ] || { echo "run_ablations.sh: no evaluation finished (logs in $OUT/logs)" >&2; exit 1; }
"$BUILD/flat_eval" --compare "${present[@]}" --out-table "$OUT/table.md" --overwrite >/dev/null || exit 1
echo "run_ablations: table in $OUT/table.md"
cat "$OUT/table.md"
