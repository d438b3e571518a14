#!/usr/bin/env bash
# Whatever the background runs of scripts/gpu_vae.sh have finished so far, into
# $OUT: for a device call near the end of the session's budget, which cannot
# wait for ALL_DONE. Waits up to WAIT_SECONDS for ALL_DONE first.
#   results.tgz  every flat_eval's results.json and table, both variants'
#                four_stages.txt and compare tables, the mesh table
#   logs.tgz     the stage logs and metrics (*.jsonl)
#   grids_*.tgz  seed 0's last validation grid of stages 2 and 4, each variant
#                (grids_stages_s2.tgz ...), and one mesh comparison
#   vae.tgz      the VAE runs' metrics and logs
#   raster.tgz   RASTER_BENCH's timings, profile and gsplat logs
set -uo pipefail
source "$(dirname "$0")/gpu_common.sh"   # ROOT, OUT, BUILD
R="${VAE_RUNS:-/tmp/flat_vae}"
limit=${WAIT_SECONDS:-0}; t0=$(date +%s)
while [ ! -f "$R/ALL_DONE" ] && [ $(( $(date +%s) - t0 )) -lt "$limit" ]; do sleep 5; done
[ -f "$R/ALL_DONE" ] && echo "all runs done" || echo "collecting while runs go on ($(( $(date +%s) - t0 )) s waited)"
nvidia-smi --query-gpu=index,utilization.gpu,memory.used --format=csv,noheader
for S in /tmp/flat_stages /tmp/flat_stages_b; do
  [ -d "$S" ] || continue
  for set in val fresh; do
    evals=$(ls -d "$S"/eval_${set}_seed*/ 2>/dev/null | while read -r d; do [ -f "$d/results.json" ] && echo "$d"; done)
    # shellcheck disable=SC2086
    [ -n "$evals" ] && "$BUILD/flat_eval" --compare $evals --out-table "$S/compare_$set.md" --overwrite >/dev/null 2>&1
  done
done
for v in "$R"/out/*/; do [ -f "$v/four_stages.txt" ] && { echo "== $(basename "$v")"; cat "$v/four_stages.txt"; }; done
cd /tmp && tar czf "$OUT/results.tgz" $(ls -d flat_stages*/eval_*/results.json flat_stages*/eval_*/table.md flat_stages*/compare_*.md \
  flat_stages*/mesh/mesh_room_*/metrics.json flat_stages*/mesh/mesh_room_*/mesh_stats.json flat_stages*/mesh/rc.txt \
  flat_stages*/mesh/*.log 2>/dev/null) \
  -C "$R" $(cd "$R" && ls out/*/*.txt out/*/*.md 2>/dev/null)   # not out's archives: copies, and the 16 MiB a file
tar czf "$OUT/logs.tgz" $(ls flat_stages*/*.log flat_stages*/seed*/stage*/metrics/*.jsonl flat_stages*/seed*/stage*/logs/*.jsonl 2>/dev/null)
# Seed 0's last grid of stages 2 and 4 of each variant, one archive each: all
# of them in one passed the device's 16 MiB a file (21 MB on 2026-11-28).
for S in flat_stages flat_stages_b; do
  for st in 2 4; do
    g=$(ls $S/seed0/stage$st/renders/*.png 2>/dev/null | tail -1)
    [ -n "$g" ] && tar czf "$OUT/grids_${S#flat_}_s$st.tgz" "$g"
  done
done
m=$(ls flat_stages/mesh/mesh_room_*/renders/compare.png 2>/dev/null | head -1)
[ -n "$m" ] && tar czf "$OUT/grids_mesh.tgz" "$m"
[ -d "$R/raster" ] && tar czf "$OUT/raster.tgz" -C "$R" raster
tar czf "$OUT/vae.tgz" -C "$R" $(cd "$R" && ls -d fixed_*/metrics fixed_*/logs fixed_*.log 2>/dev/null)
ls -la "$OUT"
