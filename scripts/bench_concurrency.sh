#!/usr/bin/env bash
# Two CPU tools side by side against one alone (issue #30): flat_synth makes
# the same batch of rooms once alone and then twice at the same time (each
# with the default threads, as a user would start them). Prints the seconds
# and the ratio (two side by side / one alone; 1.0 = free, 2.0 = no overlap).
#   bash scripts/bench_concurrency.sh [flat_synth binary] [scenes] [size]
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
BIN="${1:-$ROOT/build/flat_synth}"; SCENES="${2:-8}"; SIZE="${3:-48x80}"
T="$(mktemp -d)"; trap 'rm -rf "$T"' EXIT
synth() { "$BIN" --out "$T/$1" --scenes "$SCENES" --frames 17 --size "$SIZE" --seed 7 --log-level warn; }
now() { date +%s.%N; }
t0=$(now); synth alone; t1=$(now)
synth a & synth b & wait; t2=$(now)
cmp -s "$T/alone/room_000000/images/000008.png" "$T/a/room_000000/images/000008.png" 2>/dev/null \
  || cmp -s "$T/alone/room_000000/images/000008.safetensors" "$T/a/room_000000/images/000008.safetensors" \
  || { echo "outputs differ between runs"; exit 1; }
awk -v a="$t0" -v b="$t1" -v c="$t2" -v n="$SCENES" -v s="$SIZE" -v cores="$(nproc)" 'BEGIN {
  printf "flat_synth, %d rooms of 17 frames at %s, %d cores: one alone %.1f s; two side by side %.1f s; ratio %.2f\n",
         n, s, cores, b - a, c - b, (c - b) / (b - a) }'
