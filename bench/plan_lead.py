"""How far the mean model's plan runs ahead of the twin under a torque, where along the torque
the lead is made, and how much of the calibration's slider σ ratio it makes.

    python bench/plan_lead.py --ocp OCP.json --model MODEL.pt --heldout-seed ROOT \
        [--profile robust] [--runs 1000] [--trajectories 4000] [--data DATASET.mcap] \
        [--windows 3000] [--out lead.json]

Per constraint sample:
- `lead`: the plan's crank angle θ (the mean model's noise-free rollout) less the twin's on its
  nominal machine without the white force, warm-up averaged over STARTS start times across the
  operating range (twin.OPERATING_SECONDS, the replays' range);
- `mc_lead`: the mixed Monte-Carlo's mean θ less the held-out machines' (replay/heldout.py's
  calibration, the same machines and draws);
- the slider σ ratio (predicted / observed, mixed, as replay/heldout.py) and the same with every
  Monte-Carlo trajectory moved back by `mc_lead` (`ratio_at_twin_mean`): the slider is x(θ), so
  the same spread of θ is a wider spread of the slider where x is steeper, and a plan ahead of
  the machines past top dead centre predicts the slider's spread where it is steeper than theirs.

Along the torque, up to the last constraint sample: the mean model's one-step velocity error on
the twin's own noise-free trajectories (the same nominal machine), summed (rad/s) and split by
where the twin's backlash is: in transit across its gap, or against a stop; and per step
(`per_step`, printed in blocks of SERIES_BLOCK samples): where along the torque it is made.

With --data (the model's training dataset): the mean model's drift over as many steps as the
last constraint sample on `--windows` windows of the dataset's own episodes (signed by the
direction of motion), the lead in the regime it was trained on; the windows from
`--window-seed` (default 0).
"""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
from heldout_options import checked_line, heldout_parser

from common import streams
from common.errors import CrankError
from common.jsonio import write_json
from control.ocp_file import Profile, read_ocp
from ppann.checkpoint import load
from ppann.heads import FusedHeads
from ppann.model import PPANN, rollout
from ppann.montecarlo import monte_carlo
from ppann.transmission import draw
from replay.heldout import heldout_check
from twin import MODEL_PATH, OPERATING_SECONDS
from twin.mcap_dataset import read_dataset
from twin.physics import SliderCrank, load_model
from twin.stepping import simulate
from twin.variability import Variability

STARTS = 13
"""Start times of the nominal machine's noise-free runs, evenly over the operating range."""
SERIES_BLOCK = 10
"""Samples per block of the printed one-step velocity error along the torque."""
IN_TRANSIT = 0.9
"""The backlash is in transit where it is within this share of its half-width from centre."""


def nominal_runs(
    physics: SliderCrank, line: Variability, profile: Profile, x0: np.ndarray
) -> dict[str, np.ndarray]:
    """The line's nominal machine under the profile's torque without the white force, at STARTS
    start times: motor angle, speed and backlash angle, (STARTS, N) each."""
    quiet = replace(
        line,
        **{p.name: p.fixed() for p in line.parameters()},
        disturbance_amplitude=0.0,
    )
    n = len(profile.tau)
    runs = simulate(
        physics,
        quiet,
        draws=[quiet.nominal()] * STARTS,
        initial_states=np.tile(x0, (STARTS, 1)),
        tau=np.tile(profile.tau, (STARTS, 1)),
        disturbance=np.zeros((STARTS, n)),
        start_times=np.linspace(0.0, OPERATING_SECONDS, STARTS),
        chunk_samples=n,
        nthread=1,
    )
    sd = runs.sensordata
    return {
        "theta": physics.sensor(sd, "theta"),
        "omega": physics.sensor(sd, "omega"),
        "backlash": physics.sensor(sd, "backlash_angle"),
    }


