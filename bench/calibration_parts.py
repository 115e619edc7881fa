"""Which part of the line's spread the model gets wrong: the twin's spread of θ (and of the
slider) at the constraint samples under a torque, on the line, on the line's nominal machine
with the white force alone, and on the line's machines without it, beside the model's
Monte-Carlo modes that stand for each: `mixed` for the line, `step` for the white force,
`machine` for the machines (replay/heldout.py's calibration, one held-out root, the same
machines for each part).

    python bench/calibration_parts.py --ocp OCP.json --model MODEL.pt --heldout-seed ROOT \
        [--profile robust] [--runs 1000] [--trajectories 4000] [--variability NAME|FILE] \
        [--out parts.json]

The parts add in quadrature where they are independent: the line's observed σ against
sqrt(white² + machines²) says how far they are. "white" keeps the line's warm-up drift at its
nominal drop (the line's mean angle with it; without drift the mean crank runs ~75 mrad behind).
"""

from __future__ import annotations

import math
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

from heldout_options import checked_line, heldout_parser

from common.errors import CrankError
from common.jsonio import write_json
from common.streams import HELDOUT_STREAMS, describe
from control.ocp_file import read_ocp
from ppann.checkpoint import load
from replay.heldout import heldout_check
from twin import MODEL_PATH
from twin.physics import SliderCrank, load_model
from twin.variability import Variability

PARTS = {"line": "mixed", "white": "step", "machines": "machine"}
"""Each part of the twin's spread and the Monte-Carlo mode that models it."""


def parts_of(line: Variability) -> dict[str, Variability]:
    """The line; its nominal machine under the white force (drift kept); its machines without
    the white force."""
    nominal = {p.name: p.fixed() for p in line.parameters()}
    return {
        "line": line,
        "white": replace(line, **nominal),
        "machines": replace(line, disturbance_amplitude=0.0),
    }


def measure(
    *,
    ocp: str,
    model_path: str,
    profile: str,
    runs: int,
    seed: int,
    trajectories: int,
    variability: Variability,
) -> dict[str, Any]:
    """The observed and predicted σ of θ and of the slider per part and constraint sample."""
    if profile not in read_ocp(ocp).names:  # before the first held-out run, not after it
        raise CrankError(f"{ocp} has no profile {profile!r}")
    model, _ = load(model_path)
    physics = SliderCrank(load_model(MODEL_PATH)[0])
    out: dict[str, Any] = {}
    for part, line in parts_of(variability).items():
        checked = heldout_check(
            physics,
            ocp,
            model,
            runs=runs,
            seed=seed,
            variability=line,
            mc_samples=trajectories,
            tail_draws=100,  # the model's own rate is not read here
        )
        mode = PARTS[part]
        for k, entry in checked["profiles"][profile]["open"]["samples"].items():
            theta = entry["theta"]
            out.setdefault(k, {})[part] = {
                "mode": mode,
                "theta_observed": theta["observed_sigma"],
                "theta_predicted": theta["predicted"][mode]["sigma"],
                "theta_mean_observed": theta["observed_mean"],
                "theta_mean_predicted": theta["predicted"][mode]["mean"],
                "slider_observed": entry["observed_sigma"],
                "slider_predicted": entry["predicted"][mode]["sigma"],
            }
    return out


def main() -> None:
    parser = heldout_parser(
        __doc__.splitlines()[0],
        runs_help="held-out machines per part",
        trajectories_help="per Monte-Carlo mode",
    )
    args = parser.parse_args()
    try:
        variability = checked_line(args)
        settings = {k: v for k, v in vars(args).items() if k != "out"}
        samples = measure(
            ocp=args.ocp,
            model_path=args.model,
            profile=args.profile,
            runs=args.runs,
            seed=args.heldout_seed,
            trajectories=args.trajectories,
            variability=variability,
        )
    except (CrankError, OSError) as exc:
        sys.exit(f"calibration_parts: {exc}")
    for k, parts in samples.items():
        white, machines, line = (parts[p]["theta_observed"] for p in ("white", "machines", "line"))
        for part, f in parts.items():
            ratio = f["theta_predicted"] / f["theta_observed"]
            bias = f["theta_mean_predicted"] - f["theta_mean_observed"]
            print(
                f"sample {k} {part:8} ({f['mode']:7}): θ σ observed "
                f"{1e3 * f['theta_observed']:6.1f} mrad, predicted "
                f"{1e3 * f['theta_predicted']:6.1f} ({ratio:.2f}); mean θ predicted − observed "
                f"{1e3 * bias:+5.1f} mrad; slider σ ratio "
                f"{f['slider_predicted'] / f['slider_observed']:.2f}"
            )
        print(
            f"sample {k}: the parts in quadrature / the line's observed θ σ "
            f"{math.hypot(white, machines) / line:.3f}"
        )
    if args.out:
        write_json(
            Path(args.out),
            {
                "settings": settings,
                "heldout_streams": describe(args.heldout_seed, HELDOUT_STREAMS),
                "samples": samples,
            },
            indent=1,
        )


if __name__ == "__main__":
    main()
