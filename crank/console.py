"""The `crank` command's shared parts: the Typer app, one-line errors, progress bars, option
types and the printers several commands use. The commands are in crank/cli.py (one stage each),
crank/cli_campaign.py (the replay stage's) and crank/cli_chain.py (`run`, `study`)."""

from __future__ import annotations

import contextlib
import functools
import signal
import sys
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from common.errors import CrankError
from common.threads import rollout_threads
from control.config import PD_GAINS, OCPConfig
from crank.progress import close_bar, progress_bar
from ppann.train_config import PLAN_FIT_EPOCHS

if TYPE_CHECKING:
    from control.robust import Iteration
    from ppann.train_config import TrainConfig

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,
    help="MuJoCo slider-crank twin and PPANN robust-control testbed.",
)


VERSIONED = ("mujoco", "torch", "casadi", "numpy", "mcap", "rerun-sdk")


def _show_version(value: bool) -> None:
    if value:
        from importlib.metadata import version

        from twin import __version__

        others = ", ".join(f"{name} {version(name)}" for name in VERSIONED)
        typer.echo(f"crank {__version__} ({others})")
        raise typer.Exit()


@app.callback()
def _main(
    version: Annotated[
        bool,
        typer.Option(
            "--version", callback=_show_version, is_eager=True, help="Print versions and exit."
        ),
    ] = False,
) -> None:
    """MuJoCo slider-crank twin and PPANN robust-control testbed."""


INPUT_ERRORS = (CrankError, OSError)
"""What a command turns into one `error:` line (a bad input, a disk that is full)."""


class Terminated(KeyboardInterrupt):
    """SIGTERM (`kill`, a scheduler's or a container's stop), raised as Ctrl-C's
    KeyboardInterrupt is, so that a command stops the same way: unfinished files removed, locks
    released, the run's log written; exit status 143, as a process SIGTERM ended."""


_TERMINATED = threading.Event()
"""Set by SIGTERM: a library that turns the exception into its own KeyboardInterrupt (Ray's
wait does) still ends the command as terminated."""


def _terminate(signum: int, frame: object) -> None:
    _TERMINATED.set()
    raise Terminated


@contextlib.contextmanager
def _sigterm_as_interrupt() -> Iterator[None]:
    """SIGTERM raises `Terminated` in the main thread while the block runs, where it would
    have ended the process on the spot (a lock and hidden temporaries left behind); left
    alone where it is ignored or handled already, or off the main thread."""
    if threading.current_thread() is not threading.main_thread() or (
        signal.getsignal(signal.SIGTERM) is not signal.SIG_DFL
    ):
        yield
        return
    _TERMINATED.clear()  # a command run before in this process is not this one
    signal.signal(signal.SIGTERM, _terminate)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, signal.SIG_DFL)


@contextlib.contextmanager
def continue_hint(folder: Path, hint: str) -> Iterator[None]:
    """Ctrl-C or SIGTERM in the block, once `folder` exists (its finished work kept): the
    command's error line ends with `hint`, how to go on (`error_line`)."""
    try:
        yield
    except KeyboardInterrupt as exc:
        if folder.is_dir():
            exc.args = (hint,)
        raise


def error_line(exc: BaseException) -> str:
    """The one line a command prints (and `transcript` logs) for an input error, Ctrl-C or
    SIGTERM (with what to do next, if the command said: `exc.args`)."""
    if isinstance(exc, KeyboardInterrupt):
        what = "terminated (SIGTERM)" if isinstance(exc, Terminated) else "interrupted"
        then = "".join(f"; {a}" for a in exc.args)
        return f"error: {what}; no unfinished file was put at a target path{then}"
    return f"error: {exc}"