def velocity_error(
    model: PPANN, twin: dict[str, np.ndarray], tau: np.ndarray, *, last: int, half_gap: float
) -> dict[str, float]:
    """The mean model's one-step velocity error on the twin's trajectories up to sample `last`
    (1-based), summed over the steps (rad/s, averaged over the runs), split by the backlash."""
    x = torch.from_numpy(np.stack([twin["theta"], twin["omega"]], axis=-1)[:, : last - 1])
    u = torch.from_numpy(np.broadcast_to(tau[: last - 1], x.shape[:2]).copy())
    with torch.no_grad():
        error = model.step(x, u)[..., 1].numpy() - twin["omega"][:, 1:last]
    transit = np.abs(twin["backlash"][:, : last - 1]) < IN_TRANSIT * half_gap
    return {
        "per_step": error.mean(axis=0).tolist(),  # step k -> k + 1 (k = 1..last - 1), over runs
        "total": float(error.sum(axis=1).mean()),
        "backlash_in_transit": float((error * transit).sum(axis=1).mean()),
        "backlash_at_a_stop": float((error * ~transit).sum(axis=1).mean()),
        "steps_in_transit": float(transit.sum(axis=1).mean()),
    }


def dataset_drift(
    model: PPANN, data: str, *, steps: int, windows: int, seed: int
) -> dict[str, float]:
    """The mean model's θ after `steps` steps less the data's, on `windows` windows of single
    episodes, signed by the direction of motion: mean, its standard error and the spread, rad.

    Raises:
      CrankError: no episode holds a window of `steps` steps.
    """
    dataset = read_dataset(data)
    episode = dataset.episode
    if np.bincount(episode - episode.min()).max() <= steps:
        raise CrankError(f"{data}: no episode is longer than {steps} samples")
    rng = np.random.default_rng(seed)
    starts: list[int] = []
    while len(starts) < windows:
        i = int(rng.integers(0, len(episode) - steps - 1))
        if episode[i] == episode[i + steps]:
            starts.append(i)
    index = np.array(starts)[:, None] + np.arange(steps + 1)[None]
    theta, omega, tau = (
        torch.from_numpy(a[index]) for a in (dataset.theta, dataset.omega, dataset.tau)
    )
    with torch.no_grad():
        path = rollout(model, torch.stack([theta[:, 0], omega[:, 0]], -1), tau[:, :steps]).numpy()
    sign = np.sign(dataset.theta[index[:, -1]] - dataset.theta[index[:, 0]])
    drift = (path[:, -1, 0] - dataset.theta[index[:, -1]]) * sign
    return {
        "mean": float(drift.mean()),
        "se": float(drift.std(ddof=1) / np.sqrt(windows)),
        "sd": float(drift.std(ddof=1)),
    }


def measure(
    *,
    ocp_path: str,
    model: PPANN,
    profile: str,
    runs: int,
    seed: int,
    trajectories: int,
    variability: Variability,
) -> dict[str, Any]:
    """Every figure of the module docstring but the dataset's drift."""
    ocp = read_ocp(ocp_path)
    if profile not in ocp.names:  # before the held-out run, not after it
        raise CrankError(f"{ocp_path} has no profile {profile!r}")
    physics = SliderCrank(load_model(MODEL_PATH)[0])
    chosen = ocp.profiles[profile]
    c = ocp.config
    checked = heldout_check(
        physics,
        ocp_path,
        model,
        runs=runs,
        seed=seed,
        variability=variability,
        mc_samples=trajectories,
        tail_draws=100,  # the model's own rate is not read here
    )["profiles"][profile]["open"]["samples"]
    # the calibration's own Monte-Carlo (replay/heldout.py): the same streams, so its σ is
    # the one heldout.json reports
    heads = FusedHeads(model)
    bands = monte_carlo(
        heads,
        [chosen.theta[0], chosen.omega[0]],
        chosen.tau[:-1],
        n_samples=trajectories,
        mode="mixed",
        seed=streams.stream(c.mc_seed, "monte_carlo"),
    )
    delta = draw(heads.transmission, (trajectories,), streams.rng(c.mc_seed, "transmission"))
    x0 = physics.initial_state(c.theta_start, c.omega_start)
    twin = nominal_runs(physics, variability, chosen, x0)
    samples: dict[str, Any] = {}
    for k in c.constraint_samples:
        entry = checked[str(k)]
        theta_mc = bands.samples[:, k - 1, 0]
        mc_lead = float(theta_mc.mean() - entry["theta"]["observed_mean"])
        with np.errstate(over="ignore", invalid="ignore"):
            sigma = float(np.std(ocp.geometry.slider_position(theta_mc + delta), ddof=1))
            moved = ocp.geometry.slider_position(theta_mc - mc_lead + delta)
            sigma_moved = float(np.std(moved, ddof=1))
        observed = entry["observed_sigma"]
        nominal = float(twin["theta"][:, k - 1].mean())
        samples[str(k)] = {
            "plan_theta": float(chosen.theta[k - 1]),
            "twin_nominal_theta": nominal,
            "lead": float(chosen.theta[k - 1]) - nominal,
            "mc_lead": mc_lead,
            "theta_ratio": entry["theta"]["predicted"]["mixed"]["sigma"]
            / entry["theta"]["observed_sigma"],
            "slider_observed_sigma": observed,
            "slider_predicted_sigma": sigma,
            "heldout_predicted_sigma": entry["predicted"]["mixed"]["sigma"],
            "ratio": sigma / observed,
            "ratio_at_twin_mean": sigma_moved / observed,
        }
    last = max(c.constraint_samples)
    errors = velocity_error(
        model, twin, chosen.tau, last=last, half_gap=0.5 * physics.nominal_backlash_width
    )
    return {"samples": samples, "velocity_error": errors, "last_sample": last}


