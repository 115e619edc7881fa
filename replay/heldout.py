"""The held-out check: every torque of an ocp.json, open loop, closed loop or under the MPC, on
many machines drawn from streams no other stage uses (heldout_machines, heldout_noise), and the
PPANN's calibration there. Closed loop, each machine runs under the profile's own gains (its
LQR; robust-pd's fixed PD; replay/campaign.py) or the replay's fixed PD, and the PPANN's
prediction is its closed-loop Monte-Carlo under the same law and saturation. Predicted
slider positions include the model's transmission error (ppann/transmission.py), as the
tightening does.

100 campaign replays cannot tell 0.1 % from 2 % (P(0 of 100 | 2 %) = 13 %); this check plays each
profile on `runs` machines: the violation rate with its exact 95 % upper bound (a second stage
where those cannot decide: replay/heldout_stages.py). Beside it, calibration under the OCP's own
torque: the slider's observed σ, k·σ and one-sided quantile at each constraint sample against
the PPANN's prediction in every Monte-Carlo mode (same torque, same start state), and the same
for θ at each constraint sample and at the last one. Near top dead centre the slider is a flat
function of θ, so its σ there magnifies an error in θ's: θ's ratio says which is wrong.

`heldout.json` keys (stable):

  format, version        "crank-heldout", 8 (3: samples.<k>.theta; 4: model_rate; 5: the
                         intervals; 6: 10 000 trajectories, sigma_se, ratio_ci95 with both;
                         7: violating_placements; 8: staged)
  runs, seed, streams    machines per profile and mode, root seed, and the stream tree
  modes                  the loops every profile was played in: open, closed, mpc
  feedback               closed loop: lqr (each profile's own gains) or pd (the fixed PD)
  pd                     {kp, kd}: the fixed PD of feedback pd
  variability, max_start_time
  mc_samples             trajectories of each predicted σ (CALIBRATION_TRAJECTORIES, 10 000;
                         1000 before version 6)
  tail_draws             trajectories of each model_rate
  target_rate            0.005: a robust profile's allowed violation rate
  profiles.<nominal|robust|robust-fb|robust-pd>.<mode>:
    mpc                  (mpc mode) the MPC steps' compute times, as in replay.stats.json
    violating_runs, rate, rate_upper_95
    violating_machines   the machines below the height at any constraint sample, by their
                         index in the held-out draw (replay/campaign.py draw_machines), or
                         null beyond LISTED_MACHINES of them (since session 31)
    violating_placements each listed machine's place in the line (replay/placement.py; 7)
    samples.<k>          {height, violations, lowest, mean, plan, observed_sigma,
                          observed_sigma_ci95 (its 95 % bootstrap interval over the machines,
                          replay/spread_interval.py), observed_quantile (at Φ(-k_sigma)), skew,
                          predicted.<mode> {sigma, sigma_se (the Monte-Carlo's standard
                                            error of sigma), mean,
                                            ratio (predicted / observed σ),
                                            ratio_ci95 (the machines' interval widened by
                                            sigma_se, replay/spread_interval.py)},
                          theta {observed_sigma, observed_mean,
                                 predicted.<mode> {sigma, mean, ratio}}}
    theta_final          as samples.<k>.theta, at the last sample
    model_rate           {mode, draws, rate, samples.<k>}: the share of the PPANN's own
                         Monte-Carlo (the OCP's mode, `tail_draws` trajectories, same loop) below
                         the height, at any constraint sample and at each: what the model
                         predicts `rate` to be. A robust tightening of k sigma stands for
                         Φ(−k) (0.135 % at k = 3) at each sample; near top dead centre the
                         slider's spread is skewed and k sigma of it can stand for much more
  holds                  {profile: rate <= target_rate} per robust profile, in the loop it was
                         tightened for (open, or closed under its tube's gains), if played
  verdicts               {profile: holds | unconfirmed | fails} for the same (replay/rates.py;
                         unconfirmed: the rate within the target, its 95 % bound not)
  staged                 with a second stage (replay/heldout_stages.py), which then decides
                         holds and verdicts on all the machines played
  timing                 {simulate_s, monte_carlo_s}
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats as scistats

from common import streams
from common.atomic import check_writable, writes
from common.checks import check_count
from common.jsonio import recorded_path, write_json
from control.config import PD_GAINS, loops_of, lower_tail
from control.mpc_config import MPCConfig, check_fits
from control.ocp_file import OCPFile, read_ocp
from control.tightening import sigma_relative_se
from ppann.checkpoint import CheckpointError, load
from ppann.heads import FusedHeads
from ppann.model import PPANN
from ppann.montecarlo import Bands, Feedback
from replay.campaign import draw_machines, play
from replay.config import ReplayConfig, check_campaign_memory
from replay.heldout_stages import check_extension, extend, settle
from replay.laws import played_gains, plays_own_law, predicted_bands
from replay.model_rate import model_rate
from replay.placement import placements
from replay.rates import TARGET_RATE, rate_upper, verdict
from replay.spread_interval import CALIBRATION_TRAJECTORIES, ratio_interval, sigma_interval
from replay.statistics import mpc_timing
from twin import OPERATING_SECONDS
from twin.physics import MODEL_PATH, SliderCrank, load_model
from twin.variability import Variability

FORMAT = "crank-heldout"
VERSION = 8
LISTED_MACHINES = 50
"""A profile's machines below the height listed by index up to this many (beyond: counted)."""
MACHINES_PER_BATCH = 1000
"""Machines played at a time, open and closed loop (the same result as one batch): `crank
heldout`'s progress moves after each, so a long check (10 000 machines: ~2 min a profile on 2
cores) says where it stands."""
TAIL_DRAWS = 20_000
"""Trajectories of the model's own violation rate (`model_rate`): 27 expected below at 0.135 %,
a relative standard error of 19 %; ~1 s for 150 steps."""


