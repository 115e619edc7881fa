"""What a campaign showed: violations, spread against the PPANN's prediction, tracking, effort.

`<campaign>.stats.json` keys (stable; `version` changes if any meaning does):

  format, version         "crank-replay-stats", 3 (2: premiums and claims per robust profile,
                          in place of robust_cost_premium; 3: predicted_k_sigma under the law
                          played, or null)
  ocp                     {path, height, constraint_samples (1-based), k_sigma, premiums}:
                          premiums {profile: its cost over the nominal's, minus 1} per robust
                          profile
  config                  the resolved ReplayConfig (runs, seed, modes, gains, variability)
  claim                   {nominal_open_violating_runs, robust_open_violating_runs, holds}: the
                          paper's claim, robust open loop 0 runs below the height at any
                          constraint sample and nominal open loop at least 10 of 100 (holds
                          null without the robust profile or the open mode)
  claims                  {profile: {loop, violating_runs, runs, holds}} per robust profile
                          played in the loop it was tightened for: 0 runs below the height
  profiles.<nominal|robust|robust-fb>.<open|closed|mpc>:
    runs                  runs played
    violations            {sample: runs whose measured slider < height at that sample}
    violating_runs        runs below the height at any constraint sample
    constraint            {sample: {height, lowest, mean, observed_k_sigma, predicted_k_sigma,
                          clearance}}: slider at the constraint samples, m; observed k·σ over the
                          runs beside the PPANN's Monte-Carlo k·σ under the law played (open, the
                          closed loop's gains, the MPC's LQR; replay/laws.py), null where that
                          law is not the profile's own and the replay had no PPANN to predict
                          it with; clearance = lowest − height
    final_error           {theta, omega}: each {mean, std, max_abs} of the measured state minus
                          the OCP's θ_N, ω_N at sample N
    effort                {applied_mean, applied_std, planned}: Σ u_k² over the N samples
    tracking              {theta_rms, omega_rms}: RMS over runs and samples of the measured
                          state minus the plan's, rad and rad/s; saturated_share: the share of
                          samples whose applied torque sits at the torque limit
    mpc                   (mpc mode) {horizon, engine, deadline_ms, steps, median_ms, p99_ms,
                          max_ms, deadline_misses, qp_iterations_max}: compute time of one
                          machine's MPC step (engine: compiled or vm, control/mpc.py)
    slider                {mean, lower, upper}: per-sample mean and mean ∓ k·σ over the runs, m
  timing                  {simulate_s, log_s, rerun_s, total_s}: seconds simulating, writing
                          the MCAP, writing the .rrd, and in all (figures included)
  created                 ISO time of writing
"""

from __future__ import annotations

from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from common.jsonio import write_json
from control.ocp_file import OCPFile
from replay.campaign import Campaign, Replay
from replay.config import ReplayConfig
from replay.laws import plays_own_law

FORMAT = "crank-replay-stats"
VERSION = 3
CLAIM_NOMINAL_MIN = 10
"""The nominal profile must break the constraint on at least this many of 100 open-loop runs."""


def _spread(values: np.ndarray) -> dict[str, float]:
    return {
        "mean": float(values.mean()),
        "std": float(values.std(ddof=1)) if len(values) > 1 else 0.0,
        "max_abs": float(np.abs(values).max()),
    }


def mpc_timing(replay: Replay) -> dict[str, Any] | None:
    """The MPC steps' compute times (stats key `mpc`), or None outside the mpc mode."""
    record = replay.mpc
    if record is None:
        return None
    ms = 1e3 * record.seconds[np.isfinite(record.seconds)]
    return {
        "horizon": record.horizon,
        "engine": record.engine,
        "deadline_ms": 1e3 * record.deadline,
        "steps": int(ms.size),
        "median_ms": float(np.median(ms)),
        "p99_ms": float(np.percentile(ms, 99)),
        "max_ms": float(ms.max()),
        "deadline_misses": int(record.missed.sum()),
        "qp_iterations_max": int(record.qp_iterations.max()),
    }


def replay_statistics(replay: Replay, ocp: OCPFile) -> dict[str, Any]:
    """The statistics of one profile in one mode (keys as in the module docstring)."""
    c = ocp.config
    planned = ocp.profiles[replay.profile]
    predicted = replay.predicted_sigma
    slider = replay.slider_position
    k = c.k_sigma
    ddof = 1 if replay.runs > 1 else 0
    mean, sigma = slider.mean(axis=0), slider.std(axis=0, ddof=ddof)
    constraint, violations = {}, {}
    below = np.zeros(replay.runs, dtype=bool)
    for sample in c.constraint_samples:
        at = slider[:, sample - 1]
        below |= at < c.height
        violations[str(sample)] = int(np.count_nonzero(at < c.height))
        constraint[str(sample)] = {
            "height": c.height,
            "lowest": float(at.min()),
            "mean": float(at.mean()),
            "observed_k_sigma": float(k * sigma[sample - 1]),
            "predicted_k_sigma": None if predicted is None else float(k * predicted[sample - 1]),
            "clearance": float(at.min() - c.height),
        }
    effort = np.sum(replay.tau**2, axis=1)
    limit = c.torque_limit
    extra = {} if replay.mpc is None else {"mpc": mpc_timing(replay)}
    return {
        "runs": replay.runs,
        "violations": violations,
        "violating_runs": int(np.count_nonzero(below)),
        "constraint": constraint,
        "final_error": {
            "theta": _spread(replay.theta[:, -1] - c.theta_end),
            "omega": _spread(replay.omega[:, -1] - c.omega_end),
        },
        "effort": {
            "applied_mean": float(effort.mean()),
            "applied_std": float(effort.std(ddof=ddof)),
            "planned": float(np.sum(planned.tau**2)),
        },
        "tracking": {
            "theta_rms": float(np.sqrt(np.mean((replay.theta - planned.theta) ** 2))),
            "omega_rms": float(np.sqrt(np.mean((replay.omega - planned.omega) ** 2))),
            "saturated_share": float(np.mean(np.abs(replay.tau) >= limit - 1e-9)),
        },
        **extra,
        "slider": {
            "mean": mean.tolist(),
            "lower": (mean - k * sigma).tolist(),
            "upper": (mean + k * sigma).tolist(),
        },
    }


