"""The chain's stages, each with its inputs and output folder named: what `run_chain` runs in one
folder and what `crank sweep` runs in a folder per shared step (one dataset per twin and seed, one
model per dataset and training, one solve per model and task, one leaf per solve and replay).

Every stage writes its files into `out` under fixed names and returns the summary its caller
records; the inputs are read from the paths given, so a stage does not care which folder made them.
"""

from __future__ import annotations

import os
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from common.jsonio import write_json
from control.ocp_file import read_ocp
from control.records import RobustError
from control.solve import failed_path, solve_file
from crank.report import solve_summary, write_markdown
from ppann.data import DataError
from ppann.pipeline import train_and_report
from replay.files import output_paths, replay_file
from replay.heldout import heldout_file
from replay.rates import second_stage_end
from replay.statistics import summary_rows
from twin.generation import generate_file
from twin.physics import SliderCrank, load_model
from twin.plan_data import plan_dataset_file

if TYPE_CHECKING:
    from collections.abc import Callable

    from crank.chain import Hooks, RunConfig

DATASET = "dataset.mcap"
MODEL = "model.pt"
OCP = "ocp.json"
REPLAY = "replay.mcap"
HELDOUT = "heldout.json"
PLAN_DATASET = "plan.mcap"
TAIL_REFUSED = "ocp.tail_refused.json"
"""In round-0/: what a first solve refused by its own-tail check kept (stages.solve_first_round)."""
FIRST_ROUND = "round-0"
"""The folder of the first model and solve of a chain with a plan round."""


def generate(config: RunConfig, out: Path, *, hooks: Hooks) -> dict[str, Any]:
    """The dataset of `config.generation` on the twin of `config.model_path`: `out`/dataset.mcap."""
    return generate_file(
        config.generation,
        out=out / DATASET,
        model_path=config.model_path,
        figures=config.figures,
        on_simulated=hooks.on_simulated,
        on_written=hooks.on_written,
    )


def train(
    config: RunConfig, dataset: Path, out: Path, *, hooks: Hooks, baselines: bool = True
) -> dict[str, Any]:
    """The PPANN (and baselines if asked, and not turned off by `baselines`) trained on
    `dataset`: `out`/model.pt and its report."""
    return train_and_report(
        dataset,
        out / MODEL,
        config=config.train,
        baselines=config.baselines and baselines,
        calibration_runs=config.calibration_runs,
        figures=config.figures,
        on_epoch=hooks.on_epoch,
        on_trained=hooks.on_trained,
        on_stage=hooks.on_stage,
    )


def train_again(config: RunConfig, dataset: Path, out: Path, *, hooks: Hooks) -> dict[str, Any]:
    """The plan round's training (`train` on `dataset`, the plan round's plan.mcap); data too
    short for its splits says that it was the round's and how to run without it.

    Raises:
      DataError: the round's episodes and the dataset hold no window for a split.
    """
    try:
        return train(config, dataset, out, hooks=hooks)
    except DataError as error:
        raise DataError(
            f"training again on the plan round's {config.plan.episodes} episodes and the "
            f"dataset: {error} (--plan-episodes 0 trains once, on the dataset alone)"
        ) from error


def solve(config: RunConfig, model: Path, out: Path, *, hooks: Hooks) -> dict[str, Any]:
    """The nominal and robust OCP of `config.ocp` on `model`: `out`/ocp.json and its figures."""
    return solve_file(
        model,
        out / OCP,
        config=config.ocp,
        figures=config.figures,
        on_iteration=hooks.on_iteration,
        on_fallback=hooks.on_stage,  # e.g. "robust refused: solving the fallback robust-fb"
    )


def solve_first_round(config: RunConfig, model: Path, out: Path, *, hooks: Hooks) -> dict[str, Any]:
    """The plan round's first solve into `out` (round-0). Its torque is only played on fresh
    machines to collect data, never returned, so where a robust profile is refused by its
    own-tail check (control/tail.py; `RobustError.tail_checked`: a refusal before the check,
    such as a tightening beyond the stroke, would only be met again), and every one is refused,
    the loop's torque without the check is played instead;
    the summary keeps the refusal under "tail_refused", its files as `out`/ocp.tail_refused.json
    (bench/refused_k3.md: such refusals were the first round's over-predicted spread, which the
    round corrected on the paper task). Where they are refused before or even without the check
    (a line no open-loop torque holds), `config.ocp.fallback` is solved as a one-round run
    would, and the round plays the nominal torque (`plan`); its ocp.json says why each was
    refused. The second round's solve checks its own torque as always.

    Raises:
      RobustError: the first solve refused even without the check and with no fallback, or the
        fallback refused too (its own error).
    """
    fallback = config.ocp.fallback
    config = replace(config, ocp=replace(config.ocp, fallback=()))
    try:
        return solve(config, model, out, hooks=hooks)
    except RobustError as exc:
        first = exc
    if config.ocp.tail_check and first.tail_checked:
        # what the refused solve kept (its nominal plan and margin history), out of the way of
        # the retry, which removes a stale ocp.failed.json when it succeeds
        failed = failed_path(out / OCP)
        why, kept = str(first), failed.with_name(TAIL_REFUSED)
        if failed.is_file():
            os.replace(failed, kept)
            why = why.replace(str(failed), f"{out.name}/{kept.name}")
        tell(
            hooks,
            "the first solve refused every robust profile with its own-tail check on; solving "
            "again without the check, a torque only to play in the round",
        )
        unchecked = replace(config, ocp=replace(config.ocp, tail_check=False))
        try:
            return solve(unchecked, model, out, hooks=hooks) | {"tail_refused": why}
        except RobustError:
            if kept.is_file():  # the first refusal's error names its own files
                os.replace(kept, failed)
    if not fallback:
        raise first from None
    tell(
        hooks,
        f"the first solve refused every robust profile; solving the fallback "
        f"{', '.join(fallback)} (the round plays the nominal torque)",
    )
    with_fallback = replace(config, ocp=replace(config.ocp, fallback=fallback))
    return solve(with_fallback, model, out, hooks=hooks)


