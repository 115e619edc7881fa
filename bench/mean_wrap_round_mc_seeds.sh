#!/usr/bin/env bash
# bench/mean_wrap_round_mc_seeds.md: the seed-3 pair's final (second-round) model of each task,
# its final solve over Monte-Carlo seeds 0-4, each torque on 1000 machines of root 20261193.
# Usage: bench/mean_wrap_round_mc_seeds.sh PAPER_H200_SWEEP TASKS_SWEEP HALF (HALF: a or b)
set -euo pipefail
paper=$1; tasks=$2; half=$3
export OMP_NUM_THREADS=1 CRANK_ROLLOUT_THREADS=1
run() {  # model task-filter
  python bench/bench_tasks.py --model "$1" --only "$2" --mc-seeds 0-4 --mc-samples 1000 \
    --runs 1000 --heldout-seed 20261193 --out "mc_seeds_pair.json"
}
if [ "$half" = a ]; then
  run "$paper/solve/457292dff735/model.pt" "paper"
  run "$paper/solve/5e8a0ec04224.failed/model.pt" "horizon 200"
  run "$tasks/solve/19d469e5a9bf/model.pt" "height 0.075"
else
  run "$tasks/solve/51d1baa491d7/model.pt" "height 0.085"
  run "$tasks/solve/ed4d273ee8a9/model.pt" "samples 60"
fi
