"""Which part of the line's spread makes the slider's lower tail that the model's own check
under-counts: the twin's slider at each constraint sample under a torque, on the line, on its
nominal machine under the white force alone, and on its machines without the white force, beside
the model's Monte-Carlo mode that stands for each (`mixed`, `step`, `machine`; the parts of
bench/calibration_parts.py), compared in shape and not only in σ: skew, the lower quantiles in
standard deviations below the mean, and the share below the height.

    python bench/tail_parts.py --ocp OCP.json --model MODEL.pt --heldout-seed ROOT \
        [--profile robust] [--runs 4000] [--trajectories 20000] [--variability NAME|FILE] \
        [--out tail.json]

Beside each part: the crank angle θ's own shape (twin and model), the model's lead (its mean θ
minus the twin's), the model's slider with its Monte-Carlo moved back by that lead
(`model_moved`: what is left once the mean is right), and the twin's own θ put through the
model's transmission draws and kinematics (`twin_via_model`: whether the slider's shape is the
angle's, or the backlash's). For the line it also says what the machines below the height have in
common: each of the line's parameters' mean place in its range among them (0 its low end, 1 its
high end; 0.5 is the line's own mean) and their start time.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import numpy as np
from calibration_parts import PARTS, parts_of
from heldout_options import checked_line, heldout_parser
from scipy import stats as scistats

from common import streams
from common.errors import CrankError
from common.jsonio import write_json
from control.ocp_file import read_ocp
from ppann.checkpoint import load
from ppann.heads import FusedHeads
from ppann.montecarlo import monte_carlo
from ppann.transmission import draw
from replay.campaign import draw_machines, play
from replay.config import ReplayConfig
from replay.placement import placements
from twin import MODEL_PATH, OPERATING_SECONDS
from twin.physics import SliderCrank, load_model

LEVELS = (0.01, 0.00135)
"""The lower quantiles compared, in standard deviations below the mean (Φ(−2.33), Φ(−3))."""


def shape(x: np.ndarray, height: float) -> dict[str, Any]:
    """Mean, σ, skew, the LEVELS' quantiles in σ below the mean, and the share below `height`."""
    x = x[np.isfinite(x)]
    mean, sigma = float(x.mean()), float(x.std(ddof=1))
    return {
        "n": int(x.size),
        "mean": mean,
        "sigma": sigma,
        "skew": float(scistats.skew(x)),
        "quantiles_in_sigma": {str(q): float((np.quantile(x, q) - mean) / sigma) for q in LEVELS},
        "below": int((x < height).sum()),
        "rate": float((x < height).mean()),
    }


def placement_of(machines: Any, below: np.ndarray, line: Any, *, until: int) -> dict[str, float]:
    """Each varied parameter's mean place in its range over the machines `below` (0 low end,
    1 high end; replay/placement.py's `range_position`), and their mean start time in s."""
    placed = placements(
        machines, np.flatnonzero(below).tolist(), line, until=until, max_start_s=OPERATING_SECONDS
    )
    names = [p.name for p in line.parameters() if p.high > p.low]
    out = {n: float(np.mean([m["range_position"][n] for m in placed])) for n in names}
    out["start_time_s"] = float(np.mean([m["start_s"] for m in placed]))
    return out


