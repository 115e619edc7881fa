"""The options a held-out diagnosis of one torque takes (bench/calibration_parts.py,
bench/plan_lead.py): the torque, its model, the held-out root and machines, the Monte-Carlo's
trajectories, the line, the output; and the line they resolve to."""

from __future__ import annotations

import argparse

from common.errors import CrankError
from replay.files import ocp_variability
from twin.variability import Variability


def heldout_parser(
    description: str, *, runs_help: str, trajectories_help: str
) -> argparse.ArgumentParser:
    """A parser with --ocp, --model, --heldout-seed, --profile, --runs, --trajectories,
    --variability and --out; the caller adds its own."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--ocp", required=True, help="ocp.json (crank solve)")
    parser.add_argument("--model", required=True, help="the PPANN it was solved on")
    parser.add_argument("--heldout-seed", type=int, required=True, help="held-out root seed")
    parser.add_argument("--profile", default="robust")
    parser.add_argument("--runs", type=int, default=1000, help=runs_help)
    parser.add_argument("--trajectories", type=int, default=4000, help=trajectories_help)
    parser.add_argument(
        "--variability", help="scenario name or range file (default: the one the ocp.json records)"
    )
    parser.add_argument("--out", help="a JSON of the figures, with the settings")
    return parser


def checked_line(args: argparse.Namespace) -> Variability:
    """The line the machines are drawn from (--variability, or the ocp.json's), once --runs and
    --trajectories are checked.

    Raises:
      CrankError: fewer than 2 machines or trajectories, or an unknown line.
    """
    if args.runs < 2 or args.trajectories < 2:
        raise CrankError("--runs and --trajectories must be at least 2")
    return line_of(args.ocp, args.variability)


def line_of(ocp: str, variability: str | None) -> Variability:
    """The line `variability` names (a scenario or a range file), or the ocp.json's if None: what
    a diagnosis ran on, read back from its settings (bench/plan_lead_figure.py) as it resolved it.

    Raises:
      CrankError: an unknown line; an unreadable ocp.json, or one whose model was trained on rig
        data (no line of the twin recorded).
    """
    if variability is None:
        return ocp_variability(ocp)
    return Variability.resolve(variability)
