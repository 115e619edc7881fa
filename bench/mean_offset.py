"""Where along a plan the model's mean motor angle parts from the twin's, open loop and under the
profile's own law (bench/closed_round.md: at sample 50 of the paper task the nominal torque's is
within 0.4 mrad open loop and 5.2 ahead under its LQR). A diagnosis beside the product.

Plays `--profile` of `--ocp` on `--runs` machines (held-out streams of `--seed`: a development
root) open loop and closed loop under its gains, and runs the model's Monte-Carlo (the OCP's
mode, `--trajectories`, the plan's stream) the same two ways; prints every `--every` samples the
model's mean θ less the twin's and the twin's θ σ, and with `--figure` draws both along the plan.

    python bench/mean_offset.py --ocp OCP.json --model MODEL.pt [--profile nominal]
        [--runs 1000] [--seed 999] [--trajectories 4000] [--every 10] [--variability FILE]
        [--half-step] [--figure offset.png]

`--half-step`: also the closed loop with the twin's law tracking θ_k + dt (ω_k − ω_1) / 2 in place
of the plan's θ_k (the angle the plan's own speeds give by the trapezoid, where the model's forward
Euler step, eq. 4, takes dt ω_k), its offset read with the twin's angle less that half step (in
the model's frame): if the closed loop's offset is the model's half-sample lag, it goes.
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import numpy as np

from common import streams
from control.ocp_file import read_ocp
from ppann.checkpoint import load
from ppann.heads import FusedHeads
from ppann.montecarlo import Feedback, monte_carlo
from replay.campaign import draw_machines, play
from replay.config import ReplayConfig
from replay.files import ocp_variability
from twin import MODEL_PATH
from twin.physics import SliderCrank, load_model
from twin.variability import Variability


def offsets(args: argparse.Namespace) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per loop: the model's mean θ less the twin's, and the twin's θ σ, per sample (rad)."""
    ocp = read_ocp(args.ocp)
    planned = ocp.profiles[args.profile]
    model, _ = load(args.model)
    if args.half_step and model.config.angle_update != "euler":
        raise SystemExit(
            f"mean_offset.py: --half-step moves the plan by forward Euler's lag; {args.model} "
            f"steps its angle by {model.config.angle_update!r} (expected 'euler'), whose plan "
            "has none"
        )
    heads = FusedHeads(model)
    physics = SliderCrank(load_model(args.mjcf)[0])
    config = ReplayConfig(
        runs=args.runs,
        seed=args.seed,
        modes=("open", "closed"),
        variability=Variability.from_file(args.variability)
        if args.variability
        else ocp_variability(args.ocp),
    )
    machines = draw_machines(config, ocp.horizon, held_out=True)
    states = np.stack([planned.theta, planned.omega], axis=-1)
    gains = np.stack([planned.gain_theta, planned.gain_omega], axis=-1)
    # the half step: θ_k + dt (ω_k - ω_1) / 2 is the trapezoid's angle of the plan's own
    # speeds, where forward Euler (eq. 4) takes dt ω_k; the twin's law may track it in place of θ
    lag = 0.5 * ocp.dt * (planned.omega - planned.omega[0])
    ahead = replace(ocp, profiles={args.profile: replace(planned, theta=planned.theta + lag)})
    runs = [("open", ocp, "open", 0.0), ("closed", ocp, "closed", 0.0)]
    if args.half_step:
        runs.append(("closed, the law half a sample on", ahead, "closed", lag))
    out = {}
    for name, played, mode, behind in runs:
        twin = play(
            physics, played, profile=args.profile, mode=mode, machines=machines, config=config
        )
        bands = monte_carlo(
            heads,
            states[0],
            np.asarray(planned.tau)[:-1],
            n_samples=args.trajectories,
            mode=ocp.config.mc_mode,
            seed=streams.stream(ocp.config.mc_seed, "monte_carlo"),
            feedback=Feedback(states, gains, ocp.config.torque_limit) if mode == "closed" else None,
        )
        predicted = bands.samples[:, :, 0].mean(axis=0)
        # the twin's angle read back in the model's frame: less the half step it was asked to
        # run ahead by, if it was
        out[name] = (predicted - (twin.theta.mean(axis=0) - behind), twin.theta.std(axis=0))
    return out


def figure(found: dict[str, tuple[np.ndarray, np.ndarray]], title: str, path: Path) -> None:
    """Per loop: the model's mean θ less the twin's along the plan, beside ± the twin's θ σ."""
    from matplotlib.figure import Figure

    from common.figures import save_figure

    fig = Figure(figsize=(5 * len(found), 3.4), layout="constrained")
    axes = fig.subplots(1, len(found))
    for ax, (mode, (offset, sigma)) in zip(axes, found.items(), strict=True):
        k = np.arange(1, len(offset) + 1)
        ax.fill_between(k, -1e3 * sigma, 1e3 * sigma, color="0.85", label="± the twin's θ σ")
        ax.plot(k, 1e3 * offset, color="black", label="model's mean θ − the twin's")
        ax.axhline(0.0, color="0.5", linewidth=0.8)
        # the closed loops on one scale, so that the half step's panel reads against the other
        kept = [o for m, (o, _) in found.items() if (m == "open") == (mode == "open")]
        scale = 1.3 * max(max(np.abs(1e3 * o).max() for o in kept), 1e-3)
        ax.set(xlabel="sample", ylabel="mrad", ylim=(-scale, scale))
        ax.set_title(f"{title}: {mode}", fontsize="medium")
        ax.legend(fontsize="small", loc="upper left")
    save_figure(fig, path)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ocp", type=Path, required=True)
    parser.add_argument("--model", type=Path, required=True)
    parser.add_argument("--profile", default="nominal")
    parser.add_argument("--runs", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=999, help="a development root")
    parser.add_argument("--trajectories", type=int, default=4000)
    parser.add_argument("--every", type=int, default=10)
    parser.add_argument("--mjcf", type=Path, default=MODEL_PATH, help="the twin's MJCF")
    parser.add_argument("--variability", type=Path, default=None, help="a range file's twin")
    parser.add_argument(
        "--half-step",
        action="store_true",
        help="the twin's law tracks the plan's angle half a sample on (the trapezoid's)",
    )
    parser.add_argument("--figure", type=Path, default=None)
    args = parser.parse_args()
    found = offsets(args)
    print(f"{args.ocp} {args.profile}: {args.runs} machines of root {args.seed}")
    for mode, (offset, sigma) in found.items():
        picks = range(args.every, len(offset) + 1, args.every)
        row = ", ".join(
            f"{k}: {1e3 * offset[k - 1]:+.1f} ({1e3 * sigma[k - 1]:.1f})" for k in picks
        )
        print(f"  {mode}: model − twin mean θ, mrad (the twin's σ) at sample {row}")
    if args.figure is not None:
        figure(found, args.profile, args.figure)


if __name__ == "__main__":
    main()