def one_line_errors(command: Callable[..., Any]) -> Callable[..., Any]:
    """Turn the project's input errors into `error: ...` on stderr and exit code 2 (Ctrl-C:
    130, SIGTERM: 143)."""

    @functools.wraps(command)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            with _sigterm_as_interrupt():
                rollout_threads()  # $CRANK_ROLLOUT_THREADS checked before anything is written
                return command(*args, **kwargs)
        except INPUT_ERRORS as exc:
            typer.echo(error_line(exc), err=True)
            raise typer.Exit(2) from None
        except KeyboardInterrupt as exc:
            if _TERMINATED.is_set() and not isinstance(exc, Terminated):
                exc = Terminated(*exc.args)
            typer.echo(error_line(exc), err=True)
            raise typer.Exit(143 if isinstance(exc, Terminated) else 130) from None

    return wrapper


class _Tee:
    """A text stream that writes through to `stream` and keeps the text for a log, except
    terminal-only frames (carriage returns, escape sequences: tqdm's bars)."""

    def __init__(self, stream: Any, kept: list[str]) -> None:
        self.stream, self.kept = stream, kept
        self.encoding = getattr(stream, "encoding", "utf-8")
        self.errors = getattr(stream, "errors", "strict")

    def write(self, text: str) -> int:
        self.stream.write(text)
        if "\r" not in text and "\x1b" not in text:
            self.kept.append(text)
        return len(text)

    def flush(self) -> None:
        self.stream.flush()

    def isatty(self) -> bool:
        return self.stream.isatty()

    def fileno(self) -> int:
        return self.stream.fileno()


@contextlib.contextmanager
def transcript(path: Path, *, append: bool = False) -> Iterator[None]:
    """Everything the command prints on stdout and stderr (but progress frames), and its error
    line if it fails, also goes to `path` once the command ends, if the command created path's
    folder (a run folder, created by the chain; an existing folder is never written into), or
    after what `path` holds with `append` (a resumed run's own folder)."""
    created = not path.parent.exists()
    kept: list[str] = []
    out, err = sys.stdout, sys.stderr
    sys.stdout, sys.stderr = _Tee(out, kept), _Tee(err, kept)
    try:
        yield
    except (*INPUT_ERRORS, KeyboardInterrupt) as exc:
        kept.append(error_line(exc) + "\n")
        raise
    finally:
        sys.stdout, sys.stderr = out, err
        if (created or append) and path.parent.is_dir():
            with (
                contextlib.suppress(OSError),  # the log is a convenience, never the failure
                open(path, "a" if append else "w", encoding="utf-8") as log,
            ):
                log.write("".join(kept))


def print_summary(title: str, summary: dict[str, Any]) -> None:
    typer.echo(title)
    width = max(len(k) for k in summary)
    for key, value in summary.items():
        shown = f"{value:.6g}" if isinstance(value, float) else str(value)
        typer.echo(f"  {key:<{width}}  {shown}")


Seconds = Annotated[float, typer.Option(help="Duration of the dataset in s (500 Hz samples).")]
Seed = Annotated[int, typer.Option(help="Seed of every random draw.")]
EpisodeSeconds = Annotated[float, typer.Option(help="Length of one episode (machine draw) in s.")]
Drift = Annotated[bool, typer.Option(help="Friction drifts as each machine warms up.")]
EpisodesPerMachine = Annotated[
    int, typer.Option(help="Episodes each machine plays (a lab's few machines, several runs).")
]
Amplitude = Annotated[float, typer.Option(help="Peak excitation torque level in N·m.")]
ProfilesOption = Annotated[
    str,
    typer.Option(
        help="Comma-separated robust profiles to solve beside the nominal one: robust (tightened "
        "for the open loop, eq. 16), robust-fb (for the closed loop under the plan's LQR "
        f"gains: a tube) and robust-pd (a tube for the fixed PD Kp {PD_GAINS[0]:g}, Kd "
        f"{PD_GAINS[1]:g} the machine may already run); the held-out check plays each in its "
        "loop."
    ),
]
DEFAULT_PROFILES = ",".join(OCPConfig.profiles)


