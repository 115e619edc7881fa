"""`crank`: generate datasets on the twin, train the PPANN, solve the OCPs (next: replay).

Every command turns a bad input into one line on stderr and exit code 2, with nothing written at
the target path.
"""

from __future__ import annotations

import functools
import json
import sys
from collections.abc import Callable
from datetime import UTC, datetime
from pathlib import Path
from typing import Annotated, Any

import typer
from tqdm import tqdm

from control.ocp import OCPConfig, OCPConfigError, OCPError
from control.ocp_file import OCPFileError
from control.robust import Iteration, RobustError
from control.solve import figure_paths, solve_file
from ppann.checkpoint import CheckpointError
from ppann.data import DataError
from ppann.model import ModelConfigError
from ppann.pipeline import train_and_report
from ppann.train import TrainConfig, TrainConfigError
from twin import __version__
from twin.atomic import OutputError, atomic_path, check_writable
from twin.dataset import GenerationConfig, summarize
from twin.excitation import Excitation
from twin.generation import generate_file
from twin.mcap_dataset import ContractError, read_dataset, read_truth
from twin.physics import MODEL_PATH, ModelError
from twin.variability import ConfigError, Variability

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,
    help="MuJoCo slider-crank twin and PPANN robust-control testbed.",
)

USER_ERRORS = (
    ConfigError,
    ModelError,
    ContractError,
    OutputError,
    DataError,
    CheckpointError,
    TrainConfigError,
    ModelConfigError,
    OCPConfigError,
    OCPError,
    RobustError,
    OCPFileError,
)


def _one_line_errors(command: Callable[..., Any]) -> Callable[..., Any]:
    """Turn the project's input errors into `error: ...` on stderr and exit code 2."""

    @functools.wraps(command)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return command(*args, **kwargs)
        except USER_ERRORS as exc:
            typer.echo(f"error: {exc}", err=True)
            raise typer.Exit(2) from None
        except KeyboardInterrupt:
            typer.echo("error: interrupted; nothing was written at the target path", err=True)
            raise typer.Exit(130) from None

    return wrapper


class _Progress:
    """A progress bar on stderr, created at its first update and shown only if the step takes
    more than 2 s, so short runs print nothing but their result."""

    def __init__(self, total: int, desc: str) -> None:
        self.total, self.desc, self.bar = total, desc, None

    def update(self, n: int) -> None:
        if self.bar is None:
            self.bar = tqdm(
                total=self.total,
                desc=self.desc,
                unit="sample",
                unit_scale=True,
                delay=2.0,
                leave=False,
            )
        self.bar.update(n)

    def __enter__(self) -> _Progress:
        return self

    def __exit__(self, *exc: object) -> None:
        if self.bar is not None:
            self.bar.close()


def generate_dataset(
    *, config: GenerationConfig, out: Path, model_path: Path, figures: bool = True
) -> dict[str, Any]:
    """`generate_file` with progress bars."""
    with (
        _Progress(config.n_samples, "simulating") as sim,
        _Progress(config.n_samples, "writing MCAP") as io,
    ):
        return generate_file(
            config,
            out=out,
            model_path=model_path,
            figures=figures,
            on_simulated=sim.update,
            on_written=io.update,
        )


def _print_summary(title: str, summary: dict[str, Any]) -> None:
    typer.echo(title)
    width = max(len(k) for k in summary)
    for key, value in summary.items():
        shown = f"{value:.6g}" if isinstance(value, float) else str(value)
        typer.echo(f"  {key:<{width}}  {shown}")


def _config(
    *, seconds: float, seed: int, episode_seconds: float, drift: bool, amplitude: float
) -> GenerationConfig:
    return GenerationConfig(
        seconds=seconds,
        seed=seed,
        episode_seconds=episode_seconds,
        variability=Variability(drift=drift),
        excitation=Excitation(amplitude=amplitude),
    )


Seconds = Annotated[float, typer.Option(help="Duration of the dataset in s (500 Hz samples).")]
Seed = Annotated[int, typer.Option(help="Seed of every random draw.")]
EpisodeSeconds = Annotated[float, typer.Option(help="Length of one episode (machine draw) in s.")]
Drift = Annotated[bool, typer.Option(help="Friction drifts as each machine warms up.")]
Amplitude = Annotated[float, typer.Option(help="Peak excitation torque level in N·m.")]
ModelPath = Annotated[Path, typer.Option("--model", help="The slider-crank MJCF.")]


