"""`crank run` and `crank study`: the whole chain (crank/chain.py) with progress, and the seed
study (crank/study.py)."""

from __future__ import annotations

import json
from contextlib import AbstractContextManager
from dataclasses import replace
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from common.atomic import check_creatable
from common.errors import ConfigError
from control.config import OCPConfig
from crank.chain_progress import chain_progress
from crank.console import (
    DEFAULT_FALLBACK,
    DEFAULT_PROFILES,
    HELDOUT_RUNS,
    HELDOUT_SEED,
    Confidence,
    Drift,
    EpisodeSeconds,
    EpisodesPerMachine,
    FallbackOption,
    ModelPath,
    ProfilesOption,
    Seconds,
    Seed,
    VariabilityOption,
    app,
    continue_hint,
    fallback_list,
    one_line_errors,
    print_heldout,
    print_replay,
    print_summary,
    profiles_list,
    transcript,
)
from replay.config import ReplayConfig
from replay.rates import SECOND_STAGE, TARGET_RATE, machines_to_confirm
from replay.spread_interval import CALIBRATION_TRAJECTORIES
from twin import DATASET_SECONDS, EPISODE_SECONDS, MODEL_PATH
from twin.dataset import GenerationConfig
from twin.plan_config import PlanConfig

if TYPE_CHECKING:
    from crank.chain import RunConfig


PlanEpisodes = Annotated[
    int,
    typer.Option(
        help="The plan round: play the first solve's robust torque on this many fresh machines "
        "(with --episodes-per-machine: episodes of the dataset's machines), add their episodes "
        "to the data, train and solve again; 0: none."
    ),
]
PDOption = Annotated[
    str | None,
    typer.Option(
        help="The machine's fixed PD as KP,KD (N·m/rad, N·m·s/rad): the replays' PD and the one "
        f"the robust-pd tube is sized for (default: {ReplayConfig.kp:g},{ReplayConfig.kd:g})."
    ),
]
FiguresOption = Annotated[
    bool, typer.Option(help="Write each stage's PNGs (off: none, the same numbers, sooner).")
]
HeldoutRuns = Annotated[
    int,
    typer.Option(
        help=f"Held-out machines per profile; 0 skips the check. Fewer than "
        f"{machines_to_confirm()} cannot confirm a rate of {100 * TARGET_RATE:g} % (the "
        "exact 95 % bound of none below)."
    ),
]
HeldoutSeed = Annotated[int, typer.Option(help="Root seed of the held-out machines.")]
SecondStage = Annotated[
    int,
    typer.Option(
        help="Held-out machines a robust torque is played on beyond the first where those cannot "
        "decide its verdict (judged on all, the risk of a wrong 'holds' within 5 %); 0: one look."
    ),
]


