"""`crank sweep`: a grid of chains on Ray (crank/sweep.py), with a line per finished step."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from crank.console import app, one_line_errors

if TYPE_CHECKING:
    from crank.sweep_spec import Node


@app.command("sweep", short_help="A grid of chains over seeds, tasks, variability, on Ray.")
@one_line_errors
def sweep_command(
    spec: Annotated[
        Path | None,
        typer.Argument(
            help="The sweep's TOML: [base] (crank.toml keys), [grid] (dotted key = list of "
            "values) and [[cases]] (partial configs); see crank/sweep_spec.py."
        ),
    ] = None,
    out: Annotated[Path, typer.Option(help="Sweep folder (must not exist).")] = Path("logs/sweep"),
    executor: Annotated[
        str,
        typer.Option(help="ray (a task per step, in parallel) or sequential (in this process)."),
    ] = "ray",
    address: Annotated[
        str | None,
        typer.Option(help="A Ray cluster to join (e.g. ray://head:10001); default: a local one."),
    ] = None,
    workers: Annotated[
        int | None,
        typer.Option(help="CPUs of the local Ray instance (default: this machine's cores)."),
    ] = None,
    resume: Annotated[
        Path | None,
        typer.Option(help="Continue a sweep folder with its own sweep.toml; keeps finished steps."),
    ] = None,
) -> None:
    """Run every leaf of a sweep spec as a graph of shared steps (one dataset per seed, one model
    per dataset, one solve per task, one leaf per replay config) and write sweep.md, sweep.csv,
    sweep.json and sweep.png into the sweep folder."""
    from crank.estimate import Span
    from crank.sweep import run_sweep

    if workers is not None and workers < 1:
        raise typer.BadParameter(f"--workers must be >= 1, got {workers}")

    def started(sweep: dict[str, Any]) -> None:
        work = Span(*sweep["serial_seconds_estimate"])
        typer.echo(
            f"sweep of {len(sweep['leaves'])} leaves ({sweep['steps']}) into {folder} "
            f"on {executor}, about {sweep['disk_estimate_bytes'] / 1e9:.2g} GB of files and "
            f"{work} of work one step after another on an idle 2-core machine (steps left)",
            err=True,
        )

    def done(node: Node, result: dict[str, Any], count: int, total: int) -> None:
        where = f"[{count}/{total}] {node.kind} {node.key} ({node.leaves[0]}"
        where += f" and {len(node.leaves) - 1} more)" if len(node.leaves) > 1 else ")"
        if result.get("error"):
            typer.echo(f"{where}: error: {result['error']}", err=True)
        else:
            typer.echo(f"{where}: {result['seconds']:.1f} s", err=True)

    folder = resume if resume is not None else out
    sweep = run_sweep(
        spec,
        folder,
        executor=executor,
        address=address,
        workers=workers,
        resume=resume is not None,
        on_start=started,
        on_done=done,
    )
    failed = sum(1 for row in sweep["rows"] if row.get("error"))
    typer.echo(
        f"wrote {folder / 'sweep.md'} ({len(sweep['rows'])} leaves, {failed} failed, "
        f"{sweep['wall_s'] / 60:.1f} min)"
    )
