#!/bin/bash
# bench/plan_fit_rows.md run 3: on core C, each TASK=MODEL pair given, bench_tasks.py with
# Monte-Carlo seeds 0-4 and the staged verdict (usage: CLONE=... OUT=... plan_fit_rows_mc.sh C
# "task name"=/path/model.pt ...); each model copied into OUT/<n>/ first.
set -u
cd "$CLONE"
export OMP_NUM_THREADS=1 CRANK_ROLLOUT_THREADS=1
C=$1; shift
for PAIR in "$@"; do
  TASK=${PAIR%%=*}; MODEL=${PAIR#*=}
  DIR="$OUT/$(echo "$TASK" | tr -c 'a-z0-9\n' '_')"
  if [[ "$(date +%H%M)" > "1650" ]]; then echo "$(date +%T) $TASK not started (16:50)"; continue; fi
  mkdir -p "$DIR" && cp "$MODEL" "$DIR/model.pt"
  echo "$(date +%T) $TASK from $MODEL"
  taskset -c "$C" "$CLONE/.venv/bin/python" bench/bench_tasks.py --model "$DIR/model.pt" \
    --only "$TASK" --mc-seeds 0-4 --runs 1000 --second-stage 9000 --heldout-seed 20261279 \
    --out mc_seeds.json > "$DIR.log" 2>&1 || echo "$(date +%T) $TASK failed"
done
echo "$(date +%T) done"
