"""The `crank` command's shared parts: the Typer app, one-line errors, progress bars, option
types and the printers several commands use. The commands are in crank/cli.py (one stage each)
and crank/cli_chain.py (`run`, `study`)."""

from __future__ import annotations

import functools
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any

import typer
from tqdm import tqdm

from common.errors import CrankError
from control.robust import Iteration
from replay.files import output_paths
from replay.statistics import format_table, summary_rows

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,
    help="MuJoCo slider-crank twin and PPANN robust-control testbed.",
)


def one_line_errors(command: Callable[..., Any]) -> Callable[..., Any]:
    """Turn the project's input errors into `error: ...` on stderr and exit code 2."""

    @functools.wraps(command)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return command(*args, **kwargs)
        except (CrankError, OSError) as exc:
            typer.echo(f"error: {exc}", err=True)
            raise typer.Exit(2) from None
        except KeyboardInterrupt:
            typer.echo("error: interrupted; no unfinished file was put at a target path", err=True)
            raise typer.Exit(130) from None

    return wrapper


class Progress:
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
        if self.bar.n >= self.total:
            self.bar.close()  # done: give the line back to the next stage's bar

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc: object) -> None:
        if self.bar is not None:
            self.bar.close()


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
Amplitude = Annotated[float, typer.Option(help="Peak excitation torque level in N·m.")]
FeedbackOption = Annotated[
    str,
    typer.Option(
        help="The loop the robust tightening is sized for: none (open loop, eq. 16) or lqr (the "
        "closed loop under each profile's LQR gains: a tube; the held-out check then plays it)."
    ),
]
Confidence = Annotated[
    float,
    typer.Option(
        help="Confidence about the line the robust tightening allows for (its mean and spread "
        "are estimated from few machines); 0 = the paper's eq. 16."
    ),
]
ModelPath = Annotated[Path, typer.Option("--model", help="The slider-crank MJCF.")]
VariabilityOption = Annotated[
    str,
    typer.Option(
        "--variability",
        help="Machine variability: a scenario (paper, line-15, line-30) or a .toml/.json file.",
    ),
]
HELDOUT_SEED = 20261122
"""Default root seed of held-out machines; never used while developing the method."""


class EpochBars:
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


def print_heldout(heldout: dict[str, Any]) -> None:
    loop = heldout["mode"]
    typer.echo(f"held-out check ({heldout['runs']} machines per profile, {loop} loop):")
    for profile, entry in heldout["profiles"].items():
        typer.echo(
            f"  {profile:<8} {entry['violating_runs']:>5} below the height "
            f"({100 * entry['rate']:.2f} %, 95 % upper bound {100 * entry['rate_upper_95']:.2f} %)"
        )
    verdict = "holds" if heldout["holds"] else "does NOT hold"
    typer.echo(f"  robust {verdict} at <= {100 * heldout['target_rate']:.1f} %")


def show_iteration(it: Iteration) -> None:
    """Print one robust iteration's margins on stderr."""
    margin = ", ".join(f"{1e3 * v:.2f}" for v in it.margin)
    k_sigma = ", ".join(
        f"{1e3 * v:.2f}±{1e3 * se:.2f}"
        for v, se in zip(it.tightening, it.tightening_se, strict=True)
    )
    kind = "draft" if it.draft else "full "
    typer.echo(
        f"  robust iteration ({kind}): margin [{margin}] mm -> tightening [{k_sigma}] mm, "
        f"cost {it.cost:.5g}, {it.ipopt_iterations} IPOPT iterations",
        err=True,
    )


def print_replay(stats: dict[str, Any], out: Path) -> None:
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
