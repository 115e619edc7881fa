"""`crank`: generate datasets on the twin, train the PPANN, solve the OCPs, replay them on the twin.

Every command turns a bad input into one line on stderr and exit code 2, with nothing written at
the target path.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from common.atomic import OutputError, check_suffix
from control.config import OCPConfig, OCPConfigError
from crank.console import (
    HELDOUT_SEED,
    Amplitude,
    Confidence,
    Drift,
    EpisodeSeconds,
    EpochBars,
    FeedbackOption,
    ModelPath,
    Progress,
    Seconds,
    Seed,
    VariabilityOption,
    app,
    one_line_errors,
    print_heldout,
    print_replay,
    print_summary,
    show_iteration,
)
from ppann.train_config import TrainConfig
from replay.config import PROFILES, ReplayConfig, ReplayConfigError
from twin import MODEL_PATH, __version__
from twin.excitation import Excitation
from twin.variability import Variability

if TYPE_CHECKING:
    from twin.dataset import GenerationConfig


def generate_dataset(
    *, config: GenerationConfig, out: Path, model_path: Path, figures: bool = True
) -> dict[str, Any]:
    """`generate_file` with progress bars."""
    from twin.generation import generate_file

    with (
        Progress(config.n_samples, "simulating") as sim,
        Progress(config.n_samples, "writing MCAP") as io,
    ):
        return generate_file(
            config,
            out=out,
            model_path=model_path,
            figures=figures,
            on_simulated=sim.update,
            on_written=io.update,
        )


def _config(
    *,
    seconds: float,
    seed: int,
    episode_seconds: float,
    drift: bool,
    amplitude: float,
    variability: str,
) -> GenerationConfig:
    from twin.dataset import GenerationConfig

    return GenerationConfig(
        seconds=seconds,
        seed=seed,
        episode_seconds=episode_seconds,
        variability=Variability.resolve(variability, drift=drift),
        excitation=Excitation(amplitude=amplitude),
    )


@app.command("generate", short_help="Simulate the twin; write a 500 Hz dataset MCAP.")
@one_line_errors
def generate_command(
    seconds: Seconds = 90.0,
    seed: Seed = 0,
    out: Annotated[Path, typer.Option(help="Dataset MCAP to write.")] = Path("logs/dataset.mcap"),
    episode_seconds: EpisodeSeconds = 10.0,
    drift: Drift = True,
    amplitude: Amplitude = Excitation.amplitude,
    variability: VariabilityOption = "paper",
    model: ModelPath = MODEL_PATH,
    figures: Annotated[bool, typer.Option(help="Write coverage and excitation PNGs.")] = True,
) -> None:
    """Simulate the twin under semi-random torque and write a 500 Hz dataset MCAP."""
    config = _config(
        seconds=seconds,
        seed=seed,
        episode_seconds=episode_seconds,
        drift=drift,
        amplitude=amplitude,
        variability=variability,
    )
    summary = generate_dataset(config=config, out=out, model_path=model, figures=figures)
    print_summary(f"wrote {out}", summary)


@app.command("inspect", short_help="Check a dataset MCAP against the contract; print its summary.")
@one_line_errors
def inspect_command(
    path: Annotated[Path, typer.Argument(help="A dataset MCAP.")],
) -> None:
    """Check a dataset MCAP against the contract and print its summary."""
    from twin.dataset import summarize
    from twin.mcap_dataset import read_dataset, read_truth

    dataset = read_dataset(path)
    truth = read_truth(path)
    print_summary(f"{path}: seed {dataset.run.get('seed')}", summarize(dataset, truth))


def train_models(*, data: Path, out: Path, config: TrainConfig) -> dict[str, Any]:
    """`train_and_report` with progress bars."""
    from ppann.pipeline import train_and_report

    bars = EpochBars({"mean": config.max_epochs, "sigma": config.sigma_epochs})
    try:
        return train_and_report(
            data, out, config=config, on_epoch=bars, on_stage=lambda _: bars.close()
        )
    finally:
        bars.close()


@app.command(
    "train", short_help="Train the PPANN and both baselines; write checkpoints and report."
)
@one_line_errors
def train_command(
    data: Annotated[Path, typer.Option(help="Dataset MCAP.")] = Path("logs/dataset.mcap"),
    out: Annotated[Path, typer.Option(help="PPANN checkpoint to write.")] = Path("logs/model.pt"),
    epochs: Annotated[int, typer.Option(help="Most phase-1 epochs (early stopping).")] = (
        TrainConfig.max_epochs
    ),
    sigma_epochs: Annotated[int, typer.Option(help="Phase-2 epochs.")] = TrainConfig.sigma_epochs,
    horizon: Annotated[int, typer.Option(help="N-step-ahead horizon Ns.")] = TrainConfig.horizon,
    sigma_block: Annotated[
        int, typer.Option(help="Phase 2 fits the spread on residual sums over this many samples.")
    ] = TrainConfig.sigma_block,
    seed: Seed = 0,
) -> None:
    """Train the PPANN and both baselines; write checkpoints and the validation report."""
    from crank.report import train_summary

    config = TrainConfig(
        max_epochs=epochs,
        sigma_epochs=sigma_epochs,
        horizon=horizon,
        sigma_block=sigma_block,
        seed=seed,
    )
    report = train_models(data=data, out=out, config=config)
    print_summary(f"wrote {out} and its report", train_summary(report))


def _samples(text: str) -> tuple[int, ...]:
    try:
        return tuple(int(part) for part in text.split(","))
    except ValueError:
        raise OCPConfigError(
            f"--samples must be comma-separated integers like 50,100, got {text!r}"
        ) from None


@app.command("solve", short_help="Nominal (eqs. 10, 15) and robust (eq. 16) OCP; write ocp.json.")
@one_line_errors
def solve_command(
    model: Annotated[Path, typer.Option(help="PPANN checkpoint.")] = Path("logs/model.pt"),
    out: Annotated[Path, typer.Option(help="OCP result to write.")] = Path("logs/ocp.json"),
    horizon: Annotated[int, typer.Option(help="N, samples.")] = OCPConfig.horizon,
    height: Annotated[float, typer.Option(help="Slider lower bound, m.")] = OCPConfig.height,
    samples: Annotated[str, typer.Option(help="1-based constraint samples, comma-separated.")] = (
        "50,100"
    ),
    k_sigma: Annotated[float, typer.Option(help="k of the robust k·σ tightening.")] = (
        OCPConfig.k_sigma
    ),
    mc_samples: Annotated[
        int, typer.Option(help="Monte-Carlo trajectories; 0 = enough for the tightening.")
    ] = OCPConfig.mc_samples,
    mc_mode: Annotated[
        str, typer.Option(help="Monte-Carlo: mixed (machines + white), step (eq. 11), machine.")
    ] = OCPConfig.mc_mode,
    tightening: Annotated[
        str, typer.Option(help="gaussian (k·σ, eq. 16) or quantile (at Φ(−k)).")
    ] = OCPConfig.tightening,
    confidence: Confidence = OCPConfig.confidence,
    feedback: FeedbackOption = OCPConfig.feedback,
    torque_limit: Annotated[float, typer.Option(help="|τ| bound, N·m.")] = OCPConfig.torque_limit,
    theta_start: Annotated[float, typer.Option(help="θ_1, rad.")] = OCPConfig.theta_start,
    theta_end: Annotated[float, typer.Option(help="θ_N, rad.")] = OCPConfig.theta_end,
    seed: Annotated[int, typer.Option(help="Seed of the Monte-Carlo draws.")] = 0,
) -> None:
    """Nominal OCP (eqs. 10, 15) and robust OCP (eq. 16) on a PPANN; write ocp.json + figures."""
    from control.solve import figure_paths, solve_file
    from crank.report import solve_summary, solve_timing

    config = OCPConfig(
        horizon=horizon,
        height=height,
        constraint_samples=_samples(samples),
        k_sigma=k_sigma,
        mc_samples=mc_samples,
        mc_mode=mc_mode,
        tightening=tightening,
        confidence=confidence,
        feedback=feedback,
        torque_limit=torque_limit,
        theta_start=theta_start,
        theta_end=theta_end,
        mc_seed=seed,
    )
    payload = solve_file(model, out, config=config, on_iteration=show_iteration)
    figures = ", ".join(str(p) for p in figure_paths(out).values())
    print_summary(f"wrote {out} and {figures}", solve_summary(payload) | solve_timing(payload))


def _modes(text: str) -> tuple[str, ...]:
    """--modes text as a tuple; ReplayConfig says what is wrong with its contents."""
    return tuple(part.strip() for part in text.split(",") if part.strip())


def replay_campaign(
    *, ocp: Path, out: Path, config: ReplayConfig, model: Path, resolved: dict[str, Any]
) -> dict[str, Any]:
    """`replay_file` with a progress bar over the runs."""
    from replay.files import replay_file

    total = config.runs * len(PROFILES) * len(config.modes)
    with Progress(total, "replaying", unit="run") as bar:
        done = 0

        def on_run(n: int) -> None:
            nonlocal done
            bar.update(n - done)
            done = n

        return replay_file(
            ocp, out, config=config, model_path=model, resolved=resolved, on_run=on_run
        )


@app.command("replay", short_help="Play both torques on fresh twins; write MCAP, stats, Rerun.")
@one_line_errors
def replay_command(
    ocp: Annotated[Path, typer.Option(help="ocp.json from crank solve.")] = Path("logs/ocp.json"),
    runs: Annotated[int, typer.Option(help="Machines (runs) per profile and mode.")] = (
        ReplayConfig.runs
    ),
    seed: Annotated[int, typer.Option(help="Seed of the machines and disturbances.")] = 0,
    out: Annotated[Path, typer.Option(help="Campaign log MCAP to write.")] = Path(
        "logs/replay.mcap"
    ),
    modes: Annotated[str, typer.Option(help="open, closed or open,closed.")] = "open,closed",
    feedback: Annotated[
        str, typer.Option(help="Closed loop: lqr (the profile's gains from ocp.json) or pd.")
    ] = ReplayConfig.feedback,
    kp: Annotated[float, typer.Option(help="PD: N·m/rad on the angle error.")] = (ReplayConfig.kp),
    kd: Annotated[float, typer.Option(help="PD: N·m·s/rad on the speed error.")] = (
        ReplayConfig.kd
    ),
    max_start_time: Annotated[
        float, typer.Option(help="Machines have run U[0, this] s before (warm-up drift).")
    ] = ReplayConfig.max_start_time,
    variability: Annotated[
        str | None,
        typer.Option(
            help="Scenario or range file of the machines (default: the one in ocp.json, which "
            "is the training dataset's)."
        ),
    ] = None,
    model: ModelPath = MODEL_PATH,
) -> None:
    """Play the nominal and robust torque on freshly drawn twins, open and closed loop: the
    campaign MCAP, <stem>.stats.json, <stem>.png (Fig. 12) and <stem>.rrd (Rerun)."""
    from replay.files import ocp_variability

    check_suffix(out, ".mcap")  # before ocp.json is read for its scenario
    config = ReplayConfig(
        runs=runs,
        seed=seed,
        modes=_modes(modes),
        feedback=feedback,
        kp=kp,
        kd=kd,
        max_start_time=max_start_time,
        variability=(
            ocp_variability(ocp) if variability is None else Variability.resolve(variability)
        ),
    )
    resolved = {
        "command": "crank replay",
        "argv": sys.argv[1:],
        "ocp": str(ocp),
        "replay": config.as_dict(),
        "model": str(model),
        "project_version": __version__,
    }
    stats = replay_campaign(ocp=ocp, out=out, config=config, model=model, resolved=resolved)
    print_replay(stats, out)


@app.command("heldout", short_help="Check both torques of an ocp.json on held-out machines.")
@one_line_errors
def heldout_command(
    ocp: Annotated[Path, typer.Option(help="ocp.json from crank solve.")] = Path("logs/ocp.json"),
    model: Annotated[Path, typer.Option(help="The PPANN checkpoint the OCP was solved on.")] = (
        Path("logs/model.pt")
    ),
    runs: Annotated[int, typer.Option(help="Held-out machines per profile.")] = 1000,
    seed: Annotated[int, typer.Option(help="Root seed of the held-out machines.")] = (HELDOUT_SEED),
    out: Annotated[Path, typer.Option(help="heldout.json to write.")] = Path("logs/heldout.json"),
    variability: Annotated[
        str | None,
        typer.Option(help="Scenario or range file (default: the one in ocp.json)."),
    ] = None,
    mode: Annotated[
        str, typer.Option(help="open, or closed (each profile's LQR gains from ocp.json).")
    ] = "open",
    mjcf: Annotated[Path, typer.Option("--mjcf", help="The slider-crank MJCF.")] = MODEL_PATH,
) -> None:
    """Both torques of an ocp.json, open or closed loop, on held-out machines: violation rates
    with exact 95 % bounds, and predicted against observed spread for every Monte-Carlo mode."""
    from replay.files import ocp_variability
    from replay.heldout import heldout_file

    check_suffix(out, ".json")  # before ocp.json is read for its scenario
    if mode not in ("open", "closed"):
        raise ReplayConfigError(f"mode must be open or closed, got {mode!r}")
    ReplayConfig(runs=runs, seed=seed)  # validates runs and seed before any file is read
    chosen = ocp_variability(ocp) if variability is None else Variability.resolve(variability)
    result = heldout_file(
        ocp,
        out,
        model=model,
        runs=runs,
        seed=seed,
        variability=chosen,
        mode=mode,
        model_path=mjcf,
    )
    print_heldout(result)
    typer.echo(f"wrote {out}")


@app.command("recover", short_help="Rebuild a readable MCAP from a crashed campaign's file.")
@one_line_errors
def recover_command(
    broken: Annotated[Path, typer.Argument(help="MCAP left by a crashed campaign (.partial).")],
    fixed: Annotated[Path, typer.Argument(help="Indexed MCAP to write.")],
) -> None:
    """Rebuild a readable, indexed MCAP from what a crashed campaign writer left."""
    from replay.campaign_log import recover

    result = recover(broken, fixed)
    state = "was complete" if result.complete else "was cut short"
    typer.echo(
        f"wrote {fixed}: {result.runs} complete runs, {result.messages} messages "
        f"({result.dropped_messages} of an unfinished run dropped); {broken} {state}"
    )


def _has_display() -> bool:
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")) or (
        sys.platform in ("darwin", "win32")
    )


@app.command("view", short_help="Open a recording in the Rerun viewer.")
@one_line_errors
def view_command(
    path: Annotated[Path, typer.Argument(help="A campaign's .rrd (or an .mcap log).")],
) -> None:
    """Open a recording in the Rerun viewer, or say how to open it where there is no display."""
    from replay.recording import check_recording, rerun_version

    if not path.is_file():
        raise OutputError(f"file not found: {path}")
    if path.suffix == ".mcap":
        typer.echo(
            f"{path} is an MCAP log: open it in Foxglove (Open local file), or view the "
            f"Rerun recording beside it: crank view {path.with_suffix('.rrd')}"
        )
        return
    if path.suffix != ".rrd":
        raise OutputError(f"crank view opens .rrd recordings (or names .mcap logs), got {path}")
    check_recording(path)
    if not _has_display():
        typer.echo(
            f"no display here: copy {path} to a machine with a display and run "
            f"`rerun {path.name}` (rerun-sdk {rerun_version()}), or drop it on the Rerun "
            "web viewer of the same version"
        )
        return
    subprocess.Popen([sys.executable, "-m", "rerun", str(path)], start_new_session=True)
    typer.echo(f"opened {path} in the Rerun viewer")


def main() -> None:
    """The `crank` entry point: the app, with click's usage errors (an unknown option, a value
    that does not parse) as one `error:` line and exit code 2 like every other input error."""
    import crank.cli_chain  # noqa: F401  (registers `run` and `study` on the app)

    try:
        code = app(standalone_mode=False)
    except typer.TyperException as exc:  # click's UsageError, BadParameter, NoSuchOption, ...
        if type(exc).__name__ == "NoArgsIsHelpError":  # bare `crank`: the help, as click does
            typer.echo(exc.ctx.get_help(), err=True)  # type: ignore[attr-defined]
            sys.exit(2)
        message = exc.format_message() if hasattr(exc, "format_message") else str(exc)
        typer.echo(f"error: {' '.join(message.split())}", err=True)
        sys.exit(getattr(exc, "exit_code", 2))
    except typer.Abort:
        typer.echo("error: aborted", err=True)
        sys.exit(1)
    sys.exit(code if isinstance(code, int) else 0)
