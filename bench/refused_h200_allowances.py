"""Which of the own-tail check's allowances makes it refuse a torque (bench/refused_h200.md).

The torque's own rate, by control/tail.py's own check (its streams; TAIL_DRAWS trajectories in
one stage, as when bench/refused_h200.md's figures were taken in session 42), with no allowance,
with the line's mean at its drop only (the profile's `population`), with the machine spread at
its upper confidence bound only (all of J, B, K; J and B only), and with both (what the check
does).

Usage: python bench/refused_h200_allowances.py MODEL.pt OCP.json
"""

from __future__ import annotations

import argparse
import copy
import json
from dataclasses import replace
from pathlib import Path

import numpy as np

from control.ocp_file import read_ocp
from control.tail import TAIL_DRAWS, tail_check
from control.tightening import line_allowance
from ppann.checkpoint import load
from ppann.heads import FusedHeads
from replay.laws import profile_solution


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("model", type=Path)
    parser.add_argument("ocp", type=Path)
    args = parser.parse_args()
    model, _ = load(args.model)
    heads = FusedHeads(model)
    ocp = read_ocp(args.ocp)
    config = ocp.config
    solution = profile_solution(ocp.profiles["robust"], ocp)
    population = np.array(json.loads(args.ocp.read_text())["robust"]["population"])
    # K's spread at its estimate: a profile row of zeros is no bound (ppann/machine.py
    # sigma_upper), so the check's own allowance then raises J's and B's only
    jb = copy.copy(heads)
    jb.machine_profile = heads.machine_profile.copy()
    jb.machine_profile[2] = 0.0
    upper, _ = line_allowance(heads, config)
    print(
        f"k {config.k_sigma}; machine sigma J, B, K {np.round(heads.machine_sigma, 4)}, upper "
        f"{np.round(upper, 4)}; population {np.round(1e3 * population, 3)} mm"
    )
    none = np.zeros_like(population)
    no_confidence = replace(config, confidence=0.0)  # the model's own spread, any population
    cases = [
        ("none", {"heads": heads, "allowances": False}),
        ("mean drop only", {"heads": heads, "config": no_confidence}),
        ("spread upper (J, B, K) only", {"heads": heads, "population": none}),
        ("spread upper (J, B) only", {"heads": jb, "population": none}),
        ("both (the check)", {"heads": heads}),
        ("mean drop + upper (J, B)", {"heads": jb}),
    ]
    for name, case in cases:
        check = tail_check(
            case["heads"],
            solution,
            case.get("config", config),
            tightening=config.tightening,
            population=case.get("population", population),
            allowances=case.get("allowances", True),
            draws=TAIL_DRAWS,
        )
        per_sample = ", ".join(f"{k}: {100 * v:.3f} %" for k, v in check.samples.items())
        print(f"  {name:28s} {100 * check.rate:.3f} %  ({per_sample})")


if __name__ == "__main__":
    main()
