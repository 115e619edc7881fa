"""verify.md's tables (`crank verify`, replay/verify_report.py) and the terminal's: the constraint
samples, the runs read as one machine's beside the PPANN's white part, and the runs of several
named machines taken apart (replay/verify_machines.py)."""

from __future__ import annotations

from typing import Any


def mm_text(value: float | None, fmt: str = ".2f") -> str:
    """A length in mm (an angle in mrad), or a dash for none."""
    return "—" if value is None else f"{1e3 * value:{fmt}}"


def _ratio(ratio: float | None, ci: list[float] | None) -> str:
    """A ratio with its 95 % interval, as the tables show it."""
    shown = "—" if ratio is None else f"{ratio:.2f}"
    return shown if ci is None else f"{shown} ({ci[0]:.2f}–{ci[1]:.2f})"


def sample_rows(stats: dict[str, Any]) -> list[dict[str, str]]:
    """One row per constraint sample, for the terminal and verify.md."""
    k = stats["ocp"]["k_sigma"]
    rows = []
    for sample, s in stats["samples"].items():
        observed = None if s["observed_sigma"] is None else k * s["observed_sigma"]
        offset = s["mean_offset_sigma"]
        rows.append(
            {
                "sample": sample,
                "below": f"{s['below']}/{len(stats['runs'])}",
                "lowest mm": mm_text(s["lowest"]),
                "mean obs/pred mm": f"{mm_text(s['observed_mean'])}/{mm_text(s['predicted_mean'])}",
                f"{k:g}σ obs/pred mm": f"{mm_text(observed)}/{mm_text(k * s['predicted_sigma'])}",
                "σ pred/obs (95 %)": _ratio(s["ratio"], s["ratio_ci95"]),
                "mean offset σ": "—" if offset is None else f"{offset:+.2f}",
            }
        )
    return rows


def machine_rows(stats: dict[str, Any]) -> list[dict[str, str]]:
    """One row per constraint sample reading the runs as one machine's (no rows without the
    PPANN's split)."""
    if stats["model"] is None:
        return []
    rows = []
    for sample, s in stats["samples"].items():
        theta = s["theta"]
        offset = s["machine_offset"]
        observed = theta["observed_sigma"]
        rows.append(
            {
                "sample": sample,
                "θ σ obs/white mrad": f"{mm_text(observed, '.1f')}/"
                f"{mm_text(theta['white_sigma'], '.1f')}",
                "θ σ white/obs (95 %)": _ratio(theta["white_ratio"], theta["white_ratio_ci95"]),
                "slider σ machines mm": mm_text(s["machine_sigma"]),
                "machine offset": "—" if offset is None else f"{offset:+.2f}",
            }
        )
    return rows


def table_lines(rows: list[dict[str, str]]) -> list[str]:
    keys = list(rows[0])
    return [
        "| " + " | ".join(keys) + " |",
        "|" + " --- |" * len(keys),
        *("| " + " | ".join(r[k] for k in keys) + " |" for r in rows),
    ]


def several_rows(stats: dict[str, Any]) -> list[dict[str, str]]:
    """One row per constraint sample taking the runs of several machines apart (none unless
    the runs name several machines; replay/verify_machines.py)."""
    if stats["machines"] is None:
        return []
    rows = []

    def spread(value: float | None, ci: list[float] | None) -> str:
        shown = mm_text(value, ".1f")
        return shown if ci is None else f"{shown} ({mm_text(ci[0], '.1f')}–{mm_text(ci[1], '.1f')})"

    for sample, s in stats["machines"]["samples"].items():
        rows.append(
            {
                "sample": sample,
                "θ σ within mrad (95 %)": spread(s["within_sigma"], s["within_sigma_ci95"]),
                "white mrad": mm_text(s["white_sigma"], ".1f"),
                "white/within": _ratio(s["white_ratio"], s["white_ratio_ci95"]),
                "θ σ between mrad (95 %)": spread(s["between_sigma"], s["between_sigma_ci95"]),
                "machines mrad": mm_text(s["machine_sigma"], ".1f"),
                "machines/between": _ratio(s["machine_ratio"], s["machine_ratio_ci95"]),
            }
        )
    return rows


def _several(stats: dict[str, Any]) -> list[str]:
    """verify.md's section taking the runs of several machines apart."""
    m = stats["machines"]
    runs = "; ".join(f"{name}: {n}" for name, n in zip(m["labels"], m["runs"], strict=True))
    return [
        f"## The runs of {m['count']} machines",
        "",
        f"Runs per machine ({runs}). The motor angle θ's spread about each machine's own mean "
        "(pooled) against the PPANN's white part (a machine run after run), and the machines' "
        "own spread (their means' spread less what the runs' spread explains) against its "
        "machine part (the line's machine to machine)"
        + ("" if stats["model"] else " (no PPANN: give it with --ppann for the parts)")
        + (
            f". {m['count']} machines measure a spread to about "
            f"{100 / max(2 * (m['count'] - 1), 1) ** 0.5:.0f} %: the interval says how little."
            if max(m["runs"]) > 1
            else ". Each machine ran once: there is no spread within a machine to take apart, "
            "and the runs are the line's machines, read against its σ above."
        ),
        "",
        *table_lines(several_rows(stats)),
        "",
    ]


def spread_sections(stats: dict[str, Any]) -> list[str]:
    """verify.md's section reading the runs as one machine's, with the PPANN's split; the runs
    of several named machines are taken apart instead."""
    if stats["machines"] is not None:
        return _several(stats)
    rows = machine_rows(stats)
    if not rows:
        return [
            "No split of the spread: the plan's PPANN is not beside it (give it with --ppann).",
            "",
        ]
    model = stats["model"]
    return [
        "## If the runs are one machine's",
        "",
        f"The PPANN's spread split as its Monte-Carlo draws it (`{model['path']}`, "
        f"{stats['split_trajectories']} trajectories a part): its white part alone, a machine "
        "at the line's centre run after run, against the runs' spread in the motor angle θ "
        "(near top dead centre one machine's slider spread depends on where the machine "
        "sits; its θ spread does not); and its machines alone, the scale of the machine "
        "offset (the runs' mean slider minus the predicted one, in the machines' σ: where the "
        "runs sit; where the PPANN's machine part is small beside its white part, an offset of "
        "several σ need not mean an unusual machine).",
        "",
        *table_lines(rows),
        "",
    ]
