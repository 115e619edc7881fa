"""Named random streams: one root seed per run, one independent child per purpose.

Every random draw of the project comes from `stream(seed, name)`: the root `SeedSequence(seed)`
with a spawn key fixed by the stream's *name* (a hash of it), so

- two purposes never share numbers (replay machines are never the dataset's machines, replay
  start times never the dataset's initial angles), whatever seed each command is given;
- adding a stream, or drawing more from one, changes nothing in the others;
- the tree is a short record (`describe`) that every artifact carries.

A stream that needs one child per episode or run spawns them from its own sequence
(`stream(seed, "replay_machines").spawn(runs)`), so the first runs stay the same when more are
asked for.
"""

from __future__ import annotations

import hashlib
import threading
from collections.abc import Callable

import numpy as np

from common.checks import check_seed

STREAMS: dict[str, str] = {
    "dataset_machines": "machine draws of the dataset's episodes",
    "dataset_states": "initial states of the dataset's episodes",
    "dataset_excitation": "excitation torque of the dataset's episodes",
    "dataset_noise": "slider disturbance of the dataset's episodes",
    "dataset_start_times": "how long each dataset machine has run before its episode",
    "training": "network initialisation and minibatch order",
    "spread_calibration": "simulated lines that calibrate the line's bounds after training",
    "monte_carlo": "Monte-Carlo draws of the OCP's robust loop",
    "tail_check": "Monte-Carlo draws of a robust torque's own tail, checked after its loop",
    "tail_lines": "the lines of that check by line sampling",
    "validation_monte_carlo": "Monte-Carlo bands of the validation report",
    "calibration_machines": "twin machines of the model report's calibration",
    "calibration_noise": "slider disturbance of the calibration replays",
    "replay_machines": "campaign machines and their start times",
    "replay_noise": "slider disturbance of the campaign replays",
    "heldout_machines": "held-out machines and their start times",
    "heldout_noise": "slider disturbance of the held-out replays",
    "heldout_bootstrap": "resamples of the held-out machines for the observed spread's interval",
    "plan_machines": "machines of the plan round's added episodes and their start times",
    "plan_noise": "torque scale, dither and slider disturbance of the plan round's episodes",
    "transmission": "the crank's angle to the motor in the Monte-Carlo's slider positions",
}
"""Every stream the project draws from, with what it is for."""
HELDOUT_STREAMS = ("heldout_machines", "heldout_noise", "heldout_bootstrap")
"""The streams of a held-out check, under its own root seed."""


def spawn_key(name: str) -> int:
    """The stream's spawn key: the first 32 bits of sha256(name), stable across versions."""
    if name not in STREAMS:
        raise KeyError(f"unknown random stream {name!r}; known: {', '.join(STREAMS)}")
    return int.from_bytes(hashlib.sha256(name.encode()).digest()[:4], "big")


def stream(seed: int, name: str) -> np.random.SeedSequence:
    """The SeedSequence of stream `name` under root `seed`."""
    check_seed("seed", seed)
    return np.random.SeedSequence(seed, spawn_key=(spawn_key(name),))


def rng(seed: int, name: str) -> np.random.Generator:
    """A generator on stream `name` under root `seed`."""
    return np.random.default_rng(stream(seed, name))


def torch_seed(seed: int, name: str) -> int:
    """A 63-bit integer seed for torch, from stream `name` under root `seed`."""
    return int(stream(seed, name).generate_state(1, np.uint64)[0] >> np.uint64(1))


def describe(seed: int, names: tuple[str, ...] | None = None) -> dict[str, object]:
    """The tree as recorded in artifacts: root seed and each stream's spawn key."""
    names = tuple(STREAMS) if names is None else names
    return {
        "root_seed": seed,
        "scheme": "numpy SeedSequence(root_seed, spawn_key=(key,)); key = sha256(name)[:4]",
        "streams": {name: spawn_key(name) for name in names},
    }


class PrefixDraws:
    """Time-major draws kept for reuse: the robust loop's Monte-Carlo draws the same numbers at
    every iteration (common random numbers), so drawing them again cost it ~7 ms of ~26 per
    draft. A draw is made by `make(rows)` in row-major order from a fresh generator, so fewer rows
    are a prefix of more: `get` returns the first `rows` of the longest draw kept for `key` (the
    drafts' 99 steps of the full solve's 249, bit for bit), read-only. Keeps the `size` keys used
    last; safe to share between threads (control/aware.py checks a draft on one while the loop
    solves on another)."""

    def __init__(self, size: int = 4) -> None:
        self.size = size
        self._kept: dict[tuple, np.ndarray] = {}
        self._lock = threading.Lock()

    def get(self, key: tuple, rows: int, make: Callable[[int], np.ndarray]) -> np.ndarray:
        with self._lock:
            kept = self._kept.pop(key, None)
            if kept is None or kept.shape[0] < rows:
                kept = make(rows)
                kept.flags.writeable = False
            self._kept[key] = kept  # now the newest
            while len(self._kept) > self.size:
                del self._kept[next(iter(self._kept))]
            return kept[:rows]


def sequence_key(sequence: np.random.SeedSequence) -> tuple:
    """What determines a SeedSequence's numbers, as a hashable key."""
    return (sequence.entropy, sequence.spawn_key, sequence.pool_size)
