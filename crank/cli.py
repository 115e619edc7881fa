"""`crank`: generate datasets on the twin, train the PPANN, solve the OCPs (the replay stage's
commands are in crank/cli_campaign.py, `view` in crank/cli_view.py, `run` and `study` in
crank/cli_chain.py).

Every command turns a bad input into one line on stderr and exit code 2, with nothing written at
the target path.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from common.atomic import check_output
from control.config import OCPConfig, OCPConfigError
from crank.chain_progress import train_models
from crank.console import (
    DEFAULT_FALLBACK,
    DEFAULT_PROFILES,
    Amplitude,
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
    fallback_list,
    one_line_errors,
    print_summary,
    profiles_list,
    show_iteration,
)
from crank.progress import Progress
from ppann.train_config import TrainConfig
from twin import DATASET_SECONDS, EPISODE_SECONDS, MODEL_PATH, OPERATING_SECONDS
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
    amplitude_spread: float = 0.0,
    variability: str,
    max_start_time: float = OPERATING_SECONDS,
    episodes_per_machine: int = 1,
) -> GenerationConfig:
    from twin.dataset import GenerationConfig

    return GenerationConfig(
        seconds=seconds,
        seed=seed,
        episode_seconds=episode_seconds,
        variability=Variability.resolve(variability, drift=drift),
        excitation=Excitation(amplitude=amplitude, amplitude_spread=amplitude_spread),
        max_start_time=max_start_time,
        episodes_per_machine=episodes_per_machine,
    )


@app.command("generate", short_help="Simulate the twin; write a 500 Hz dataset MCAP.")
@one_line_errors
def generate_command(
    seconds: Seconds = DATASET_SECONDS,
    seed: Seed = 0,
    out: Annotated[Path, typer.Option(help="Dataset MCAP to write.")] = Path("logs/dataset.mcap"),
    episode_seconds: EpisodeSeconds = EPISODE_SECONDS,
    drift: Drift = True,
    amplitude: Amplitude = Excitation.amplitude,
    amplitude_spread: Annotated[
        float,
        typer.Option(
            help="Each episode draws its peak level in [amplitude - this, amplitude] N·m "
            "(0: every episode at --amplitude)."
        ),
    ] = Excitation.amplitude_spread,
    variability: VariabilityOption = "paper",
    model: ModelPath = MODEL_PATH,
    figures: Annotated[bool, typer.Option(help="Write coverage and excitation PNGs.")] = True,
    max_start_time: Annotated[
        float,
        typer.Option(
            help="Each machine has run U[0, this] s before its episode (warm-up drift); the "
            "replays' default, so that training and checked machines are one population."
        ),
    ] = OPERATING_SECONDS,
    episodes_per_machine: EpisodesPerMachine = 1,
) -> None:
    """Simulate the twin under semi-random torque and write a 500 Hz dataset MCAP."""
    check_output("out", out, suffix=".mcap", inputs={"model_path": model})
    config = _config(
        seconds=seconds,
        seed=seed,
        episode_seconds=episode_seconds,
        drift=drift,
        amplitude=amplitude,
        amplitude_spread=amplitude_spread,
        variability=variability,
        max_start_time=max_start_time,
        episodes_per_machine=episodes_per_machine,
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
    if dataset.run.get("source") == "import":  # rig data: no truth channel, no seed
        print_summary(f"{path}: rig data from {dataset.run.get('input')}", summarize(dataset))
        return
    if not dataset.run:  # another tool's measurements: what a learner needs, nothing more
        print_summary(f"{path}: measurements without a run record", summarize(dataset))
        return
    truth = read_truth(path)  # the twin's files carry their truth
    print_summary(f"{path}: seed {dataset.run.get('seed')}", summarize(dataset, truth))


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
    epoch_windows: Annotated[
        int, typer.Option(help="Most training windows per phase-1 epoch (a random subset).")
    ] = TrainConfig.epoch_windows,
    horizon: Annotated[int, typer.Option(help="N-step-ahead horizon Ns.")] = TrainConfig.horizon,
    sigma_block: Annotated[
        int, typer.Option(help="Phase 2 fits the spread on residual sums over this many samples.")
    ] = TrainConfig.sigma_block,
    early_stopping: Annotated[
        str,
        typer.Option(
            help="What phase 1's early stopping scores: machines (the last 3/90 of every "
            "training episode) or tail (the paper's: the validation split, one machine)."
        ),
    ] = TrainConfig.early_stopping,
    sigma_lever: Annotated[
        bool,
        typer.Option(
            help="Fit a white slider force through the kinematics beside the sigma networks."
        ),
    ] = TrainConfig.sigma_lever,
    residual_mean: Annotated[
        bool,
        typer.Option(
            help="Take the residual's mean given each sample's state and torque (the mean "
            "model's own error) out before phase 2 fits the spread."
        ),
    ] = TrainConfig.residual_mean,
    machine_terms: Annotated[
        str,
        typer.Option(
            help="What a machine's log-factors scale: augmented (eq. 14's whole terms) or "
            "prior (the motor's physical terms alone)."
        ),
    ] = TrainConfig.machine_terms,
    mean_wrap: Annotated[
        bool,
        typer.Option(help="Let z_K's mean network see theta mod 2 pi (a load continuous at TDC)."),
    ] = TrainConfig.mean_wrap,
    coulomb: Annotated[
        bool,
        typer.Option(help="Give the PPANN's prior a Coulomb friction torque, fitted in phase 1."),
    ] = TrainConfig.coulomb,
    white_inertia: Annotated[
        str,
        typer.Option(
            help="How the Monte-Carlo draws z_J's white noise: quotient (eq. 14 with z drawn) or "
            "linear (to first order about the mean: zero-mean)."
        ),
    ] = TrainConfig.white_inertia,
    angle_update: Annotated[
        str,
        typer.Option(
            help="How a step moves the angle: euler (eq. 4) or trapezoid (by the mean of the "
            "speeds before and after the step)."
        ),
    ] = TrainConfig.angle_update,
    plan_fit: Annotated[
        bool,
        typer.Option(help="Go on with phase 1 to the plan round's episodes' mean, if any."),
    ] = TrainConfig.plan_fit,
    bound_lines: Annotated[
        int,
        typer.Option(
            help="Lines a candidate of the bounds' calibration by simulation, for a line of "
            "2-32 machines (0: the exact levels of the directly observed case)."
        ),
    ] = TrainConfig.bound_lines,
    seed: Seed = 0,
) -> None:
    """Train the PPANN and both baselines; write checkpoints and the validation report."""
    check_output("out", out, suffix=".pt", inputs={"data_path": data})
    from crank.report import train_summary

    config = TrainConfig(
        max_epochs=epochs,
        sigma_epochs=sigma_epochs,
        epoch_windows=epoch_windows,
        horizon=horizon,
        sigma_block=sigma_block,
        early_stopping=early_stopping,
        sigma_lever=sigma_lever,
        residual_mean=residual_mean,
        machine_terms=machine_terms,
        coulomb=coulomb,
        mean_wrap=mean_wrap,
        white_inertia=white_inertia,
        angle_update=angle_update,
        plan_fit=plan_fit,
        bound_lines=bound_lines,
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
        str,
        typer.Option(
            help="centred (k·σ below the Monte-Carlo's mean), gaussian (k·σ below the plan, "
            "eq. 16) or quantile (at Φ(−k))."
        ),
    ] = OCPConfig.tightening,
    confidence: Confidence = OCPConfig.confidence,
    tail_check: Annotated[
        bool,
        typer.Option(
            "--tail-check/--no-tail-check",
            help="Check each robust torque's own violation rate (20 000 trajectories) and solve "
            "it again where it is above 0.5 % (--tail-remedy).",
        ),
    ] = OCPConfig.tail_check,
    tail_remedy: Annotated[
        str,
        typer.Option(
            help="What the tail check solves such a torque again with: raise-k (the k its "
            "check predicts, then quantile) or quantile."
        ),
    ] = OCPConfig.tail_remedy,
    profiles: ProfilesOption = DEFAULT_PROFILES,
    fallback: FallbackOption = DEFAULT_FALLBACK,
    torque_limit: Annotated[float, typer.Option(help="|τ| bound, N·m.")] = OCPConfig.torque_limit,
    theta_start: Annotated[float, typer.Option(help="θ_1, rad.")] = OCPConfig.theta_start,
    theta_end: Annotated[float, typer.Option(help="θ_N, rad.")] = OCPConfig.theta_end,
    seed: Annotated[int, typer.Option(help="Seed of the Monte-Carlo draws.")] = 0,
    compiled: Annotated[
        bool,
        typer.Option(
            "--compiled/--no-compiled",
            help="Compile the NLP to C first (~6 s more to build, each IPOPT iteration ~3x "
            "cheaper; needs a C compiler, else as without).",
        ),
    ] = OCPConfig.compiled,
    pd_kp: Annotated[
        float, typer.Option(help="robust-pd: the machine's PD, N·m/rad on the angle error.")
    ] = OCPConfig.pd_kp,
    pd_kd: Annotated[
        float, typer.Option(help="robust-pd: the machine's PD, N·m·s/rad on the speed error.")
    ] = OCPConfig.pd_kd,
) -> None:
    """Nominal OCP (eqs. 10, 15) and robust OCP (eq. 16) on a PPANN; write ocp.json + figures."""
    check_output("out", out, suffix=".json", inputs={"model_path": model})
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
        tail_check=tail_check,
        tail_remedy=tail_remedy,
        profiles=tuple(profiles_list(profiles)),
        fallback=tuple(fallback_list(fallback)),
        torque_limit=torque_limit,
        theta_start=theta_start,
        theta_end=theta_end,
        mc_seed=seed,
        compiled=compiled,
        pd_kp=pd_kp,
        pd_kd=pd_kd,
    )
    payload = solve_file(
        model,
        out,
        config=config,
        on_iteration=show_iteration,
        on_fallback=lambda text: typer.echo(f"{text} ...", err=True),
    )
    figures = ", ".join(str(p) for p in figure_paths(out, tuple(payload["profiles"])).values())
    print_summary(f"wrote {out} and {figures}", solve_summary(payload) | solve_timing(payload))


def main() -> None:
    """The `crank` entry point: the app, with click's usage errors (an unknown option, a value
    that does not parse) as one `error:` line and exit code 2 like every other input error."""
    # register the other commands on the app, in the help's order: replay, heldout, recover
    # (crank/cli_campaign.py), view (crank/cli_view.py), run and study (crank/cli_chain.py),
    # import and export (crank/cli_import.py), sweep (crank/cli_sweep.py)
    import crank.cli_campaign  # noqa: I001 (the help's order, not the alphabet's)
    import crank.cli_view
    import crank.cli_chain
    import crank.cli_import
    import crank.cli_sweep  # noqa: F401

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
