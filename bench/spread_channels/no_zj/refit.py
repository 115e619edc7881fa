"""Development: phase 2 fitted again on a trained model with z_J's white channel off (its sigma
network held at its floor), the mean and everything else as trained; warm from the trained
sigma networks."""
import sys
from pathlib import Path
import torch
torch.set_num_threads(1)
from ppann.checkpoint import load, save
from ppann.train import History, make_splits, train_sigma
from ppann.train_config import TrainConfig
from twin.mcap_dataset import read_dataset

s, off = int(sys.argv[1]), sys.argv[2]
model, payload = load(f"/work/r53/models/s{s}/model.pt")
dataset = read_dataset(f"/work/r53/models/s{s}/dataset.mcap")
config = TrainConfig(seed=s)
splits = make_splits(dataset, config)
with torch.no_grad():
    for name in off:
        last = model.sigma_nets[name][-1]
        last.weight.zero_()
        last.bias.fill_(-50.0)
history = History()
train_sigma(model, dataset, splits, config, history=history)
print(s, "lever", history.lever_sigma, "machine", model.machine_sigma.tolist(), "was", payload["state_dict"]["machine_sigma"].tolist(), payload["state_dict"].get("lever_sigma"))
extra = {k: v for k, v in payload.items() if k not in ("format", "version", "kind", "config", "state_dict", "geometry")}
out = Path(f"/work/r54/nj/s{s}"); out.mkdir(parents=True, exist_ok=True)
save(out / "model.pt", model, kind="ppann", extra=extra)
