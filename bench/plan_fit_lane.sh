#!/bin/bash
# usage: ROOT=<held-out root> CLONE=<clone with its own .venv> [MC_SEED=<seed>] plan_fit_lane.sh CORE OUTROOT KEY...
# Session 89's task leaves under /tmp/s89/tasks/solve/KEY: B = `crank train --plan-fit` on the leaf's
# plan.mcap and `crank solve` with its [ocp]; A = the leaf's own model and torque; both played on
# ROOT's machines. MC_SEED: B's Monte-Carlo seed, by default the leaf's training seed (the chain's).
# bench/plan_fit.md ran it with ROOT=20261271 CLONE=/work/run91 MC_SEED=0 (its amendment 2 re-solved
# seed 1's leaves with 1); bench/plan_fit_mean.md with ROOT=20261273 CLONE=/work/run92.
set -u
CORE=$1; OUT=$2; shift 2
PY=$CLONE/.venv/bin
export OMP_NUM_THREADS=1 CRANK_ROLLOUT_THREADS=1
for KEY in "$@"; do
  LEAF=/tmp/s89/tasks/solve/$KEY; D=$OUT/$KEY; mkdir -p $D/a $D/b
  read SEED H HEIGHT SAMPLES <<< $($PY/python -c "
import json;c=json.load(open('$LEAF/config.json'));o=c['ocp']
print(c['train']['seed'], o['horizon'], o['height'], ','.join(map(str,o['constraint_samples'])))")
  echo "$(date +%T) $KEY seed $SEED horizon $H height $HEIGHT samples $SAMPLES"
  taskset -c $CORE $PY/crank train --plan-fit --data $LEAF/plan.mcap --out $D/b/model.pt --seed $SEED > $D/b/train.log 2>&1 || { echo "train failed $KEY"; continue; }
  taskset -c $CORE $PY/crank solve --model $D/b/model.pt --out $D/b/ocp.json --horizon $H --height $HEIGHT --samples $SAMPLES --mc-samples 1000 --seed ${MC_SEED:-$SEED} > $D/b/solve.log 2>&1 || echo "solve failed $KEY"
  for L in a b; do
    if [ $L = a ]; then M=$LEAF/model.pt; O=$LEAF/ocp.json; else M=$D/b/model.pt; O=$D/b/ocp.json; fi
    [ -f $O ] || continue
    taskset -c $CORE $PY/crank heldout --ocp $O --model $M --seed $ROOT --runs 2000 --out $D/$L/heldout.json > $D/$L/heldout.log 2>&1 || echo "heldout failed $KEY $L"
    taskset -c $CORE $PY/python $CLONE/bench/plan_lead.py --ocp $O --model $M --heldout-seed $ROOT --runs 1000 --trajectories 4000 --out $D/$L/lead.json > $D/$L/lead.log 2>&1 || echo "lead failed $KEY $L"
  done
  echo "$(date +%T) $KEY done"
done
