"""What sets the crank's angle to the motor (delta, ppann/transmission.py)? A diagnosis on a
dataset, toward a load-conditioned delta (bench/transmission_load.md; session 75).

The Monte-Carlo draws delta from one marginal distribution fitted on the whole dataset, whatever
the load; under feedback that makes the tubes' slider spread at sample 100 1.3-3x too wide
(bench/tube_backlash.md). This script measures, on the dataset's samples `transmission_angles`
uses, how much of delta's spread a signed one-dimensional load explains: u = tau - J alpha - b
omega - f sign(omega), the torque through the backlash gap (the motor's torque less what its own
rotor takes), binned into `--bins` quantile bins; the within-bin standard deviation is the spread
a delta conditioned on u would draw. J, b, f come either from the MJCF's motor joint (the
twin's truth: a ceiling, not for learners) or from a grid search on the measurements alone
(alpha from differences of the measured omega). delta itself is checked against the truth
channel's backlash angle.

With `--ocp` (the run's ocp.json) it also plays the file's profiles open and closed loop on
`--runs` replay machines (the replay streams of `--seed`; development machines, not held-out
ones) and prints, at each constraint sample, delta's spread and mean on the twin (its backlash
sensor) beside the spread a delta conditioned on the fitted load would draw for those runs (the
runs' own u, binned as the dataset's) and the marginal one the Monte-Carlo draws today.

    python bench/transmission_load.py --data logs/<run>/dataset.mcap [--bins 20]
        [--ocp logs/<run>/ocp.json --runs 300 --seed 7]
"""

from __future__ import annotations

import argparse
import itertools
import time
from pathlib import Path
from typing import Any

import numpy as np

from ppann.transmission import SLOPE_SHARE, transmission_angles
from twin.mcap_dataset import read_dataset, read_model_xml, read_truth
from twin.physics import SAMPLE_RATE


def samples(path: Path) -> dict[str, np.ndarray]:
    """delta from the measured slider and the load's parts, on the samples delta is fitted on."""
    data, truth = read_dataset(path), read_truth(path)
    geometry = data.geometry
    names = ("delta", "truth", "tau", "alpha", "omega")
    parts: dict[str, list[np.ndarray]] = {k: [] for k in names}
    for episode in np.unique(data.episode):
        at = data.episode == episode
        theta, omega = data.theta[at], data.omega[at]
        usable = np.abs(geometry.slider_slope(theta)) >= SLOPE_SHARE * geometry.crank_length
        parts["delta"].append(
            transmission_angles(theta, data.slider_position[at], geometry=geometry)
        )
        parts["truth"].append(truth.backlash_angle[at][usable])
        parts["tau"].append(data.tau[at][usable])
        parts["alpha"].append(np.gradient(omega, 1.0 / SAMPLE_RATE)[usable])
        parts["omega"].append(omega[usable])
    return {k: np.concatenate(v) for k, v in parts.items()}


def within_bins(delta: np.ndarray, load: np.ndarray, bins: int) -> tuple[float, np.ndarray]:
    """delta's standard deviation about its bin's mean (bins of equal count in `load`), and
    each bin's own."""
    edges = np.quantile(load, np.linspace(0.0, 1.0, bins + 1))
    index = np.clip(np.searchsorted(edges, load, side="right") - 1, 0, bins - 1)
    per_bin = np.array([delta[index == b].std() for b in range(bins)])
    means = np.array([delta[index == b].mean() for b in range(bins)])
    return float((delta - means[index]).std()), per_bin


def load(s: dict[str, np.ndarray], inertia: float, damping: float, friction: float) -> np.ndarray:
    return s["tau"] - inertia * s["alpha"] - damping * s["omega"] - friction * np.sign(s["omega"])


def mujoco_model(path: Path) -> Any:
    """The dataset's own MJCF, compiled."""
    import mujoco

    return mujoco.MjModel.from_xml_string(read_model_xml(path))


