"""A dataset plus episodes of a robust torque played on fresh machines of its line (session 22's
pilot of "data where the plans go", README *The machine's factors on the motor's terms*).

    python bench/plan_episodes.py --dataset D/dataset.mcap --ocp S/ocp.json --episodes 240 \
        --out P/plan.mcap
    crank train --data P/plan.mcap --out P/model.pt --seed 0   # then crank solve, crank heldout

Each added episode is one machine drawn from the dataset's scenario with a development stream
(SeedSequence(999, spawn_key=(22,)), never a held-out root), warm for U[0, max_start_time] s as
the dataset's, from the plan's first state (rest at bottom dead centre), under the robust
profile's torque scaled by U(0.9, 1.1) plus a smooth dither (white of `--dither` N·m averaged
over 10 samples, scaled back to that standard deviation), and the scenario's slider force. The
added episodes come first, so that none lands in the validation tail. No ground truth channel
is written (training reads none).
"""

from __future__ import annotations

import argparse

import numpy as np

from control.ocp_file import read_ocp
from twin.dataset import Dataset
from twin.mcap_dataset import read_dataset, read_model_xml, read_run, write_dataset
from twin.physics import SAMPLE_RATE, SliderCrank
from twin.stepping import simulate
from twin.variability import Variability

DEVELOPMENT_STREAM = np.random.SeedSequence(999, spawn_key=(22,))


def plan_episodes(dataset_path: str, ocp_path: str, episodes: int, dither: float, out: str):
    base, run = read_dataset(dataset_path), dict(read_run(dataset_path))
    plan = read_ocp(ocp_path).profiles["robust"]
    config = dict(run["config"])
    variability = Variability.from_dict(config["variability"])
    physics = SliderCrank()
    rng = np.random.default_rng(DEVELOPMENT_STREAM)
    n = len(plan.tau) - 1
    machines = [variability.sample(rng) for _ in range(episodes)]
    starts = rng.uniform(0, config["max_start_time"], episodes)
    white = rng.standard_normal((episodes, n + 9))
    smooth = np.stack([np.convolve(w, np.ones(10) / np.sqrt(10), mode="valid") for w in white])
    scale = rng.uniform(0.9, 1.1, (episodes, 1))
    limit = physics.torque_limit
    tau = np.clip(plan.tau[None, :n] * scale + dither * smooth[:, :n], -limit, limit)
    force = np.stack([variability.disturbance(rng, n) for _ in range(episodes)])
    state = physics.initial_state(plan.theta[0], plan.omega[0])
    runs = simulate(
        physics,
        variability,
        draws=machines,
        initial_states=np.repeat(state[None], episodes, 0),
        tau=tau,
        disturbance=force,
        start_times=starts,
    )
    sd = runs.sensordata.reshape(-1, runs.sensordata.shape[-1])
    added = {
        "theta": physics.sensor(sd, "theta"),
        "omega": physics.sensor(sd, "omega"),
        "tau": runs.tau.reshape(-1),
        "slider_position": physics.sensor(sd, "slider_position"),
    }
    episode = np.concatenate([np.repeat(np.arange(episodes), n), base.episode + episodes])
    merged = Dataset(
        t=np.arange(len(episode)) / SAMPLE_RATE,
        episode=episode,
        **{k: np.concatenate([v, getattr(base, k)]) for k, v in added.items()},
    )
    run["episodes"] = [
        {"index": i, "samples": n, "machine": m.as_dict(), "plan_episode": True}
        for i, m in enumerate(machines)
    ] + run["episodes"]
    run["plan_episodes"] = {"ocp": ocp_path, "episodes": episodes, "dither": dither, "seed": 999}
    write_dataset(out, merged, None, run=run, model_xml=read_model_xml(dataset_path))
    print(f"wrote {out}: {len(episode)} samples, {episodes} episodes of the plan first")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--dataset", required=True)
    parser.add_argument("--ocp", required=True, help="ocp.json whose robust torque is played")
    parser.add_argument("--episodes", type=int, default=240)
    parser.add_argument("--dither", type=float, default=0.3, help="N·m")
    parser.add_argument("--out", required=True)
    args = parser.parse_args()
    plan_episodes(args.dataset, args.ocp, args.episodes, args.dither, args.out)


if __name__ == "__main__":
    main()
