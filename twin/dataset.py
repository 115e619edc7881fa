"""Datasets: episodes of the twin under semi-random torque, as measurement and ground truth.

A dataset is a sequence of episodes (default 72 × 10 s; the paper's 9 × 10 s). Each episode is
a fresh machine draw (friction, backlash, warm-up) that has been running U[0, max_start_time] s
(twin.OPERATING_SECONDS, the replays' range: the machines learnt from and the machines checked
come from one population), from a state drawn uniformly over the whole stroke, under the slider
disturbance throughout. Until session 17 every episode started cold: the model never saw a warm
machine, while the held-out machines had run up to 60 s (docs/history.md, *Warm machines*). `t`
keeps running across episodes and every sample carries its episode index, so training windows never
cross a boundary.

Random streams (common/streams.py): the named streams dataset_machines, dataset_states,
dataset_excitation, dataset_noise and dataset_start_times of the seed each spawn one child per
episode. Changing one of them, or the number of episodes, leaves the others as they were, and no
other stage of the project (replays, Monte-Carlo, training) draws from them.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, fields

import numpy as np

from common.checks import check_count, check_finite, check_seed
from common.errors import ConfigError
from common.streams import stream
from twin import DATASET_SECONDS, EPISODE_SECONDS, OPERATING_SECONDS
from twin.excitation import Excitation
from twin.geometry import Geometry
from twin.physics import SAMPLE_RATE, SliderCrank
from twin.stepping import simulate
from twin.variability import MachineDraw, Variability

MEASUREMENT_FIELDS = ("t", "episode", "theta", "omega", "tau", "slider_position")
TRUTH_FIELDS = (
    "t",
    "episode",
    "crank_angle",
    "backlash_angle",
    "disturbance_force",
    "loop_closure_error",
    "motor_frictionloss",
    "motor_damping",
    "slider_frictionloss",
    "slider_damping",
    "backlash_width",
)


@dataclass(frozen=True)
class GenerationConfig:
    """How to generate a dataset. Defaults: 72 machines of 10 s at 500 Hz, eight times the paper's
    90 s (twin.PAPER_SECONDS). The machine-level spread is estimated from the training machines (9
    left the predicted slider σ at 1.47 times the held-out machines' on one seed of five), and the
    mean model's error where a torque crawls over top dead centre shrinks as 1/sqrt(data): at 180 s
    its crank angle after the crawl was up to 0.19 rad off the machines' mean and the predicted
    slider σ up to 1.54 times the observed, at 720 s within 0.07 rad and 1.30 (docs/history.md,
    *Four times the data*)."""

    seconds: float = DATASET_SECONDS
    seed: int = 0
    episode_seconds: float = EPISODE_SECONDS
    variability: Variability = field(default_factory=Variability)
    excitation: Excitation = field(default_factory=Excitation)
    max_start_time: float = OPERATING_SECONDS
    """Each episode's machine has run U[0, max_start_time] s before its first sample (warm-up
    drift), s; 0: every machine starts cold."""
    episodes_per_machine: int = 1
    """Episodes each machine plays, as a lab runs its few machines several times: machine m plays
    episodes m k .. m k + k - 1, each from its own state, torque, noise and warm-up time, and the
    run record gives them one `machine_id` (`episode_machines`); 1: every episode a fresh machine.
    """

    def __post_init__(self) -> None:
        check_finite("seconds", self.seconds, positive=True)
        check_count("episodes_per_machine", self.episodes_per_machine)
        check_finite("episode_seconds", self.episode_seconds, positive=True)
        check_finite("max_start_time", self.max_start_time, nonneg=True)
        check_seed("seed", self.seed)
        if self.n_samples < 2:
            raise ConfigError(
                f"seconds must cover at least 2 samples at {SAMPLE_RATE:g} Hz, got {self.seconds}"
            )
        if round(self.episode_seconds * SAMPLE_RATE) < 2:  # one machine per sample: no motion
            raise ConfigError(
                f"episode_seconds must cover at least 2 samples at {SAMPLE_RATE:g} Hz, got "
                f"{self.episode_seconds}"
            )

    @property
    def n_samples(self) -> int:
        return math.floor(self.seconds * SAMPLE_RATE + 1e-9)

    def episode_lengths(self) -> list[int]:
        """Samples per episode: whole episodes, the last one possibly shorter."""
        per = max(1, round(self.episode_seconds * SAMPLE_RATE))
        full, rest = divmod(self.n_samples, per)
        return [per] * full + ([rest] if rest else [])

    def as_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class Dataset:
    """What a learner may use: the `/slider_crank/measurement` channel. Arrays are (n_samples,)."""

    t: np.ndarray
    episode: np.ndarray
    theta: np.ndarray
    omega: np.ndarray
    tau: np.ndarray
    slider_position: np.ndarray
    run: dict = field(default_factory=dict)
    """The file's `run` metadata: seed, config, machine draws, versions, MJCF hash."""

    def __len__(self) -> int:
        return len(self.t)

    @property
    def geometry(self) -> Geometry:
        """The mechanism the data was recorded on (its run record; the paper's if not given)."""
        return Geometry.from_dict(self.run.get("geometry"), source="the dataset's run record")


