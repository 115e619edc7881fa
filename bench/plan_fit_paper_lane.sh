#!/bin/bash
# bench/plan_fit_mean.md run 2: the paper task, seed S on core C (usage: plan_fit_paper_lane.sh C S); A = crank run's chain, B = plan_fit on its plan.mcap.
set -u
C=$1; S=$2; ROOT=20261274; PY=/work/run92/.venv/bin; OUT=/tmp/s92/run2
export OMP_NUM_THREADS=1 CRANK_ROLLOUT_THREADS=1
D=$OUT/seed$S; mkdir -p $D/a $D/b
echo "$(date +%T) seed $S chain"
taskset -c $C $PY/crank run --seed $S --heldout-seed $ROOT --heldout-runs 2000 --logs $OUT --name chain$S > $D/chain.log 2>&1 || { echo "chain failed"; exit 1; }
R=$OUT/chain$S
echo "$(date +%T) seed $S B"
taskset -c $C $PY/crank train --plan-fit --data $R/plan.mcap --out $D/b/model.pt --seed $S > $D/b/train.log 2>&1 || { echo "train failed"; exit 1; }
taskset -c $C $PY/crank solve --model $D/b/model.pt --out $D/b/ocp.json --mc-samples 1000 --seed $S > $D/b/solve.log 2>&1 || echo "solve failed"
for L in a b; do
  if [ $L = a ]; then M=$R/model.pt; O=$R/ocp.json; else M=$D/b/model.pt; O=$D/b/ocp.json; fi
  [ -f $O ] || continue
  taskset -c $C $PY/crank heldout --ocp $O --model $M --seed $ROOT --runs 2000 --out $D/$L/heldout.json > $D/$L/heldout.log 2>&1 || echo "heldout failed $L"
  taskset -c $C $PY/python /work/run92/bench/plan_lead.py --ocp $O --model $M --heldout-seed $ROOT --runs 1000 --trajectories 4000 --out $D/$L/lead.json > $D/$L/lead.log 2>&1 || echo "lead failed $L"
done
echo "$(date +%T) seed $S done"