def main() -> None:
    parser = heldout_parser(
        __doc__.splitlines()[0],
        runs_help="held-out machines",
        trajectories_help="mixed Monte-Carlo",
    )
    parser.add_argument("--data", help="the model's training dataset, for its drift there")
    parser.add_argument("--windows", type=int, default=3000, help="dataset windows (--data)")
    parser.add_argument("--window-seed", type=int, default=0, help="draws the windows (--data)")
    args = parser.parse_args()
    torch.set_num_threads(1)
    try:
        variability = checked_line(args)
        if args.windows < 2:
            raise CrankError("--windows must be at least 2")
        model, _ = load(args.model)  # eval mode
        out = measure(
            ocp_path=args.ocp,
            model=model,
            profile=args.profile,
            runs=args.runs,
            seed=args.heldout_seed,
            trajectories=args.trajectories,
            variability=variability,
        )
        if args.data:
            out["dataset_drift"] = dataset_drift(
                model,
                args.data,
                steps=out["last_sample"],
                windows=args.windows,
                seed=args.window_seed,
            )
    except (CrankError, OSError) as exc:
        sys.exit(f"plan_lead: {exc}")
    for k, f in out["samples"].items():
        print(
            f"sample {k}: lead {1e3 * f['lead']:+5.1f} mrad (plan {f['plan_theta']:.4f}, twin's "
            f"nominal machine {f['twin_nominal_theta']:.4f}); Monte-Carlo lead "
            f"{1e3 * f['mc_lead']:+5.1f} mrad; θ σ ratio {f['theta_ratio']:.3f}; slider σ ratio "
            f"{f['ratio']:.3f}, at the twin's mean θ {f['ratio_at_twin_mean']:.3f}"
        )
    e = out["velocity_error"]
    print(
        f"one-step velocity error summed to sample {out['last_sample']}: {e['total']:+.2f} rad/s "
        f"({e['backlash_in_transit']:+.2f} over the {e['steps_in_transit']:.1f} steps the "
        f"backlash is in transit, {e['backlash_at_a_stop']:+.2f} against a stop)"
    )
    per_step = np.asarray(e["per_step"])
    starts = range(0, len(per_step), SERIES_BLOCK)
    sums = [per_step[a : a + SERIES_BLOCK].sum() for a in starts]
    ends = [min(a + SERIES_BLOCK, len(per_step)) for a in starts]
    blocks = [f"{a + 1}-{b} {v:+.2f}" for a, b, v in zip(starts, ends, sums, strict=True)]
    print(f"  by samples (rad/s): {', '.join(blocks)}")
    if "dataset_drift" in out:
        d = out["dataset_drift"]
        print(
            f"drift over {out['last_sample']} steps on its own dataset: "
            f"{1e3 * d['mean']:+.1f} ± {1e3 * d['se']:.1f} mrad (spread {1e3 * d['sd']:.0f})"
        )
    if args.out:
        settings = {k: v for k, v in vars(args).items() if k != "out"}
        write_json(
            Path(args.out),
            {
                "settings": settings,
                "starts": STARTS,
                "heldout_streams": streams.describe(args.heldout_seed, streams.HELDOUT_STREAMS),
                **out,
            },
            indent=1,
        )


if __name__ == "__main__":
    main()
