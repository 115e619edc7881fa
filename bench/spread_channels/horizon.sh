#!/bin/bash
# development: seed 11 retrained with phase-1 horizon $1, solved, parts on root 999
H=$1
cd /work/w54
export PYTHONPATH=/work/w54
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 CRANK_ROLLOUT_THREADS=1
D=/work/r54/h/h$H
mkdir -p $D
rm -f $D/end
date +%s > $D/start
.venv/bin/python - <<PY > $D/train.log 2>&1
import torch; torch.set_num_threads(1)
from pathlib import Path
from ppann.pipeline import train_and_report
from ppann.train_config import TrainConfig
r = train_and_report(Path("/work/r53/models/s11/dataset.mcap"), Path("$D/model.pt"), config=TrainConfig(seed=11, horizon=$H), baselines=False)
m = r["models"]["ppann"]
print("epochs", m["epochs"], m["best_epoch"], m["phase1_converged"], m["train_seconds"], m["rmse_10_step"], m["rmse_100_step"])
PY
date +%s > $D/trained
.venv/bin/crank solve --model $D/model.pt --seed 11 --out $D/ocp.json > $D/solve.log 2>&1
.venv/bin/python bench/calibration_parts.py --ocp $D/ocp.json --model $D/model.pt --heldout-seed 999 --runs 1000 --out $D/parts.json > $D/parts.log 2>&1
echo done > $D/end
