#!/bin/bash
# bench/plan_fit_last_rows.md run 3: once lane L of plan_fit_last_lanes.sh has ended, take the
# next line study not yet taken and run it on the lane's core, until none is left or it is past
# the stopping time (usage: CLONE=... OUT=... plan_fit_last_lines.sh A|B).
set -u
cd "$CLONE"
export OMP_NUM_THREADS=1 CRANK_ROLLOUT_THREADS=1
STOP=1955
case "$1" in A) C=0 ;; B) C=1 ;; *) echo "lane A or B" >&2; exit 2 ;; esac
while [[ ! -e "$OUT/lane$1.end" ]]; do sleep 30; done
printf 'heldout_second_stage = 9000\n\n[train]\nplan_fit = true\n' > "$OUT/plan_fit_lines.toml"
mkdir -p "$OUT/lines"
for LEAF in line-15:1 line-30:1 line-15:2 line-15:3; do
  V=${LEAF%%:*}; S=${LEAF#*:}; NAME="$V-seed$S"
  mkdir "$OUT/lines/$NAME.claim" 2>/dev/null || continue
  if [[ "$(date +%H%M)" > "$STOP" ]]; then echo "$(date +%T) $NAME not started ($STOP)"; continue; fi
  echo "$(date +%T) study $NAME"
  taskset -c "$C" "$CLONE/.venv/bin/crank" study --variability "$V" --seeds "$S" \
    --profiles robust,robust-fb,robust-pd --config "$OUT/plan_fit_lines.toml" \
    --heldout-runs 1000 --heldout-seed 20261282 --no-figures --out "$OUT/lines/$NAME" \
    > "$OUT/lines/$NAME.log" 2>&1 || echo "$(date +%T) $NAME failed"
done
echo "$(date +%T) done"
