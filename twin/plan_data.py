"""Data where the plans go: a dataset plus episodes of a planned torque played on fresh machines,
or on the dataset's own machines where it names them (a lab's few machines).

The chain's plan round (crank/chain.py, `[plan] episodes`) trains a model, solves the OCP, plays the
returned torque on `episodes` machines of the dataset's line that no other stage draws (the streams
`plan_machines` and `plan_noise`) — a lab's dataset: on its own machines again —, adds those
episodes to the dataset, and trains and solves again. The excitation of the dataset rarely crawls
over the dead centres the way a plan does; the machines' spread there is what the robust margin is
made of (docs/history.md, *The machine's factors on the motor's terms*, session 22).

Each added episode is one machine drawn from the dataset's scenario — or, where the dataset's run
record names machines (`machine_id`: a lab runs its few machines again, it has no others), the
next of those machines in turn, with its recorded draw and id —, warm for U[0, max_start_time] s
like the dataset's, started from the plan's first state, under the plan's
torque scaled by U(0.9, 1.1) plus a smooth dither (white of `dither` N·m averaged over 10 samples,
scaled back to that standard deviation), clipped to the torque limit, with the scenario's slider
force. The added episodes come first so that none lands in the validation tail of training.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from common import streams
from common.atomic import check_writable
from common.errors import ConfigError
from twin.dataset import Dataset, Episode, measured_channels
from twin.generation import episode_record
from twin.mcap_dataset import read_dataset, read_model_xml, read_run, write_dataset
from twin.physics import SAMPLE_RATE, SliderCrank
from twin.plan_config import DITHER_SAMPLES, PlanConfig
from twin.stepping import simulate
from twin.variability import MachineDraw, Variability


def plan_torques(
    tau: np.ndarray, *, episodes: int, dither: float, limit: float, rng: np.random.Generator
) -> np.ndarray:
    """(episodes, len(tau)) torques: `tau` scaled by U(0.9, 1.1) per episode plus the smooth
    dither, clipped to ±`limit`."""
    n = len(tau)
    white = rng.standard_normal((episodes, n + DITHER_SAMPLES - 1))
    box = np.ones(DITHER_SAMPLES) / np.sqrt(DITHER_SAMPLES)  # unit variance after averaging
    smooth = np.stack([np.convolve(w, box, mode="valid") for w in white])
    scale = rng.uniform(0.9, 1.1, (episodes, 1))
    return np.clip(tau[None, :] * scale + dither * smooth, -limit, limit)


def lab_machines(run: dict[str, Any]) -> list[tuple[Any, MachineDraw]]:
    """The machines a dataset's run record names (`machine_id`), in order of first appearance, each
    with its recorded draw; empty for a dataset of fresh machines.

    Raises:
      ConfigError: a named machine without a recorded draw (a rig's: the twin cannot play it).
    """
    named: dict[str, tuple[Any, MachineDraw]] = {}
    for e in run.get("episodes", []):
        label = e.get("machine_id")
        if label is None or str(label) in named:
            continue
        if "machine" not in e:
            raise ConfigError(
                f"the dataset's machine {label!r} has no recorded draw: the plan round plays the "
                "twin's machines, not a rig's"
            )
        named[str(label)] = (label, MachineDraw(**e["machine"]))
    return list(named.values())


def plan_dataset_file(
    dataset_path: str | Path,
    out: str | Path,
    *,
    tau: np.ndarray,
    theta0: float,
    omega0: float,
    config: PlanConfig,
    seed: int,
    physics: SliderCrank,
    played: dict[str, Any],
    feedback: Callable[[int, np.ndarray], np.ndarray] | None = None,
) -> dict[str, Any]:
    """Write `out`: the dataset of `dataset_path` after `config.episodes` episodes of the torque
    `tau` (one per sample) from (`theta0`, `omega0`) on machines of its scenario drawn with the
    root `seed`, or on the dataset's own machines in turn where it names them (`lab_machines`).
    `played` (which solve and profile the torque is) is recorded in the file's run record under
    "plan_round". `feedback`: a closed-loop law (twin/stepping.py `simulate`'s) added to each
    episode's torque before the limit, the same draws otherwise (bench/closed_round.py plays a
    tube's law; the chain's round is open loop). Returns the round's summary.

    Raises:
      ConfigError: no episodes asked for, or a torque that is not a finite sequence of two or
        more samples (one beyond the limit is clipped to it, as the dither may take it there).
    """
    out = Path(out)
    if config.episodes < 1:
        raise ConfigError("a plan round needs plan.episodes >= 1")
    tau = np.asarray(tau, dtype=float)
    if tau.ndim != 1 or len(tau) < 2 or not np.all(np.isfinite(tau)):
        raise ConfigError("the planned torque must be a finite sequence of 2 or more samples")
    check_writable(out)
    base, run = read_dataset(dataset_path), dict(read_run(dataset_path))
    generation = dict(run["config"])
    variability = Variability.from_dict(generation["variability"])
    machines_rng = streams.rng(seed, "plan_machines")
    lab = lab_machines(run)
    if lab:
        ids, machines = zip(*(lab[i % len(lab)] for i in range(config.episodes)), strict=True)
    else:
        ids = (None,) * config.episodes
        machines = tuple(variability.sample(machines_rng) for _ in range(config.episodes))
    starts = machines_rng.uniform(0, generation.get("max_start_time", 0.0), config.episodes)
    noise = streams.rng(seed, "plan_noise")
    limit = physics.torque_limit
    torques = plan_torques(
        tau, episodes=config.episodes, dither=config.dither, limit=limit, rng=noise
    )
    n = len(tau)
    force = np.stack([variability.disturbance(noise, n) for _ in range(config.episodes)])
    state = physics.initial_state(theta0, omega0)
    runs = simulate(
        physics,
        variability,
        draws=machines,
        initial_states=np.repeat(state[None], config.episodes, 0),
        tau=torques,
        disturbance=force,
        start_times=starts,
        feedback=feedback,
    )
    sd = runs.sensordata.reshape(-1, runs.sensordata.shape[-1])
    added = measured_channels(physics, sd, runs.tau.reshape(-1))
    episode = np.concatenate(
        [np.repeat(np.arange(config.episodes), n), base.episode + config.episodes]
    )
    merged = Dataset(
        t=np.arange(len(episode)) / SAMPLE_RATE,
        episode=episode,
        **{k: np.concatenate([v, getattr(base, k)]) for k, v in added.items()},
    )
    first = [
        episode_record(
            Episode(i, n, machine, float(theta0), float(omega0), float(start), machine_id=label)
        )
        | {"plan_episode": True}
        for i, (machine, start, label) in enumerate(zip(machines, starts, ids, strict=True))
    ]
    later = [e | {"index": e["index"] + config.episodes} for e in run.get("episodes", [])]
    summary = {
        "episodes": config.episodes,
        "dither": config.dither,
        "machines": len(lab) or config.episodes,
        "fresh_machines": not lab,
        "samples_added": int(config.episodes * n),
        "samples": len(episode),
        "played": played,
        "streams": streams.describe(seed, ("plan_machines", "plan_noise")),
        "torque_clipped_fraction": float(np.mean(np.abs(runs.tau) >= limit)),
    }
    run |= {"episodes": first + later, "n_samples": len(episode), "plan_round": summary}
    write_dataset(out, merged, None, run=run, model_xml=read_model_xml(dataset_path))
    return summary
