"""`crank compare`: every profile of a run under every controller, per product-line scenario.

For each finished run folder (`crank run`, best with `--profiles robust,robust-fb,robust-pd`;
one folder per variability scenario) the profiles of its ocp.json are played on the twin of the
run's scenario under four controllers — open loop, the fixed PD the run's replays played
(`replay.kp`, `kd`; every run of a compare must share it), the profile's own law (its LQR),
and the online MPC on the run's PPANN — on the run's 100 campaign machines and on held-out
machines (streams heldout_machines / heldout_noise of `heldout_seed`; every controller on the
same machines). One row per scenario, profile and controller: violations, lowest run, the
profile's cost premium, the Σu² applied against the nominal plan's, tracking RMS, saturation
share, the final θ/ω error and, under the MPC, its step times.

Files in `<out>/`: `compare.json` (the rows, each run's seeds and the settings), `compare.md` (a
table per scenario, and the verdict against issue 12's targets: ≤ 0.5 % of held-out machines,
Σu² within 10 % of the nominal plan's), `compare.png` (held-out violation rate and premium
against the scenario's spread). `merge_compares` joins compare folders made apart (in parallel,
or on other machines) with the same settings into one. A sweep folder (`crank sweep`) stands for
its finished leaves, each compared with its solve and model steps' plan and PPANN.
"""

from __future__ import annotations

import json
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from common import streams
from common.atomic import writes
from common.errors import ConfigError
from common.jsonio import write_json
from control.mpc_config import MPCConfig
from crank.chain import Hooks, RunConfig
from crank.run_twin import run_twin
from crank.sweep_spec import folder as step_folder
from twin.variability import Variability

CONTROLLERS = {
    "open": ("open", "lqr"),
    "closed-PD": ("closed", "pd"),
    "closed-LQR": ("closed", "lqr"),
    "mpc": ("mpc", "lqr"),
}
"""Each column's replay mode and closed-loop law (replay/config.py); closed-LQR plays each
profile's own gains. A robust-pd profile sized for the fixed PD has no closed-LQR row: its own
law is the closed-PD row."""
TARGET_EFFORT = 0.10
"""Issue 12: Σu² applied within 10 % of the nominal plan's."""
SPREAD_KEYS = ("motor_frictionloss", "motor_damping", "slider_frictionloss", "slider_damping")


def spread(variability: Variability) -> float:
    """The scenario's spread: the largest half-range of friction and damping over its nominal
    (0.05 for `paper`, 0.15 and 0.30 for `line-15`, `line-30`)."""
    values = [getattr(variability, key) for key in SPREAD_KEYS]
    return max((p.high - p.low) / (2 * p.nominal) for p in values)


def _sweep_leaf(run_dir: Path) -> dict[str, Any] | None:
    """The sweep.json entry of a sweep's leaf folder (`<sweep>/leaf/<key>`), or None."""
    sweep = run_dir.parent.parent / "sweep.json"
    if run_dir.parent.name != "leaf" or not sweep.is_file():
        return None
    leaves = json.loads(sweep.read_text()).get("leaves", [])
    return next((leaf for leaf in leaves if leaf["steps"]["leaf"] == run_dir.name), None)


def expand_sweeps(paths: list[Path]) -> list[Path]:
    """Run folders as given, a sweep folder (sweep.json) replaced by its finished leaves' folders
    in the sweep's order (a leaf whose step failed or did not run is left out).

    Raises:
      ConfigError: a sweep folder with no finished leaf.
    """
    out: list[Path] = []
    for path in map(Path, paths):
        if not (path / "sweep.json").is_file():
            out.append(path)
            continue
        leaves = json.loads((path / "sweep.json").read_text()).get("leaves", [])
        done = [step_folder(path, "leaf", leaf["steps"]["leaf"]) for leaf in leaves]
        done = [d for d in done if (d / "report.md").is_file()]
        if not done:
            raise ConfigError(f"sweep folder {path} has no finished leaf to compare")
        out += done
    return out