@app.command("generate")
@_one_line_errors
def generate_command(
    seconds: Seconds = 90.0,
    seed: Seed = 0,
    out: Annotated[Path, typer.Option(help="Dataset MCAP to write.")] = Path("logs/dataset.mcap"),
    episode_seconds: EpisodeSeconds = 10.0,
    drift: Drift = True,
    amplitude: Amplitude = Excitation.amplitude,
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
    )
    summary = generate_dataset(config=config, out=out, model_path=model, figures=figures)
    _print_summary(f"wrote {out}", summary)


@app.command("inspect")
@_one_line_errors
def inspect_command(
    path: Annotated[Path, typer.Argument(help="A dataset MCAP.")],
) -> None:
    """Check a dataset MCAP against the contract and print its summary."""
    dataset = read_dataset(path)
    truth = read_truth(path)
    _print_summary(f"{path}: seed {dataset.run.get('seed')}", summarize(dataset, truth))


class _EpochBars:
    """One progress bar per model and phase, showing the latest loss."""

    def __init__(self, epochs: dict[str, int]) -> None:
        self.epochs, self.bar, self.key = epochs, None, None

    def __call__(self, kind: str, phase: str, epoch: int, loss: float) -> None:
        if (kind, phase) != self.key:
            self.close()
            self.key = (kind, phase)
            self.bar = tqdm(
                total=self.epochs[phase], desc=f"{kind} {phase}", unit="epoch", leave=False
            )
        self.bar.update(1)
        self.bar.set_postfix(loss=f"{loss:.4g}")

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def train_models(*, data: Path, out: Path, config: TrainConfig) -> dict[str, Any]:
    """`train_and_report` with progress bars."""
    bars = _EpochBars({"mean": config.max_epochs, "sigma": config.sigma_epochs})
    try:
        return train_and_report(data, out, config=config, on_epoch=bars)
    finally:
        bars.close()


def _train_summary(report: dict[str, Any]) -> dict[str, Any]:
    rows: dict[str, Any] = {}
    for kind, entry in report["models"].items():
        r10 = entry["rmse_10_step"]
        rows[f"{kind} 10-step RMSE θ / ω"] = f"{r10['theta']:.4f} rad / {r10['omega']:.3f} rad/s"
    for mode in ("step", "trajectory"):
        c = report["calibration"][mode]
        rows[f"σ predicted/observed ({mode})"] = (
            f"θ {c['theta']['median']:.2f}, slider {c['slider_position']['median']:.2f}"
        )
    rows["PPANN training"] = f"{report['models']['ppann']['train_seconds']:.1f} s"
    return rows


@app.command("train")
@_one_line_errors
def train_command(
    data: Annotated[Path, typer.Option(help="Dataset MCAP.")] = Path("logs/dataset.mcap"),
    out: Annotated[Path, typer.Option(help="PPANN checkpoint to write.")] = Path("logs/model.pt"),
    epochs: Annotated[int, typer.Option(help="Most phase-1 epochs (early stopping).")] = (
        TrainConfig.max_epochs
    ),
    sigma_epochs: Annotated[int, typer.Option(help="Phase-2 epochs.")] = TrainConfig.sigma_epochs,
    horizon: Annotated[int, typer.Option(help="N-step-ahead horizon Ns.")] = TrainConfig.horizon,
    seed: Seed = 0,
) -> None:
    """Train the PPANN and both baselines; write checkpoints and the validation report."""
    config = TrainConfig(max_epochs=epochs, sigma_epochs=sigma_epochs, horizon=horizon, seed=seed)
    report = train_models(data=data, out=out, config=config)
    _print_summary(f"wrote {out} and its report", _train_summary(report))