def profiles_list(text: str) -> list[str]:
    """--profiles text as a list; OCPConfig says what is wrong with its contents."""
    return [part.strip() for part in text.split(",") if part.strip()]


FallbackOption = Annotated[
    str,
    typer.Option(
        help="Comma-separated robust profiles solved only where every one of --profiles is "
        "refused (on a line no open-loop torque holds: the LQR tube beside the refusal), or "
        "none."
    ),
]
DEFAULT_FALLBACK = ",".join(OCPConfig.fallback) or "none"


def fallback_list(text: str) -> list[str]:
    """--fallback text as a list ("none": empty); OCPConfig says what is wrong with it."""
    return [] if text.strip() == "none" else profiles_list(text)


Confidence = Annotated[
    float,
    typer.Option(
        help="Confidence that the robust tightening is not short (the line's mean and spread "
        "are estimated from few machines, the spread's effect from a finite Monte-Carlo); "
        "0 = the paper's eq. 16."
    ),
]
ModelPath = Annotated[Path, typer.Option("--model", help="The slider-crank MJCF.")]
PDKp = Annotated[float, typer.Option("--kp", help="The fixed PD: N·m/rad on the angle error.")]
PDKd = Annotated[float, typer.Option("--kd", help="The fixed PD: N·m·s/rad on the speed error.")]
VariabilityOption = Annotated[
    str,
    typer.Option(
        "--variability",
        help="Machine variability: a scenario (paper, line-15, line-30) or a .toml/.json file.",
    ),
]
HELDOUT_SEED = 20261122
"""Default root seed of held-out machines; never used while developing the method."""
HELDOUT_RUNS = 1000
"""Held-out machines per profile in `crank run` and `crank study`."""


class EpochBars:
    """A progress bar per model and phase with its latest loss (side by side: ppann/fit.py)."""

    def __init__(self, epochs: dict[str, int]) -> None:
        self.epochs = epochs
        self.bars: dict[str, tuple[str, Any]] = {}
        """Per model kind, its current phase and bar."""

    @classmethod
    def of(cls, config: TrainConfig) -> EpochBars:
        """The bars of training under `config`: phase 1, phase 2 and the bounds' calibration."""
        from ppann.inversion import calibration_epochs  # torch: not for `crank --help`

        bounds = calibration_epochs(config.sigma_epochs, lines=config.bound_lines)
        phases = {"mean": config.max_epochs, "plan": PLAN_FIT_EPOCHS, "sigma": config.phase2_epochs}
        return cls(phases | {"bounds": bounds})

    def __call__(self, kind: str, phase: str, epoch: int, loss: float) -> None:
        if kind not in self.bars or self.bars[kind][0] != phase:
            self.done(kind)
            bar = progress_bar(total=self.epochs[phase], desc=f"{kind} {phase}", unit="epoch")
            self.bars[kind] = (phase, bar)
        bar = self.bars[kind][1]
        bar.set_postfix(loss=f"{loss:.4g}")  # first: a LineBar prints on update
        bar.update(1)

    def done(self, kind: str, *, stopped: bool = False) -> None:
        """Close the bar of `kind` (its training has ended; `stopped` by an error or Ctrl-C)."""
        if kind in self.bars:
            close_bar(self.bars.pop(kind)[1], stopped=stopped)

    def close(self, *, stopped: bool = False) -> None:
        """Close every bar (a stage ends; `stopped` by an error or Ctrl-C)."""
        for kind in list(self.bars):
            self.done(kind, stopped=stopped)


def _predicted(entry: dict[str, Any]) -> str:
    """The model's own rate beside the observed one (heldout.json version 4), or nothing."""
    if "model_rate" not in entry:
        return ""
    return f"; the model predicted {100 * entry['model_rate']['rate']:.2f} %"


