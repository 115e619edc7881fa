"""Development (bench/spread_channels.md): the mixed Monte-Carlo's σ of the slider and of θ at
samples 50 and 100 under session 53's robust torques of seeds 10-14, as trained, with z_J's white
channel off, and with every generic white channel off (the slider force's alone), each over the
line's observed σ on development root 999 (bench/seeds_10_14/parts_dev/).

    PYTHONPATH=.:bench python bench/spread_channels/no_zj/mixed_off.py
"""

import copy
import json
from pathlib import Path

import numpy as np
from spread_channels import switch_off

from control.ocp_file import read_ocp
from ppann.checkpoint import load
from ppann.model import PPANN
from ppann.montecarlo import monte_carlo


def without(model: PPANN, off: str) -> PPANN:
    """A copy of `model` with the white channels named in `off` at their floor."""
    out = copy.deepcopy(model)
    switch_off(out, off)
    return out


def main() -> None:
    for seed in range(10, 15):
        model, _ = load(f"/work/r53/models/s{seed}/model.pt")
        plan = read_ocp(f"/work/r53/f/{seed}/ocp.json").profiles["robust"]
        path = Path(f"bench/seeds_10_14/parts_dev/parts_{seed}.json")
        twin = json.loads(path.read_text())["samples"]
        shown = []
        for name, off in (("all", ""), ("no z_J", "J"), ("force only", "JBK")):
            bands = monte_carlo(
                without(model, off),
                [plan.theta[0], plan.omega[0]],
                plan.tau[:-1],
                n_samples=4000,
                mode="mixed",
                seed=999,
                at=[49, 99],
            )
            theta = np.asarray(bands.samples)[:, :, 0]
            slider = model.geometry.slider_position(theta)
            ratios = []
            for i, k in enumerate(("50", "100")):
                line = twin[k]["line"]
                x = slider[:, i].std(ddof=1) / line["slider_observed"]
                t = theta[:, i].std(ddof=1) / line["theta_observed"]
                ratios.append(f"θ {t:.2f} x {x:.2f}")
            shown.append(f"{name}: " + " | ".join(ratios))
        print(seed, "; ".join(shown), flush=True)


if __name__ == "__main__":
    main()