@app.command("run")
@_one_line_errors
def run_command(
    seconds: Seconds = 90.0,
    seed: Seed = 0,
    logs: Annotated[Path, typer.Option(help="Output root; the run goes in logs/<run>/.")] = Path(
        "logs"
    ),
    name: Annotated[str | None, typer.Option(help="Run folder name (default: time stamp).")] = None,
    episode_seconds: EpisodeSeconds = 10.0,
    drift: Drift = True,
    model: ModelPath = MODEL_PATH,
) -> None:
    """The whole chain into logs/<run>/. So far: generate, train and validate, solve the OCPs."""
    config = _config(
        seconds=seconds,
        seed=seed,
        episode_seconds=episode_seconds,
        drift=drift,
        amplitude=Excitation.amplitude,
    )
    train_config = TrainConfig(seed=seed)
    ocp_config = OCPConfig(mc_seed=seed)
    name = name or datetime.now(UTC).strftime("%Y%m%d-%H%M%S") + f"-seed{seed}"
    run_dir = logs / name
    if run_dir.exists():
        raise OutputError(f"run folder already exists: {run_dir}")
    resolved = {
        "command": "crank run",
        "argv": sys.argv[1:],
        "seed": seed,
        "generate": config.as_dict(),
        "train": train_config.as_dict(),
        "solve": ocp_config.as_dict(),
        "model": str(model),
        "project_version": __version__,
    }
    check_writable(run_dir / "config.json")
    _write_json(run_dir / "config.json", resolved)
    summary = generate_dataset(config=config, out=run_dir / "dataset.mcap", model_path=model)
    trained = train_models(
        data=run_dir / "dataset.mcap", out=run_dir / "model.pt", config=train_config
    )
    solved = solve_ocp(model=run_dir / "model.pt", out=run_dir / "ocp.json", config=ocp_config)
    report = {
        "config": resolved,
        "dataset": summary,
        "ppann": trained,
        "ocp": _solve_summary(solved),
    }
    _write_json(run_dir / "report.json", report)
    _print_summary(f"run {run_dir}: dataset", summary)
    _print_summary("PPANN", _train_summary(trained))
    _print_summary("OCP", _solve_summary(solved))


def _samples(text: str) -> tuple[int, ...]:
    try:
        return tuple(int(part) for part in text.split(","))
    except ValueError:
        raise OCPConfigError(
            f"--samples must be comma-separated integers like 50,100, got {text!r}"
        ) from None


def solve_ocp(*, model: Path, out: Path, config: OCPConfig) -> dict[str, Any]:
    """`solve_file`, printing each robust iteration's margins on stderr."""

    def show(it: Iteration) -> None:
        margin = ", ".join(f"{1e3 * v:.2f}" for v in it.margin)
        k_sigma = ", ".join(f"{1e3 * v:.2f}" for v in it.k_sigma)
        typer.echo(
            f"  robust iteration: margin [{margin}] mm -> kσ [{k_sigma}] mm, cost {it.cost:.5g}",
            err=True,
        )

    return solve_file(model, out, config=config, on_iteration=show)


def _solve_summary(payload: dict[str, Any]) -> dict[str, Any]:
    n, r = payload["nominal"], payload["robust"]
    t = payload["timing"]
    return {
        "nominal cost": n["cost"],
        "robust cost": f"{r['cost']:.6g} ({r['cost'] / n['cost'] - 1:+.1%})",
        "robust iterations": len(payload["robust_iterations"]),
        "final margins": ", ".join(
            f"{1e3 * (h - payload['config']['height']):.2f} mm" for h in r["heights"]
        ),
        "nominal solve": f"{t['nominal_solve_s']:.2f} s",
        "robust loop": f"{t['robust_loop_s']:.2f} s",
    }


@app.command("solve")
@_one_line_errors
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
    mc_samples: Annotated[int, typer.Option(help="Monte-Carlo trajectories.")] = (
        OCPConfig.mc_samples
    ),
    mc_mode: Annotated[str, typer.Option(help="z draws: step (eq. 11) or trajectory.")] = (
        OCPConfig.mc_mode
    ),
    torque_limit: Annotated[float, typer.Option(help="|τ| bound, N·m.")] = OCPConfig.torque_limit,
    theta_start: Annotated[float, typer.Option(help="θ_1, rad.")] = OCPConfig.theta_start,
    theta_end: Annotated[float, typer.Option(help="θ_N, rad.")] = OCPConfig.theta_end,
    seed: Annotated[int, typer.Option(help="Seed of the Monte-Carlo draws.")] = 0,
) -> None:
    """Nominal OCP (eqs. 10, 15) and robust OCP (eq. 16) on a PPANN; write ocp.json + figures."""
    config = OCPConfig(
        horizon=horizon,
        height=height,
        constraint_samples=_samples(samples),
        k_sigma=k_sigma,
        mc_samples=mc_samples,
        mc_mode=mc_mode,
        torque_limit=torque_limit,
        theta_start=theta_start,
        theta_end=theta_end,
        mc_seed=seed,
    )
    payload = solve_ocp(model=model, out=out, config=config)
    figures = ", ".join(str(p) for p in figure_paths(out).values())
    _print_summary(f"wrote {out} and {figures}", _solve_summary(payload))


def _write_json(path: Path, payload: dict[str, Any]) -> None:
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(payload, indent=2) + "\n")


def main() -> None:
    app()
