"""`crank`: generate datasets on the twin, train the PPANN, solve the OCPs, replay them on the twin.

Every command turns a bad input into one line on stderr and exit code 2, with nothing written at
the target path.
"""

from __future__ import annotations

import functools
import json
import os
import subprocess
import sys
import time
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
from crank.report import solve_summary, train_summary, write_markdown
from ppann.checkpoint import CheckpointError
from ppann.data import DataError
from ppann.model import ModelConfigError
from ppann.pipeline import finite_or_none, train_and_report
from ppann.train import TrainConfig, TrainConfigError
from replay.campaign import PROFILES, ReplayConfig, ReplayConfigError
from replay.campaign_log import RecoverError, recover
from replay.files import output_paths, replay_file
from replay.recording import RecordingError, check_recording, rerun_version
from replay.statistics import format_table, summary_rows
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
    ReplayConfigError,
    RecoverError,
    RecordingError,
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
            typer.echo("error: interrupted; no unfinished file was put at a target path", err=True)
            raise typer.Exit(130) from None

    return wrapper


class _Progress:
    """A progress bar on stderr, created at its first update and shown only if the step takes
    more than 2 s, so short runs print nothing but their result."""

    def __init__(self, total: int, desc: str, *, unit: str = "sample") -> None:
        self.total, self.desc, self.unit, self.bar = total, desc, unit, None

    def update(self, n: int) -> None:
        if self.bar is None:
            self.bar = tqdm(
                total=self.total,
                desc=self.desc,
                unit=self.unit,
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
    _print_summary(f"wrote {out} and its report", train_summary(report))


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
    runs: Annotated[int, typer.Option(help="Replay machines per profile and mode.")] = (
        ReplayConfig.runs
    ),
    model: ModelPath = MODEL_PATH,
) -> None:
    """The whole chain into logs/<run>/: generate, train and validate, solve the OCPs, replay
    them on the twin open and closed loop, report (report.json, report.md, figures)."""
    config = _config(
        seconds=seconds,
        seed=seed,
        episode_seconds=episode_seconds,
        drift=drift,
        amplitude=Excitation.amplitude,
    )
    train_config = TrainConfig(seed=seed)
    ocp_config = OCPConfig(mc_seed=seed)
    replay_config = ReplayConfig(runs=runs, seed=seed)
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
        "replay": replay_config.as_dict(),
        "model": str(model),
        "project_version": __version__,
    }
    check_writable(run_dir / "config.json")
    _write_json(run_dir / "config.json", resolved)
    started = time.perf_counter()
    steps: dict[str, float] = {}

    def lap(step: str, t0: float) -> None:
        steps[step] = time.perf_counter() - t0

    t0 = time.perf_counter()
    summary = generate_dataset(config=config, out=run_dir / "dataset.mcap", model_path=model)
    lap("generate", t0)
    t0 = time.perf_counter()
    trained = train_models(
        data=run_dir / "dataset.mcap", out=run_dir / "model.pt", config=train_config
    )
    lap("train", t0)
    t0 = time.perf_counter()
    solved = solve_ocp(model=run_dir / "model.pt", out=run_dir / "ocp.json", config=ocp_config)
    lap("solve", t0)
    t0 = time.perf_counter()
    stats = replay_campaign(
        ocp=run_dir / "ocp.json",
        out=run_dir / "replay.mcap",
        config=replay_config,
        model=model,
        resolved=resolved,
    )
    lap("replay", t0)
    steps["total"] = time.perf_counter() - started
    report = {
        "config": resolved,
        "dataset": summary,
        "ppann": trained,
        "ocp": solve_summary(solved),
        "replay": {
            "claim": stats["claim"],
            "robust_cost_premium": stats["ocp"]["robust_cost_premium"],
            "table": summary_rows(stats),
            "stats": output_paths(run_dir / "replay.mcap")["stats"].name,
        },
        "wall_seconds": steps,
    }
    _write_json(run_dir / "report.json", report)
    write_markdown(run_dir / "report.md", report, stats=stats)
    _print_summary(f"run {run_dir}: dataset", summary)
    _print_summary("PPANN", train_summary(trained))
    _print_summary("OCP", solve_summary(solved))
    typer.echo("replay on the twin")
    _print_replay(stats, run_dir / "replay.mcap")
    typer.echo(
        "wall time: "
        + ", ".join(f"{k} {v:.0f} s" for k, v in steps.items())
        + f"; report: {run_dir / 'report.md'}"
    )


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
        kind = "draft" if it.draft else "full "
        typer.echo(
            f"  robust iteration ({kind}): margin [{margin}] mm -> kσ [{k_sigma}] mm, "
            f"cost {it.cost:.5g}, {it.ipopt_iterations} IPOPT iterations",
            err=True,
        )

    return solve_file(model, out, config=config, on_iteration=show)


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
    _print_summary(f"wrote {out} and {figures}", solve_summary(payload))


