"""A plan round played in a tube's own loop, toward the tubes' closed-loop mean (a diagnosis
beside the product; bench/load_delta.md). Writes `--out`: the dataset `--data` (a run's
plan.mcap, the data its final model was trained on) after `--episodes` episodes of the profile
`--profile` of `--ocp` played closed loop under its own gains on fresh machines of the dataset's
line (the streams plan_machines and plan_noise of `--seed`: pass a seed no run used), each as
the chain's plan round plays its torque (twin/plan_data.py: warm like the dataset's machines,
from the plan's first state, the torque scaled by U(0.9, 1.1) plus the smooth dither), with the
profile's tracking law on top. `crank train --data OUT` then trains on it; the tube solved
again on that model and checked on development machines says whether the model's closed-loop
mean offset along the tube's plan came from too little data in that loop.

    python bench/closed_round.py --data RUN/plan.mcap --ocp OCP.json [--profile robust-fb]
        [--episodes 240] [--seed 87] --out closed.mcap
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from common import streams
from control.ocp_file import read_ocp
from replay.campaign import tracking_law
from replay.config import ReplayConfig
from twin.dataset import Dataset, Episode, measured_channels
from twin.generation import episode_record
from twin.mcap_dataset import read_dataset, read_model_xml, read_run, write_dataset
from twin.physics import SAMPLE_RATE, SliderCrank, load_model
from twin.plan_config import PlanConfig
from twin.plan_data import plan_torques
from twin.stepping import simulate
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
    base, run = read_dataset(args.data), dict(read_run(args.data))
    generation = dict(run["config"])
    line = Variability.from_dict(generation["variability"])
    physics = SliderCrank(load_model(run["mjcf_path"])[0])
    machines_rng = streams.rng(args.seed, "plan_machines")
    machines = [line.sample(machines_rng) for _ in range(args.episodes)]
    starts = machines_rng.uniform(0, generation.get("max_start_time", 0.0), args.episodes)
    noise = streams.rng(args.seed, "plan_noise")
    limit = physics.torque_limit
    config = PlanConfig()
    torques = plan_torques(
        np.asarray(profile.tau),
        episodes=args.episodes,
        dither=config.dither,
        limit=limit,
        rng=noise,
    )
    n = len(profile.tau)
    force = np.stack([line.disturbance(noise, n) for _ in range(args.episodes)])
    theta0, omega0 = float(profile.theta[0]), float(profile.omega[0])
    state = physics.initial_state(theta0, omega0)
    runs = simulate(
        physics,
        line,
        draws=machines,
        initial_states=np.repeat(state[None], args.episodes, 0),
        tau=torques,
        disturbance=force,
        start_times=starts,
        feedback=tracking_law(physics, profile, ReplayConfig(variability=line)),
    )
    sd = runs.sensordata.reshape(-1, runs.sensordata.shape[-1])
    added = measured_channels(physics, sd, runs.tau.reshape(-1))
    episode = np.concatenate([np.repeat(np.arange(args.episodes), n), base.episode + args.episodes])
    merged = Dataset(
        t=np.arange(len(episode)) / SAMPLE_RATE,
        episode=episode,
        **{k: np.concatenate([v, getattr(base, k)]) for k, v in added.items()},
    )
    first = [
        episode_record(Episode(i, n, machine, theta0, omega0, float(start)))
        | {"plan_episode": True, "closed_loop": args.profile}
        for i, (machine, start) in enumerate(zip(machines, starts, strict=True))
    ]
    later = [e | {"index": e["index"] + args.episodes} for e in run.get("episodes", [])]
    run |= {
        "episodes": first + later,
        "n_samples": len(episode),
        "closed_round": {
            "ocp": str(args.ocp),
            "profile": args.profile,
            "episodes": args.episodes,
            "streams": streams.describe(args.seed, ("plan_machines", "plan_noise")),
        },
    }
    write_dataset(args.out, merged, None, run=run, model_xml=read_model_xml(args.data))
    clipped = float(np.mean(np.abs(runs.tau) >= limit))
    print(
        f"wrote {args.out}: {args.episodes} closed-loop episodes of {args.profile} before "
        f"{base.episode.max() + 1} of {args.data} ({len(episode)} samples; torque at the limit "
        f"{100 * clipped:.2f} % of the added samples)"
    )


if __name__ == "__main__":
    main()