@app.command("run", short_help="The whole chain into logs/<run>/ (the main job).")
@one_line_errors
def run_command(
    context: typer.Context,
    seconds: Seconds = DATASET_SECONDS,
    seed: Seed = 0,
    logs: Annotated[Path, typer.Option(help="Output root; the run goes in logs/<run>/.")] = Path(
        "logs"
    ),
    name: Annotated[str | None, typer.Option(help="Run folder name (default: time stamp).")] = None,
    episode_seconds: EpisodeSeconds = EPISODE_SECONDS,
    episodes_per_machine: EpisodesPerMachine = GenerationConfig.episodes_per_machine,
    drift: Drift = True,
    variability: VariabilityOption = "paper",
    confidence: Confidence = OCPConfig.confidence,
    profiles: ProfilesOption = DEFAULT_PROFILES,
    fallback: FallbackOption = DEFAULT_FALLBACK,
    pd: PDOption = None,
    runs: Annotated[int, typer.Option(help="Replay machines per profile and mode.")] = (
        ReplayConfig.runs
    ),
    heldout_runs: HeldoutRuns = HELDOUT_RUNS,
    heldout_seed: HeldoutSeed = HELDOUT_SEED,
    heldout_second_stage: SecondStage = SECOND_STAGE,
    heldout_trajectories: Annotated[
        int,
        typer.Option(
            help="Monte-Carlo trajectories of each spread the held-out check predicts (fewer: "
            "wider ratio intervals in heldout.json)."
        ),
    ] = CALIBRATION_TRAJECTORIES,
    plan_episodes: PlanEpisodes = PlanConfig.episodes,
    model: ModelPath = MODEL_PATH,
    figures: FiguresOption = True,
    resume: Annotated[
        Path | None,
        typer.Option(
            help="Continue an unfinished run folder with its own config.json, from the first "
            "stage it has not finished; only --profiles, --fallback, --pd, --confidence, --runs "
            "and the --heldout-* options may be given, for the stages it has not made, and "
            "--model: a copy of its twin's MJCF elsewhere."
        ),
    ] = None,
    config: Annotated[
        Path | None,
        typer.Option(
            help="A crank.toml with any of the chain's settings (crank config --show); the "
            "flags given here override it."
        ),
    ] = None,
) -> None:
    """The whole chain into logs/<run>/: generate, train and validate, solve the OCPs, replay
    them on the twin open and closed loop, report (report.json, report.md, figures)."""
    from crank.config_file import build, defaults, merge, read_values
    from crank.resume import check_new_run, resumed_config, with_settings

    given = _given(context)
    if resume is not None:
        others = [p for p in given if p != "resume" and p not in RESUME_FLAGS]
        if others:
            option = "--" + others[0].replace("_", "-")
            raise ConfigError(
                f"--resume continues with the folder's config.json; drop {option} (only "
                f"{', '.join('--' + f.replace('_', '-') for f in RESUME_FLAGS)} may change, for "
                "the stages the run has not made)"
            )
        changes = flag_values({p: v for p, v in given.items() if p in RESUME_FLAGS})
        _run(with_settings(resumed_config(resume), changes), resume, resume=True)
        return
    values = read_values(config) if config is not None else defaults()
    values = merge(values, flag_values(given), source="the command line")
    if name is not None and (name in ("", ".", "..") or Path(name).name != name or "\\" in name):
        raise ConfigError(f"--name must be a plain folder name inside --logs, got {name!r}")
    if name is not None:  # before the chain's modules load (build's): a line in about a second
        check_new_run(logs / name)
    check_creatable(logs)
    run_config = build(values, source=str(config) if config is not None else "command line")
    name = name or datetime.now(UTC).strftime("%Y%m%d-%H%M%S") + f"-seed{run_config.seed}"
    _run(run_config, logs / name, resume=False)


def _given(context: typer.Context) -> dict[str, Any]:
    """The options given on the command line (not left at their defaults), by name."""
    return {
        p: v
        for p, v in context.params.items()
        if getattr(context.get_parameter_source(p), "name", "") != "DEFAULT"
    }


FLAG_KEYS = {
    "seed": ("seed",),
    "seconds": ("generation", "seconds"),
    "episode_seconds": ("generation", "episode_seconds"),
    "episodes_per_machine": ("generation", "episodes_per_machine"),
    "drift": ("generation", "drift"),
    "variability": ("generation", "variability"),
    "confidence": ("ocp", "confidence"),
    "profiles": ("ocp", "profiles"),
    "fallback": ("ocp", "fallback"),
    "runs": ("replay", "runs"),
    "heldout_runs": ("heldout_runs",),
    "heldout_seed": ("heldout_seed",),
    "heldout_second_stage": ("heldout_second_stage",),
    "heldout_trajectories": ("heldout_trajectories",),
    "model": ("model",),
    "plan_episodes": ("plan", "episodes"),
    "figures": ("figures",),
    "mc_mode": ("ocp", "mc_mode"),
    "tightening": ("ocp", "tightening"),
    "baselines": ("baselines",),
}
"""Where each flag of `crank run` and `crank study` sits in the config file
(crank/config_file.py)."""
STUDY_SETTINGS = {"baselines": False, "heldout_second_stage": 0}
"""Where `crank study` differs from `crank run` if neither its file nor a flag says: no
baselines (a seed's row needs the PPANN's torques alone), one look on the held-out machines
(its table compares seeds on the same machine count)."""
RESUME_FLAGS = (
    "profiles",
    "fallback",
    "pd",
    "confidence",
    "runs",
    "heldout_runs",
    "heldout_seed",
    "heldout_second_stage",
    "heldout_trajectories",
    "model",
)
"""The flags `crank run --resume` takes: settings of the solve, the replays and the held-out
check, for the stages the run has not made, and the twin's MJCF moved (crank/resume.py)."""


