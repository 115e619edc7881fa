"""How a machine's friction and damping move the crank at the constraint samples, on the twin and
in the model: one machine of the line's mean (nominal friction, damping and backlash, warmed up
for `--start` s at the nominal drop, no white force) with its four friction and damping
parameters all scaled by e^η, η on a grid, played open loop under a torque; beside it the
model's mean trajectory with its damping factor scaled by e^η (the machine-level offset
ppann/machine.py draws, as "augmented" applies it: B_m (1 + z_B) e^η). No held-out machine is
drawn: the grid is deterministic.

    python bench/crawl_response.py --ocp OCP.json --model MODEL.pt [--profile robust] \
        [--eta 0.08] [--points 9] [--start 30] [--out response.json] [--figure response.png]

A straight response (θ moves as far ahead for −η as behind for +η) turns a symmetric spread of
machines into a symmetric spread of θ; a bent one skews it, and past top dead centre the
slider's lower tail is θ's upper one (bench/tail_parts.md).
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import torch

from common.errors import CrankError
from common.figures import save_figure
from common.jsonio import write_json
from control.ocp_file import OCPFile, read_ocp
from ppann.checkpoint import load
from ppann.heads import FusedHeads
from ppann.montecarlo import monte_carlo
from replay.campaign import Machines, play
from replay.config import ReplayConfig
from twin import MODEL_PATH
from twin.physics import SliderCrank, load_model
from twin.variability import MachineDraw, Variability

B = 1
"""The damping factor's index in the model's (J, B, K)."""


def twin_theta(plan: OCPFile, profile: str, etas: np.ndarray, start: float) -> np.ndarray:
    """The twin's θ, (len(etas), horizon), one machine per η (module docstring)."""
    base = Variability()
    line = replace(
        base, **{p.name: p.fixed() for p in base.parameters()}, disturbance_amplitude=0.0
    )
    draws = [
        MachineDraw(
            motor_frictionloss=base.motor_frictionloss.nominal * np.exp(e),
            motor_damping=base.motor_damping.nominal * np.exp(e),
            slider_frictionloss=base.slider_frictionloss.nominal * np.exp(e),
            slider_damping=base.slider_damping.nominal * np.exp(e),
            backlash_width=base.backlash_width.nominal,
            warmup_drop=base.warmup_drop.nominal,
        )
        for e in etas
    ]
    n = len(etas)
    config = ReplayConfig(runs=n, seed=0, variability=line, max_start_time=start)
    machines = Machines(
        draws=draws, start_times=np.full(n, start), disturbance=np.zeros((n, plan.horizon))
    )
    physics = SliderCrank(load_model(MODEL_PATH)[0])
    replay = play(physics, plan, profile=profile, mode="open", machines=machines, config=config)
    return replay.theta


def model_theta(plan: OCPFile, model_path: str, profile: str, etas: np.ndarray) -> np.ndarray:
    """The model's mean θ, (len(etas), horizon), its damping factor scaled by e^η (and with
    `PPANNConfig.coulomb` its Coulomb friction, as a machine's factor scales it)."""
    planned = plan.profiles[profile]
    model, _ = load(model_path)
    if model.config.machine_terms != "augmented":
        raise CrankError(f"{model_path}: machine_terms {model.config.machine_terms!r}")
    factor = model.physical_factor.detach().clone()
    coulomb = model.coulomb_log.detach().clone() if model.config.coulomb else None
    model.machine_sigma.zero_()
    out = []
    for e in etas:
        scaled = factor.clone()
        scaled[B] *= float(np.exp(e))
        with torch.no_grad():
            model.physical_factor.copy_(scaled)
            if coulomb is not None:  # the damping factor scales the prior's Coulomb friction too
                model.coulomb_log.copy_(coulomb + float(e))
        bands = monte_carlo(
            FusedHeads(model),
            [planned.theta[0], planned.omega[0]],
            planned.tau[:-1],
            n_samples=2,  # the fewest it draws; with no machine spread both are the mean
            mode="machine",
            seed=np.random.SeedSequence(0),
        )
        out.append(bands.samples[0, :, 0])
    return np.array(out)