def _run_folder(run_dir: Path, *, mjcf: Path | None = None) -> tuple[RunConfig, Path, Path, Path]:
    """A finished run folder's (or a sweep leaf's) configuration, ocp.json, model.pt and twin
    (crank/run_twin.py: `mjcf` or the run's MJCF, checked against its dataset); a ConfigError
    names what is missing. A sweep leaf's plan is its solve step's; its model the model step's,
    or the solve step's where the leaf ran the plan round (the solve step trained the model its
    torque is of, crank/sweep.py); its dataset the data step's."""
    names = ("config.json", "ocp.json", "model.pt", "report.md", "dataset.mcap")
    files = {name: run_dir / name for name in names}
    if not files["config.json"].is_file():
        raise ConfigError(f"{run_dir} is not a finished run folder (no config.json)")
    config = RunConfig.from_dict(json.loads(files["config.json"].read_text()))
    if (leaf := _sweep_leaf(run_dir)) is not None:
        sweep, steps = run_dir.parent.parent, leaf["steps"]
        solve = step_folder(sweep, "solve", steps["solve"])
        files["ocp.json"] = solve / "ocp.json"
        trained = solve if config.plan.episodes else step_folder(sweep, "model", steps["model"])
        files["model.pt"] = trained / "model.pt"
        files["dataset.mcap"] = step_folder(sweep, "data", steps["data"]) / "dataset.mcap"
    for name, path in files.items():
        if not path.is_file():
            raise ConfigError(f"{run_dir} is not a finished run folder (no {name})")
    twin = run_twin(files["dataset.mcap"], config.model_path, mjcf=mjcf)
    return config, files["ocp.json"], files["model.pt"], twin


UNREAD_TRAJECTORIES = 100
"""The held-out check's Monte-Carlo size in a compare: its rows are observations (rates, the
lowest runs), so the check's predictions are not read and run at the smallest size it takes
(replay.heldout.check_trajectories) instead of 10 000 per mode and 20 000 for the model's rate."""


def _label(run_dir: Path) -> str:
    """A run folder's name in progress lines: a sweep leaf's options, else the folder's name."""
    leaf = _sweep_leaf(run_dir)
    return run_dir.name if leaf is None else leaf["name"]


