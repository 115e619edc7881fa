"""`crank replay`, `heldout` and `recover`: the replay stage's commands (registered on
the app by crank/cli.py's `main`). Like every command, a bad input is one line on stderr and exit
code 2, with nothing written at the target path; the engines are imported inside each command."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from common.atomic import check_output
from common.checks import check_count
from control.mpc_config import MPCConfig, MPCConfigError
from crank.console import (
    HELDOUT_SEED,
    ModelPath,
    PDKd,
    PDKp,
    app,
    one_line_errors,
    print_heldout,
    print_replay,
)
from crank.progress import Progress
from replay.config import MAX_RUNS, ReplayConfig, played_line
from replay.rates import SECOND_STAGE, TARGET_RATE, machines_to_confirm, second_stage_end
from replay.spread_interval import CALIBRATION_TRAJECTORIES
from twin import MODEL_PATH, __version__
from twin.variability import Variability

if TYPE_CHECKING:
    from control.ocp_file import OCPFile


def _modes(text: str) -> tuple[str, ...]:
    """--modes text as a tuple; ReplayConfig says what is wrong with its contents."""
    return tuple(part.strip() for part in text.split(",") if part.strip())


MPCHorizon = Annotated[
    int, typer.Option("--mpc-horizon", help="mpc mode: samples predicted at each step.")
]
MPCWeights = Annotated[
    str,
    typer.Option(
        "--mpc-weights",
        help="mpc mode: q_theta,q_omega,r of the tracking cost (default: the LQR's, Bryson's "
        "rule on 20 mrad, 1 rad/s, 1 N·m).",
    ),
]
MPCDeadline = Annotated[
    float, typer.Option("--mpc-deadline-ms", help="mpc mode: compute time allowed per step.")
]
MPCSliderLimit = Annotated[
    bool,
    typer.Option(
        "--mpc-slider-limit/--no-mpc-slider-limit",
        help="mpc mode: also hold the OCP's slider height at its constraint samples in the QP.",
    ),
]
PPANNPath = Annotated[
    Path | None,
    typer.Option(
        "--ppann",
        help="The PPANN checkpoint the mpc mode and the prediction under --feedback pd use "
        "(default: the one ocp.json names).",
    ),
]
_MPC = MPCConfig()
DEFAULT_WEIGHTS = f"{_MPC.q_theta:g},{_MPC.q_omega:g},{_MPC.r:g}"


def mpc_config(*, horizon: int, weights: str, deadline_ms: float, slider_limit: bool) -> MPCConfig:
    """The MPC settings of --mpc-horizon, --mpc-weights, --mpc-deadline-ms and
    --mpc-slider-limit."""
    parts = [p.strip() for p in weights.split(",")]
    try:
        q_theta, q_omega, r = (float(p) for p in parts)
    except ValueError:
        raise MPCConfigError(
            f"--mpc-weights must be three numbers q_theta,q_omega,r, got {weights!r}"
        ) from None
    return MPCConfig(
        horizon=horizon,
        q_theta=q_theta,
        q_omega=q_omega,
        r=r,
        deadline=deadline_ms / 1e3,
        slider_limit=slider_limit,
    )


def replay_campaign(
    *,
    ocp: Path,
    out: Path,
    config: ReplayConfig,
    model: Path,
    ppann: Path | None,
    resolved: dict[str, Any],
) -> dict[str, Any]:
    """`replay_file` with a progress bar over the runs."""
    from replay.files import replay_file

    with Progress(0, "replaying", unit="run") as bar:  # its total once the inputs are checked
        return replay_file(
            ocp,
            out,
            config=config,
            model_path=model,
            resolved=resolved,
            on_run=bar.update,
            on_start=bar.start,
            ppann=ppann,
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
    modes: Annotated[
        str,
        typer.Option(
            help="Any of open, closed and mpc (the online MPC on the PPANN), comma-separated."
        ),
    ] = "open,closed",
    feedback: Annotated[
        str,
        typer.Option(
            help="Closed loop: lqr (each profile's own gains from ocp.json: its LQR, robust-pd's "
            "PD) or pd (the fixed PD --kp, --kd)."
        ),
    ] = ReplayConfig.feedback,
    kp: PDKp = ReplayConfig.kp,
    kd: PDKd = ReplayConfig.kd,
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
    ppann: PPANNPath = None,
    mpc_horizon: MPCHorizon = _MPC.horizon,
    mpc_weights: MPCWeights = DEFAULT_WEIGHTS,
    mpc_deadline_ms: MPCDeadline = 1e3 * _MPC.deadline,
    mpc_slider_limit: MPCSliderLimit = _MPC.slider_limit,
) -> None:
    """Play the nominal and robust torques on freshly drawn twins, open and closed loop (and
    under the online MPC with --modes …,mpc): the campaign MCAP, <stem>.stats.json, <stem>.png
    (Fig. 12) and <stem>.rrd (Rerun)."""
    # before ocp.json is read for its scenario, and before the campaign's modules are loaded
    check_output(
        "out", out, suffix=".mcap", inputs={"ocp_path": ocp, "model_path": model, "ppann": ppann}
    )
    from replay.files import ocp_variability

    mpc = mpc_config(
        horizon=mpc_horizon,
        weights=mpc_weights,
        deadline_ms=mpc_deadline_ms,
        slider_limit=mpc_slider_limit,
    )
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
        mpc=mpc,
    )
    resolved = {
        "command": "crank replay",
        "argv": sys.argv[1:],
        "ocp": str(ocp),
        "replay": config.as_dict(),
        "model": str(model),
        "ppann": None if ppann is None else str(ppann),
        "project_version": __version__,
    }
    stats = replay_campaign(
        ocp=ocp, out=out, config=config, model=model, ppann=ppann, resolved=resolved
    )
    print_replay(stats, out)


@app.command("heldout", short_help="Check every torque of an ocp.json on held-out machines.")
@one_line_errors
def heldout_command(
    ocp: Annotated[Path, typer.Option(help="ocp.json from crank solve.")] = Path("logs/ocp.json"),
    model: Annotated[Path, typer.Option(help="The PPANN checkpoint the OCP was solved on.")] = (
        Path("logs/model.pt")
    ),
    runs: Annotated[
        int,
        typer.Option(
            help=f"Held-out machines per profile (fewer than {machines_to_confirm()} cannot "
            f"confirm a rate of {100 * TARGET_RATE:g} %)."
        ),
    ] = 1000,
    seed: Annotated[int, typer.Option(help="Root seed of the held-out machines.")] = (HELDOUT_SEED),
    second_stage: Annotated[
        int,
        typer.Option(
            help="Machines a robust torque is played on beyond --runs where those cannot decide "
            "its verdict (judged on all, the risk of a wrong 'holds' within 5 %); 0: one look."
        ),
    ] = SECOND_STAGE,
    trajectories: Annotated[
        int,
        typer.Option(
            help="Monte-Carlo trajectories of each predicted spread (the model's own rate takes "
            "twice as many; fewer: wider ratio intervals)."
        ),
    ] = CALIBRATION_TRAJECTORIES,
    out: Annotated[Path, typer.Option(help="heldout.json to write.")] = Path("logs/heldout.json"),
    variability: Annotated[
        str | None,
        typer.Option(help="Scenario or range file (default: the one in ocp.json)."),
    ] = None,
    modes: Annotated[
        str | None,
        typer.Option(
            help="Comma-separated loops to play every profile in: open, closed (each profile's "
            "LQR gains from ocp.json), mpc (the online MPC on --model). Default: the loops the "
            "file's robust profiles were tightened for (open for robust, closed for the tubes)."
        ),
    ] = None,
    mjcf: Annotated[Path, typer.Option("--mjcf", help="The slider-crank MJCF.")] = MODEL_PATH,
    feedback: Annotated[
        str,
        typer.Option(
            help="Closed loop: lqr (each profile's own gains from ocp.json: its LQR, robust-pd's "
            "PD) or pd (the fixed PD --kp, --kd)."
        ),
    ] = ReplayConfig.feedback,
    kp: PDKp = ReplayConfig.kp,
    kd: PDKd = ReplayConfig.kd,
    mpc_horizon: MPCHorizon = _MPC.horizon,
    mpc_weights: MPCWeights = DEFAULT_WEIGHTS,
    mpc_deadline_ms: MPCDeadline = 1e3 * _MPC.deadline,
    mpc_slider_limit: MPCSliderLimit = _MPC.slider_limit,
) -> None:
    """Every torque of an ocp.json, open or closed loop or under the MPC, on held-out machines:
    violation rates with exact 95 % bounds, and predicted against observed spread for every
    Monte-Carlo mode."""
    # before ocp.json is read for its scenario, and before the check's modules are loaded
    check_output(
        "out", out, suffix=".json", inputs={"ocp_path": ocp, "model": model, "model_path": mjcf}
    )
    from crank.estimate import heldout_time
    from replay.files import ocp_variability
    from replay.heldout import heldout_file

    mpc = mpc_config(
        horizon=mpc_horizon,
        weights=mpc_weights,
        deadline_ms=mpc_deadline_ms,
        slider_limit=mpc_slider_limit,
    )
    # validates runs, seed and modes before any file is read
    loops = None if modes is None else _modes(modes)  # None: the file's (heldout_file)
    checked = ("open",) if loops is None else loops
    ReplayConfig(runs=runs, seed=seed, modes=checked, feedback=feedback, kp=kp, kd=kd)
    check_count("second_stage", second_stage, low=0, high=MAX_RUNS)
    chosen = ocp_variability(ocp) if variability is None else Variability.resolve(variability)
    # its total once the file is read; "done" after the last profile's line, not before it
    bar = Progress(0, "held-out", unit="machine", close_when_full=False)

    def on_start(solved: OCPFile, played: tuple[str, ...]) -> None:
        bar.start(runs * len(solved.names) * len(played))
        span = heldout_time(
            runs=runs,
            horizon=solved.horizon,
            profiles=len(solved.names),
            modes=played,
            mpc_horizon=mpc.horizon,
        )
        typer.echo(
            f"held-out check: {', '.join(solved.names)} in {', '.join(played)} on {runs} "
            f"machines of root {seed}; about {span} on an idle 2-core machine",
            err=True,
        )

    def on_extend(name: str, loop: str, more: int) -> None:
        bar.echo(f"  {name} {loop}: not decided on {runs} machines; {more} more of the draw")
        bar.more(more)

    with bar:
        result = heldout_file(
            ocp,
            out,
            model=model,
            runs=runs,
            seed=seed,
            variability=chosen,
            modes=loops,
            feedback=feedback,
            kp=kp,
            kd=kd,
            model_path=mjcf,
            mpc=mpc,
            mc_samples=trajectories,
            on_played=lambda name, mode, entry: bar.echo(
                played_line(name, mode, feedback=feedback, below=entry["violating_runs"], runs=runs)
            ),
            on_machines=lambda _name, _mode, machines: bar.update(machines),
            on_start=on_start,
            extend_to=second_stage_end(runs, second_stage),
            on_extend=on_extend,
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
    check_output("fixed", fixed, suffix=".mcap", inputs={"broken": broken})
    from replay.recover import recover

    result = recover(broken, fixed)
    state = "was complete" if result.complete else "was cut short"
    typer.echo(
        f"wrote {fixed}: {result.runs} complete runs, {result.messages} messages "
        f"({result.dropped_messages} of an unfinished run dropped); {broken} {state}"
    )
