"""How long a request will take, said before the work starts (and kept in the run's report beside
what it took).

Each stage's time is a sum of unit costs times what the request asks for (dataset seconds, windows
× epochs, runs × samples), with the unit costs measured on an idle 2-core machine of the project's
kind. A busy machine takes longer: two chains side by side took 1.5-2.5× as long. The unit costs
of generation, training, the solves, the plan stage and the replay are those of session 82's
idle `crank run --seed 0 --heldout-runs 0` (71d315b, AMD EPYC; 458 s where the estimate of then
said 9-18 min): phase 1 of the PPANN 0.78 and 0.87 s an epoch (the plan round's beside the
baselines), phase 2 111 and 126 s, the rest of the stage 15 and 23 s, the dataset 24 s, each
solve 4.9 s, the replay 5.9 s. Session 70's (602dd34) had counted phase 1 1.61 s an epoch,
phase 2 153 s, the dataset 34 s; the held-out check's 26 s and the MPC's steps are older
measurements, not taken again. Sessions 52-53's (phase 1 1.98-2.73 s an epoch with `torch.tanh`)
put that run's training at the bottom of its range; session 21's had said 3-7 min for trainings
that took 7-9.5. Phase 1 of training stops early at a number of epochs nobody knows in advance
(58-73 on seeds 0-4 of `paper`, 37-117 on `line-30`, 68-188 in the plan round's two trainings),
so the training estimate is a range: its low end at EARLY_EPOCHS, its high end at the epoch cap.
The plan round's training also counts `plan_fit`'s continued phase 1 (PLAN_STEP, session 96).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

from ppann.train_config import PLAN_FIT_EPOCHS, PLAN_FIT_MIN_EPISODES
from replay.rates import second_stage_end
from twin.physics import SAMPLE_RATE

if TYPE_CHECKING:
    from collections.abc import Iterable

    from crank.chain import RunConfig
    from ppann.train_config import TrainConfig
    from twin.dataset import GenerationConfig

GENERATE_PER_SECOND = 0.033
"""Seconds of generation (simulation and MCAP) per second of dataset (23.6 s for 720 s in session
82's run; 0.047 in session 70's, 0.068 in session 52's)."""
REWRITE_PER_SECOND = 0.0030
"""The plan stage's seconds per second of the dataset it adds its episodes to, beside the
generation of those episodes: it reads the dataset and writes it again with them (the plan
stage of the four idle fresh-clone runs of sessions 70-71 took 6, 7, 7 and 9 s, 7.25 s on
average, of which the generation of its 72 s counts 3.4 s: 3.9 s for the 720 s dataset; timed
apart in session 72 beside a sweep (in its own scheduling group), reading it took 1.0 s and
writing it 2.1 s). Session 82's plan stage took 4.5 s: 2.1 s beside the 2.4 s the generation
counts, 0.0030 a dataset second (0.0054 before)."""
WINDOW_STEP_EPOCH = {"ppann": 1.83e-6, "physics": 0.105e-6, "blackbox": 1.36e-6}
"""Phase-1 seconds per training window, window step and epoch, per model kind (session 82's run,
of 45 000 windows of 10 steps: 75 PPANN epochs in 58.8 s alone and 93 in 80.6 s in the plan
round beside the baselines, their mean; there 107 black-box epochs in 65.5 s and 193
physics-only ones in 9.1 s; session 70's were 3.57e-6, 0.20e-6, 3.11e-6, session 52's, with
`torch.tanh`, 4.77e-6, 0.18e-6, 4.03e-6)."""
SIGMA_SAMPLE_EPOCH = 0.40e-6
"""Phase-2 seconds per training sample and epoch (that run: 800 epochs of 348 000 samples in
110.9 s, the plan round's 800 of 382 568 in 125.7 s; session 70's 0.55e-6, session 52's
0.65e-6)."""
PLAN_STEP = 0.92e-3
"""`plan_fit`'s continued phase 1: seconds per minibatch and plan-episode step beyond its window
loss (the plan episodes rolled out whole and back-propagated at every minibatch: their steps run
one after another, the episodes side by side, so their count is left out). Session 96's
fresh-clone `crank run` (a149189): 10 epochs of 11 minibatches and 150 steps in 46.4 s, where
its phase 1 beside the baselines took 1.69 s an epoch (session 82's 0.87): 2.95 s an epoch beyond
the windows, 1.52 s at session 82's pace. On one core beside another lane (session 95, line-15):
10 epochs in 37.9 s."""
VALIDATION = 19.0
"""Validation, Monte-Carlo bands and the 100-run twin calibration of the default dataset, s
(the training stage less its two phases: 15.1 and 22.5 s in that run's two trainings; 25.0 and
25.4 in session 70's, 33-34 s in sessions 52 and 53)."""
EARLY_EPOCHS = 37
"""The fewest phase-1 epochs seen before early stopping (seeds 0-4 of paper and line-30)."""
SOLVE = 4.9
"""The nominal and robust OCP at the default horizon (150) and Monte-Carlo (1000), s (4.8 and
5.1 s in session 82's run; 6.8 before)."""
REPLAY_FIXED, REPLAY_PER_SAMPLE = 2.0, 65e-6
"""A campaign: fixed seconds (figures, Rerun) and seconds per run, profile, mode and sample
(session 82's run: 5.9 s for 100 runs of 2 profiles in 2 modes of 150 samples; 128e-6 before,
when the log had just come to carry Foxglove's channels)."""
HELDOUT_PER_SAMPLE = 87e-6
"""The held-out check: seconds per machine, profile and sample (with its Monte-Carlo): 26 s for
the default's 1000 machines, two profiles and 150 samples in session 70's run (31 s, 103e-6,
in session 52's)."""


@dataclass(frozen=True)
class Span:
    """A time estimate from `low` to `high` seconds."""

    low: float
    high: float

    def __add__(self, other: Span) -> Span:
        return Span(self.low + other.low, self.high + other.high)

    def __mul__(self, factor: float) -> Span:
        return Span(self.low * factor, self.high * factor)

    def __str__(self) -> str:
        low, high = _duration(self.low), _duration(self.high)
        if low == high:
            return low
        low_value, low_unit = low.split(" ")
        high_unit = high.split(" ")[1]
        return f"{low_value}-{high}" if low_unit == high_unit else f"{low}-{high}"

    def as_list(self) -> list[float]:
        return [round(self.low, 1), round(self.high, 1)]


def generate_time(config: GenerationConfig) -> Span:
    seconds = GENERATE_PER_SECOND * config.seconds
    return Span(seconds, seconds)


def rewrite_time(config: GenerationConfig) -> Span:
    """Reading the dataset of `config` and writing it again (the plan round's)."""
    seconds = REWRITE_PER_SECOND * config.seconds
    return Span(seconds, seconds)


def train_time(
    config: TrainConfig,
    generation: GenerationConfig,
    *,
    baselines: bool,
    plan_episodes: int = 0,
    plan_steps: int = 0,
) -> Span:
    """Phase 1 at EARLY_EPOCHS to the cap, phase 2, and the validation. The baselines train
    beside the PPANN, one after the other on the second core (ppann/fit.py `fit_all`), so
    phase 1 takes the longer of the two lanes. `plan_episodes` of `plan_steps` steps in the data
    (the plan round's): `plan_fit`'s continued phase 1 too, where it runs."""
    windows = generation.n_samples * (1 - config.validation_fraction)
    epoch = min(windows, config.epoch_windows)
    lanes = [WINDOW_STEP_EPOCH["ppann"]]
    if baselines:
        lanes.append(WINDOW_STEP_EPOCH["physics"] + WINDOW_STEP_EPOCH["blackbox"])
    per_epoch = max(lanes) * epoch * config.horizon
    phase1 = Span(per_epoch * min(EARLY_EPOCHS, config.max_epochs), per_epoch * config.max_epochs)
    if config.plan_fit and plan_episodes >= PLAN_FIT_MIN_EPISODES:
        batches = math.ceil(epoch / config.batch_size)
        plan = PLAN_FIT_EPOCHS * (per_epoch + PLAN_STEP * batches * plan_steps)
        phase1 = phase1 + Span(plan, plan)
    phase2 = SIGMA_SAMPLE_EPOCH * windows * config.phase2_epochs
    return phase1 + Span(phase2 + VALIDATION, phase2 + VALIDATION)


def solve_time(*, horizon: int, mc_samples: int) -> Span:
    seconds = SOLVE * horizon / 150 * (0.8 + 0.2 * mc_samples / 1000)
    return Span(seconds, seconds)


MPC_STEP = (0.35e-3, 50e-6)
"""One machine's MPC step inside a campaign: fixed seconds and seconds per predicted sample
(bench_mpc: 20 machines x 149 steps took 2.5 s at horizon 10 and 6.0 s at 30)."""


def replay_time(
    *, runs: int, modes: int, horizon: int, mpc_horizon: int | None = None, profiles: int = 2
) -> Span:
    """`mpc_horizon`: the MPC's, when the modes include mpc; `profiles`: nominal and the robust
    ones."""
    seconds = REPLAY_FIXED + REPLAY_PER_SAMPLE * runs * profiles * modes * horizon
    if mpc_horizon is not None:
        seconds += _mpc_steps(runs=runs, profiles=profiles, horizon=horizon, mpc=mpc_horizon)
    return Span(seconds, seconds)


def _mpc_steps(*, runs: int, profiles: int, horizon: int, mpc: int) -> float:
    """Seconds of every machine's MPC steps, each profile, the MPC predicting `mpc` samples."""
    fixed, per = MPC_STEP
    return (fixed + per * mpc) * runs * profiles * horizon


def heldout_time(
    *,
    runs: int,
    horizon: int,
    profiles: int = 2,
    modes: tuple[str, ...] = ("open",),
    mpc_horizon: int | None = None,
) -> Span:
    """The held-out check: every profile in every loop of `modes` on `runs` machines, the mpc
    loop's steps (`mpc_horizon`: the MPC's) as a campaign's."""
    seconds = HELDOUT_PER_SAMPLE * runs * profiles * len(modes) * horizon
    if "mpc" in modes and mpc_horizon is not None:
        seconds += _mpc_steps(runs=runs, profiles=profiles, horizon=horizon, mpc=mpc_horizon)
    return Span(seconds, seconds)


def run_time(config: RunConfig) -> dict[str, Span]:
    """Per stage of `crank run`, and "total"."""
    horizon = config.ocp.horizon
    profiles = 1 + len(config.ocp.profiles)
    solve = solve_time(horizon=horizon, mc_samples=config.ocp.mc_samples) * len(config.ocp.profiles)
    rounds = config.plan.episodes > 0
    stages = {
        "generate": generate_time(config.generation),
        "train": train_time(
            config.train, config.generation, baselines=config.baselines and not rounds
        ),
        "solve": solve,
    }
    if rounds:
        added = config.plan.episodes * horizon / SAMPLE_RATE  # seconds of data the round adds
        merged = replace(config.generation, seconds=config.generation.seconds + added)
        stages |= {
            "plan": generate_time(replace(config.generation, seconds=added))
            + rewrite_time(config.generation),
            "train_plan": train_time(
                config.train,
                merged,
                baselines=config.baselines,
                plan_episodes=config.plan.episodes,
                plan_steps=horizon,
            ),
            "solve_plan": solve,
        }
    stages |= {
        "replay": replay_time(
            runs=config.replay.runs,
            modes=len(config.replay.modes),
            horizon=horizon,
            mpc_horizon=config.replay.mpc.horizon if "mpc" in config.replay.modes else None,
            profiles=profiles,
        ),
    }
    if config.heldout_runs:
        stages["heldout"] = heldout_time(
            runs=config.heldout_runs,
            horizon=horizon,
            profiles=profiles,
            modes=config.heldout_modes,  # the robust profiles' loops: open, closed
        )
        end = second_stage_end(config.heldout_runs, config.heldout_second_stage)
        if end:  # only a robust torque its first machines cannot judge plays these: the high end
            more = heldout_time(
                runs=end - config.heldout_runs, horizon=horizon, profiles=len(config.ocp.profiles)
            )
            stages["heldout"] = stages["heldout"] + Span(0.0, more.high)
    return _with_total(stages)


def left(stages: dict[str, Span], done: Iterable[str]) -> dict[str, Span]:
    """`run_time`'s stages but those `done` (a resumed run's), with their "total"."""
    return _with_total({name: s for name, s in stages.items() if name not in {*done, "total"}})


def _with_total(stages: dict[str, Span]) -> dict[str, Span]:
    """`stages` and their sum as "total"."""
    total = Span(0.0, 0.0)
    for span in stages.values():
        total = total + span
    return stages | {"total": total}


def describe(stages: dict[str, Span], *, times: int = 1) -> str:
    """One line: the total (of `times` such runs) and its parts."""
    parts = ", ".join(f"{name} {span}" for name, span in stages.items() if name != "total")
    total = stages["total"] * times
    each = f"; each run: {parts}" if times > 1 else f" ({parts})"
    trains = any(name.startswith("train") for name in stages)
    cap = "; training stops early, the upper end is its epoch cap" if trains else ""
    return f"estimated time on an idle 2-core machine: {total}{each}{cap}"


def _duration(seconds: float) -> str:
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 5400:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"
