#!/usr/bin/env bash
# Runs the ```bash blocks of a guide (default docs/own_videos.md) in order, in
# one bash with `set -euo pipefail`, in the current folder. The guide's first
# block sets its variables with `: "${NAME:=default}"`, so any of them set in
# the environment wins (a rehearsal: REHEARSAL=1 CONFIGS=configs/tiny ...; the
# guide's top says which). ```text blocks are illustrations and are not run.
#   bash scripts/run_guide.sh [GUIDE.md]
#   GUIDE_PRINT=1 bash scripts/run_guide.sh   # print the script it would run, run nothing
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
GUIDE="${1:-$ROOT/docs/own_videos.md}"
[ -f "$GUIDE" ] || { echo "run_guide: $GUIDE: no such file" >&2; exit 2; }

# The bash blocks: lines between a fence line "```bash" and the next "```",
# each block preceded by an echo naming it and its line in the guide.
script=$(awk -v guide="$GUIDE" '
  /^```bash[[:space:]]*$/ { inside = 1; n++; printf "echo \"[run_guide] block %d (%s:%d)\"\n", n, guide, NR; next }
  /^```/ && inside { inside = 0; next }
  inside { print }
  END { if (inside) { print "run_guide: unterminated ```bash block" > "/dev/stderr"; exit 1 } }
' "$GUIDE")
[ -n "$script" ] || { echo "run_guide: $GUIDE has no \`\`\`bash block" >&2; exit 2; }

if [ "${GUIDE_PRINT:-0}" = 1 ]; then
  printf '%s\n' "$script"
  exit 0
fi
# From a file, not stdin: a command of the guide that reads stdin must not eat the script.
file=$(mktemp "${TMPDIR:-/tmp}/run_guide.XXXXXX.sh")
trap 'rm -f "$file"' EXIT
printf 'set -euo pipefail\n%s\n' "$script" > "$file"
start=$(date +%s)
bash "$file" < /dev/null
echo "[run_guide] every block of $GUIDE ran in $(( $(date +%s) - start )) s"
