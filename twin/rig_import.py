"""Rig data into the dataset contract: a CSV, Parquet or MCAP recording of a real machine,
with its own column names, units, signs and rate, becomes a dataset MCAP a learner can read.

    spec = ImportSpec.parse(columns="t=time,theta=enc,tau=cmd", units="t=ms,theta=deg")
    import_table("rig.csv", "rig.mcap", spec=spec)

Fields: `t`, `theta` and `tau` are required; `omega` (else the central difference of theta),
`slider_position` (else x(theta) of the model's geometry: a rigid, backlash-free reading),
`episode` (else one episode, or one per gap with `split_on_gaps`) and `machine` (an integer id:
the episodes of one id are runs of one machine, which training gives one offset; else every
episode a machine of its own; a change of id starts a new episode) are optional. Each episode is
resampled onto a grid at `rate_hz` from its first sample: theta, omega and the slider linearly,
the torque as the mean of the source's zero-order hold over each new interval (the torque applied
from one sample to the next, as the contract says), so picking every second sample of a 1 kHz
table reproduces a 500 Hz one exactly. A gap (an interval above `max_gap` times the median) is an
error unless `split_on_gaps`; so are a NaN, time that does not increase, and an unknown column.
Several files (a file per run) make one dataset, each file's episodes numbered on from the last;
`machines` names each file's machine where the files have no machine column.

The file has no truth channel and no model.xml: training skips the twin calibration, and a
replay on the twin needs a scenario named by the user (the twin is not the rig): the file's
variability is RIG_SCENARIO, which the checkpoint and ocp.json carry on.
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from common.atomic import check_writable, writes
from common.errors import ConfigError
from twin.dataset import Dataset, summarize
from twin.generation import provenance
from twin.geometry import Geometry
from twin.mcap_dataset import write_dataset
from twin.physics import MODEL_PATH, SAMPLE_RATE, SliderCrank, load_model
from twin.rig_table import RigDataError, read_table
from twin.rig_units import UNITS, check_units, option_pairs

REQUIRED = ("t", "theta", "tau")
OPTIONAL = ("omega", "slider_position", "episode", "machine")
LABELS = ("episode", "machine")
"""Fields that number rows rather than measure them: integers, no unit, no sign."""
RIG_SCENARIO = {"name": "rig", "source": "crank import"}
"""What rig data records as its variability scenario (the dataset's, the checkpoint's and
ocp.json's): a real machine, not a scenario of the twin to replay on."""
MAX_JITTER = 0.2
"""The largest standard deviation of the source's sample interval, as a share of its median."""


@dataclass(frozen=True)
class ImportSpec:
    """How a table's columns become the contract's fields."""

    columns: dict[str, str]
    """Contract field -> the table's column."""
    units: dict[str, str] = field(default_factory=dict)
    """Contract field -> its unit in the table (UNITS); the contract's own if not given."""
    flip: tuple[str, ...] = ()
    """Fields whose sign is the opposite of the contract's (theta counter-clockwise, ...)."""
    rate_hz: float = SAMPLE_RATE
    max_gap: float = 5.0
    """An interval above this many median intervals is a gap."""
    split_on_gaps: bool = False

    def __post_init__(self) -> None:
        known = REQUIRED + OPTIONAL
        options = (("--map", self.columns), ("--units", self.units), ("--flip", self.flip))
        for what, names in options:
            unknown = [n for n in names if n not in known]
            if unknown:
                raise ConfigError(
                    f"{what}: unknown field {unknown[0]!r} (fields: {', '.join(known)})"
                )
        missing = [n for n in REQUIRED if n not in self.columns]
        if missing:
            raise ConfigError(f"--map must name a column for {', '.join(missing)}")
        check_units(self.units, known)
        for name in LABELS:
            if name in self.flip:
                raise ConfigError(f"--flip: the {name} column has no sign")
        if not (np.isfinite(self.rate_hz) and 1.0 <= self.rate_hz <= 1e5):
            raise ConfigError(f"--rate must be within 1-100000 Hz, got {self.rate_hz}")
        if not (np.isfinite(self.max_gap) and self.max_gap > 1.0):
            raise ConfigError(f"--max-gap must be above 1 (median intervals), got {self.max_gap}")

    @classmethod
    def parse(cls, *, columns: str, units: str = "", flip: str = "", **options: Any) -> ImportSpec:
        """From the command line's `field=column,...`, `field=unit,...` and `field,...`."""
        return cls(
            columns=option_pairs(columns, "--map"),
            units=option_pairs(units, "--units"),
            flip=tuple(n.strip() for n in flip.split(",") if n.strip()),
            **options,
        )

    def as_dict(self) -> dict[str, Any]:
        return {
            "columns": self.columns,
            "units": self.units,
            "flip": list(self.flip),
            "rate_hz": self.rate_hz,
            "max_gap": self.max_gap,
            "split_on_gaps": self.split_on_gaps,
        }


@dataclass(frozen=True)
class Resampled:
    """A table on the contract's grid, and what the resampling found."""

    dataset: Dataset
    source_rate_hz: float
    jitter: float
    gaps: list[dict[str, float]]
    derived: list[str]
    machines: list[int | None]
    """Each episode's machine id (the table's machine column); None: a machine of its own."""


def resample(
    table: dict[str, np.ndarray], spec: ImportSpec, *, geometry: Geometry, source: str
) -> Resampled:
    """The table's mapped columns in the contract's units, signs and rate (module docstring).

    Raises:
      RigDataError: NaN, time not increasing, jitter or a gap (without split_on_gaps), an
        episode too short for two samples at the rate.
    """
    fields = {}
    for name, column in spec.columns.items():
        values = table[column]
        bad = np.flatnonzero(~np.isfinite(values))
        if bad.size:
            raise RigDataError(
                f"{source}: column {column!r} ({name}) is not finite at {bad.size} row(s), "
                f"first at data row {bad[0] + 1} ({values[bad[0]]})"
            )
        factor = UNITS[name][spec.units.get(name, next(iter(UNITS[name])))]
        fields[name] = values * factor * (-1.0 if name in spec.flip else 1.0)
    t = fields["t"]
    if len(t) < 3:
        raise RigDataError(f"{source}: {len(t)} rows; a dataset needs at least 3")
    step = np.diff(t)
    if not np.all(step > 0):
        row = int(np.flatnonzero(step <= 0)[0]) + 2
        raise RigDataError(f"{source}: time does not increase at data row {row} ({t[row - 1]} s)")
    same = np.ones(len(step), bool)
    for name in LABELS:  # a new episode where the run's number or the machine changes
        labels = fields.get(name)
        if labels is None:
            continue
        if not np.all(labels == np.round(labels)):
            raise RigDataError(f"{source}: the {name} column holds non-integers")
        same &= labels[1:] == labels[:-1]
    episode = fields.get("episode")
    median = float(np.median(step[same])) if same.any() else float(np.median(step))
    jitter = float(np.std(step[same & (step <= spec.max_gap * median)]) / median)
    if jitter > MAX_JITTER:
        raise RigDataError(
            f"{source}: the sample interval varies by {100 * jitter:.0f} % of its median "
            f"({1e3 * median:.3g} ms); above {100 * MAX_JITTER:.0f} % it is not one rate"
        )
    is_gap = same & (step > spec.max_gap * median)
    gaps = [{"at_s": float(t[i]), "seconds": float(step[i])} for i in np.flatnonzero(is_gap)]
    if gaps and not spec.split_on_gaps:
        first = gaps[0]
        raise RigDataError(
            f"{source}: a gap of {1e3 * first['seconds']:.3g} ms at t = {first['at_s']:.6g} s "
            f"({len(gaps)} in all, median interval {1e3 * median:.3g} ms); --split-on-gaps "
            "starts a new episode at each"
        )
    starts = np.flatnonzero(np.r_[True, ~same | is_gap])
    stops = np.r_[starts[1:], len(t)]
    pieces = [
        _episode(fields, slice(a, b), k, spec.rate_hz, geometry, source)
        for k, (a, b) in enumerate(zip(starts, stops, strict=True))
    ]
    columns = {name: np.concatenate([p[name] for p in pieces]) for name in pieces[0]}
    derived = [n for n in ("omega", "slider_position") if n not in spec.columns]
    if episode is None:
        derived.append("episode")
    dataset = Dataset(**columns, run={})
    machine = fields.get("machine")
    machines = [None if machine is None else int(machine[a]) for a in starts]
    return Resampled(dataset, 1.0 / median, jitter, gaps, derived, machines)


def _episode(
    fields: dict[str, np.ndarray],
    rows: slice,
    index: int,
    rate: float,
    geometry: Geometry,
    source: str,
) -> dict[str, np.ndarray]:
    """One episode on the grid t0 + k/rate, k = 0 .. while a whole interval fits."""
    t = fields["t"][rows]
    dt = 1.0 / rate
    n = int(np.floor((t[-1] - t[0]) * rate + 1e-9))
    if n < 2:
        raise RigDataError(
            f"{source}: episode {index} (from t = {t[0]:.6g} s) lasts {t[-1] - t[0]:.3g} s, "
            f"too short for two samples at {rate:g} Hz"
        )
    grid = t[0] + dt * np.arange(n + 1)
    grid[-1] = min(grid[-1], t[-1])  # the rounding of n * dt
    theta = np.unwrap(fields["theta"][rows])
    out = {"t": grid[:n], "episode": np.full(n, index, dtype=np.int64)}
    out["theta"] = np.interp(grid[:n], t, theta)
    if "omega" in fields:
        out["omega"] = np.interp(grid[:n], t, fields["omega"][rows])
    else:
        out["omega"] = np.gradient(np.interp(grid, t, theta), dt)[:n]
    # The torque is held from each row to the next: its integral is piecewise linear in time,
    # exact under np.interp, and each new interval gets its mean.
    tau = fields["tau"][rows]
    held = np.r_[0.0, np.cumsum(tau[:-1] * np.diff(t))]
    out["tau"] = np.diff(np.interp(grid, t, held)) / np.diff(grid)
    if "slider_position" in fields:
        out["slider_position"] = np.interp(grid[:n], t, fields["slider_position"][rows])
    else:
        out["slider_position"] = geometry.slider_position(out["theta"])
    return out


@writes("out", inputs=("data", "model_path"), suffix=".mcap")
def import_table(
    data: str | Path | Sequence[str | Path],
    out: str | Path,
    *,
    spec: ImportSpec,
    model_path: str | Path = MODEL_PATH,
    machines: Sequence[str] | None = None,
) -> dict[str, Any]:
    """Write the rig table `data`, or several (a file per run: each file's episodes follow the
    previous file's), as a dataset MCAP at `out`; return its run record (with the dataset's
    `summary`; `inputs` names each file with its sha256 and episodes).

    `model_path` is the MJCF of the machine (its geometry and torque limit go into the record;
    the rig's own MJCF if the user has one, else the project's). `machines`: each file's
    machine, one label per file (files of one label are runs of one machine), where the files
    have no machine column; None: the column's ids, or every episode a machine of its own.
    """
    files = [Path(data)] if isinstance(data, str | Path) else [Path(d) for d in data]
    if not files:
        raise RigDataError("no rig data given")
    labels = _file_machines(machines, files, spec)
    resolved = [f.resolve() for f in files]
    for i, f in enumerate(files):  # before the first file is read
        if resolved[i] in resolved[:i]:
            raise RigDataError(f"{f} is named twice")
        if not f.is_file():
            raise RigDataError(f"rig data not found: {f}")
    out = Path(out)
    check_writable(out)
    physics = SliderCrank(load_model(model_path)[0])
    results = [
        resample(read_table(f, spec), spec, geometry=physics.geometry, source=str(f)) for f in files
    ]
    dataset = _joined([r.dataset for r in results])
    digests = [hashlib.sha256(f.read_bytes()).hexdigest() for f in files]
    lengths = np.bincount(dataset.episode).tolist()
    ids = [  # each episode's machine: its file's label, or the table's machine column
        m if label is None else label
        for r, label in zip(results, labels, strict=True)
        for m in r.machines
    ]
    run = {
        "source": "import",
        "input": ", ".join(f.name for f in files),
        **({"input_sha256": digests[0]} if len(files) == 1 else {}),
        "inputs": [
            {"name": f.name, "sha256": d, "episodes": int(r.dataset.episode[-1]) + 1}
            for f, d, r in zip(files, digests, results, strict=True)
        ],
        "import": spec.as_dict(),
        "rate_hz": spec.rate_hz,
        "n_samples": len(dataset),
        "source_rate_hz": float(np.median([r.source_rate_hz for r in results])),
        "source_jitter": max(r.jitter for r in results),
        "gaps": [g | {"file": f.name} for f, r in zip(files, results, strict=True) for g in r.gaps],
        "derived": results[0].derived,
        "torque_limit": physics.torque_limit,
        "geometry": physics.geometry.as_dict(),
        "config": {"variability": RIG_SCENARIO},
        "episodes": [
            {"index": k, "n_samples": n} | ({} if m is None else {"machine_id": m})
            for k, (n, m) in enumerate(zip(lengths, ids, strict=True))
        ],
        **provenance(model_path),
    }
    run["summary"] = summarize(replace(dataset, run=run))
    write_dataset(out, dataset, None, run=run, model_xml=None)
    return run


def _file_machines(
    machines: Sequence[str] | None, files: list[Path], spec: ImportSpec
) -> list[str | None]:
    """Each file's machine label (`import_table`'s `machines`), None where not given."""
    if machines is None:
        return [None] * len(files)
    if "machine" in spec.columns:
        raise RigDataError("--machines names each file's machine: not with a machine column")
    labels = [str(m).strip() for m in machines]
    if len(labels) != len(files) or not all(labels):
        raise RigDataError(
            f"--machines: {len(labels)} label(s) for {len(files)} file(s); give one non-empty "
            "label per file, in the files' order (e.g. --machines A,A,B)"
        )
    return labels


def _joined(datasets: list[Dataset]) -> Dataset:
    """The files' datasets one after the other, each one's episodes numbered on from the last."""
    first = 0
    episodes = []
    for d in datasets:
        episodes.append(d.episode + first)
        first += int(d.episode[-1]) + 1
    columns = ("t", "theta", "omega", "tau", "slider_position")
    joined = {c: np.concatenate([getattr(d, c) for d in datasets]) for c in columns}
    return Dataset(**joined, episode=np.concatenate(episodes), run={})
