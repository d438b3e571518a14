#!/usr/bin/env bash
# Dataset preparation at scale (issue #43 "Scale"), on the CPU: N small
# RealEstate10K-format clips (flat_synth --format re10k, 2 of them corrupt)
# through flat_import batch mode and flat_latents, timed, with the peak memory
# of every process, and killed halfway (SIGKILL) then rerun.
#   bash scripts/bench_dataset_scale.sh [build dir] [clips] [size HxW] [frames]
#     defaults: build/, 1000 clips, 32x48, 9 frames (5-6 minutes on 2 idle cores)
# It measures
#   import   flat_import re10k --in CAMS --frames-dir FRAMES --out OUT --depth DEPTH
#            --normals NORMALS --normals-convention opengl --scale 0.5 --jobs 1, then
#            --jobs 2 into a fresh folder: clips/min (import_summary.json), wall time,
#            peak RSS; the two corrupt clips of the manifest must be the failures;
#   latents  flat_latents --random-weights --dim 4 --window 5 --device cpu: one
#            process with 1 thread (OMP_NUM_THREADS=1 --threads 1), one with 2
#            threads, two processes at once (--shard 0/2 and 1/2, 1 thread each),
#            and one process on a quarter of the scenes (the peak must not grow
#            with the number of scenes); scenes encoded per minute from the
#            report (flat_latents_report*.json: sets_per_minute, one set per
#            scene here), peak RSS per process;
#   kill     flat_import --jobs 2 and then flat_latents started on every clip,
#            SIGKILLed when half the clips are done (counted from the output
#            folders), rerun: the rerun must find exactly what was done as
#            already present, do only the rest, rewrite nothing that was done
#            (files newer than a marker), and leave no staging folder / staged file.
# Peak RSS is /usr/bin/time -v's "Maximum resident set size" (Debian package
# `time`: apt-get install time); RSS is also sampled from /proc every 0.2 s
# to compare the first and second half of a run. JSON is read with jq (apt-get
# install jq). A process that only loads the libraries (`--version`) is
# measured too: that baseline is most of every peak. Each run's other_s is
# the CPU time the rest of the machine used meanwhile (/proc/stat): a figure
# with a large one was measured on cores shared with other work.
# The tools are copied into a temp folder first (a rebuild during the run does
# not change them); everything lands in one mktemp folder under $TMPDIR
# (about 1 GB for 1000 clips of 32x48), removed at the end, also on error or
# Ctrl-C (any tool still running is killed). Exit 1 when a check fails.
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
BUILD="${1:-$ROOT/build}"
N="${2:-1000}"
SIZE="${3:-32x48}"
FRAMES="${4:-9}"
CORRUPT=2
UNIT=0.5
WINDOW=5
DIM=4
QUARTER=$((N / 4))
GOOD=$((N - CORRUPT))
for tool in flat_synth flat_import flat_latents; do
  [ -x "$BUILD/$tool" ] || { echo "no $BUILD/$tool: build it first"; exit 2; }
done
[ -x /usr/bin/time ] || { echo "/usr/bin/time missing: apt-get install time"; exit 2; }
command -v jq >/dev/null || { echo "jq missing: apt-get install jq"; exit 2; }
[ "$N" -ge 16 ] || { echo "clips: at least 16"; exit 2; }
[ "$FRAMES" -ge "$WINDOW" ] || { echo "frames: at least $WINDOW (one latent window)"; exit 2; }

T="$(mktemp -d "${TMPDIR:-/tmp}/flat_dataset_scale.XXXXXX")"
cleanup() {  # this script's background jobs that still run, and their children (the tools under /usr/bin/time)
  local p c
  for p in $(jobs -p); do
    for c in $(pgrep -P "$p" || true); do kill -KILL "$c" 2>/dev/null || true; done
    kill -KILL "$p" 2>/dev/null || true
  done
  wait 2>/dev/null || true
  rm -rf "$T"
}
trap cleanup EXIT
trap 'exit 130' INT TERM
free_mb=$(df -Pm "$T" | awk 'NR == 2 {print $4}')
need_mb=$((N * 2 + 500))
[ "$free_mb" -ge "$need_mb" ] || { echo "$T: $free_mb MB free, want $need_mb"; exit 2; }
mkdir "$T/bin"
cp "$BUILD/flat_synth" "$BUILD/flat_import" "$BUILD/flat_latents" "$T/bin/"
B="$T/bin"

