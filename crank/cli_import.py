"""`crank import`, `crank export` and `crank verify`: a real machine's measurements (CSV, Parquet,
MCAP) into the dataset contract, a solved profile out as a table its controller plays, and the
runs it played there checked against the plan."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from crank.console import ModelPath, app, one_line_errors, print_summary
from replay.verify import ALIGNS, PLAYED_TOLERANCE
from twin import MODEL_PATH
from twin.physics import SAMPLE_RATE

UnitsOption = Annotated[
    str,
    typer.Option(
        help="field=unit pairs where the rig's table differs from s, rad, rad/s, N*m, m (t: ms, "
        "us, ns; theta: deg, rev; omega: rpm, deg/s, rev/s; tau: mN*m; slider_position: mm, cm)."
    ),
]
FlipOption = Annotated[
    str, typer.Option(help="Fields whose sign on the rig is the opposite of the contract's.")
]


@app.command("import", short_help="Rig data (CSV, Parquet, MCAP) into a dataset to train on.")
@one_line_errors
def import_command(
    data: Annotated[
        list[Path],
        typer.Argument(
            metavar="DATA...",
            help="The rig's data: .csv (header row), .parquet or .mcap (JSON, ROS 2); several "
            "files (a file per run) become one dataset, each file's episodes after the last's.",
        ),
    ],
    columns: Annotated[
        str,
        typer.Option(
            "--map",
            help="field=column pairs: t, theta, tau required; omega, slider_position, episode, "
            "machine (an integer id: episodes of one id are runs of one machine) optional (e.g. "
            "t=time,theta=enc,tau=cmd; in an MCAP columns are TOPIC.FIELD and t=log_time).",
        ),
    ],
    out: Annotated[Path, typer.Option(help="Dataset MCAP to write.")] = Path("logs/rig.mcap"),
    units: UnitsOption = "",
    flip: FlipOption = "",
    rate: Annotated[float, typer.Option(help="Rate to resample to, Hz (the PPANN's).")] = (
        SAMPLE_RATE
    ),
    max_gap: Annotated[
        float, typer.Option(help="An interval above this many median intervals is a gap.")
    ] = 5.0,
    split_on_gaps: Annotated[
        bool, typer.Option(help="Start a new episode at each gap instead of refusing it.")
    ] = False,
    machines: Annotated[
        str,
        typer.Option(
            help="Each file's machine, one label per file in order (e.g. A,A,B: the first two "
            "files are runs of one machine); default: every episode a machine of its own."
        ),
    ] = "",
    model: ModelPath = MODEL_PATH,
) -> None:
    """Resample a rig's table onto the contract's grid, in its units and signs, and write a
    dataset MCAP that `crank train` reads (no truth channel and no twin: training skips the
    twin calibration; replaying a plan on the twin needs --variability)."""
    from twin.rig_import import ImportSpec, import_table

    spec = ImportSpec.parse(
        columns=columns,
        units=units,
        flip=flip,
        rate_hz=rate,
        max_gap=max_gap,
        split_on_gaps=split_on_gaps,
    )
    labels = machines.split(",") if machines else None  # import: ~0.6 s for 90 s at 1 kHz
    run = import_table(data, out, spec=spec, model_path=model, machines=labels)
    summary = run["summary"] | {
        "source_rate_hz": round(run["source_rate_hz"], 3),
        "source_jitter_pct": round(100 * run["source_jitter"], 2),
        "gaps": len(run["gaps"]),
        "derived": ", ".join(run["derived"]) or "none",
    }
    source = str(data[0]) if len(data) == 1 else f"{len(data)} files ({run['input']})"
    print_summary(f"wrote {out} from {source}", summary)


@app.command("export", short_help="A profile of an ocp.json as a CSV a machine's controller plays.")
@one_line_errors
def export_command(
    ocp: Annotated[Path, typer.Argument(help="The ocp.json of `crank solve` or `crank run`.")],
    out: Annotated[Path, typer.Option(help="CSV to write.")] = Path("logs/profile.csv"),
    profile: Annotated[
        str | None,
        typer.Option(
            help="The profile (nominal, robust, robust-fb, robust-pd); default: the "
            "file's first robust one."
        ),
    ] = None,
    units: UnitsOption = "",
    flip: FlipOption = "",
) -> None:
    """One row per sample: the planned torque, the angle and speed to track, the gains of the
    profile's law and the slider it predicts; the law to play and the task in the "#" lines
    before the header. Open loop a machine plays the torque alone; closed loop the law."""
    from common.atomic import check_output
    from control.export import ExportSpec, export_file

    check_output("out", out, suffix=".csv", inputs={"ocp_path": ocp})
    spec = ExportSpec.parse(units=units, flip=flip)
    written = export_file(ocp, out, profile=profile, spec=spec)
    typer.echo(
        f"wrote {out}: profile {written['profile']} ({written['loop']} loop), "
        f"{written['rows']} rows of {', '.join(written['columns'])}"
    )


@app.command("verify", short_help="Runs of a profile recorded on a machine, against its plan.")
@one_line_errors
def verify_command(
    ocp: Annotated[Path, typer.Argument(help="The ocp.json the profile came from.")],
    data: Annotated[
        Path,
        typer.Argument(help="The runs, imported by `crank import`: one episode per run."),
    ],
    out: Annotated[
        Path, typer.Option(help="verify.json to write; verify.md and verify.png beside it.")
    ] = Path("logs/verify.json"),
    profile: Annotated[
        str | None,
        typer.Option(help="The profile the runs played; default: the file's first robust one."),
    ] = None,
    align: Annotated[
        str,
        typer.Option(
            help=f"{' or '.join(ALIGNS)}. start: each run's first sample is the plan's first; "
            "torque: from the sample where its torque is nearest the profile's law (a "
            "recording with a lead-in)."
        ),
    ] = "start",
    played_tolerance: Annotated[
        float,
        typer.Option(
            help="A run whose torque is further than this share of the torque limit (RMS) from "
            "the profile's law played something else, and is refused."
        ),
    ] = PLAYED_TOLERANCE,
    control_rate: Annotated[
        float | None,
        typer.Option(
            help="Hz: the rate the machine's controller evaluated the closed-loop law at, a "
            "whole multiple of the plan's (default the plan's: once a sample, as exported)."
        ),
    ] = None,
    ppann: Annotated[
        Path | None,
        typer.Option(
            help="The PPANN the plan was solved on, to split the spread into its white and "
            "machine parts (default: the checkpoint ocp.json names, if it is there)."
        ),
    ] = None,
    figures: Annotated[bool, typer.Option(help="Write verify.png.")] = True,
) -> None:
    """Count the runs below the height at each constraint sample and set the slider's observed
    mean and spread beside what the PPANN predicted in the profile's loop; each run is first
    checked to have played the profile's law (open: its torque; closed: its tracking law)."""
    from common.atomic import check_output

    check_output(
        "out", out, suffix=".json", inputs={"ocp_path": ocp, "data_path": data, "ppann": ppann}
    )
    from replay.statistics import format_table
    from replay.verify_report import claim_text, output_paths, verify_file
    from replay.verify_tables import machine_rows, sample_rows, several_rows

    stats = verify_file(
        ocp,
        data,
        out,
        profile=profile,
        align=align,
        played_tolerance=played_tolerance,
        control_rate=control_rate,
        ppann=ppann,
        figures=figures,
    )
    typer.echo(format_table(sample_rows(stats)))
    if stats["machines"] is not None:
        typer.echo(f"the runs of {stats['machines']['count']} machines, θ:")
        typer.echo(format_table(several_rows(stats)))
    elif stats["model"] is not None:
        typer.echo("if the runs are one machine's:")
        typer.echo(format_table(machine_rows(stats)))
    typer.echo(claim_text(stats))
    written = [p for kind, p in output_paths(out).items() if figures or kind != "figure"]
    typer.echo(f"wrote {', '.join(map(str, written))}")