def compare_run(
    run_dir: str | Path,
    *,
    runs: int,
    heldout_runs: int,
    heldout_seed: int,
    mpc: MPCConfig,
    mjcf: Path | None = None,
    hooks: Hooks | None = None,
) -> dict[str, Any]:
    """Every profile of one run folder under every controller: {scenario, spread, seeds, rows},
    on the run's twin (`mjcf`: a copy of it in place of the path its config.json names);
    `hooks`: a line per stage and per profile checked (`on_stage`), what the "campaign" and the
    "held-out" stage will play (`on_total`, before the stage's line) and as they play (`on_runs`).

    Raises:
      ConfigError: not a finished run folder, or the twin is not the run's.
    """
    from control.ocp_file import read_ocp
    from ppann.checkpoint import CheckpointError, load
    from ppann.model import PPANN
    from replay.campaign import run_campaign
    from replay.config import ReplayConfig, played_line
    from replay.heldout import heldout_check
    from replay.laws import plays_own_law
    from replay.statistics import campaign_statistics
    from twin.physics import SliderCrank, load_model

    run_dir = Path(run_dir)
    hooks = hooks or Hooks()
    stage = hooks.on_stage or (lambda _: None)
    total = hooks.on_total or (lambda _stage, _count: None)
    played = hooks.on_runs or (lambda _stage, _count: None)
    config, ocp_path, model_path, twin = _run_folder(run_dir, mjcf=mjcf)
    ocp = read_ocp(ocp_path)
    model, payload = load(model_path)
    if not isinstance(model, PPANN):
        raise CheckpointError(f"{model_path}: a {payload['kind']} model; compare needs a PPANN")
    physics = SliderCrank(load_model(twin)[0])
    variability = config.generation.variability
    base = ReplayConfig(
        runs=runs,
        seed=config.replay.seed,
        modes=("open", "closed", "mpc"),
        max_start_time=config.replay.max_start_time,
        variability=variability,
        mpc=mpc,
        kp=config.replay.kp,  # the PD the run's replays played
        kd=config.replay.kd,
    )
    pd = replace(base, modes=("closed",), feedback="pd")
    label = _label(run_dir)
    loops = len(base.modes) + len(pd.modes)  # every profile in each: what both stages play
    total("campaign", runs * len(ocp.names) * loops)
    stage(f"{label}: {runs} campaign machines, {len(ocp.names)} profiles × 4 controllers")
    shared = {"model": model, "on_machines": lambda n: played("campaign", n)}
    campaign = run_campaign(physics, ocp, config=base, **shared)
    stats = {
        "lqr": campaign_statistics(campaign, ocp, ocp_path=ocp_path, timing={}),
        "pd": campaign_statistics(
            run_campaign(physics, ocp, config=pd, machines=campaign.machines, **shared),
            ocp,
            ocp_path=ocp_path,
            timing={},
        ),
    }
    held = {}
    total("held-out", heldout_runs * len(ocp.names) * loops)
    for feedback, modes in (("lqr", base.modes), ("pd", pd.modes)):
        stage(f"{label}: {heldout_runs} held-out machines, {', '.join(modes)} ({feedback})")
        held[feedback] = heldout_check(
            physics,
            ocp_path,
            model,
            runs=heldout_runs,
            seed=heldout_seed,
            variability=variability,
            max_start_time=base.max_start_time,
            modes=modes,
            mpc=mpc,
            feedback=feedback,
            kp=base.kp,
            kd=base.kd,
            mc_samples=UNREAD_TRAJECTORIES,
            tail_draws=UNREAD_TRAJECTORIES,
            on_machines=lambda _profile, _mode, n: played("held-out", n),
            on_played=lambda name, mode, entry, law=feedback: stage(
                played_line(
                    name, mode, feedback=law, below=entry["violating_runs"], runs=heldout_runs
                )
            ),
        )
    nominal_effort = float(np.sum(ocp.nominal.tau**2))
    rows = []
    for name in ocp.names:
        for controller, (mode, feedback) in CONTROLLERS.items():
            if controller == "closed-LQR" and plays_own_law(ocp.profiles[name], pd):
                continue  # its own gains are this PD (robust-pd): the closed-PD row
            s = stats[feedback]["profiles"][name][mode]
            h = held[feedback]["profiles"][name][mode]
            rows.append(
                {
                    "scenario": variability.name,
                    "spread": spread(variability),
                    "seed": config.seed,
                    "profile": name,
                    "loop": ocp.profiles[name].loop,
                    "controller": controller,
                    "below_campaign": s["violating_runs"],
                    "campaign_runs": s["runs"],
                    "lowest_campaign_mm": 1e3 * min(c["lowest"] for c in s["constraint"].values()),
                    "heldout_rate": h["rate"],
                    "heldout_upper_95": h["rate_upper_95"],
                    "lowest_heldout_mm": 1e3 * min(e["lowest"] for e in h["samples"].values()),
                    "premium": 0.0 if name == "nominal" else ocp.premium(name),
                    "effort_applied": s["effort"]["applied_mean"],
                    "effort_over_nominal": s["effort"]["applied_mean"] / nominal_effort - 1,
                    "theta_rms_mrad": 1e3 * s["tracking"]["theta_rms"],
                    "saturated_share": s["tracking"]["saturated_share"],
                    "final_theta_error": s["final_error"]["theta"]["mean"],
                    "final_omega_error": s["final_error"]["omega"]["mean"],
                    "mpc": s.get("mpc"),
                }
            )
    return {
        "run": str(run_dir),
        "mjcf": str(twin),  # checked to be the bytes the run's dataset was generated from
        "scenario": variability.name,
        "spread": spread(variability),
        "seed": config.seed,
        "replay_seed": base.seed,
        "pd": {"kp": base.kp, "kd": base.kd},
        "heldout_streams": streams.describe(heldout_seed, streams.HELDOUT_STREAMS),
        "refused": ocp.refused,
        "rows": rows,
    }