def motor_joint(path: Path) -> tuple[float, float, float]:
    """armature, damping and frictionloss of the MJCF's motor joint (the dataset's own MJCF)."""
    model = mujoco_model(path)
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
    parser.add_argument("--ocp", type=Path, default=None)
    parser.add_argument("--runs", type=int, default=300)
    parser.add_argument("--seed", type=int, default=7)
    args = parser.parse_args()
    started = time.perf_counter()
    s = samples(args.data)
    delta = s["delta"]
    mrad = 1e3
    print(f"dataset: {args.data} ({delta.size} samples away from the dead centres)")
    print(
        f"delta: sd {mrad * delta.std():.2f} mrad; against the truth channel's backlash angle: "
        f"correlation {np.corrcoef(delta, s['truth'])[0, 1]:.7f}, "
        f"rms difference {mrad * np.sqrt(np.mean((delta - s['truth']) ** 2)):.3f} mrad"
    )
    rows = [("the torque alone (J = b = f = 0)", (0.0, 0.0, 0.0))]
    rows.append(("the MJCF's motor joint (truth)", motor_joint(args.data)))
    grid = itertools.product(
        np.linspace(0.0, 2e-3, 11), np.linspace(0.0, 0.16, 9), np.linspace(0.0, 0.06, 5)
    )
    fitted = min(grid, key=lambda p: within_bins(delta, load(s, *p), args.bins)[0])
    rows.append(("fitted on the measurements", tuple(float(v) for v in fitted)))
    print(f"delta's spread left within {args.bins} equal-count bins of the load u:")
    for name, (inertia, damping, friction) in rows:
        left, per_bin = within_bins(delta, load(s, inertia, damping, friction), args.bins)
        pressed = int(np.sum(per_bin <= 0.3 * delta.std()))
        print(
            f"  {name}: J {inertia:.2e} kg m^2, b {damping:.3f} N m s, f {friction:.3f} N m -> "
            f"{mrad * left:.2f} mrad ({left / delta.std():.0%} of delta's); bins at most 30 % of "
            f"it: {pressed} of {args.bins}; per bin {np.round(mrad * per_bin, 1).tolist()}"
        )
    if args.ocp is not None:
        replayed(args, s, fitted)
    print(f"wall {time.perf_counter() - started:.1f} s")


def replayed(args: argparse.Namespace, s: dict[str, np.ndarray], fitted: tuple) -> None:
    """delta on the twin under each profile, open and closed loop, beside the conditioned and
    the marginal model's spread (module docstring)."""
    from control.ocp_file import read_ocp
    from replay.campaign import draw_machines, play
    from replay.config import ReplayConfig
    from twin.physics import SliderCrank
    from twin.variability import Variability

    ocp = read_ocp(args.ocp)
    physics = SliderCrank(mujoco_model(args.data))
    delta = s["delta"]
    u = load(s, *fitted)
    edges = np.quantile(u, np.linspace(0.0, 1.0, args.bins + 1))
    index = np.clip(np.searchsorted(edges, u, side="right") - 1, 0, args.bins - 1)
    sd = np.array([delta[index == b].std() for b in range(args.bins)])
    mean = np.array([delta[index == b].mean() for b in range(args.bins)])
    scenario = Variability.from_dict(read_dataset(args.data).run["config"]["variability"])
    config = ReplayConfig(
        runs=args.runs, seed=args.seed, modes=("open", "closed"), variability=scenario
    )
    machines = draw_machines(config, ocp.horizon)
    print(
        f"on {args.runs} replay machines of seed {args.seed} ({scenario.name}), delta in mrad: "
        "the twin's sd (mean) | conditioned on the runs' u | marginal"
    )
    for name in ocp.names:
        for mode in config.modes:
            run = play(physics, ocp, profile=name, mode=mode, machines=machines, config=config)
            alpha = np.gradient(run.omega, 1.0 / SAMPLE_RATE, axis=1)
            for k in ocp.config.constraint_samples:
                i = k - 1
                ur = run.tau[:, i] - fitted[0] * alpha[:, i] - fitted[1] * run.omega[:, i]
                ur = ur - fitted[2] * np.sign(run.omega[:, i])
                at = np.clip(np.searchsorted(edges, ur, side="right") - 1, 0, args.bins - 1)
                conditioned = np.sqrt(np.mean(sd[at] ** 2) + np.var(mean[at]))
                twin = run.backlash_angle[:, i]
                print(
                    f"  {name:9s} {mode:6s} sample {k:3d}: {1e3 * twin.std():5.2f} "
                    f"({1e3 * twin.mean():+6.2f}) | {1e3 * conditioned:5.2f} | "
                    f"{1e3 * delta.std():5.2f}   (u {ur.mean():+.2f} ± {ur.std():.2f} N m)"
                )


if __name__ == "__main__":
    main()
