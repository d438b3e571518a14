#!/usr/bin/env bash
# Two CPU tools side by side against one alone (issue #30). Each run uses the
# tool's default threads, as a user would start them; the script prints the
# seconds and the ratio (two side by side / one alone; 1.0 = free, 2.0 = no
# overlap, the target is <= 2.5).
#   bash scripts/bench_concurrency.sh synth [build dir] [scenes] [size]
#     flat_synth makes the same batch of rooms once alone, then twice at once
#     (and the outputs must agree);
#   bash scripts/bench_concurrency.sh latents [build dir] [dim]
#     flat_latents (random-weight encoder of base width `dim`, default 32, on
#     the CPU) encodes the same 4 rooms of 17 frames at 96x160 once alone,
#     then two copies at once;
#   bash scripts/bench_concurrency.sh train [build dir] [steps]
#     flat_train (configs/tiny/stage1.yaml on the CPU, from scratch, on 4
#     synthetic rooms with random-weight dim-8 latents, no validation) runs
#     `steps` steps once alone, then twice at once (DEVICE=cuda: both on the
#     one GPU, validating on 2 rooms every 10 steps).
# Extra environment (OMP_NUM_THREADS, OMP_WAIT_POLICY) passes through to the tools.
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
MODE="${1:-synth}"
BUILD="${2:-$ROOT/build}"
T="$(mktemp -d)"; trap 'rm -rf "$T"' EXIT
now() { date +%s.%N; }
report() {  # $1: what, $2 $3 $4: times
  awk -v what="$1" -v a="$2" -v b="$3" -v c="$4" -v cores="$(nproc)" 'BEGIN {
    printf "%s, %d cores: one alone %.1f s; two side by side %.1f s; ratio %.2f\n", what, cores, b - a, c - b, (c - b) / (b - a) }'
}
case "$MODE" in
  synth)
    SCENES="${3:-8}"; SIZE="${4:-48x80}"
    synth() { "$BUILD/flat_synth" --out "$T/$1" --count "$SCENES" --frames 17 --size "$SIZE" --seed 7 --log-level warn; }
    t0=$(now); synth alone; t1=$(now)
    synth a & synth b & wait; t2=$(now)
    cmp -s "$T/alone/room_000000/images/000008.png" "$T/a/room_000000/images/000008.png" 2>/dev/null \
      || cmp -s "$T/alone/room_000000/images/000008.safetensors" "$T/a/room_000000/images/000008.safetensors" \
      || { echo "outputs differ between runs"; exit 1; }
    report "flat_synth, $SCENES rooms of 17 frames at $SIZE" "$t0" "$t1" "$t2"
    ;;
  latents)
    DIM="${3:-32}"
    "$BUILD/flat_synth" --out "$T/src" --count 4 --frames 17 --size 96x160 --seed 3 --log-level warn
    latents() {
      rm -rf "$T/$1"; cp -r "$T/src" "$T/$1"
      "$BUILD/flat_latents" --scenes "$T/$1" --random-weights --seed 0 --dim "$DIM" --window 17 --device cpu \
        --log-level error >"$T/latents_$1.log" 2>&1 || { echo "flat_latents $1 failed:"; tail -3 "$T/latents_$1.log"; exit 1; }
    }
    t0=$(now); latents alone; t1=$(now)
    latents a & latents b & wait; t2=$(now)
    report "flat_latents on cpu, 4 rooms of 17 frames at 96x160, dim $DIM" "$t0" "$t1" "$t2"
    ;;
  train)
    STEPS="${3:-30}"
    "$BUILD/flat_synth" --out "$T/data" --count 4 --frames 17 --size 48x80 --seed 7 --log-level warn
    "$BUILD/flat_latents" --scenes "$T/data" --random-weights --seed 0 --dim 8 --window 9 --step 4 --log-level warn
    DEVICE="${DEVICE:-cpu}"
    val=(--set validation.datasets=[])
    [ "$DEVICE" = cuda ] && val=(--set "validation.datasets=[{root: $T/data}]" --set validation.every=10 --set validation.scenes=2)
    train() {
      "$BUILD/flat_train" --config "$ROOT/configs/tiny/stage1.yaml" --set run_dir="$T/run_$1" --set steps="$STEPS" \
        --set init.from=scratch --set "init.path=''" --set "data.datasets=[{root: $T/data}]" --set device="$DEVICE" \
        "${val[@]}" --set checkpoint.every=100000 --log-level warn >"$T/train_$1.log" 2>&1 \
        || { echo "flat_train $1 failed:"; tail -5 "$T/train_$1.log"; exit 1; }
    }
    t0=$(now); train alone; t1=$(now)
    train a & train b & wait; t2=$(now)
    report "flat_train on $DEVICE, configs/tiny/stage1.yaml, $STEPS steps" "$t0" "$t1" "$t2"
    ;;
  *) echo "usage: $0 synth|latents|train [build dir] ..."; exit 2 ;;
esac