@writes("out", all_or_nothing=True)
def compare_runs(
    run_dirs: list[Path],
    out: str | Path,
    *,
    runs: int = 100,
    heldout_runs: int = 1000,
    heldout_seed: int,
    mpc: MPCConfig | None = None,
    mjcf: Path | None = None,
    hooks: Hooks | None = None,
) -> dict[str, Any]:
    """`compare_run` for each run folder, written to `out`/compare.{json,md,png}.

    Raises:
      ConfigError: no run folder, a folder named twice or not a finished run, a twin not the
        run's, runs whose replays played different fixed PDs, or `out` exists.
    """

    out = Path(out)
    run_dirs = expand_sweeps(run_dirs)
    if not run_dirs:
        raise ConfigError("compare needs at least one run folder")
    if len({p.resolve() for p in run_dirs}) != len(run_dirs):
        raise ConfigError("a run folder is named twice")
    from replay.config import ReplayConfig, check_campaign_memory
    from replay.rates import TARGET_RATE

    # every folder and count checked before any replay
    configs = [_run_folder(run_dir, mjcf=mjcf)[0] for run_dir in run_dirs]
    horizon = max(c.ocp.horizon for c in configs)
    pds = {(c.replay.kp, c.replay.kd) for c in configs}
    if len(pds) > 1:
        raise ConfigError(
            "the runs' replays played different fixed PDs ("
            + ", ".join(f"Kp {kp:g} Kd {kd:g}" for kp, kd in sorted(pds))
            + "): compare them apart"
        )
    ((kp, kd),) = pds
    ReplayConfig(runs=runs)
    ReplayConfig(runs=heldout_runs)
    check_campaign_memory(heldout_runs, modes=len(CONTROLLERS), horizon=horizon, held_out=True)
    if out.exists():
        raise ConfigError(f"compare folder already exists: {out}")
    mpc = mpc or MPCConfig()
    started = time.perf_counter()
    results = [
        compare_run(
            p,
            runs=runs,
            heldout_runs=heldout_runs,
            heldout_seed=heldout_seed,
            mpc=mpc,
            mjcf=mjcf,
            hooks=hooks,
        )
        for p in run_dirs
    ]
    compare = {
        "format": "crank-compare",
        "version": 1,
        "runs": runs,
        "heldout_runs": heldout_runs,
        "heldout_seed": heldout_seed,
        "controllers": {k: {"mode": m, "feedback": f} for k, (m, f) in CONTROLLERS.items()},
        "pd": {"kp": kp, "kd": kd},  # every run's replays' (checked above)
        "mpc": mpc.as_dict(),
        "target_rate": TARGET_RATE,  # the held-out check's
        "target_effort": TARGET_EFFORT,
        "scenarios": results,
        "wall_s": time.perf_counter() - started,
    }
    _write(compare, out)
    return compare


SETTINGS = ("runs", "heldout_runs", "heldout_seed", "controllers", "pd", "mpc", "target_rate")


@writes("out", all_or_nothing=True)
def merge_compares(folders: list[Path], out: str | Path) -> dict[str, Any]:
    """One compare folder from several made with the same settings: their scenarios in order.

    Raises:
      ConfigError: fewer than two folders, one without compare.json, settings that differ, a
        run in two of them, or `out` exists.
    """
    out = Path(out)
    if len(folders) < 2:
        raise ConfigError("--merge needs at least two compare folders")
    parts = []
    for folder in folders:
        path = Path(folder) / "compare.json"
        if not path.is_file():
            raise ConfigError(f"{folder} is not a compare folder (no compare.json)")
        parts.append(json.loads(path.read_text()))
    for folder, part in zip(folders[1:], parts[1:], strict=True):
        differ = [k for k in SETTINGS if part[k] != parts[0][k]]
        if differ:
            raise ConfigError(f"{folder} was compared with other settings: {', '.join(differ)}")
    runs = [s["run"] for part in parts for s in part["scenarios"]]
    if len(set(runs)) != len(runs):
        raise ConfigError("a run is in two of the compare folders")
    if out.exists():
        raise ConfigError(f"compare folder already exists: {out}")
    merged = {
        **parts[0],
        "scenarios": [s for part in parts for s in part["scenarios"]],
        "wall_s": sum(part["wall_s"] for part in parts),
        "merged_from": [str(f) for f in folders],
    }
    _write(merged, out)
    return merged


def counted(compare: dict[str, Any]) -> str:
    """What a compare holds, for the terminal: "3 runs of 1 scenario" (compare.json's
    `scenarios` has an entry per run; several seeds of one scenario are several entries)."""
    runs = len(compare["scenarios"])
    kinds = len({entry["scenario"] for entry in compare["scenarios"]})
    return f"{runs} run{'s' * (runs != 1)} of {kinds} scenario{'s' * (kinds != 1)}"


def _write(compare: dict[str, Any], out: Path) -> None:
    """compare.json, compare.md and compare.png into the new folder `out`."""
    from common.figures import save_figure
    from crank.compare_report import figure, markdown

    out.mkdir(parents=True)
    write_json(out / "compare.json", compare, indent=1)
    (out / "compare.md").write_text(markdown(compare))
    save_figure(figure(compare), out / "compare.png")
