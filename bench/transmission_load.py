"""What sets the crank's angle to the motor (delta, ppann/transmission.py)? A diagnosis on a
dataset, toward a load-conditioned delta (bench/transmission_load.md; session 75).

The Monte-Carlo draws delta from one marginal distribution fitted on the whole dataset, whatever
the load; under feedback that makes the tubes' slider spread at sample 100 1.3-3x too wide
(bench/tube_backlash.md). This script measures, on the dataset's samples `transmission_angles`
uses, how much of delta's spread a signed load explains: u = tau - J alpha - b omega
- f sign(omega), the torque through the backlash gap (the motor's torque less what its own rotor
takes). A delta conditioned on u draws from u's bin (`--bins` equal-count bins); one conditioned
on u now and u `m` samples before (each `--lags` m) from a cell of 10 x 10 (the gap has memory:
the crank takes time to cross it). J, b, f come from the MJCF's motor joint (the twin's truth: a
ceiling, not for learners) or from a grid search on the measurements alone (alpha from
differences of the measured omega); delta itself is checked against the truth channel's
backlash angle.

With `--ocp` (the run's ocp.json) it also plays the file's profiles open and closed loop on
`--runs` replay machines (the replay streams of `--seed`; development machines, not held-out
ones) and prints, at each constraint sample, delta's spread and mean on the twin (its backlash
sensor) beside the spread each conditioned delta would draw for those runs (their own u, binned
as the dataset's) and the marginal one the Monte-Carlo draws today.

    python bench/transmission_load.py --data logs/<run>/dataset.mcap [--bins 20]
        [--lags 5,10,20] [--ocp logs/<run>/ocp.json --runs 300 --seed 7]
"""

from __future__ import annotations

import argparse
import itertools
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ppann.transmission import SLOPE_SHARE, transmission_angles
from twin.mcap_dataset import read_dataset, read_model_xml, read_truth
from twin.physics import SAMPLE_RATE

CELLS = 10
"""Bins of u now and of u before, each, for a lag's conditioned delta."""
LEAST = 30
"""Samples a cell needs to count (fewer: left out of the spread)."""


def samples(path: Path, lags: tuple[int, ...], *, truth: bool = True) -> dict[str, np.ndarray]:
    """delta from the measured slider and the load's parts (now and `lag` samples before), on
    the samples delta is fitted on that have the longest lag inside their episode; with `truth`,
    the truth channel's backlash angle beside it (a plan round's file carries none)."""
    data = read_dataset(path)
    backlash = read_truth(path).backlash_angle if truth else None
    geometry = data.geometry
    first = max(lags, default=0)
    parts: dict[str, list[np.ndarray]] = {}

    def keep(name: str, values: np.ndarray) -> None:
        parts.setdefault(name, []).append(values)

    for episode in np.unique(data.episode):
        at = np.flatnonzero(data.episode == episode)
        theta, omega = data.theta[at], data.omega[at]
        alpha = np.gradient(omega, 1.0 / SAMPLE_RATE)
        usable = np.abs(geometry.slider_slope(theta)) >= SLOPE_SHARE * geometry.crank_length
        index = np.flatnonzero(usable)
        late = index >= first
        delta = transmission_angles(theta, data.slider_position[at], geometry=geometry)
        keep("delta", delta[late])
        if backlash is not None:
            keep("truth", backlash[at][index[late]])
        for lag in (0, *lags):
            i = index[late] - lag
            keep(f"tau{lag}", data.tau[at][i])
            keep(f"alpha{lag}", alpha[i])
            keep(f"omega{lag}", omega[i])
    return {k: np.concatenate(v) for k, v in parts.items()}


def torque_through_gap(
    tau: np.ndarray, alpha: np.ndarray, omega: np.ndarray, coefficients: tuple
) -> np.ndarray:
    """u = tau - J alpha - b omega - f sign(omega): the motor's torque less what its own rotor
    takes, with (J, b, f) = `coefficients`."""
    inertia, damping, friction = coefficients
    return tau - inertia * alpha - damping * omega - friction * np.sign(omega)