def tell(hooks: Hooks, text: str) -> None:
    """`text` to the user as a stage line, where the run shows them."""
    if hooks.on_stage is not None:
        hooks.on_stage(text)


def plan(config: RunConfig, dataset: Path, ocp: Path, out: Path) -> dict[str, Any]:
    """`dataset` with `config.plan.episodes` episodes of `ocp`'s torque on fresh machines (on the
    dataset's own where it names them: twin/plan_data.py):
    `out`/plan.mcap. The torque is the open-loop robust profile's, or the nominal one's when the
    OCP asks for no open-loop robust profile or has none (refused)."""
    solved = read_ocp(ocp)
    name = "robust" if "robust" in solved.profiles else "nominal"
    profile = solved.profiles[name]
    physics = SliderCrank(load_model(config.model_path)[0])
    return plan_dataset_file(
        dataset,
        out / PLAN_DATASET,
        tau=profile.tau[:-1],
        theta0=float(profile.theta[0]),
        omega0=float(profile.omega[0]),
        config=config.plan,
        seed=config.seed,
        physics=physics,
        # by its path inside `out` where it is there (a sweep's step folder is renamed once done)
        played={
            "ocp": str(ocp.relative_to(out) if ocp.is_relative_to(out) else ocp),
            "profile": name,
        },
    )


def replay(
    config: RunConfig,
    ocp: Path,
    out: Path,
    *,
    resolved: dict[str, Any],
    hooks: Hooks,
    nthread: int | None = None,
) -> dict[str, Any]:
    """Every profile of `ocp` played on the campaign machines: `out`/replay.mcap and its stats."""
    return replay_file(
        ocp,
        out / REPLAY,
        config=config.replay,
        model_path=config.model_path,
        resolved=resolved,
        nthread=nthread,
        on_run=_counted(hooks.on_runs, "replay"),
        on_start=_counted(hooks.on_total, "replay"),
        figures=config.figures,
    )


def _counted(hook: Callable[[str, int], None] | None, stage: str) -> Callable[[int], None] | None:
    """A count callback of `stage` that passes its number on to `hook` (or none without one)."""
    return None if hook is None else lambda n: hook(stage, n)


def heldout(
    config: RunConfig, ocp: Path, model: Path, out: Path, *, hooks: Hooks
) -> dict[str, Any]:
    """Every profile of `ocp` on `config.heldout_runs` held-out machines, in the loops its
    robust profiles (a fallback's included) were tightened for, and a robust one those cannot
    judge on `config.heldout_second_stage` more: `out`/heldout.json."""
    played, total = _counted(hooks.on_runs, "heldout"), _counted(hooks.on_total, "heldout")
    runs, second = config.heldout_runs, config.heldout_second_stage

    def on_extend(profile: str, loop: str, more: int) -> None:
        if hooks.on_stage is not None:
            hooks.on_stage(
                f"held-out: {profile} ({loop} loop) not decided on {runs} machines; "
                f"{more} more of the same draw"
            )
        if hooks.on_more is not None:
            hooks.on_more("heldout", more)

    return heldout_file(
        ocp,
        out / HELDOUT,
        model=model,
        runs=config.heldout_runs,
        seed=config.heldout_seed,
        variability=config.generation.variability,
        max_start_time=config.replay.max_start_time,
        kp=config.replay.kp,  # recorded beside the own-law loops (a robust-pd's gains are this PD)
        kd=config.replay.kd,
        model_path=config.model_path,
        mc_samples=config.heldout_trajectories,
        on_machines=None if played is None else lambda _profile, _mode, n: played(n),
        on_start=None
        if total is None
        else lambda solved, loops: total(config.heldout_runs * len(solved.names) * len(loops)),
        extend_to=second_stage_end(runs, second),
        on_extend=on_extend,
    )


def write_report(
    out: Path,
    *,
    resolved: dict[str, Any],
    dataset: dict[str, Any],
    trained: dict[str, Any],
    solved: dict[str, Any],
    stats: dict[str, Any],
    checked: dict[str, Any] | None,
    seconds: dict[str, float],
    plan_round: dict[str, Any] | None = None,
    estimated: dict[str, list[float]],
) -> dict[str, Any]:
    """`out`/report.json and report.md from what the stages returned; returns report.json's
    content. report.md is written last: a folder with it is finished."""
    report = {
        "config": resolved,
        "dataset": dataset,
        "ppann": trained,
        "ocp": solve_summary(solved),
        "refused": solved["refused"],  # robust profiles asked for that have no torque: why
        "fallback": solved.get("fallback", []),  # solved because every one asked was refused
        "replay": {
            "claim": stats["claim"],
            "claims": stats["claims"],
            "premiums": stats["ocp"]["premiums"],
            "table": summary_rows(stats),
            "stats": output_paths(out / REPLAY)["stats"].name,
        },
        "heldout": checked,
        "plan_round": None
        if plan_round is None
        else {
            "plan": plan_round["plan"],
            "first_solve": solve_summary(plan_round["first_solve"]),
            "first_refused": plan_round["first_solve"]["refused"],
            # the first solve's own-tail refusal, whose unchecked torque the round played
            "first_tail_refused": plan_round["first_solve"].get("tail_refused"),
        },
        "wall_seconds": seconds,
        "estimated_seconds": estimated,
    }
    write_json(out / "report.json", report, indent=2)
    write_markdown(out / "report.md", report, stats=stats)
    return report
