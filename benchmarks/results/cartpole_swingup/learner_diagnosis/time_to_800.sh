#!/bin/bash
# Wall time from the bare README command to its first evaluation >= 800 (issue 14's "800 within 30 s").
# usage: bash time_to_800.sh SEED [hydra overrides...]   (run from anywhere; one run at a time on an idle machine)
# Starts `python scripts/train.py task=cartpole_swingup seed=SEED steps=20000 progress=false [overrides]` in a fresh
# folder under ${TMPDIR:-/tmp}, watches its eval.csv and stops the run (SIGTERM: it saves and exits) at the first
# evaluation >= 800; prints the env steps, the score, the seconds since the command and eval.csv's own wall_seconds
# (training time, without start-up).
set -u
repo=$(cd "$(dirname "$0")/../../../.." && pwd)
if [ $# -lt 1 ]; then echo "usage: bash time_to_800.sh SEED [hydra overrides...]" >&2; exit 2; fi
seed=$1; shift
dir=$(mktemp -d "${TMPDIR:-/tmp}/time_to_800.XXXX")
cd "$dir"
start=$(date +%s.%N)
"$repo/.venv/bin/python" "$repo/scripts/train.py" task=cartpole_swingup seed="$seed" steps=20000 progress=false "$@" \
  > out.log 2>&1 &
pid=$!
csv=""
while kill -0 $pid 2>/dev/null; do
  csv=$(ls runs/cartpole_swingup/*/seed*/eval.csv 2>/dev/null | head -1)
  if [ -n "$csv" ]; then
    hit=$(awk -F, 'NR > 1 && $2 >= 800 {printf "%s env steps, %.1f, eval.csv wall %.1f s", $1, $2, $6; exit}' "$csv")
    if [ -n "$hit" ]; then
      now=$(date +%s.%N)
      echo "seed $seed $*: 800 at $hit; $(echo "$now - $start" | bc) s after the command ($dir)"
      kill -TERM $pid; wait $pid; exit 0
    fi
  fi
  sleep 0.2
done
if [ -z "$csv" ]; then
  echo "seed $seed $*: the run ended before its first evaluation; its output: $dir/out.log" >&2; exit 1
fi
echo "seed $seed $*: no evaluation >= 800 in 20,000 env steps: $(awk -F, 'NR > 1 {printf "%s:%.0f ", $1, $2}' "$csv") ($dir)"