def check_trajectories(name: str, value: object) -> None:
    """Refuse a Monte-Carlo size for the check's predictions outside [100, 1 000 000] (fewer
    cannot estimate a σ to a useful interval; more do not fit in memory beside the replays)."""
    check_count(name, value, low=100, high=1_000_000)


def _ratio(predicted: float, observed: float) -> float | None:
    return predicted / observed if observed > 0 and math.isfinite(predicted) else None


def _theta_calibration(
    observed: np.ndarray, predicted: dict[str, Bands], index: int
) -> dict[str, Any]:
    """θ's observed mean and σ over the machines at one sample and each mode's predicted mean
    and σ there."""
    sigma = float(observed.std(ddof=1))
    return {
        "observed_sigma": sigma,
        "observed_mean": float(observed.mean()),
        "predicted": {
            mode: {
                "sigma": float(b.std[index, 0]),
                "mean": float(b.mean[index, 0]),
                "ratio": _ratio(float(b.std[index, 0]), sigma),
            }
            for mode, b in predicted.items()
        },
    }


def heldout_check(
    physics: SliderCrank,
    ocp_path: str | Path,
    model: PPANN,
    *,
    runs: int,
    seed: int,
    variability: Variability,
    max_start_time: float = OPERATING_SECONDS,
    mc_samples: int = CALIBRATION_TRAJECTORIES,
    tail_draws: int = TAIL_DRAWS,
    modes: tuple[str, ...] = ("open",),
    mpc: MPCConfig | None = None,
    feedback: str = "lqr",
    kp: float = PD_GAINS[0],
    kd: float = PD_GAINS[1],
    on_played: Callable[[str, str, dict[str, Any]], None] | None = None,
    batch: int = MACHINES_PER_BATCH,
    on_machines: Callable[[str, str, int], None] | None = None,
    on_start: Callable[[OCPFile, tuple[str, ...]], None] | None = None,
    extend_to: int = 0,
    on_extend: Callable[[str, str, int], None] | None = None,
) -> dict[str, Any]:
    """Play every profile in each of `modes` on the same `runs` held-out machines; return
    heldout.json's content. Closed loop is each profile's own law (its gains in ocp.json), or
    with `feedback` "pd" the fixed PD `kp`, `kd`, and the prediction is the closed-loop
    Monte-Carlo under that law. In mpc mode each machine runs the online MPC on `model`
    (settings `mpc`), and the prediction beside it is the closed loop's under the LQR the MPC
    is while no bound is active (its weights' gains along the plan, whatever law the profile
    was tightened for). `on_played(profile, mode, entry)` sees each entry as soon as it is
    done (progress: the MPC on 1000 machines takes about a minute a profile), `on_machines(
    profile, mode, machines just played)` after each `batch` of them open or closed loop (the
    same result as one batch, bit for bit), and `on_start(ocp file, modes)` once every input has
    been checked, before the first play.
    With `extend_to` > `runs`, a robust profile the first `runs` machines cannot judge is
    judged in two stages (replay/heldout_stages.py; `on_extend(profile, loop, machines)`).

    Raises:
      GeometryError: the plan, the model and the twin are not all of one mechanism.
    """
    ocp = read_ocp(ocp_path)
    ocp.geometry.check_same(physics.geometry, this=str(ocp_path), that="the twin")
    ocp.geometry.check_same(model.geometry, this=str(ocp_path), that="the model")
    config = ReplayConfig(
        runs=runs,
        seed=seed,
        modes=modes,
        variability=variability,
        max_start_time=max_start_time,
        mpc=mpc if mpc is not None else MPCConfig(),
        feedback=feedback,
        kp=kp,
        kd=kd,
    )
    machines = draw_machines(config, ocp.horizon, held_out=True)
    if on_start is not None:
        on_start(ocp, modes)
    heads = FusedHeads(model)
    c = ocp.config
    level = lower_tail(c.k_sigma)
    bootstrap = streams.rng(seed, "heldout_bootstrap")
    out: dict[str, Any] = {
        "format": FORMAT,
        "version": VERSION,
        "ocp": str(ocp_path),
        "runs": runs,
        "seed": seed,
        "modes": list(modes),
        "feedback": feedback,
        "pd": {"kp": kp, "kd": kd},
        "streams": streams.describe(seed, streams.HELDOUT_STREAMS),
        "variability": variability.as_dict(),
        "max_start_time": max_start_time,
        "mc_samples": mc_samples,
        "tail_draws": tail_draws,
        "target_rate": TARGET_RATE,
        "profiles": {name: {} for name in ocp.names},
    }
    simulate_s = mc_s = 0.0
    for profile, mode in ((p, m) for p in ocp.names for m in modes):
        t0 = time.perf_counter()
        replay = play(
            physics,
            ocp,
            profile=profile,
            mode=mode,
            machines=machines,
            config=config,
            model=model,
            batch=batch,
            on_machines=None
            if on_machines is None
            else lambda played, p=profile, m=mode: on_machines(p, m, played),
        )
        simulate_s += time.perf_counter() - t0
        planned = ocp.profiles[profile]
        mpc_gains = None if replay.mpc is None else replay.mpc.gains
        gains = played_gains(planned, mode, config, mpc_gains=mpc_gains)
        law = None
        if gains is not None:  # closed loop, or the LQR the MPC is
            states = np.stack([planned.theta, planned.omega], axis=-1)
            law = Feedback(states, gains, c.torque_limit)
        t0 = time.perf_counter()
        predicted, delta = predicted_bands(heads, ocp, planned, law=law, n_samples=mc_samples)
        mc_s += time.perf_counter() - t0
        below = np.zeros(runs, dtype=bool)
        samples: dict[str, Any] = {}
        for k in c.constraint_samples:
            x = replay.slider_position[:, k - 1]
            violated = x < c.height
            below |= violated
            observed = float(x.std(ddof=1))
            interval = sigma_interval(x, rng=bootstrap)
            entry: dict[str, Any] = {
                "height": c.height,
                "violations": int(violated.sum()),
                "lowest": float(x.min()),
                "mean": float(x.mean()),
                "plan": float(planned.slider[k - 1]),
                "observed_sigma": observed,
                "observed_sigma_ci95": list(interval),
                "observed_quantile": float(np.quantile(x, level)),
                "skew": float(scistats.skew(x)),
                "predicted": {},
            }
            for mc_mode, bands in predicted.items():
                with np.errstate(over="ignore", invalid="ignore"):
                    slider = ocp.geometry.slider_position(bands.samples[:, k - 1, 0] + delta)
                    sigma = float(np.std(slider, ddof=1))
                    own = sigma_relative_se(slider)
                entry["predicted"][mc_mode] = {
                    "sigma": sigma,
                    "sigma_se": sigma * own if math.isfinite(sigma * own) else None,
                    "mean": float(np.mean(slider)),
                    "ratio": _ratio(sigma, observed),
                    "ratio_ci95": ratio_interval(
                        sigma, observed, interval, predicted_relative_se=own
                    ),
                }
            entry["theta"] = _theta_calibration(replay.theta[:, k - 1], predicted, k - 1)
            samples[str(k)] = entry
        violating = int(below.sum())
        listed = np.flatnonzero(below).tolist() if violating <= LISTED_MACHINES else None
        t0 = time.perf_counter()
        tail = model_rate(heads, planned, c, n_samples=tail_draws, law=law)
        mc_s += time.perf_counter() - t0
        out["profiles"][profile][mode] = {
            **({} if replay.mpc is None else {"mpc": mpc_timing(replay)}),
            "violating_runs": violating,
            # which held-out machines (their index in draw_machines' order: a replay can
            # play them again), where few enough to list
            "violating_machines": listed,
            "violating_placements": placements(
                machines,
                listed,
                variability,
                until=max(c.constraint_samples),
                max_start_s=max_start_time,
            ),
            "rate": violating / runs,
            "rate_upper_95": rate_upper(violating, runs),
            "samples": samples,
            "theta_final": _theta_calibration(replay.theta[:, -1], predicted, -1),
            "model_rate": tail,
        }
        if on_played is not None:
            on_played(profile, mode, out["profiles"][profile][mode])
    judged = {
        name: out["profiles"][name][loop]
        for name in ocp.robust_names
        if (loop := ocp.profiles[name].loop) in modes
        and (loop == "open" or plays_own_law(ocp.profiles[name], config))
    }
    out["holds"] = {name: e["rate"] <= TARGET_RATE for name, e in judged.items()}
    out["verdicts"] = {name: verdict(e["violating_runs"], runs) for name, e in judged.items()}
    if extend_to:
        out["staged"] = extend(
            physics,
            ocp,
            judged={n: (ocp.profiles[n].loop, e["violating_runs"]) for n, e in judged.items()},
            config=config,
            extend_to=extend_to,
            batch=batch,
            listed_most=LISTED_MACHINES,
            on_extend=on_extend,
            on_machines=on_machines,
        )
        settle(out)
    out["timing"] = {"simulate_s": simulate_s, "monte_carlo_s": mc_s}
    return out


