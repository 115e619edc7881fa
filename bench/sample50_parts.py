"""Where the tubes' tail at a constraint sample comes from on the twin: the motor angle θ, the
crank's angle to the motor δ (the backlash sensor), and how the two move together — beside what
the model's Monte-Carlo assumes (δ drawn from its marginal, independently of θ).

Session 86 (bench/tubes_mc_seeds_shipped.md) found every machine below a tube's height below at
sample 50, where the crank crosses the backlash gap, and the model's own rate 2.2-13x under the
twin's there; bench/transmission_load.md had named a δ conditioned on the torque through the
gap as the candidate. This script plays each closed-loop profile of an ocp.json under its own
gains on `--runs` machines (held-out streams of `--seed`: pass a development root, not a
held-out one) and prints at each constraint sample: θ's and δ's spread, their correlation, the
slider's spread and count below the height as played, and the same with δ taken from another
machine at random (δ independent of θ, as the model draws it), and with δ at its mean (θ
alone); δ fitted on the torque through the gap now and LAG samples before (u = τ − J α − b ω −
f sign ω with the MJCF's motor joint: a ceiling; least squares on these runs themselves) plus a
residual independent of θ; the machines below and where they sit in the line (each
parameter's median place in its range, 0 its low end, 1 its high end).

    python bench/sample50_parts.py --ocp OCP.json [OCP.json ...] [--profiles robust-fb,robust-pd]
        [--runs 4000] [--seed 999] [--model MJCF] [--figure parts.png]

`--figure`: per file and profile, at the first constraint sample, the twin's (θ, δ) with the
machines below marked, and the slider's lower tail as played beside δ drawn independently.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from transmission_load import motor_coefficients, torque_through_gap

from control.ocp_file import read_ocp
from replay.campaign import Machines, draw_machines, play
from replay.config import ReplayConfig
from replay.files import ocp_variability
from twin import MODEL_PATH
from twin.physics import SAMPLE_RATE, SliderCrank, load_model
from twin.variability import Variability

LAG = 5
"""Samples (10 ms) between the two loads δ is fitted on (bench/transmission_load.md)."""


@dataclass(frozen=True)
class Shown:
    """One row of the figure: a profile at a constraint sample on every machine."""

    title: str
    theta: np.ndarray
    delta: np.ndarray
    slider: np.ndarray
    independent: np.ndarray
    height: float


def places(machines: Machines, line: Variability, indices: np.ndarray) -> dict[str, float]:
    """Each uncertain parameter's median place in its range over machines `indices`."""
    out = {}
    for parameter in line.parameters():
        span = parameter.high - parameter.low
        if span > 0:
            values = [getattr(machines.draws[i], parameter.name) for i in indices]
            out[parameter.name] = round((float(np.median(values)) - parameter.low) / span, 2)
    return out


