"""The lab's side of the loop (`crank verify`): runs of a profile played on a real machine,
recorded and imported (`crank import`), checked against the plan as the twin's replays are.

A rig user takes a profile out with `crank export`, plays it on the machine several times (each
run from the plan's start state), records the motor's angle and speed, the torque applied and the
slider if a sensor reads it, and imports the recording with the export's `--units`/`--flip`: one
episode per run. Each run is lined up with the plan and checked to have played the profile's law
before anything is counted; then, at each constraint sample, the runs below the height and the
slider's observed mean and σ beside what the PPANN predicted in the profile's loop.

Alignment: a run's first sample is the plan's sample 1 (`align="start"`, the recording starts
with the profile), or the sample from which its torque is nearest the law's over the samples up
to the last constraint sample (`align="torque"`, a recording with a lead-in).

Played check: the law is the one `crank export` writes (open loop u_k = tau_k; closed loop
u_k = clip(tau_k + gain_theta_k (theta_k - θ_k) + gain_omega_k (omega_k - ω_k), ±limit) on the
run's own θ_k, ω_k; replay/campaign.py tracking_law), evaluated once a sample or, for a
controller faster than the plan, as often as it does (replay/played_law.py). A run whose torque
is more than `played_tolerance` of the torque limit from it (RMS over the samples compared) is
refused, with where its torque is nearest the law: counting a run of another torque, or one
started elsewhere, would say nothing about this profile. The samples compared are the plan's
N, or the run's own if it stops sooner (an import ends each episode a sample before its last
row); it must reach the last constraint sample.

Runs on one machine are not the line's machines: their spread is that machine's run to run
(the disturbance, the warm-up), not the product line's, which the PPANN's σ in ocp.json stands
for. With the plan's PPANN the spread is split as its Monte-Carlo draws it: the white part
alone (mode step, one machine at the line's centre) and the machines alone (mode machine).
The white part is set against the runs' spread in the motor angle θ, not in the slider: near
top dead centre the slider is a flat function of θ, so one machine's slider spread there
depends on where that machine sits (a machine 1.3 machine σ high showed 2.0 mm where the line's
centre predicts 3.0), while its θ spread does not (the same runs: 150 against 140 mrad). The
machines' part is the scale on which the runs' mean slider says where their machine sits.

`verify.json` keys (stable; format "crank-verify", version 1):

  ocp                {path, sha256, profile, loop, height, constraint_samples (1-based),
                     k_sigma (the profile's own: its tail's check may have raised it), premium,
                     dt, horizon, torque_limit}
  data               {path, sha256, source, input, slider: measured or derived (x(θ) of the
                     motor angle: rigid and backlash-free, blind to what the constraint is about
                     beyond θ), episodes}
  model              {path, sha256} of the PPANN that split the spread (the plan's own), or
                     null
  split_trajectories trajectories of each part's σ
  align, played_tolerance, bootstrap_seed, target_rate
  control_rate_hz    the rate the law was evaluated at (the plan's, or --control-rate)
  runs               per run {episode, offset (its sample lined up with sample 1), start_s,
                     samples (compared), played_rms (N·m), theta_rms (rad, from the plan's θ),
                     slider {k: m}, below (under the height at any constraint sample),
                     machine (its machine's label where the runs name several; else null)}
  samples.<k>        {height, below, lowest, observed_mean, observed_sigma (ddof 1),
                     observed_sigma_ci95 (bootstrap over the runs, replay/spread_interval.py),
                     predicted_mean, predicted_sigma (the PPANN's Monte-Carlo in the
                     profile's loop), ratio (predicted / observed σ), ratio_ci95,
                     mean_offset_sigma ((observed − predicted mean) / predicted σ),
                     white_sigma, machine_sigma (the PPANN's σ from its white part alone, a
                     machine at the line's centre: one machine's run-to-run spread; and from
                     its machines alone: the line's machine-to-machine spread; null without
                     the PPANN), machine_offset ((observed − predicted mean) / machine σ:
                     where the runs' machine sits in the line, if they are one machine's),
                     theta {observed_sigma, observed_sigma_ci95, white_sigma, white_ratio,
                     white_ratio_ci95}: the motor angle's spread over the runs against the
                     white part's (white σ / observed σ: the runs read as one machine's)};
                     σ and its ratios null with one run, the split's without the PPANN
  machines           runs named to several machines (replay/verify_machines.py): {count,
                     labels, runs (per machine), samples.<k> {within_sigma (θ about each
                     machine's mean, pooled), white_sigma, white_ratio, between_sigma (the
                     machines' own θ spread), machine_sigma, machine_ratio, each σ and ratio
                     with its _ci95}}; null unless the runs name two or more machines
  violating_runs, rate, rate_upper_95 (exact one-sided, replay/rates.py)
  verdict            holds | unconfirmed | fails against target_rate for a robust profile
                     (replay/rates.py); null for the nominal one, which claims nothing
  created            ISO time of writing
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from common.errors import CrankError
from common.jsonio import recorded_path
from control.config import TARGET_RATE
from control.ocp_file import OCPFile, Profile
from replay.played_law import PlayedLaw
from replay.rates import rate_upper, verdict
from replay.spread_interval import CALIBRATION_TRAJECTORIES, ratio_interval, sigma_interval
from replay.verify_machines import machines_section, run_machines
from twin.dataset import Dataset, check_step

FORMAT = "crank-verify"
VERSION = 1
PLAYED_TOLERANCE = 0.05
"""The largest RMS of a run's torque from the law it is checked against, as a share of the
torque limit (0.5 N·m of the paper's 10): a run beyond it played something else."""
ALIGNS = ("start", "torque")
BOOTSTRAP_SEED = 0
"""The stream of the observed σ's bootstrap interval: the same runs give the same interval."""


class VerifyError(CrankError, ValueError):
    """Recorded runs that cannot be checked against the plan; the message names the run."""


@dataclass(frozen=True)
class RigRuns:
    """The runs lined up with the plan; arrays (runs, n), n the samples compared."""

    episodes: np.ndarray
    offsets: np.ndarray
    start_s: np.ndarray
    theta: np.ndarray
    omega: np.ndarray
    tau: np.ndarray
    slider: np.ndarray


def line_up(
    dataset: Dataset,
    ocp: OCPFile,
    *,
    profile: str,
    align: str,
    played_tolerance: float,
    per_sample: int = 1,
) -> RigRuns:
    """Each episode of `dataset` lined up with the plan of `profile` and checked to have played
    its law, evaluated `per_sample` times a sample (module docstring; replay/played_law.py).

    Raises:
      VerifyError: a run too short for the last constraint sample, or one that did not play the
        law (naming it, where its torque is nearest the law, and whether the law evaluated
        faster matches it).
    """
    plan, limit = ocp.profiles[profile], ocp.config.torque_limit
    law = PlayedLaw(plan, limit=limit, per_sample=per_sample)
    last, horizon = max(ocp.config.constraint_samples), ocp.horizon
    tolerance = played_tolerance * limit
    hz = per_sample / ocp.dt
    loop = f"the {plan.loop} loop's law" + (f" at {hz:g} Hz" if plan.loop == "closed" else "")
    rows: dict[str, list[Any]] = {k: [] for k in ("episodes", "offsets", "start_s")}
    series: dict[str, list[np.ndarray]] = {k: [] for k in ("theta", "omega", "tau", "slider")}
    for number, episode in enumerate(np.unique(dataset.episode), start=1):
        at = np.flatnonzero(dataset.episode == episode)
        theta, omega, tau = dataset.theta[at], dataset.omega[at], dataset.tau[at]
        name = f"run {number} (episode {episode})"
        if len(at) < last:
            raise VerifyError(
                f"{name} has {len(at)} samples; the constraint's last is sample {last} "
                f"({(last - 1) * ocp.dt:.3g} s in): record each run for the whole profile"
            )
        # where the run is nearest the law: searched only to line it up, or to say in a refusal
        nearest = law.nearest(theta, omega, tau, window=last) if align == "torque" else None
        offset = 0 if nearest is None else nearest[0]
        n = min(horizon, len(at) - offset)
        window = [x[offset : offset + n] for x in (theta, omega, tau)]
        rms = float(law.rms(*window))
        if rms > tolerance:
            found, found_rms = nearest or law.nearest(theta, omega, tau, window=last)
            where = (
                f"it is nearest from its sample {found + 1} (t = {found * ocp.dt:.4g} s, "
                f"{found_rms:.3g} N·m): --align torque, or trim the recording there"
                if align == "start" and found_rms <= tolerance
                else f"its nearest stretch, from its sample {found + 1}, is {found_rms:.3g} N·m "
                f"from it up to sample {last}: was it this profile?"
            )
            if law.faster_match(*window, tolerance=tolerance):
                where = (
                    f"it is within the tolerance of the law evaluated faster than {hz:g} Hz: "
                    "give the controller's rate with --control-rate"
                )
            raise VerifyError(
                f"{name} did not play profile {profile}: its torque is {rms:.3g} N·m RMS from "
                f"{loop} over {n} samples, above --played-tolerance {played_tolerance:g} of the "
                f"{limit:g} N·m limit; {where}"
            )
        rows["episodes"].append(int(episode))
        rows["offsets"].append(offset)
        rows["start_s"].append(float(dataset.t[at[offset]] - dataset.t[at[0]]))
        for key, values in (("theta", theta), ("omega", omega), ("tau", tau)):
            series[key].append(values[offset : offset + n])
        series["slider"].append(dataset.slider_position[at][offset : offset + n])
    n = min(len(s) for s in series["theta"])  # the shortest run's: every run compared alike
    return RigRuns(
        **{k: np.asarray(v) for k, v in rows.items()},
        **{k: np.stack([s[:n] for s in v]) for k, v in series.items()},
    )


def check_data(dataset: Dataset, ocp: OCPFile, *, source: str) -> None:
    """Refuse data of another mechanism or rate than the plan's.

    Raises:
      GeometryError: another mechanism. ConfigError: another rate (import with --rate).
    """
    ocp.geometry.check_same(dataset.geometry, this="the plan", that=source)
    if len(dataset) < 2:
        raise VerifyError(f"{source}: {len(dataset)} sample(s); nothing to check")
    check_step(dataset, step=ocp.dt, stepper="the plan steps", source=source)


def _sample(
    ocp: OCPFile,
    plan: Profile,
    at: np.ndarray,
    theta: np.ndarray,
    sample: int,
    split: dict[str, float] | None,
) -> dict[str, Any]:
    """What the runs' slider `at` constraint sample `sample` shows beside the prediction, and
    (with its parts, `split`) their motor angle `theta` there beside the white part's."""
    height = ocp.config.height
    predicted_mean = float(plan.slider_mc_mean[sample - 1])
    predicted = float(plan.sigma_in(plan.loop)[sample - 1])
    out: dict[str, Any] = {
        "height": height,
        "below": int(np.count_nonzero(at < height)),
        "lowest": float(at.min()),
        "observed_mean": float(at.mean()),
        "observed_sigma": None,
        "observed_sigma_ci95": None,
        "predicted_mean": predicted_mean,
        "predicted_sigma": predicted,
        "ratio": None,
        "ratio_ci95": None,
        "mean_offset_sigma": (float(at.mean()) - predicted_mean) / predicted if predicted else None,
        "white_sigma": None if split is None else split["white"],
        "machine_sigma": None if split is None else split["machine"],
        "machine_offset": None,
        "theta": _theta(theta, split),
    }
    if split is not None and split["machine"] > 0:
        out["machine_offset"] = (float(at.mean()) - predicted_mean) / split["machine"]
    out |= _observed(at, predicted)
    return out


def _theta(theta: np.ndarray, split: dict[str, float] | None) -> dict[str, Any]:
    """The runs' θ spread at one sample beside the PPANN's white part's (None without it)."""
    white = None if split is None else split["theta_white"]
    spread = _observed(theta, white)
    return {
        "observed_sigma": spread["observed_sigma"],
        "observed_sigma_ci95": spread["observed_sigma_ci95"],
        "white_sigma": white,
        "white_ratio": spread["ratio"],
        "white_ratio_ci95": spread["ratio_ci95"],
    }


def _observed(values: np.ndarray, predicted: float | None) -> dict[str, Any]:
    """The runs' σ of `values` (ddof 1) with its bootstrap interval, and `predicted` over it
    with the ratio's interval; None where one run, or no prediction, leaves one undefined."""
    out: dict[str, Any] = dict.fromkeys(
        ("observed_sigma", "observed_sigma_ci95", "ratio", "ratio_ci95")
    )
    if len(values) < 2:
        return out
    observed = float(values.std(ddof=1))
    interval = sigma_interval(values, rng=np.random.default_rng(BOOTSTRAP_SEED))
    out["observed_sigma"], out["observed_sigma_ci95"] = observed, list(interval)
    if predicted is not None and observed > 0:
        out["ratio"] = predicted / observed
        out["ratio_ci95"] = ratio_interval(predicted, observed, interval)
    return out


def verify_statistics(
    ocp: OCPFile,
    runs: RigRuns,
    *,
    profile: str,
    ocp_path: Path,
    data_path: Path,
    dataset: Dataset,
    align: str,
    played_tolerance: float,
    per_sample: int = 1,
    out: Path,
    model_path: Path | None = None,
    split: dict[int, dict[str, float]] | None = None,
) -> dict[str, Any]:
    """verify.json's content (keys in the module docstring) for the file at `out` (paths are
    recorded relative to its folder where they lie in it); `split`: spread_split's, by the
    PPANN at `model_path`."""
    c, plan = ocp.config, ocp.profiles[profile]
    limit, n = c.torque_limit, runs.theta.shape[1]
    played = PlayedLaw(plan, limit=limit, per_sample=per_sample).rms(
        runs.theta, runs.omega, runs.tau
    )
    theta_rms = np.sqrt(np.mean((runs.theta - plan.theta[:n]) ** 2, axis=1))
    at = {k: runs.slider[:, k - 1] for k in c.constraint_samples}
    below = np.zeros(len(runs.episodes), dtype=bool)
    for values in at.values():
        below |= values < c.height
    count, total = int(np.count_nonzero(below)), len(below)
    derived = "slider_position" in dataset.run.get("derived", [])
    labels = run_machines(dataset, runs.episodes)
    machines = None
    if labels is not None:
        theta_at = {k: runs.theta[:, k - 1] for k in c.constraint_samples}
        machines = machines_section(theta_at, labels, split, seed=BOOTSTRAP_SEED)
    return {
        "format": FORMAT,
        "version": VERSION,
        "ocp": {
            "path": recorded_path(ocp_path, artifact=out),
            "sha256": hashlib.sha256(ocp_path.read_bytes()).hexdigest(),
            "profile": profile,
            "loop": plan.loop,
            "height": c.height,
            "constraint_samples": list(c.constraint_samples),
            "k_sigma": ocp.raw.get(profile, {}).get("k_sigma", c.k_sigma),
            "premium": ocp.premium(profile) if profile != "nominal" else 0.0,
            "dt": ocp.dt,
            "horizon": ocp.horizon,
            "torque_limit": limit,
        },
        "data": {
            "path": recorded_path(data_path, artifact=out),
            "sha256": hashlib.sha256(data_path.read_bytes()).hexdigest(),
            "source": dataset.run.get("source"),
            "input": dataset.run.get("input"),
            "slider": "derived" if derived else "measured",
            "episodes": total,
        },
        "model": None
        if model_path is None
        else {
            "path": recorded_path(model_path, artifact=out),
            "sha256": hashlib.sha256(model_path.read_bytes()).hexdigest(),
        },
        "split_trajectories": None if split is None else CALIBRATION_TRAJECTORIES,
        "align": align,
        "played_tolerance": played_tolerance,
        "control_rate_hz": per_sample / ocp.dt,
        "bootstrap_seed": BOOTSTRAP_SEED,
        "target_rate": TARGET_RATE,
        "runs": [
            {
                "episode": int(runs.episodes[r]),
                "offset": int(runs.offsets[r]),
                "start_s": float(runs.start_s[r]),
                "samples": n,
                "played_rms": float(played[r]),
                "theta_rms": float(theta_rms[r]),
                "slider": {str(k): float(v[r]) for k, v in at.items()},
                "below": bool(below[r]),
                "machine": None if labels is None else labels[r],
            }
            for r in range(total)
        ],
        "samples": {
            str(k): _sample(
                ocp, plan, v, runs.theta[:, k - 1], k, None if split is None else split[k]
            )
            for k, v in at.items()
        },
        "machines": machines,
        "violating_runs": count,
        "rate": count / total,
        "rate_upper_95": rate_upper(count, total),
        "verdict": None if profile == "nominal" else verdict(count, total),
        "created": datetime.now(UTC).isoformat(timespec="seconds"),
    }
