"""Which of the own-tail check's allowances makes it refuse a torque (bench/refused_h200.md).

The torque's own rate (control/tail.py: the check's own streams and counter-based normals,
TAIL_DRAWS trajectories) with no allowance, with the line's mean at its drop only (the profile's
`population`), with the machine spread at its upper confidence bound only (all of J, B, K; J and
B only), and with both (what the check does).

Usage: python bench/refused_h200_allowances.py MODEL.pt OCP.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from common.streams import stream
from control.ocp_file import read_ocp
from control.tail import TAIL_DRAWS, lowered_sliders, share_below
from control.tightening import confidence_quantile
from ppann.checkpoint import load
from ppann.machine import sigma_upper
from ppann.model import FusedHeads


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("model", type=Path)
    parser.add_argument("ocp", type=Path)
    args = parser.parse_args()
    model, _ = load(args.model)
    heads = FusedHeads(model)
    ocp = read_ocp(args.ocp)
    config, planned = ocp.config, ocp.profiles["robust"]
    population = np.array(json.loads(args.ocp.read_text())["robust"]["population"])
    estimate = np.asarray(heads.machine_sigma, dtype=float)
    upper = sigma_upper(estimate, heads.machine_profile, confidence_quantile(config.confidence))
    upper_jb = np.array([upper[0], upper[1], estimate[2]])
    print(
        f"k {config.k_sigma}; machine sigma J, B, K {estimate.round(4)}, upper {upper.round(4)}; "
        f"population {np.round(1e3 * population, 3)} mm"
    )
    x0 = np.array([planned.theta[0], planned.omega[0]])
    cases = [
        ("none", estimate, 0.0),
        ("mean drop only", estimate, population),
        ("spread upper (J, B, K) only", upper, 0.0),
        ("spread upper (J, B) only", upper_jb, 0.0),
        ("both (the check)", upper, population),
        ("mean drop + upper (J, B)", upper_jb, population),
    ]
    for name, sigma, drop in cases:
        paths, angles = stream(config.mc_seed, "tail_check").spawn(2)
        lowered = lowered_sliders(
            heads,
            x0,
            planned.tau,
            config,
            draws=TAIL_DRAWS,
            paths=paths,
            angles=angles,
            machine_sigma=sigma,
            population=drop,
            normals="counter",
        )
        rate, samples = share_below(lowered, config)
        per_sample = ", ".join(f"{k}: {100 * v:.3f} %" for k, v in samples.items())
        print(f"  {name:28s} {100 * rate:.3f} %  ({per_sample})")


if __name__ == "__main__":
    main()