def pd_gains(text: str) -> tuple[float, float]:
    """`--pd KP,KD` as two numbers (range checks are the configs')."""
    parts = text.split(",")
    try:
        kp, kd = (float(part) for part in parts)
    except ValueError:
        raise ConfigError(f"--pd takes the gains as KP,KD, e.g. 20,0.5; got {text!r}") from None
    return kp, kd


def flag_values(given: dict[str, Any]) -> dict[str, Any]:
    """The flags given on the command line as a partial config file; `--pd` sets the PD of the
    replays and of the robust-pd tube alike."""
    out: dict[str, Any] = {}
    for flag, value in given.items():
        if flag == "pd":
            kp, kd = pd_gains(value)
            out.setdefault("ocp", {}).update(pd_kp=kp, pd_kd=kd)
            out.setdefault("replay", {}).update(kp=kp, kd=kd)
            continue
        if flag not in FLAG_KEYS:
            continue
        *tables, key = FLAG_KEYS[flag]
        table = out
        for t in tables:
            table = table.setdefault(t, {})
        if flag in ("profiles", "fallback"):
            value = (profiles_list if flag == "profiles" else fallback_list)(value)
        table[key] = str(value) if isinstance(value, Path) else value
    return out


@app.command("config", short_help="Print the chain's configuration as a crank.toml.")
@one_line_errors
def config_command(
    config: Annotated[
        Path | None, typer.Option(help="A crank.toml to resolve (default: the defaults alone).")
    ] = None,
    show: Annotated[bool, typer.Option(help="Print the resolved configuration.")] = True,
) -> None:
    """Print the configuration `crank run --config FILE` would use, as TOML: every key with its
    value (the defaults, or FILE's values over them); flags of `crank run` override it."""
    from crank.config_file import build, defaults, read_values, to_toml

    values = read_values(config) if config is not None else defaults()
    build(values, source=str(config) if config is not None else "defaults")  # values in range
    if show:
        source = f"{config} over the defaults" if config is not None else "the defaults"
        header = f"crank run --config: {source}; flags of crank run override these"
        typer.echo(to_toml(values, header=header), nl=False)


def _run(config: RunConfig, run_dir: Path, *, resume: bool) -> None:
    """run_chain with progress bars, stage lines, run.log and the summary tables."""
    from control.records import RobustError
    from crank.chain import run_chain
    from crank.estimate import describe
    from crank.report import train_summary

    with transcript(run_dir / "run.log", append=resume):
        with chain_progress(config) as shown:
            hooks = replace(
                shown, on_estimate=lambda stages: typer.echo(describe(stages), err=True)
            )
            try:
                with continue_hint(run_dir, f"continue it with: crank run --resume {run_dir}"):
                    report = run_chain(config, run_dir, hooks=hooks, resume=resume)
            except RobustError as exc:  # every profile refused: the closed loop is one resume away
                if "robust-fb" not in (*config.ocp.profiles, *config.ocp.fallback):
                    exc.args = (
                        f"{exc}; to try the closed loop on this run's model: crank run --resume "
                        f"{run_dir} --profiles robust-fb",
                    )
                raise
        print_summary(f"run {run_dir}: dataset", report["dataset"])
        print_summary("PPANN", train_summary(report["ppann"]))
        print_summary("OCP", report["ocp"])
        typer.echo("replay on the twin")
        stats = json.loads((run_dir / report["replay"]["stats"]).read_text())
        print_replay(stats, run_dir / "replay.mcap")
        if report["heldout"] is not None:
            print_heldout(report["heldout"])
        typer.echo(
            "wall time: "
            + ", ".join(f"{k} {v:.0f} s" for k, v in report["wall_seconds"].items())
            + f"; report: {run_dir / 'report.md'}"
        )


