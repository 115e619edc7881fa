#!/bin/bash
# bench/plan_fit_staged.md: crank run with [train] plan_fit = true on the paper task, each seed
# given, on core C (usage: ROOT=... CLONE=... OUT=... plan_fit_staged_lane.sh C SEED...).
set -u
C=$1; shift
export OMP_NUM_THREADS=1 CRANK_ROLLOUT_THREADS=1
mkdir -p "$OUT"
printf '[train]\nplan_fit = true\n' > "$OUT/plan_fit.toml"
for S in "$@"; do
  echo "$(date +%T) seed $S"
  taskset -c "$C" "$CLONE/.venv/bin/crank" run --seed "$S" --config "$OUT/plan_fit.toml" \
    --heldout-seed "$ROOT" --no-figures --logs "$OUT" --name "seed$S" > "$OUT/seed$S.log" 2>&1 \
    || echo "seed $S failed"
done
echo "$(date +%T) done"
