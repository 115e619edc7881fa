"""A `crank run` folder's dataset trained again with another training seed (the initial weights
and the windows of each epoch; the dataset is the same), the PPANN alone, one torch thread
(bench/init_variance.md, session 58).

    python bench/init_variance/train_init.py RUN_FOLDER TRAIN_SEED OUT_FOLDER

(session 58 ran it on seed 4's folder with training seeds 104, 204 and 304)."""

import json
import sys
from dataclasses import replace
from pathlib import Path

import torch

from crank.chain import RunConfig
from ppann.pipeline import train_and_report

torch.set_num_threads(1)
src, seed, out = Path(sys.argv[1]), int(sys.argv[2]), Path(sys.argv[3])
out.mkdir(parents=True, exist_ok=True)
config = RunConfig.from_dict(json.loads((src / "config.json").read_text()))
train = replace(config.train, seed=seed)
print("train config", train.as_dict(), flush=True)
report = train_and_report(
    src / "dataset.mcap",
    out / "model.pt",
    config=train,
    baselines=False,
    on_stage=lambda s: print(s, flush=True),
)
print("phase-1 epochs", report["models"]["ppann"].get("epochs"), flush=True)