def load(parts: dict[str, np.ndarray], coefficients: tuple, lag: int = 0) -> np.ndarray:
    """`torque_through_gap` of a dataset's samples (`samples`), `lag` samples before."""
    tau, alpha, omega = (parts[f"{k}{lag}"] for k in ("tau", "alpha", "omega"))
    return torque_through_gap(tau, alpha, omega, coefficients)


def _edges(x: np.ndarray, bins: int) -> np.ndarray:
    return np.quantile(x, np.linspace(0.0, 1.0, bins + 1))


def _bin(x: np.ndarray, edges: np.ndarray) -> np.ndarray:
    return np.clip(np.searchsorted(edges, x, side="right") - 1, 0, len(edges) - 2)


@dataclass(frozen=True)
class Conditioned:
    """delta's mean and spread per cell of u (and of u before, for a lag)."""

    edges: tuple[np.ndarray, ...]
    mean: np.ndarray
    sd: np.ndarray

    @classmethod
    def fit(cls, delta: np.ndarray, loads: tuple[np.ndarray, ...], bins: int) -> Conditioned:
        edges = tuple(_edges(u, bins) for u in loads)
        cell = cls._cell(edges, loads)
        count = np.bincount(cell, minlength=bins ** len(loads))
        total = np.bincount(cell, weights=delta, minlength=count.size)
        square = np.bincount(cell, weights=delta**2, minlength=count.size)
        with np.errstate(invalid="ignore", divide="ignore"):
            mean = np.where(count >= LEAST, total / count, np.nan)
            sd = np.sqrt(np.maximum(square / count - mean**2, 0.0))
        return cls(edges, mean, sd)

    @staticmethod
    def _cell(edges: tuple[np.ndarray, ...], loads: tuple[np.ndarray, ...]) -> np.ndarray:
        cell = np.zeros(loads[0].shape, dtype=int)
        for e, u in zip(edges, loads, strict=True):
            cell = cell * (len(e) - 1) + _bin(u, e)
        return cell

    def left(self, delta: np.ndarray, loads: tuple[np.ndarray, ...]) -> float:
        """delta's spread about its cell's mean (cells with too few samples left out)."""
        mean = self.mean[self._cell(self.edges, loads)]
        return float(np.nanstd(delta - mean))

    def spread(self, loads: tuple[np.ndarray, ...]) -> float:
        """The spread of a delta drawn from each run's own cell."""
        cell = self._cell(self.edges, loads)
        return float(np.sqrt(np.nanmean(self.sd[cell] ** 2) + np.nanvar(self.mean[cell])))


def mujoco_model(path: Path) -> Any:
    """The dataset's own MJCF, compiled."""
    import mujoco

    return mujoco.MjModel.from_xml_string(read_model_xml(path))


def motor_joint(path: Path) -> tuple[float, float, float]:
    """armature, damping and frictionloss of the MJCF's motor joint (the dataset's own MJCF)."""
    return motor_coefficients(mujoco_model(path))