def parts(
    path: Path, physics: SliderCrank, *, runs: int, seed: int, wanted: list[str]
) -> list[Shown]:
    """The module docstring's lines for one ocp.json; its rows at the first constraint sample."""
    ocp = read_ocp(path)
    geometry = ocp.geometry
    config = ReplayConfig(
        runs=runs, seed=seed, modes=("closed",), variability=ocp_variability(path)
    )
    machines = draw_machines(config, ocp.horizon, held_out=True)
    shuffled = np.random.default_rng(0).permutation(runs)
    height = ocp.config.height
    coefficients = motor_coefficients(physics.model)
    shown = []
    print(f"{path}: {runs} machines of root {seed} ({config.variability.name})")
    for name in [n for n in ocp.names if not wanted or n in wanted]:
        run = play(physics, ocp, profile=name, mode="closed", machines=machines, config=config)
        alpha = np.gradient(run.omega, 1.0 / SAMPLE_RATE, axis=1)
        load = torque_through_gap(run.tau, alpha, run.omega, coefficients)
        for k in ocp.config.constraint_samples:
            i = k - 1
            theta, delta = run.theta[:, i], run.backlash_angle[:, i]
            slider = run.slider_position[:, i]
            played = geometry.slider_position(run.crank_angle[:, i])
            independent = geometry.slider_position(theta + delta[shuffled])
            alone = geometry.slider_position(theta + delta.mean())
            below = np.flatnonzero(slider < height)
            print(
                f"  {name:9s} sample {k:3d}: θ sd {1e3 * theta.std():5.2f} mrad, δ sd "
                f"{1e3 * delta.std():5.2f} mrad (mean {1e3 * delta.mean():+6.2f}), corr(θ, δ) "
                f"{np.corrcoef(theta, delta)[0, 1]:+.2f}; slider sd {1e3 * slider.std():.3f} mm "
                f"(x(θ+δ) {1e3 * played.std():.3f}), with δ independent "
                f"{1e3 * independent.std():.3f}, θ alone {1e3 * alone.std():.3f}; below "
                f"{below.size} of {runs} (δ independent {int(np.sum(independent < height))}, "
                f"θ alone {int(np.sum(alone < height))})"
            )
            basis = np.column_stack([np.ones(runs), load[:, i], load[:, i - LAG]])
            weights, *_ = np.linalg.lstsq(basis, delta, rcond=None)
            fit = basis @ weights
            loaded = geometry.slider_position(theta + fit + (delta - fit)[shuffled])
            print(
                f"      δ on u now and {LAG} samples before: R² "
                f"{1 - np.var(delta - fit) / np.var(delta):.2f}, corr(θ, fit) "
                f"{np.corrcoef(theta, fit)[0, 1]:+.2f}; slider sd with δ = fit + a residual "
                f"independent of θ {1e3 * loaded.std():.3f} mm, below "
                f"{int(np.sum(loaded < height))}"
            )
            if below.size:
                where = places(machines, config.variability, below)
                print(f"      the machines below, median place in each range: {where}")
            if k == ocp.config.constraint_samples[0]:
                title = f"{path.parent.name}, {name}, sample {k}"
                shown.append(Shown(title, theta, delta, slider, independent, height))
    return shown


def figure(shown: list[Shown], path: Path) -> None:
    """Per row: the twin's θ about its mean against δ, the machines below in red; the slider's
    lower quarter as played and with δ drawn independently of θ."""
    from matplotlib.figure import Figure

    from common.figures import save_figure

    fig = Figure(figsize=(10, 2.8 * len(shown)), layout="constrained")
    axes = fig.subplots(len(shown), 2, squeeze=False)
    for row, (left, right) in zip(shown, axes, strict=True):
        below = row.slider < row.height
        centred = 1e3 * (row.theta - row.theta.mean())
        left.scatter(centred, 1e3 * row.delta, s=2, color="0.6", label="a machine")
        left.scatter(centred[below], 1e3 * row.delta[below], s=16, color="red", label="below")
        corr = np.corrcoef(row.theta, row.delta)[0, 1]
        left.set(xlabel="θ − its mean [mrad]", ylabel="δ [mrad]")
        left.set_title(f"{row.title}: corr(θ, δ) {corr:+.2f}", fontsize="medium")
        left.legend(fontsize="small", loc="lower right")
        low = min(row.slider.min(), row.independent.min(), row.height)
        edges = 1e3 * np.linspace(low, np.quantile(row.slider, 0.25), 40)
        right.hist(1e3 * row.slider, edges, histtype="step", color="black", label="played")
        right.hist(
            1e3 * row.independent,
            edges,
            histtype="step",
            color="tab:blue",
            label="δ independent of θ",
        )
        right.axvline(1e3 * row.height, color="tab:orange", label="height")
        right.set(xlabel="slider [mm], its lower quarter", ylabel="machines", yscale="log")
        right.set_title(
            f"below: {int(below.sum())} played, {int(np.sum(row.independent < row.height))} "
            f"with δ independent",
            fontsize="medium",
        )
        right.legend(fontsize="small", loc="upper left")
    save_figure(fig, path)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ocp", type=Path, nargs="+", required=True)
    parser.add_argument("--profiles", default="", help="comma-separated (default: every one)")
    parser.add_argument("--runs", type=int, default=4000)
    parser.add_argument("--seed", type=int, default=999, help="a development root")
    parser.add_argument("--model", type=Path, default=MODEL_PATH, help="the twin's MJCF")
    parser.add_argument("--figure", type=Path, default=None)
    args = parser.parse_args()
    physics = SliderCrank(load_model(args.model)[0])
    wanted = [n for n in args.profiles.split(",") if n]
    shown = []
    for path in args.ocp:
        shown += parts(path, physics, runs=args.runs, seed=args.seed, wanted=wanted)
    if args.figure is not None:
        figure(shown, args.figure)


if __name__ == "__main__":
    main()
