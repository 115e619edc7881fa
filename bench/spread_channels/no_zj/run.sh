#!/bin/bash
cd /work/main
export PYTHONPATH=/work/main:/work/main/bench OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 CRANK_ROLLOUT_THREADS=1
one() {
  s=$1; D=/work/r54/nj/s$s
  .venv/bin/python bench/spread_channels/no_zj/refit.py $s J /work/r54/nj > /work/r54/nj/refit_$s.log 2>&1
  .venv/bin/crank solve --model $D/model.pt --seed $s --out $D/ocp.json > $D/solve.log 2>&1
  .venv/bin/python bench/calibration_parts.py --ocp $D/ocp.json --model $D/model.pt --heldout-seed 999 --runs 1000 --out $D/parts.json > $D/parts.log 2>&1
}
rm -f /work/r54/nj/end
(one 11; one 10; one 13) &
(one 14; one 12) &
wait
date > /work/r54/nj/end