def measure(
    *, ocp: str, model_path: str, profile: str, runs: int, seed: int, trajectories: int, line: Any
) -> dict[str, Any]:
    """The twin's and the model's slider shape per part and constraint sample."""
    plan = read_ocp(ocp)
    if profile not in plan.names:
        raise CrankError(f"{ocp} has no profile {profile!r}")
    model, _ = load(model_path)
    heads = FusedHeads(model)
    physics = SliderCrank(load_model(MODEL_PATH)[0])
    c, planned = plan.config, plan.profiles[profile]
    delta = draw(heads.transmission, (trajectories,), streams.rng(c.mc_seed, "transmission"))
    out: dict[str, Any] = {}
    for part, variability in parts_of(line).items():
        config = ReplayConfig(
            runs=runs, seed=seed, variability=variability, max_start_time=OPERATING_SECONDS
        )
        machines = draw_machines(config, plan.horizon, held_out=True)
        replay = play(physics, plan, profile=profile, mode="open", machines=machines, config=config)
        bands = monte_carlo(
            heads,
            [planned.theta[0], planned.omega[0]],
            planned.tau[:-1],
            n_samples=trajectories,
            mode=PARTS[part],
            seed=streams.stream(c.mc_seed, "monte_carlo"),
        )
        below_any = np.zeros(runs, dtype=bool)
        for k in c.constraint_samples:
            twin = replay.slider_position[:, k - 1]
            below_any |= twin < c.height
            theta = bands.samples[:, k - 1, 0]
            lead = float(np.nanmean(theta) - replay.theta[:, k - 1].mean())
            own = replay.theta[:, k - 1] + delta[:runs] if runs <= trajectories else None
            with np.errstate(over="ignore", invalid="ignore"):
                predicted = plan.geometry.slider_position(theta + delta)
                moved = plan.geometry.slider_position(theta - lead + delta)
            out.setdefault(str(k), {})[part] = {
                "mode": PARTS[part],
                "twin": shape(twin, c.height),
                "model": shape(predicted, c.height),
                "twin_theta": shape(replay.theta[:, k - 1], -np.inf),
                "model_theta": shape(theta, -np.inf),
                "lead": lead,
                "model_moved": shape(moved, c.height),
            }
            if own is not None:  # the twin's own angle through the model's transmission
                entry = out[str(k)][part]
                entry["twin_via_model"] = shape(plan.geometry.slider_position(own), c.height)
        if part == "line" and below_any.any():
            out["line_below"] = {
                "machines": int(below_any.sum()),
                "placement": placement_of(
                    machines, below_any, variability, until=max(c.constraint_samples)
                ),
            }
    return out


def main() -> None:
    parser = heldout_parser(
        __doc__.splitlines()[0],
        runs_help="machines per part",
        trajectories_help="per Monte-Carlo mode",
    )
    args = parser.parse_args()
    try:
        line = checked_line(args)
        result = measure(
            ocp=args.ocp,
            model_path=args.model,
            profile=args.profile,
            runs=args.runs,
            seed=args.heldout_seed,
            trajectories=args.trajectories,
            line=line,
        )
    except (CrankError, OSError) as exc:
        sys.exit(f"tail_parts: {exc}")
    for k, parts in result.items():
        if k == "line_below":
            continue
        for part, f in parts.items():
            cells = []
            for who in ("twin", "twin_via_model", "model", "model_moved"):
                if who not in f:
                    continue
                s = f[who]
                q = s["quantiles_in_sigma"]
                cells.append(
                    f"{who} σ {1e3 * s['sigma']:5.2f} mm skew {s['skew']:+.2f} "
                    f"q1% {q['0.01']:+.2f}σ q0.135% {q['0.00135']:+.2f}σ "
                    f"below {s['below']}/{s['n']}"
                )
            print(f"sample {k} {part:8} ({f['mode']:7}): " + " | ".join(cells))
            t, m = f["twin_theta"], f["model_theta"]
            print(
                f"    θ: twin σ {1e3 * t['sigma']:.1f} mrad skew {t['skew']:+.2f} | model σ "
                f"{1e3 * m['sigma']:.1f} mrad skew {m['skew']:+.2f} | the model's lead "
                f"{1e3 * f['lead']:+.1f} mrad (model_moved: its Monte-Carlo moved back by it)"
            )
    if "line_below" in result:
        b = result["line_below"]
        places = ", ".join(f"{n} {v:.2f}" for n, v in b["placement"].items())
        print(f"line: {b['machines']} machines below; their mean place: {places}")
    if args.out:
        settings = {k: v for k, v in vars(args).items() if k != "out"}
        write_json(Path(args.out), {"settings": settings, "samples": result}, indent=1)


if __name__ == "__main__":
    main()