FAILED=0
check() {  # $1: condition (0/1 from a test), $2: what
  if [ "$1" = 0 ]; then echo "  ok: $2"; else echo "  FAILED: $2"; FAILED=1; fi
}
is() { if [ "$1" = "$2" ]; then echo 0; else echo 1; fi; }
now() { date +%s.%N; }
# CPU time of the whole machine so far (user+nice+system+irq+softirq+steal), in seconds.
busy_s() { awk -v hz="$(getconf CLK_TCK)" '/^cpu / {printf "%.2f", ($2 + $3 + $4 + $7 + $8 + $9) / hz}' /proc/stat; }
peak_mb() { awk -F': ' '/Maximum resident set size/ {printf "%.0f", $2 / 1024}' "$1"; }
# CPU seconds the rest of the machine used during run $1 (its own processes' CPU $2, default its cpu_s
# taken off): well above 0 means other work shared the cores.
other_s() {
  awk -v a="$(cat "$T/$1.busy0")" -v b="$(cat "$T/$1.busy1")" -v own="${2:-$(cpu_s "$T/$1.time")}" \
    'BEGIN {o = b - a - own; printf "%.1f", o < 0 ? 0 : o}'
}
cpu_s() { awk -F': ' '/(User|System) time \(seconds\)/ {s += $2} END {printf "%.1f", s}' "$1"; }
wall_s() { awk -F': ' '/Elapsed \(wall clock\)/ {n = split($2, a, ":"); s = 0; for (i = 1; i <= n; ++i) s = s * 60 + a[i]; printf "%.1f", s}' "$1"; }
# Max of the RSS samples of the first and of the second half of a run, in MB.
halves_mb() { awk '{v[NR] = $1} END {if (NR < 2) {print "-"; exit} h = int(NR / 2); a = 0; b = 0; for (i = 1; i <= NR; ++i) if (i <= h) { if (v[i] > a) a = v[i] } else if (v[i] > b) b = v[i]; printf "%.0f / %.0f", a / 1024, b / 1024}' "$1"; }

