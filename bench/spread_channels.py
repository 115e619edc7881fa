"""Which of the model's channels makes the spread of θ it predicts at the constraint samples under
a torque: the white part (Monte-Carlo mode `step`) with each white channel alone — the sigma
networks of z_J, z_B, z_K (the others set to their floor) and the slider force through the
kinematics (ppann/lever.py) — and the machines' part (mode `machine`) with each log-factor of
the machine-level model alone (ppann/machine.py). No machine is drawn: beside them, optionally,
the twin's observed parts from a `bench/calibration_parts.py --out` file of the same torque.

    python bench/spread_channels.py --ocp OCP.json --model MODEL.pt [--profile robust] \
        [--trajectories 4000] [--seed 999] [--parts parts.json] [--out channels.json]

Independent channels add in squares: the sum of the channels' squares over the whole's says
how nearly they do.
"""

from __future__ import annotations

import argparse
import copy
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np
import torch

from common.errors import CrankError
from common.jsonio import write_json
from control.ocp_file import read_ocp
from ppann.checkpoint import load
from ppann.model import PPANN, Z_NAMES
from ppann.montecarlo import monte_carlo

OFF = -50.0
"""Bias of a sigma network's last layer (weights zeroed) that turns it off: softplus(-50) ~ 2e-22,
so the network gives its floor."""


def switch_off(model: PPANN, names: str) -> None:
    """Hold the sigma networks of the white channels in `names` ("J", "B", "K") at their floor,
    in place."""
    with torch.no_grad():
        for name in names:
            last = model.sigma_nets[name][-1]
            last.weight.zero_()
            last.bias.fill_(OFF)


def white_only(model: PPANN, keep: str | None) -> PPANN:
    """`model` with only the white channel `keep` ("J", "B", "K" or "F" for the slider force;
    None: all of them)."""
    if keep is None:
        return model
    out = copy.deepcopy(model)
    switch_off(out, "".join(name for name in Z_NAMES if name != keep))
    if keep != "F" and hasattr(out, "lever_sigma"):
        with torch.no_grad():
            out.lever_sigma.zero_()
    return out


def theta_sigma(
    model: PPANN,
    plan: Any,
    samples: list[int],
    *,
    mode: str,
    n: int,
    seed: int,
    machine_sigma: np.ndarray | None = None,
) -> list[float]:
    """The Monte-Carlo's σ of θ at the 1-based `samples` under the plan's torque, rad."""
    bands = monte_carlo(
        model,
        [plan.theta[0], plan.omega[0]],
        plan.tau[:-1],
        n_samples=n,
        mode=mode,
        seed=seed,
        machine_sigma=machine_sigma,
        at=[k - 1 for k in samples],
    )
    return [float(v) for v in np.asarray(bands.samples)[:, :, 0].std(axis=0, ddof=1)]


def channels(
    model: PPANN, plan: Any, samples: list[int], *, n: int, seed: int
) -> dict[str, dict[str, list[float]]]:
    """θ's σ per sample for the whole and each channel of the white and the machines' parts."""
    white = {
        name or "all": theta_sigma(
            white_only(model, name), plan, samples, mode="step", n=n, seed=seed
        )
        for name in (None, "J", "B", "K", "F")
    }
    spread = model.machine_sigma.detach().numpy().copy()
    machines = {"all": theta_sigma(model, plan, samples, mode="machine", n=n, seed=seed)}
    for i, name in enumerate(Z_NAMES):
        alone = np.where(np.arange(3) == i, spread, 0.0)
        machines[name] = theta_sigma(
            model, plan, samples, mode="machine", n=n, seed=seed, machine_sigma=alone
        )
    return {"white": white, "machines": machines}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ocp", required=True)
    parser.add_argument("--model", required=True)
    parser.add_argument("--profile", default="robust")
    parser.add_argument("--trajectories", type=int, default=4000)
    parser.add_argument("--seed", type=int, default=999)
    parser.add_argument("--parts", help="bench/calibration_parts.py's file of the same torque")
    parser.add_argument("--out")
    args = parser.parse_args()
    try:
        ocp = read_ocp(args.ocp)
        if args.profile not in ocp.names:
            raise CrankError(f"{args.ocp} has no profile {args.profile!r}")
        model, _ = load(args.model)
        if not isinstance(model, PPANN):
            raise CrankError(f"{args.model}: not a PPANN")
    except CrankError as exc:
        sys.exit(f"spread_channels: {exc}")
    samples = list(ocp.config.constraint_samples)
    found = channels(
        model, ocp.profiles[args.profile], samples, n=args.trajectories, seed=args.seed
    )
    twin = json.loads(Path(args.parts).read_text())["samples"] if args.parts else None
    for part, by in found.items():
        for i, k in enumerate(samples):
            whole = by["all"][i]
            shown = ", ".join(f"{name} {1e3 * v[i]:.1f}" for name, v in by.items() if name != "all")
            squares = sum(v[i] ** 2 for name, v in by.items() if name != "all") / whole**2
            seen = ""
            if twin is not None:
                observed = twin[str(k)][part]["theta_observed"]
                seen = f"; twin {1e3 * observed:.1f} (all / twin {whole / observed:.2f})"
            print(
                f"sample {k} {part:<8}: θ σ mrad all {1e3 * whole:.1f}; alone {shown} "
                f"(squares / all² {squares:.2f}){seen}",
                flush=True,
            )
    if args.out:
        write_json(args.out, {"settings": vars(args), "samples": samples, "theta_sigma": found})


if __name__ == "__main__":
    main()
