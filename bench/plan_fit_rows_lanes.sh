#!/bin/bash
# bench/plan_fit_rows.md: lane A (core 0) the tasks' seeds 2-3; lane B (core 1) seed 4 then the
# wide lines (usage: CLONE=... OUT=... plan_fit_rows_lanes.sh A|B).
set -u
cd "$CLONE"
export OMP_NUM_THREADS=1 CRANK_ROLLOUT_THREADS=1
mkdir -p "$OUT"
sweep() {  # core spec name
  echo "$(date +%T) $3"
  taskset -c "$1" "$CLONE/.venv/bin/crank" sweep "$CLONE/bench/$2" --executor sequential \
    --out "$OUT/$3" > "$OUT/$3.log" 2>&1 || echo "$(date +%T) $3 failed"
}
case "$1" in
  A) sweep 0 plan_fit_tasks_a_sweep.toml tasks_a ;;
  B) sweep 1 plan_fit_tasks_b_sweep.toml tasks_b
     sweep 1 plan_fit_lines_sweep.toml lines ;;
esac
echo "$(date +%T) done"