# Samples VmRSS (kB) of the child of /usr/bin/time pid $1 into $2 until it ends.
sample_rss() {
  local child=""
  for _ in $(seq 200); do
    child=$(pgrep -P "$1" | head -1 || true)
    [ -z "$child" ] || break
    kill -0 "$1" 2>/dev/null || break
    sleep 0.02
  done
  [ -n "$child" ] || return 0
  while [ -r "/proc/$child/status" ]; do
    while read -r key value _; do
      [ "$key" = VmRSS: ] && echo "$value" >>"$2"
    done <"/proc/$child/status" 2>/dev/null || true
    sleep 0.2
  done
}
# Starts "$@" under /usr/bin/time -v as run $LABEL: $T/LABEL.time, .out, .rss;
# sets STARTED to the time pid (wait on it with finish LABEL PID).
start_timed() {
  local label=$1; shift
  : >"$T/$label.rss"
  busy_s >"$T/$label.busy0"
  /usr/bin/time -v -o "$T/$label.time" "$@" >"$T/$label.out" 2>&1 &
  STARTED=$!
  sample_rss "$STARTED" "$T/$label.rss" &
}
finish() {  # $1 label, $2 pid: waits, stores the exit code in $T/label.rc
  local rc=0
  wait "$2" || rc=$?
  echo "$rc" >"$T/$1.rc"
  busy_s >"$T/$1.busy1"
}
timed() { local label=$1; start_timed "$@"; finish "$label" "$STARTED"; }
rc_of() { cat "$T/$1.rc"; }
# Complete scene folders under $1 (a scene.json, not a staging folder).
scenes_done() { find "$1" -mindepth 2 -maxdepth 2 -name scene.json -not -path '*.incomplete-*' -not -path '*.old-*' 2>/dev/null | wc -l; }
staging_left() { find "$1" -mindepth 1 -maxdepth 1 \( -name '*.incomplete-*' -o -name '*.old-*' \) 2>/dev/null | wc -l; }
latents_done() { find "$1" -mindepth 2 -maxdepth 2 -name 'latents_*.safetensors' 2>/dev/null | wc -l; }
latents_listed() { grep -l '"latents_.*\.safetensors"' "$1"/*/scene.json 2>/dev/null | wc -l; }
staged_left() { find "$1" -mindepth 2 -maxdepth 2 -name 'latents_*.safetensors.staged-*' | wc -l; }
# Kills pid $1 with SIGKILL once `$2 $3` prints at least $4; 0 when it was
# killed, 1 when it ended first.
kill_at() {
  local pid=$1 count=$2 dir=$3 target=$4
  while kill -0 "$pid" 2>/dev/null; do
    if [ "$($count "$dir")" -ge "$target" ]; then
      kill -KILL "$pid"
      wait "$pid" 2>/dev/null || true
      return 0
    fi
    sleep 0.05
  done
  return 1
}

echo "dataset scale: $N clips ($CORRUPT corrupt) of $FRAMES frames at $SIZE, $(nproc) cores; temp folder $T"
echo "commit $(git -C "$ROOT" rev-parse --short HEAD 2>/dev/null || echo '?'), $(date -u +%Y-%m-%dT%H:%MZ), load average $(cut -d' ' -f1-3 /proc/loadavg)"
RAW="$T/raw"

echo "== 1. flat_synth --format re10k --count $N"
timed synth env OMP_NUM_THREADS=1 "$B/flat_synth" --format re10k --out "$RAW" --count "$N" --frames "$FRAMES" \
  --size "$SIZE" --corrupt "$CORRUPT" --seed 0 --unit "$UNIT" --no-truth --threads 2 --log-level warn
[ "$(rc_of synth)" = 0 ] || { echo "flat_synth failed:"; tail -5 "$T/synth.out"; exit 1; }
CORRUPT_NAMES=$(jq -r '.corrupt | sort | join(",")' "$RAW/manifest.json")
echo "  $(wall_s "$T/synth.time") s, $(du -sm "$RAW" | cut -f1) MB; corrupt clips: $CORRUPT_NAMES"
timed base_import "$B/flat_import" --version
timed base_latents "$B/flat_latents" --version

import_cmd() {  # $1: out, $2: jobs; sets IMPORT
  IMPORT=("$B/flat_import" re10k --in "$RAW/cameras" --frames-dir "$RAW/frames" --out "$1" --depth "$RAW/depth"
          --normals "$RAW/normals" --normals-convention opengl --scale "$UNIT" --jobs "$2" --log-level warn)
}
check_import() {  # $1 label, $2 out: exit 1 with exactly the corrupt clips failed, the others imported
  local s="$2/import_summary.json"
  check "$(is "$(rc_of "$1")/$(jq -r '"\(.imported)/\(.failed)"' "$s")" "1/$GOOD/$CORRUPT")" \
    "$1: exit 1, $GOOD imported, $CORRUPT failed"
  check "$(is "$(jq -r '[.failures[].name] | sort | join(",")' "$s")" "$CORRUPT_NAMES")" \
    "$1: the failures are the manifest's corrupt clips"
}
echo "== 2. flat_import, --jobs 1 and --jobs 2"
for jobs in 1 2; do
  import_cmd "$T/imp_j$jobs" "$jobs"
  timed "import_j$jobs" "${IMPORT[@]}"
  check_import "import_j$jobs" "$T/imp_j$jobs"
done

echo "== 3. flat_latents: 1 process (1 thread, 2 threads), 2 processes, a quarter of the scenes"
# Fresh copies of imported scenes for the runs that need them.
cp -r "$T/imp_j1" "$T/lat_2t"
mkdir "$T/lat_quarter"
find "$T/imp_j1" -mindepth 1 -maxdepth 1 -type d | sort | head -"$QUARTER" | xargs -I{} cp -r {} "$T/lat_quarter/"
latents() {  # $1 label, $2 threads, then the scenes folder and extra flags
  local label=$1 threads=$2; shift 2
  start_timed "$label" env OMP_NUM_THREADS="$threads" "$B/flat_latents" --scenes "$@" --random-weights --seed 0 \
    --dim "$DIM" --window "$WINDOW" --device cpu --threads "$threads" --log-level warn
}
latents lat_1p 1 "$T/imp_j1"; finish lat_1p "$STARTED"
latents lat_2t 2 "$T/lat_2t"; finish lat_2t "$STARTED"
latents lat_quarter 1 "$T/lat_quarter"; finish lat_quarter "$STARTED"
t0=$(now)
latents lat_s0 1 "$T/imp_j2" --shard 0/2; p0=$STARTED
latents lat_s1 1 "$T/imp_j2" --shard 1/2; p1=$STARTED
finish lat_s0 "$p0"; finish lat_s1 "$p1"
t1=$(now)
REP1="$T/imp_j1/flat_latents_report.json" REP2T="$T/lat_2t/flat_latents_report.json"
REPQ="$T/lat_quarter/flat_latents_report.json"
REPS0="$T/imp_j2/flat_latents_report.shard-0-of-2.json" REPS1="$T/imp_j2/flat_latents_report.shard-1-of-2.json"
check_latents() {  # $1 label, $2 report, $3 scenes
  check "$(is "$(rc_of "$1")/$(jq -r '"\(.encoded)/\(.present)/\(.failed | length)"' "$2")" "0/$3/0/0")" \
    "$1: exit 0, $3 scenes encoded, none present or failed"
}
check_latents lat_1p "$REP1" "$GOOD"
check_latents lat_2t "$REP2T" "$GOOD"
check_latents lat_quarter "$REPQ" "$QUARTER"
check_latents lat_s0 "$REPS0" $(( (GOOD + 1) / 2 ))
check_latents lat_s1 "$REPS1" $(( GOOD / 2 ))
ENC2=$(( $(jq .encoded "$REPS0") + $(jq .encoded "$REPS1") ))
WALL2=$(awk -v a="$t0" -v b="$t1" 'BEGIN {printf "%.1f", b - a}')
RATE2=$(awk -v n="$ENC2" -v s="$WALL2" 'BEGIN {printf "%.0f", n * 60 / s}')
PQ=$(peak_mb "$T/lat_quarter.time") P1=$(peak_mb "$T/lat_1p.time")
check "$(awk -v q="$PQ" -v a="$P1" 'BEGIN {print (a <= q * 1.05 + 16) ? 0 : 1}')" \
  "peak RSS of one process does not grow with the scenes: $QUARTER scenes $PQ MB, $GOOD scenes $P1 MB"

echo "== 4. kill halfway, rerun"
KI="$T/imp_kill"
import_cmd "$KI" 2
"${IMPORT[@]}" >"$T/import_killed.out" 2>&1 &
kp=$!
if ! kill_at "$kp" scenes_done "$KI" $((GOOD / 2)); then echo "flat_import ended before the kill: use more clips"; exit 1; fi
IK_DONE=$(scenes_done "$KI") IK_STAGING=$(staging_left "$KI")
touch "$T/marker_import"
timed import_rerun "${IMPORT[@]}"
IS="$KI/import_summary.json"
IR_PRESENT=$(jq .already_present "$IS") IR_IMPORTED=$(jq .imported "$IS")
IR_NEW=$(find "$KI" -mindepth 1 -maxdepth 1 -type d -newer "$T/marker_import" | wc -l)
check "$(is "$IR_PRESENT/$IR_IMPORTED/$(jq .failed "$IS")" "$IK_DONE/$((GOOD - IK_DONE))/$CORRUPT")" \
  "import rerun: already_present $IR_PRESENT = $IK_DONE done before the kill, imported $IR_IMPORTED = the rest, $CORRUPT failed"
check "$(is "$IR_NEW" "$IR_IMPORTED")" "import rerun: $IR_NEW scene folders written, as many as imported"
check "$(is "$(staging_left "$KI")" 0)" "import rerun: no staging folder left ($IK_STAGING after the kill)"
check "$(is "$(scenes_done "$KI")" "$GOOD")" "import rerun: $GOOD scenes"

OMP_NUM_THREADS=1 "$B/flat_latents" --scenes "$KI" --random-weights --seed 0 --dim "$DIM" --window "$WINDOW" \
  --device cpu --threads 1 --log-level warn >"$T/latents_killed.out" 2>&1 &
kp=$!
if ! kill_at "$kp" latents_done "$KI" $((GOOD / 2)); then echo "flat_latents ended before the kill: use more clips"; exit 1; fi
LK_FILES=$(latents_done "$KI") LK_LISTED=$(latents_listed "$KI") LK_STAGED=$(staged_left "$KI")
touch "$T/marker_latents"
latents lat_rerun 1 "$KI"; finish lat_rerun "$STARTED"
LS="$KI/flat_latents_report.json"
LR_PRESENT=$(jq .present "$LS") LR_ENCODED=$(jq .encoded "$LS")
LR_NEW=$(find "$KI" -mindepth 2 -maxdepth 2 -name 'latents_*.safetensors' -newer "$T/marker_latents" | wc -l)
check "$(is "$(rc_of lat_rerun)/$LR_PRESENT/$LR_ENCODED" "0/$LK_LISTED/$((GOOD - LK_LISTED))")" \
  "latents rerun: present $LR_PRESENT = $LK_LISTED committed before the kill ($LK_FILES files), encoded $LR_ENCODED = the rest"
check "$(is "$LR_NEW" "$LR_ENCODED")" "latents rerun: $LR_NEW latent files written, as many as encoded"
check "$(is "$(staged_left "$KI")/$(latents_listed "$KI")" "0/$GOOD")" \
  "latents rerun: no staged file left ($LK_STAGED after the kill), $GOOD scenes hold the set"

CPU2=$(awk -v a="$(cpu_s "$T/lat_s0.time")" -v b="$(cpu_s "$T/lat_s1.time")" 'BEGIN {printf "%.1f", a + b}')
echo
echo "== $N clips of $FRAMES frames at $SIZE ($GOOD good), $(nproc) cores"
printf '%-42s %7s %6s %6s %7s %10s %7s %13s\n' run wall_s tool_s cpu_s other_s items/min peak_MB "RSS_halves_MB"
row() {  # label, what, summary or report (or -), rate field[, own CPU for other_s][, "-" for no RSS halves]
  local tool=- rate=-
  if [ "$3" != - ]; then tool=$(jq -r '.seconds * 10 | round / 10' "$3"); rate=$(jq -r "$4 | . * 10 | round / 10" "$3"); fi
  printf '%-42s %7s %6s %6s %7s %10s %7s %13s\n' "$2" "$(wall_s "$T/$1.time")" "$tool" "$(cpu_s "$T/$1.time")" \
    "$(other_s "$1" "${5:-}")" "$rate" "$(peak_mb "$T/$1.time")" "${6:-$(halves_mb "$T/$1.rss")}"
}
row base_import "flat_import --version (libraries only)" - - "" -
row base_latents "flat_latents --version (libraries only)" - - "" -
row synth "flat_synth --format re10k, 2 threads" -
row import_j1 "import --jobs 1 ($GOOD clips)" "$T/imp_j1/import_summary.json" .clips_per_minute
row import_j2 "import --jobs 2 ($GOOD clips)" "$T/imp_j2/import_summary.json" .clips_per_minute
row lat_1p "latents, 1 process x 1 thread ($GOOD)" "$REP1" "(.sets_per_minute // .scenes_per_minute)"
row lat_2t "latents, 1 process x 2 threads ($GOOD)" "$REP2T" "(.sets_per_minute // .scenes_per_minute)"
row lat_quarter "latents, 1 process x 1 thread ($QUARTER)" "$REPQ" "(.sets_per_minute // .scenes_per_minute)"
row lat_s0 "latents, shard 0/2, 1 thread (at once)" "$REPS0" "(.sets_per_minute // .scenes_per_minute)" "$CPU2"
row lat_s1 "latents, shard 1/2, 1 thread (at once)" "$REPS1" "(.sets_per_minute // .scenes_per_minute)" "$CPU2"
printf '%-42s %7s %6s %6s %7s %10s\n' "latents, 2 processes together ($ENC2)" "$WALL2" - "$CPU2" \
  "$(other_s lat_s0 "$CPU2")" "$RATE2"
row import_rerun "import rerun after SIGKILL (--jobs 2)" "$IS" .clips_per_minute
row lat_rerun "latents rerun after SIGKILL (1 thread)" "$LS" "(.sets_per_minute // .scenes_per_minute)"
echo "kill: import killed at $IK_DONE/$GOOD scenes ($IK_STAGING staging folder(s) left); rerun: $IR_PRESENT present, $IR_IMPORTED imported, $IR_NEW written"
echo "kill: latents killed at $LK_LISTED/$GOOD committed ($LK_FILES files, $LK_STAGED staged file(s) left); rerun: $LR_PRESENT present, $LR_ENCODED encoded, $LR_NEW written"
echo "tool_s: the seconds of import_summary.json / of the latents report (the tool's own clock, without start-up)."
echo "items/min: clips_per_minute of import_summary.json / sets_per_minute of the latents report (scenes_per_minute before"
echo "8008b20; here one set per scene): clips imported / scenes encoded per minute of tool_s, present ones not counted;"
echo "the 2-process row: both shards' encoded scenes over the wall time of the pair."
echo "cpu_s: user + system CPU seconds of the process (/usr/bin/time); other_s: CPU seconds the rest of the machine"
echo "used meanwhile (/proc/stat; well above 0: other work shared the cores; load average now $(cut -d' ' -f1-3 /proc/loadavg))."
echo "RSS_halves_MB: the largest /proc RSS sample in the first and in the second half of the run."
echo "temp folder at its largest: $(du -sm "$T" | cut -f1) MB"
[ "$FAILED" = 0 ] || { echo "SOME CHECKS FAILED"; exit 1; }
