"""`crank sweep`: a grid of chains on Ray (crank/sweep.py), with a line per finished step; and
`crank compare` (crank/compare.py): the controllers of finished runs side by side."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from common.errors import ConfigError
from crank.console import HELDOUT_RUNS, HELDOUT_SEED, app, continue_hint, one_line_errors

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
        typer.Option(
            help="Continue a sweep folder with its own sweep.toml; keeps finished steps "
            "(refused where its twin or its settings changed since they were made)."
        ),
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
            what = "refused" if result.get("refused") else "error"
            typer.echo(f"{where}: {what}: {result['error']}", err=True)
        elif result.get("found"):
            typer.echo(f"{where}: found finished (made in {result['seconds']:.1f} s)", err=True)
        else:
            typer.echo(f"{where}: {result['seconds']:.1f} s", err=True)

    folder = resume if resume is not None else out
    with continue_hint(folder, f"continue it with: crank sweep --resume {folder}"):  # steps kept
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
    from crank.sweep_report import failure

    rows = sweep["rows"]
    leaves = len({row["leaf"] for row in rows})
    failed = sum(1 for row in rows if failure(row) == "failed")
    refused = sum(1 for row in rows if failure(row) == "refused")
    typer.echo(
        f"wrote {folder / 'sweep.md'} ({leaves} leaves, {len(rows)} rows of a leaf and profile, "
        f"{failed} failed, {refused} profiles refused, {sweep['wall_s'] / 60:.1f} min)"
    )


@app.command("compare", short_help="Every profile under every controller, per scenario run.")
@one_line_errors
def compare_command(
    run_dirs: Annotated[
        list[Path],
        typer.Argument(
            metavar="RUN_DIR...",
            help="Finished run folders (crank run, best with --profiles "
            "robust,robust-fb,robust-pd), one per variability scenario, or sweep folders (each "
            "finished leaf), whose replays played one fixed PD; with --merge, compare folders "
            "to join.",
        ),
    ],
    out: Annotated[Path, typer.Option(help="Folder to write (must not exist).")] = Path(
        "logs/compare"
    ),
    runs: Annotated[int, typer.Option(help="Campaign machines per profile and controller.")] = 100,
    heldout_runs: Annotated[
        int, typer.Option(help="Held-out machines per profile and controller.")
    ] = HELDOUT_RUNS,
    heldout_seed: Annotated[int, typer.Option(help="Root seed of the held-out machines.")] = (
        HELDOUT_SEED
    ),
    mjcf: Annotated[
        Path | None,
        typer.Option(
            help="A copy of the runs' twin, for folders moved away from the MJCF their "
            "config.json names (checked against each dataset's sha256).",
        ),
    ] = None,
    merge: Annotated[
        bool,
        typer.Option(
            help="Join compare folders made apart (in parallel, elsewhere) with the same "
            "settings into --out; no replay."
        ),
    ] = False,
) -> None:
    """Play every profile of each run's ocp.json open loop, under the fixed PD, under its LQR
    law and under the online MPC, on campaign and held-out machines of the run's scenario;
    write compare.md (a table per scenario), compare.json and compare.png."""
    from crank.compare import compare_runs, counted, merge_compares

    if merge:
        if mjcf is not None:
            raise ConfigError("--mjcf is for replays; --merge joins compare folders and plays none")
        result = merge_compares(run_dirs, out)
        typer.echo(f"wrote {out / 'compare.md'} ({counted(result)})")
        return
    from crank.chain import Hooks
    from crank.progress import StageBars

    with StageBars(unit="machine") as bars:  # a bar for each run's campaign and held-out stage
        result = compare_runs(
            run_dirs,
            out,
            runs=runs,
            heldout_runs=heldout_runs,
            heldout_seed=heldout_seed,
            mjcf=mjcf,
            hooks=Hooks(on_stage=bars.echo, on_total=bars.start, on_runs=bars.update),
        )
    typer.echo(
        f"wrote {out / 'compare.md'}, compare.json, compare.png "
        f"({counted(result)}, {result['wall_s'] / 60:.1f} min)"
    )