@app.command("study", short_help="The chain once per seed, each checked on held-out machines.")
@one_line_errors
def study_command(
    context: typer.Context,
    seeds: Annotated[str, typer.Option(help="Seeds: a range like 0-9 or a list like 0,3,7.")] = (
        "0-9"
    ),
    out: Annotated[Path, typer.Option(help="Study folder (one seed-<s>/ run folder each).")] = Path(
        "logs/study"
    ),
    variability: VariabilityOption = "paper",
    seconds: Seconds = DATASET_SECONDS,
    episode_seconds: EpisodeSeconds = EPISODE_SECONDS,
    episodes_per_machine: EpisodesPerMachine = GenerationConfig.episodes_per_machine,
    runs: Annotated[int, typer.Option(help="Campaign machines per profile and mode.")] = 100,
    heldout_runs: HeldoutRuns = HELDOUT_RUNS,
    heldout_seed: HeldoutSeed = HELDOUT_SEED,
    mc_mode: Annotated[str, typer.Option(help="Monte-Carlo mode of the robust OCP.")] = (
        OCPConfig.mc_mode
    ),
    tightening: Annotated[
        str, typer.Option(help="centred (k·σ below the mean), gaussian (k·σ, eq. 16) or quantile.")
    ] = OCPConfig.tightening,
    confidence: Confidence = OCPConfig.confidence,
    plan_episodes: PlanEpisodes = PlanConfig.episodes,
    profiles: ProfilesOption = DEFAULT_PROFILES,
    fallback: FallbackOption = DEFAULT_FALLBACK,
    pd: PDOption = None,
    baselines: Annotated[bool, typer.Option(help="Also train the two baselines.")] = False,
    figures: FiguresOption = True,
    resume: Annotated[bool, typer.Option(help="Continue a study, keeping done seeds.")] = False,
    config: Annotated[
        Path | None,
        typer.Option(
            help="A crank.toml with any of the chain's settings (crank config --show), its seed "
            "replaced by each of --seeds; the flags given here override it."
        ),
    ] = None,
) -> None:
    """The chain once per seed, each robust torque checked on held-out machines: study.md,
    study.csv, study.json and study.png (violation rate and premium against seed)."""
    check_creatable(out)  # before the chain's modules load
    from crank.chain import Hooks
    from crank.config_file import build, defaults, merge, read_values
    from crank.estimate import Span, describe
    from crank.study import parse_seeds, run_study

    chosen = parse_seeds(seeds)
    values = merge(defaults(), STUDY_SETTINGS, source="crank study")
    if config is not None:
        values = read_values(config, base=values)
    values = merge(values, flag_values(_given(context)), source="the command line")
    base = build(
        {**values, "seed": chosen[0]}, source=str(config) if config is not None else "command line"
    )

    def progress(seed: int) -> AbstractContextManager[Hooks]:
        typer.echo(f"seed {seed}: running the chain into {out / f'seed-{seed}'}", err=True)
        return chain_progress(base.with_seed(seed), prefix=f"  seed {seed}: ")

    def show(row: dict[str, Any]) -> None:
        name = f"{row['profile']}{' (fallback)' if row.get('fallback') else ''}"
        if row.get("error"):
            typer.echo(f"seed {row['seed']}: {name}: error: {row['error']}")
        elif "robust_heldout_rate" in row:
            typer.echo(
                f"seed {row['seed']}: {name} {row['robust_100']}/{row['campaign_runs']} "
                f"{row['loop']} loop, held-out {100 * row['robust_heldout_rate']:.2f} % of "
                f"{row['heldout_runs']} (95 % bound {100 * row['robust_heldout_upper_95']:.2f} %, "
                f"{row['robust_heldout_verdict']}), "
                f"premium {100 * row['premium']:.1f} %"
            )

    def estimate(times: dict[str, Span], left: int) -> None:
        typer.echo(f"{left} of {len(chosen)} seeds to run; {describe(times, times=left)}", err=True)

    with continue_hint(out, "continue it with the same command and --resume"):  # seeds kept
        study = run_study(
            base, chosen, out, resume=resume, progress=progress, on_row=show, on_estimate=estimate
        )
    typer.echo(f"wrote {out / 'study.md'} ({study['wall_s'] / 60:.1f} min)")