def print_heldout(heldout: dict[str, Any]) -> None:
    from replay.config import loop_label
    from replay.placement import in_words, named
    from replay.rates import heldout_verdict_text

    typer.echo(f"held-out check ({heldout['runs']} machines per profile and loop):")
    for profile, played in heldout["profiles"].items():
        for mode, entry in played.items():
            loop = loop_label(mode, heldout["feedback"])
            typer.echo(
                f"  {profile:<9} {loop:<6} {entry['violating_runs']:>5} below the height "
                f"({100 * entry['rate']:.2f} %, 95 % upper bound "
                f"{100 * entry['rate_upper_95']:.2f} %)" + _predicted(entry) + _which(entry)
            )
            for machine, where in named(entry):  # where they sit in the line
                typer.echo(f"    machine {machine}: {in_words(where)}")
    for profile in heldout["holds"]:
        typer.echo(f"  {profile} in its loop {heldout_verdict_text(heldout, profile)}")


def _which(entry: dict[str, Any]) -> str:
    """The held-out machines below the height by index, where at most MOST_NAMED
    (heldout.json's violating_machines, since session 31; a file before version 7 has no
    placements, so `named` gives none), else nothing."""
    from replay.placement import MOST_NAMED

    machines = entry.get("violating_machines") or []
    if not machines or len(machines) > MOST_NAMED:
        return ""
    return f"; machine{'s' if len(machines) > 1 else ''} {', '.join(map(str, machines))}"


def show_iteration(it: Iteration) -> None:
    """Print one robust iteration's margins on stderr."""
    margin = ", ".join(f"{1e3 * v:.2f}" for v in it.margin)
    k_sigma = ", ".join(
        f"{1e3 * v:.2f}±{1e3 * se:.2f}"
        for v, se in zip(it.tightening, it.tightening_se, strict=True)
    )
    kind = "draft" if it.draft else "full "
    kept = "kept" if it.scheme == "aware" else "used"  # control/aware.py: the slider's margin
    typer.echo(
        f"  {it.profile} iteration ({kind}, {it.scheme}, {it.samples} trajectories): margin "
        f"{kept} [{margin}] mm -> "
        f"tightening at k {it.k_sigma:g} [{k_sigma}] mm, "
        f"cost {it.cost:.5g}, {it.ipopt_iterations} IPOPT iterations",
        err=True,
    )


def print_replay(stats: dict[str, Any], out: Path) -> None:
    from replay.files import output_paths
    from replay.foxglove import FOXGLOVE_LAYOUT
    from replay.statistics import format_table, summary_rows

    typer.echo(format_table(summary_rows(stats)))
    unpredicted = [
        f"{name} {mode}"
        for name, modes in stats["profiles"].items()
        for mode, s in modes.items()
        if any(c["predicted_k_sigma"] is None for c in s["constraint"].values())
    ]
    if unpredicted:
        typer.echo(
            f"—: no prediction for {', '.join(unpredicted)} (the PD is not their own law, and "
            "the PPANN ocp.json names is not there or not the plan's: give it with --ppann)"
        )
    claim = stats["claim"]
    if claim["holds"] is not None:
        verdict = "holds" if claim["holds"] else "does NOT hold"
        typer.echo(
            f"claim {verdict}: robust open loop {claim['robust_open_violating_runs']} of "
            f"{stats['config']['runs']} runs below the height, nominal "
            f"{claim['nominal_open_violating_runs']} (needs >= {claim['nominal_needed']})"
        )
    for name, c in stats.get("claims", {}).items():
        if name != "robust":  # the paper's claim above
            verdict = "holds" if c["holds"] else "does NOT hold"
            typer.echo(
                f"{name} {verdict}: {c['loop']} loop {c['violating_runs']} of {c['runs']} runs "
                f"below the height"
            )
    files = ", ".join(str(p) for p in output_paths(out).values())
    typer.echo(f"wrote {files}")
    typer.echo(f"Foxglove: open {out} and import the layout {FOXGLOVE_LAYOUT}")