@writes("out", inputs=("ocp_path", "model", "model_path"), suffix=".json")
def heldout_file(
    ocp_path: str | Path,
    out: str | Path,
    *,
    model: str | Path,
    runs: int = 1000,
    seed: int,
    variability: Variability,
    max_start_time: float = OPERATING_SECONDS,
    modes: tuple[str, ...] | None = None,
    model_path: str | Path = MODEL_PATH,
    mpc: MPCConfig | None = None,
    feedback: str = "lqr",
    kp: float = PD_GAINS[0],
    kd: float = PD_GAINS[1],
    mc_samples: int = CALIBRATION_TRAJECTORIES,
    on_played: Callable[[str, str, dict[str, Any]], None] | None = None,
    on_machines: Callable[[str, str, int], None] | None = None,
    on_start: Callable[[OCPFile, tuple[str, ...]], None] | None = None,
    extend_to: int = 0,
    on_extend: Callable[[str, str, int], None] | None = None,
) -> dict[str, Any]:
    """`heldout_check` on the twin of `model_path`, written to `out` (heldout.json), in `modes`
    or (None) the loops of the file's robust profiles, a fallback's too ("open" if none); its
    model's own rate from TAIL_DRAWS per CALIBRATION_TRAJECTORIES of `mc_samples` trajectories."""
    check_trajectories("trajectories", mc_samples)
    check_extension(runs, extend_to)
    tail_draws = TAIL_DRAWS * mc_samples // CALIBRATION_TRAJECTORIES
    check_writable(out)
    solved = read_ocp(ocp_path)
    modes = (loops_of(solved.robust_names) or ("open",)) if modes is None else modes
    horizon = solved.horizon
    check_campaign_memory(runs, modes=len(modes), horizon=horizon, held_out=True)
    if "mpc" in modes:
        check_fits(mpc if mpc is not None else MPCConfig(), horizon)
    ppann, payload = load(model)
    if not isinstance(ppann, PPANN):
        raise CheckpointError(
            f"{model}: a {payload['kind']} model; the held-out check needs a PPANN"
        )
    physics = SliderCrank(load_model(model_path)[0])
    result = heldout_check(
        physics,
        ocp_path,
        ppann,
        runs=runs,
        seed=seed,
        variability=variability,
        max_start_time=max_start_time,
        modes=modes,
        mpc=mpc,
        feedback=feedback,
        kp=kp,
        kd=kd,
        mc_samples=mc_samples,
        tail_draws=tail_draws,
        on_played=on_played,
        on_machines=on_machines,
        on_start=on_start,
        extend_to=extend_to,
        on_extend=on_extend,
    )
    result["ocp"] = recorded_path(ocp_path, artifact=out)  # relative inside the run folder
    write_json(out, result)
    return result
