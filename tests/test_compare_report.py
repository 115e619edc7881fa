"""crank/compare_report.py: the targets' verdict per tube, against exact text."""

from __future__ import annotations

import pytest

from crank.compare_report import verdict
from replay.rates import rate_upper


def _row(profile: str, controller: str, *, below: int, runs: int = 1000) -> dict:
    return {
        "profile": profile,
        "controller": controller,
        "below_campaign": 0,
        "campaign_runs": 100,
        "heldout_rate": below / runs,
        "heldout_upper_95": rate_upper(below, runs),
        "effort_over_nominal": 0.02,
    }


@pytest.mark.parametrize(
    ("below", "runs", "word"),
    [
        (0, 1000, "**met**"),
        (2, 1000, "**met on these machines, not confirmed: the bound is above the target**"),
        (0, 100, "**met on these machines, not confirmed: the bound is above the target**"),
        (6, 1000, "**NOT met**"),
    ],
)
def test_a_tube_meets_the_target_only_with_its_bound(below: int, runs: int, word: str) -> None:
    """Each tube is judged under its own law only; a rate within 0.5 % whose exact bound is not
    (2 of 1000: 0.63 %; 0 of 100: 2.95 %) is not a confirmed target."""
    rows = [_row("robust-fb", "closed-LQR", below=below, runs=runs)]
    rows.append(_row("robust-fb", "closed-PD", below=50))  # not its law: not judged
    lines = verdict({"rows": rows}, rate=0.005, effort=0.10)
    assert len(lines) == 1 and lines[0].startswith("- robust-fb under closed-LQR: 0/100")
    assert f"below (bound {100 * rate_upper(below, runs):.2f} %): {word}; Σu² applied" in lines[0]