def motor_coefficients(model: Any) -> tuple[float, float, float]:
    """armature, damping and frictionloss of a compiled model's motor joint."""
    dof = model.joint("motor").dofadr[0]
    return (
        float(model.dof_armature[dof]),
        float(model.dof_damping[dof]),
        float(model.dof_frictionloss[dof]),
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, required=True)
    parser.add_argument("--bins", type=int, default=20)
    parser.add_argument("--lags", default="5,10,20")
    parser.add_argument("--ocp", type=Path, default=None)
    parser.add_argument("--runs", type=int, default=300)
    parser.add_argument("--seed", type=int, default=7)
    args = parser.parse_args()
    lags = tuple(int(m) for m in args.lags.split(",") if m)
    started = time.perf_counter()
    parts = samples(args.data, lags)
    delta = parts["delta"]
    mrad = 1e3
    print(f"dataset: {args.data} ({delta.size} samples away from the dead centres)")
    print(
        f"delta: sd {mrad * delta.std():.2f} mrad; against the truth channel's backlash angle: "
        f"correlation {np.corrcoef(delta, parts['truth'])[0, 1]:.7f}, "
        f"rms difference {mrad * np.sqrt(np.mean((delta - parts['truth']) ** 2)):.3f} mrad"
    )
    grid = itertools.product(
        np.linspace(0.0, 2e-3, 11), np.linspace(0.0, 0.16, 9), np.linspace(0.0, 0.06, 5)
    )

    def left(c: tuple) -> float:
        return Conditioned.fit(delta, (load(parts, c),), args.bins).left(delta, (load(parts, c),))

    fitted = tuple(float(v) for v in min(grid, key=left))
    rows = [
        ("the torque alone (J = b = f = 0)", (0.0, 0.0, 0.0)),
        ("the MJCF's motor joint (truth)", motor_joint(args.data)),
        ("fitted on the measurements", fitted),
    ]
    print(f"delta's spread left within {args.bins} equal-count bins of the load u:")
    for name, c in rows:
        u = (load(parts, c),)
        model = Conditioned.fit(delta, u, args.bins)
        pressed = int(np.sum(model.sd <= 0.3 * delta.std()))
        print(
            f"  {name}: J {c[0]:.2e} kg m^2, b {c[1]:.3f} N m s, f {c[2]:.3f} N m -> "
            f"{mrad * model.left(delta, u):.2f} mrad ({model.left(delta, u) / delta.std():.0%} "
            f"of delta's); bins at most 30 % of it: {pressed} of {args.bins}; per bin "
            f"{np.round(mrad * model.sd, 1).tolist()}"
        )
    # each model by the lags of the loads it is conditioned on (0: u now)
    models = {(0,): Conditioned.fit(delta, (load(parts, fitted),), args.bins)}
    for lag in lags:
        u = (load(parts, fitted), load(parts, fitted, lag))
        models[0, lag] = Conditioned.fit(delta, u, CELLS)
        print(
            f"  the fitted u now and {lag} samples before ({CELLS} x {CELLS} cells): "
            f"{mrad * models[0, lag].left(delta, u):.2f} mrad"
        )
    if args.ocp is not None:
        replayed(args, delta, fitted, models)
    print(f"wall {time.perf_counter() - started:.1f} s")


def replayed(
    args: argparse.Namespace,
    delta: np.ndarray,
    fitted: tuple,
    models: dict[tuple[int, ...], Conditioned],
) -> None:
    """delta on the twin under each profile, open and closed loop, beside each conditioned
    model's spread and the marginal's (module docstring)."""
    from control.ocp_file import read_ocp
    from replay.campaign import draw_machines, play
    from replay.config import ReplayConfig
    from twin.physics import SliderCrank
    from twin.variability import Variability

    ocp = read_ocp(args.ocp)
    physics = SliderCrank(mujoco_model(args.data))
    scenario = Variability.from_dict(read_dataset(args.data).run["config"]["variability"])
    config = ReplayConfig(
        runs=args.runs, seed=args.seed, modes=("open", "closed"), variability=scenario
    )
    machines = draw_machines(config, ocp.horizon)
    named = [", ".join(f"u-{lag}" if lag else "u" for lag in lags) for lags in models]
    print(
        f"on {args.runs} replay machines of seed {args.seed} ({scenario.name}), delta in mrad: "
        f"the twin's sd (mean) | conditioned on {' | on '.join(named)} | marginal"
    )
    for name in ocp.names:
        for mode in config.modes:
            run = play(physics, ocp, profile=name, mode=mode, machines=machines, config=config)
            alpha = np.gradient(run.omega, 1.0 / SAMPLE_RATE, axis=1)
            u = torque_through_gap(run.tau, alpha, run.omega, fitted)
            for k in ocp.config.constraint_samples:
                i = k - 1
                drawn = [
                    m.spread(tuple(u[:, i - lag] for lag in lags)) for lags, m in models.items()
                ]
                twin = run.backlash_angle[:, i]
                print(
                    f"  {name:9s} {mode:6s} sample {k:3d}: {1e3 * twin.std():5.2f} "
                    f"({1e3 * twin.mean():+6.2f}) | "
                    + " | ".join(f"{1e3 * s:5.2f}" for s in drawn)
                    + f" | {1e3 * delta.std():5.2f}   (u {u[:, i].mean():+.2f} ± "
                    f"{u[:, i].std():.2f} N m)"
                )


if __name__ == "__main__":
    main()