@dataclass(frozen=True)
class GroundTruth:
    """What a learner must not use: the `/slider_crank/truth` channel. Arrays are (n_samples,)."""

    t: np.ndarray
    episode: np.ndarray
    crank_angle: np.ndarray
    backlash_angle: np.ndarray
    disturbance_force: np.ndarray
    loop_closure_error: np.ndarray
    motor_frictionloss: np.ndarray
    motor_damping: np.ndarray
    slider_frictionloss: np.ndarray
    slider_damping: np.ndarray
    backlash_width: np.ndarray


@dataclass(frozen=True)
class Episode:
    """How one episode was set up: its machine and its initial state."""

    index: int
    n_samples: int
    machine: MachineDraw
    theta0: float
    omega0: float
    start_time: float = 0.0
    """How long the machine had run before the episode's first sample, s."""
    machine_id: int | None = None
    """The machine's number where several episodes play one (GenerationConfig.
    episodes_per_machine > 1); None: a machine of the episode's own."""


def generate(
    config: GenerationConfig,
    *,
    physics: SliderCrank | None = None,
    on_progress: Callable[[int], None] | None = None,
    nthread: int | None = None,
) -> tuple[Dataset, GroundTruth, list[Episode]]:
    """Simulate the episodes of `config` on the twin; all episodes step in one native batch.

    Args:
      config: duration, seed, variability and excitation.
      physics: the twin (default: models/slider_crank.xml).
      on_progress: called with the number of samples (over all episodes) just completed.
      nthread: rollout threads (default: `twin.stepping.rollout_threads()`, all cores unless set).
    """
    physics = physics if physics is not None else SliderCrank()
    lengths = config.episode_lengths()
    longest = max(lengths)
    per_episode = {
        name: stream(config.seed, name).spawn(len(lengths))
        for name in (
            "dataset_machines",
            "dataset_states",
            "dataset_excitation",
            "dataset_noise",
            "dataset_start_times",
        )
    }

    episodes, states = [], []
    tau = np.zeros((len(lengths), longest))
    disturbance = np.zeros((len(lengths), longest))
    for i, n in enumerate(lengths):
        per = config.episodes_per_machine  # machine m draws from episode m's machine stream
        machine_rng, state_rng, torque_rng, noise_rng, start_rng = (
            np.random.default_rng(children[i // per if name == "dataset_machines" else i])
            for name, children in per_episode.items()
        )
        machine = config.variability.sample(machine_rng)
        theta0 = float(state_rng.uniform(0.0, 2.0 * np.pi))
        start = float(start_rng.uniform(0.0, config.max_start_time))
        machine_id = i // per if per > 1 else None
        episodes.append(Episode(i, n, machine, theta0, 0.0, start, machine_id))
        states.append(physics.initial_state(theta0, 0.0))
        tau[i] = config.excitation.torque(
            torque_rng, longest, rate=SAMPLE_RATE, limit=physics.torque_limit
        )
        disturbance[i] = config.variability.disturbance(noise_rng, longest)

    runs = simulate(
        physics,
        config.variability,
        draws=[e.machine for e in episodes],
        initial_states=np.array(states),
        tau=tau,
        disturbance=disturbance,
        start_times=np.array([e.start_time for e in episodes]),
        nthread=nthread,
        on_chunk=None if on_progress is None else (lambda n: on_progress(n * len(lengths))),
    )

    def flat(values: np.ndarray) -> np.ndarray:
        """Concatenate each episode's first n samples: (n_runs, longest, ...) → (n_samples, ...)."""
        return np.concatenate([values[i, :n] for i, n in enumerate(lengths)])

    sd = flat(runs.sensordata)
    t = np.arange(config.n_samples) / SAMPLE_RATE
    episode = np.repeat(np.arange(len(lengths)), lengths)
    channels = measured_channels(physics, sd, flat(runs.tau))
    theta = channels["theta"]
    backlash = physics.sensor(sd, "backlash_angle")
    dataset = Dataset(t=t, episode=episode, **channels)
    truth = GroundTruth(
        t=t,
        episode=episode,
        crank_angle=theta + backlash,
        backlash_angle=backlash,
        disturbance_force=flat(runs.disturbance),
        loop_closure_error=physics.loop_closure_error(sd),
        backlash_width=np.repeat([e.machine.backlash_width for e in episodes], lengths),
        **{name: flat(values) for name, values in runs.friction.items()},
    )
    return dataset, truth, episodes


def machine_ids(dataset: Dataset) -> dict[int, str | int]:
    """The run record's `machine_id` of each episode that has one, by episode index."""
    return {
        int(e["index"]): e["machine_id"]
        for e in dataset.run.get("episodes", [])
        if e.get("machine_id") is not None
    }


def episode_machines(dataset: Dataset) -> np.ndarray:
    """(n_samples,) the machine each sample was recorded on, numbered 0, 1, ... in order of first
    appearance. Episodes the run record gives one `machine_id` share a machine (a lab's runs of
    one machine: GenerationConfig.episodes_per_machine, `crank import`'s machine column); every
    other episode, as every episode of a dataset without ids, is a machine of its own."""
    ids = machine_ids(dataset)
    episodes, first, inverse = np.unique(dataset.episode, return_index=True, return_inverse=True)
    numbers: dict[tuple[str, str], int] = {}
    of_episode = np.empty(len(episodes), dtype=np.int64)
    for j in np.argsort(first, kind="stable"):  # the episodes in the order they start
        label = ids.get(int(episodes[j]))
        key = ("episode", str(episodes[j])) if label is None else ("machine", str(label))
        of_episode[j] = numbers.setdefault(key, len(numbers))
    return of_episode[inverse.reshape(-1)]


def measured_channels(
    physics: SliderCrank, sensordata: np.ndarray, tau: np.ndarray
) -> dict[str, np.ndarray]:
    """The measured channels of a dataset but time and episode, from the twin's sensor rows
    (n_samples, nsensordata) and the torque applied at each."""
    return {
        "theta": physics.sensor(sensordata, "theta"),
        "omega": physics.sensor(sensordata, "omega"),
        "tau": tau,
        "slider_position": physics.sensor(sensordata, "slider_position"),
    }


def measurement_arrays(dataset: Dataset) -> dict[str, np.ndarray]:
    return {name: getattr(dataset, name) for name in MEASUREMENT_FIELDS}


def truth_arrays(truth: GroundTruth) -> dict[str, np.ndarray]:
    return {f.name: getattr(truth, f.name) for f in fields(GroundTruth)}


def check_step(dataset: Dataset, *, step: float, stepper: str, source: str) -> None:
    """Refuse data sampled at another interval than `step` (s), what `stepper` (the PPANN, a
    plan) steps by: it would be read one sample for another.

    Raises:
      ConfigError: both rates, and the import that would give the data at the right one.
    """
    dt = float(dataset.t[1] - dataset.t[0])
    if abs(dt - step) > 1e-6 * step:
        raise ConfigError(
            f"{source}: sampled every {1e3 * dt:.4g} ms ({1 / dt:.5g} Hz), {stepper} at "
            f"{1 / step:g} Hz; import the data again with --rate {1 / step:g}"
        )


def summarize(dataset: Dataset, truth: GroundTruth | None = None) -> dict[str, float | int]:
    """Figures that say whether a dataset is fit for training (and the twin within its bounds)."""
    bins = np.histogram(np.mod(dataset.theta, 2 * np.pi), bins=12, range=(0, 2 * np.pi))[0]
    summary: dict[str, float | int] = {
        "n_samples": len(dataset),
        "seconds": float(len(dataset) / dataset.run.get("rate_hz", SAMPLE_RATE)),
        "episodes": len(np.unique(dataset.episode)),
        "machines": int(episode_machines(dataset).max()) + 1,
        "theta_bins_covered_of_12": int(np.count_nonzero(bins)),
        "omega_min": float(dataset.omega.min()),
        "omega_max": float(dataset.omega.max()),
        "tau_abs_max": float(np.abs(dataset.tau).max()),
        "slider_position_min": float(dataset.slider_position.min()),
        "slider_position_max": float(dataset.slider_position.max()),
    }
    if truth is not None:
        summary |= {
            "disturbance_abs_max": float(np.abs(truth.disturbance_force).max()),
            "backlash_over_half_width_max": float(
                np.max(np.abs(truth.backlash_angle) / (0.5 * truth.backlash_width))
            ),
            "loop_closure_error_max": float(truth.loop_closure_error.max()),
        }
    return summary