def campaign_statistics(
    campaign: Campaign,
    ocp: OCPFile,
    *,
    ocp_path: str | Path,
    timing: dict[str, float],
) -> dict[str, Any]:
    """Every profile and mode, the claim, and what produced them."""
    c = ocp.config
    profiles: dict[str, dict[str, Any]] = {p: {} for p in ocp.names}
    for (profile, mode), replay in campaign.replays.items():
        profiles[profile][mode] = replay_statistics(replay, ocp)
    claim: dict[str, Any] = {"holds": None}
    if "open" in campaign.config.modes and "robust" in ocp.names:
        nominal = profiles["nominal"]["open"]["violating_runs"]
        robust = profiles["robust"]["open"]["violating_runs"]
        needed = int(np.ceil(CLAIM_NOMINAL_MIN * campaign.config.runs / 100))
        claim = {
            "nominal_open_violating_runs": nominal,
            "robust_open_violating_runs": robust,
            "nominal_needed": needed,
            "holds": robust == 0 and nominal >= needed,
        }
    return {
        "format": FORMAT,
        "version": VERSION,
        "ocp": {
            "path": str(ocp_path),
            "height": c.height,
            "constraint_samples": list(c.constraint_samples),
            "k_sigma": c.k_sigma,
            "premiums": {name: ocp.premium(name) for name in ocp.robust_names},
        },
        "config": campaign.config.as_dict(),
        "claim": claim,
        "claims": _claims(profiles, ocp, config=campaign.config),
        "profiles": profiles,
        "timing": timing,
        "created": datetime.now(UTC).isoformat(timespec="seconds"),
    }


def _claims(
    profiles: dict[str, dict[str, Any]], ocp: OCPFile, *, config: ReplayConfig
) -> dict[str, Any]:
    """Each robust profile in the loop it was tightened for, if that loop was played (closed:
    under the gains its tube was sized with, replay/laws.py plays_own_law)."""
    claims = {}
    for name in ocp.robust_names:
        loop = ocp.profiles[name].loop
        played = profiles[name].get(loop)
        if played is None or (loop == "closed" and not plays_own_law(ocp.profiles[name], config)):
            continue
        claims[name] = {
            "loop": loop,
            "violating_runs": played["violating_runs"],
            "runs": played["runs"],
            "holds": played["violating_runs"] == 0,
        }
    return claims


def write_statistics(path: str | Path, stats: dict[str, Any]) -> None:
    write_json(path, stats)


def summary_rows(stats: dict[str, Any]) -> list[dict[str, str]]:
    """One row per profile and mode, for the terminal table and report.md."""
    rows = []
    samples = stats["ocp"]["constraint_samples"]
    k = f"{stats['ocp']['k_sigma']:g}σ"
    for profile, modes in stats["profiles"].items():
        for mode, s in modes.items():
            row = {"profile": profile, "mode": mode}
            for n in samples:
                c = s["constraint"][str(n)]
                row[f"below@{n}"] = f"{s['violations'][str(n)]}/{s['runs']}"
                row[f"lowest@{n} mm"] = f"{1e3 * c['lowest']:.1f}"
                predicted = c["predicted_k_sigma"]
                shown = "—" if predicted is None else f"{1e3 * predicted:.1f}"
                row[f"{k}@{n} obs/pred mm"] = f"{1e3 * c['observed_k_sigma']:.1f}/{shown}"
            theta = s["final_error"]["theta"]
            row["θ_N err rad"] = f"{theta['mean']:+.3f}±{theta['std']:.3f}"
            row["Σu² (plan)"] = f"{s['effort']['applied_mean']:.0f} ({s['effort']['planned']:.0f})"
            if any("mpc" in m for m in stats["profiles"].values()):
                step = s.get("mpc")
                row["MPC step ms med/p99 (misses)"] = (
                    f"{step['median_ms']:.2f}/{step['p99_ms']:.2f} ({step['deadline_misses']})"
                    if step
                    else ""
                )
            rows.append(row)
    return rows


def format_table(rows: list[dict[str, str]], *, markdown: bool = False) -> str:
    """The rows as an aligned text table, or a Markdown one."""
    if not rows:
        return ""
    keys = list(rows[0])
    if markdown:
        lines = ["| " + " | ".join(keys) + " |", "|" + " --- |" * len(keys)]
        lines += ["| " + " | ".join(r[k] for k in keys) + " |" for r in rows]
        return "\n".join(lines)
    widths = {k: max(len(k), *(len(r[k]) for r in rows)) for k in keys}
    lines = ["  ".join(k.ljust(widths[k]) for k in keys)]
    lines += ["  ".join(r[k].ljust(widths[k]) for k in keys) for r in rows]
    return "\n".join(lines)
