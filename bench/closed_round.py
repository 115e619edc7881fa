"""A plan round played in a tube's own loop, toward the tubes' closed-loop mean (a diagnosis
beside the product; bench/load_delta.md). Writes `--out`: the dataset `--data` (a run's
plan.mcap, the data its final model was trained on) after `--episodes` episodes of the profile
`--profile` of `--ocp` played closed loop under its own gains on fresh machines of the dataset's
line (the streams plan_machines and plan_noise of `--seed`: pass a seed no run used), each as
the chain's plan round plays its torque (twin/plan_data.py `plan_dataset_file`, its `feedback`:
warm like the dataset's machines, from the plan's first state, the torque scaled by U(0.9, 1.1)
plus the smooth dither), with the profile's tracking law on top. `crank train --data OUT` then
trains on it; the tube solved again on that model and checked on development machines says
whether the model's closed-loop mean offset along the tube's plan came from too little data in
that loop (bench/closed_round.md: it did not).

    python bench/closed_round.py --data RUN/plan.mcap --ocp OCP.json [--profile robust-fb]
        [--episodes 240] [--seed 87] --out closed.mcap
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from control.ocp_file import read_ocp
from replay.campaign import tracking_law
from replay.config import ReplayConfig
from twin.mcap_dataset import read_run
from twin.physics import SliderCrank, load_model
from twin.plan_config import PlanConfig
from twin.plan_data import plan_dataset_file
from twin.variability import Variability


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, required=True)
    parser.add_argument("--ocp", type=Path, required=True)
    parser.add_argument("--profile", default="robust-fb")
    parser.add_argument("--episodes", type=int, default=PlanConfig().episodes)
    parser.add_argument("--seed", type=int, default=87)
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    ocp = read_ocp(args.ocp)
    profile = ocp.profiles[args.profile]
    run = read_run(args.data)
    line = Variability.from_dict(run["config"]["variability"])
    physics = SliderCrank(load_model(run["mjcf_path"])[0])
    summary = plan_dataset_file(
        args.data,
        args.out,
        tau=np.asarray(profile.tau),
        theta0=float(profile.theta[0]),
        omega0=float(profile.omega[0]),
        config=PlanConfig(episodes=args.episodes),
        seed=args.seed,
        physics=physics,
        played={"ocp": str(args.ocp), "profile": args.profile, "loop": "closed"},
        feedback=tracking_law(physics, profile, ReplayConfig(variability=line)),
    )
    print(
        f"wrote {args.out}: {args.episodes} closed-loop episodes of {args.profile} before "
        f"those of {args.data} ({summary['samples']} samples; torque at the limit "
        f"{100 * summary['torque_clipped_fraction']:.2f} % of the added samples)"
    )


if __name__ == "__main__":
    main()
