"""Development (bench/spread_channels.md): phase 2 fitted again on a trained model with white
channels off (their sigma networks held at their floor), the mean and everything else as
trained, warm from the trained sigma networks.

    PYTHONPATH=.:bench python bench/spread_channels/no_zj/refit.py SEED CHANNELS OUT_DIR

(e.g. 11 J /work/r54/nj)

reads /work/r53/models/s<SEED>/{model.pt,dataset.mcap} (session 53's default models) and writes
OUT_DIR/s<SEED>/model.pt.
"""

import sys
from pathlib import Path

import torch
from spread_channels import switch_off

from ppann.checkpoint import load, save
from ppann.train import History, make_splits, train_sigma
from ppann.train_config import TrainConfig
from twin.mcap_dataset import read_dataset

KEPT = ("format", "version", "kind", "config", "state_dict", "geometry")
"""The checkpoint keys `save` writes itself."""


def main() -> None:
    torch.set_num_threads(1)
    seed, off, out = int(sys.argv[1]), sys.argv[2], Path(sys.argv[3])
    model, payload = load(f"/work/r53/models/s{seed}/model.pt")
    dataset = read_dataset(f"/work/r53/models/s{seed}/dataset.mcap")
    config = TrainConfig(seed=seed)
    switch_off(model, off)
    history = History()
    train_sigma(model, dataset, make_splits(dataset, config), config, history=history)
    was = payload["state_dict"]
    print(
        seed,
        "lever",
        history.lever_sigma,
        "machine",
        model.machine_sigma.tolist(),
        "was",
        was["machine_sigma"].tolist(),
        was.get("lever_sigma"),
    )
    folder = out / f"s{seed}"
    folder.mkdir(parents=True, exist_ok=True)
    extra = {k: v for k, v in payload.items() if k not in KEPT}
    save(folder / "model.pt", model, kind="ppann", extra=extra)


if __name__ == "__main__":
    main()