def measure(*, ocp: str, model_path: str, profile: str, etas: np.ndarray, start: float) -> dict:
    """θ at each constraint sample per η, twin and model, and the bend: how far ahead at −η
    over how far behind at +η, at the grid's ends."""
    plan = read_ocp(ocp)
    if profile not in plan.names:
        raise CrankError(f"{ocp} has no profile {profile!r}")
    twin = twin_theta(plan, profile, etas, start)
    model = model_theta(plan, model_path, profile, etas)
    middle = len(etas) // 2
    samples: dict[str, Any] = {}
    for k in plan.config.constraint_samples:
        entry = {}
        for who, theta in (("twin", twin), ("model", model)):
            moved = theta[:, k - 1] - theta[middle, k - 1]
            entry[who] = {
                "theta_at_zero": float(theta[middle, k - 1]),
                "moved": moved.tolist(),
                "ahead_over_behind": float(-moved[0] / moved[-1]),
            }
        samples[str(k)] = entry
    return {"etas": etas.tolist(), "samples": samples}


def figure(result: dict, path: str) -> None:
    """θ's move against η per constraint sample, twin and model."""
    samples = result["samples"]
    fig, axes = plt.subplots(1, len(samples), figsize=(5.5 * len(samples), 4.5), squeeze=False)
    etas = 100 * np.array(result["etas"])
    for ax, (k, entry) in zip(axes[0], samples.items(), strict=True):
        for who, style in (("twin", "o-"), ("model", "s--")):
            e = entry[who]
            ax.plot(
                etas,
                1e3 * np.array(e["moved"]),
                style,
                label=f"{who} (ahead / behind {e['ahead_over_behind']:.2f})",
            )
        ax.axhline(0.0, color="black", lw=0.8)
        ax.set_xlabel("η: friction and damping × e^η, %")
        ax.set_ylabel("θ − θ at η = 0, mrad")
        lead = 1e3 * (entry["model"]["theta_at_zero"] - entry["twin"]["theta_at_zero"])
        ax.set_title(f"sample {k} (the model's lead at η = 0: {lead:+.0f} mrad)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    save_figure(fig, path)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ocp", required=True)
    parser.add_argument("--model", required=True)
    parser.add_argument("--profile", default="robust")
    parser.add_argument("--eta", type=float, default=0.08, help="the grid's end, log-factor")
    parser.add_argument("--points", type=int, default=9, help="odd: the middle one is η = 0")
    parser.add_argument("--start", type=float, default=30.0, help="s the machine ran before")
    parser.add_argument("--out", help="a JSON of the figures, with the settings")
    parser.add_argument("--figure", help="a PNG of θ's move against η")
    args = parser.parse_args()
    try:
        if args.points < 3 or args.points % 2 == 0 or not 0 < args.eta < 1:
            raise CrankError("--points must be odd and at least 3, --eta in (0, 1)")
        etas = np.linspace(-args.eta, args.eta, args.points)
        result = measure(
            ocp=args.ocp, model_path=args.model, profile=args.profile, etas=etas, start=args.start
        )
    except (CrankError, OSError) as exc:
        sys.exit(f"crawl_response: {exc}")
    for k, entry in result["samples"].items():
        for who in ("twin", "model"):
            e = entry[who]
            moves = " ".join(f"{1e3 * m:+5.0f}" for m in e["moved"])
            bend = e["ahead_over_behind"]
            print(f"sample {k} {who:5}: θ moves {moves} mrad; ahead / behind {bend:.2f}")
    if args.out:
        settings = {k: v for k, v in vars(args).items() if k not in ("out", "figure")}
        write_json(Path(args.out), {"settings": settings, **result}, indent=1)
    if args.figure:
        figure(result, args.figure)


if __name__ == "__main__":
    main()
