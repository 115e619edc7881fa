"""Where the tubes' tail at a constraint sample comes from on the twin: the motor angle θ, the
crank's angle to the motor δ (the backlash sensor), and how the two move together — beside what
the model's Monte-Carlo assumes (δ drawn from its marginal, independently of θ).

Session 86 (bench/tubes_mc_seeds_shipped.md) found every machine below a tube's height below at
sample 50, where the crank crosses the backlash gap, and the model's own rate 2.2-13x under the
twin's there; bench/transmission_load.md had named a δ conditioned on the torque through the
gap as the candidate. This script plays each closed-loop profile of an ocp.json under its own
gains on `--runs` machines (held-out streams of `--seed`: pass a development root, not a
held-out one) and prints at each constraint sample: θ's and δ's spread, their correlation, the
slider's spread and rate below the height as played, and the same with δ taken from another
machine at random (δ independent of θ, as the model draws it), and with δ at its mean (θ
alone); the machines below and where they sit in the line (each parameter's place in its
range, 0 low, 1 high).

    python bench/sample50_parts.py --ocp OCP.json [--runs 4000] [--seed 999] [--model MJCF]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from control.ocp_file import read_ocp
from replay.campaign import draw_machines, play
from replay.config import ReplayConfig
from replay.files import ocp_variability
from twin import MODEL_PATH
from twin.physics import SAMPLE_RATE, SliderCrank, load_model

LAG = 5
"""Samples (10 ms) between the two loads delta is fitted on (bench/transmission_load.md)."""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ocp", type=Path, required=True)
    parser.add_argument("--runs", type=int, default=4000)
    parser.add_argument("--seed", type=int, default=999, help="a development root")
    parser.add_argument("--model", type=Path, default=MODEL_PATH, help="the twin's MJCF")
    args = parser.parse_args()
    ocp = read_ocp(args.ocp)
    physics = SliderCrank(load_model(args.model)[0])
    geometry = ocp.geometry
    config = ReplayConfig(
        runs=args.runs, seed=args.seed, modes=("closed",), variability=ocp_variability(args.ocp)
    )
    machines = draw_machines(config, ocp.horizon, held_out=True)
    shuffled = np.random.default_rng(0).permutation(args.runs)
    height = ocp.config.height
    dof = physics.model.joint("motor").dofadr[0]
    mjmodel = physics.model
    motor = tuple(
        float(a[dof]) for a in (mjmodel.dof_armature, mjmodel.dof_damping, mjmodel.dof_frictionloss)
    )

    def places(indices: np.ndarray) -> dict[str, float]:
        """Each uncertain parameter's median place in its range over machines `indices`."""
        out = {}
        for parameter in config.variability.parameters():
            span = parameter.high - parameter.low
            if span > 0:
                values = [getattr(machines.draws[i], parameter.name) for i in indices]
                out[parameter.name] = round(float(np.median(values) - parameter.low) / span, 2)
        return out

    print(f"{args.ocp}: {args.runs} machines of root {args.seed} ({config.variability.name})")
    for name in ocp.names:
        run = play(physics, ocp, profile=name, mode="closed", machines=machines, config=config)
        alpha = np.gradient(run.omega, 1.0 / SAMPLE_RATE, axis=1)
        for k in ocp.config.constraint_samples:
            i = k - 1
            theta, delta = run.theta[:, i], run.backlash_angle[:, i]
            slider = run.slider_position[:, i]
            crank = run.crank_angle[:, i]
            played = geometry.slider_position(crank)
            independent = geometry.slider_position(theta + delta[shuffled])
            alone = geometry.slider_position(theta + delta.mean())
            corr = np.corrcoef(theta, delta)[0, 1]
            below = np.flatnonzero(slider < height)
            print(
                f"  {name:9s} sample {k:3d}: θ sd {1e3 * theta.std():5.2f} mrad, δ sd "
                f"{1e3 * delta.std():5.2f} mrad (mean {1e3 * delta.mean():+6.2f}), corr(θ, δ) "
                f"{corr:+.2f}; slider sd {1e3 * slider.std():.3f} mm (x(θ+δ) "
                f"{1e3 * played.std():.3f}), with δ independent {1e3 * independent.std():.3f}, "
                f"θ alone {1e3 * alone.std():.3f}; below {below.size} of {args.runs} "
                f"(δ independent {int(np.sum(independent < height))}, θ alone "
                f"{int(np.sum(alone < height))})"
            )
            # delta explained by the torque through the gap now and LAG samples before (u with
            # the MJCF's motor joint: a ceiling), a least-squares fit on these runs themselves
            u = run.tau - motor[0] * alpha - motor[1] * run.omega - motor[2] * np.sign(run.omega)
            basis = np.column_stack([np.ones(args.runs), u[:, i], u[:, i - LAG]])
            coefficients, *_ = np.linalg.lstsq(basis, delta, rcond=None)
            fit = basis @ coefficients
            residual = (delta - fit)[shuffled]
            loaded = geometry.slider_position(theta + fit + residual)
            print(
                f"      δ on u now and {LAG} samples before: R² "
                f"{1 - np.var(delta - fit) / np.var(delta):.2f}, corr(θ, fit) "
                f"{np.corrcoef(theta, fit)[0, 1]:+.2f}; slider sd with δ = fit + a residual "
                f"independent of θ {1e3 * loaded.std():.3f} mm, below "
                f"{int(np.sum(loaded < height))}"
            )
            if below.size:
                print(f"      the machines below, median place in each range: {places(below)}")


if __name__ == "__main__":
    main()