def _modes(text: str) -> tuple[str, ...]:
    """--modes text as a tuple; ReplayConfig says what is wrong with its contents."""
    return tuple(part.strip() for part in text.split(",") if part.strip())


def replay_campaign(
    *, ocp: Path, out: Path, config: ReplayConfig, model: Path, resolved: dict[str, Any]
) -> dict[str, Any]:
    """`replay_file` with a progress bar over the runs."""
    total = config.runs * len(PROFILES) * len(config.modes)
    with _Progress(total, "replaying", unit="run") as bar:
        done = 0

        def on_run(n: int) -> None:
            nonlocal done
            bar.update(n - done)
            done = n

        return replay_file(
            ocp, out, config=config, model_path=model, resolved=resolved, on_run=on_run
        )


def _print_replay(stats: dict[str, Any], out: Path) -> None:
    typer.echo(format_table(summary_rows(stats)))
    claim = stats["claim"]
    if claim["holds"] is not None:
        verdict = "holds" if claim["holds"] else "does NOT hold"
        typer.echo(
            f"claim {verdict}: robust open loop {claim['robust_open_violating_runs']} of "
            f"{stats['config']['runs']} runs below the height, nominal "
            f"{claim['nominal_open_violating_runs']} (needs >= {claim['nominal_needed']})"
        )
    files = ", ".join(str(p) for p in output_paths(out).values())
    typer.echo(f"wrote {files}")


@app.command("replay")
@_one_line_errors
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
    kp: Annotated[float, typer.Option(help="Closed loop: N·m/rad on the angle error.")] = (
        ReplayConfig.kp
    ),
    kd: Annotated[float, typer.Option(help="Closed loop: N·m·s/rad on the speed error.")] = (
        ReplayConfig.kd
    ),
    max_start_time: Annotated[
        float, typer.Option(help="Machines have run U[0, this] s before (warm-up drift).")
    ] = ReplayConfig.max_start_time,
    model: ModelPath = MODEL_PATH,
) -> None:
    """Play the nominal and robust torque on freshly drawn twins, open and closed loop: the
    campaign MCAP, <stem>.stats.json, <stem>.png (Fig. 12) and <stem>.rrd (Rerun)."""
    config = ReplayConfig(
        runs=runs, seed=seed, modes=_modes(modes), kp=kp, kd=kd, max_start_time=max_start_time
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
    _print_replay(stats, out)


@app.command("recover")
@_one_line_errors
def recover_command(
    broken: Annotated[Path, typer.Argument(help="MCAP left by a crashed campaign (.partial).")],
    fixed: Annotated[Path, typer.Argument(help="Indexed MCAP to write.")],
) -> None:
    """Rebuild a readable, indexed MCAP from what a crashed campaign writer left."""
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


@app.command("view")
@_one_line_errors
def view_command(
    path: Annotated[Path, typer.Argument(help="A campaign's .rrd (or an .mcap log).")],
) -> None:
    """Open a recording in the Rerun viewer, or say how to open it where there is no display."""
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


def _write_json(path: Path, payload: dict[str, Any]) -> None:
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(finite_or_none(payload), indent=2, allow_nan=False) + "\n")


def main() -> None:
    app()
