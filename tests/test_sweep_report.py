"""crank/sweep_report.py: the sweep's verdict and figure from result rows, against exact
text (no sweep runs here; tests/test_sweep.py runs them)."""

from __future__ import annotations

import numpy as np

from crank.sweep_report import figure, markdown


def test_the_verdict_judges_the_returned_torques_and_names_unconfirmed_bounds() -> None:
    def row(seed: int, rate: float, upper: float) -> dict:
        return {
            "leaf": f"seed={seed}",
            "seed": seed,
            "profile": "robust",
            "robust_heldout_rate": rate,
            "robust_heldout_upper_95": upper,
            "heldout_runs": 1000,
            "robust_100": 0,
            "campaign_runs": 100,
            "premium": 0.3,
        }

    sweep = {"axes": ["seed"], "steps": "", "executor": "ray", "wall_s": 1.0, "heldout_seeds": [7]}
    refused = {"leaf": "seed=2", "seed": 2, "error": "no robust profile", "failed_step": "solve"}
    text = markdown(sweep, [row(0, 0.001, 0.0047), row(1, 0.003, 0.0077), refused])
    assert "every robust torque returned (2 of 3 profiles of a leaf)" in text
    # one profile of a solve that wrote the others: run_rows' row has no failed step
    one = {"leaf": "seed=3", "seed": 3, "profile": "robust", "error": "open loop cannot keep"}
    assert "- seed=3: robust refused: open loop cannot keep" in markdown(sweep, [one])
    # two profiles of one leaf are two rows, one leaf
    assert markdown(sweep, [one, one | {"profile": "robust-fb"}]).startswith("# Sweep: 1 leaves")
    assert "worst 0.30 % (seed=1, robust), target <= 0.5 %: **met**" in text
    assert "- 1 of them not confirmed by their held-out verdict (worst 95 % bound 0.77 %)" in text
    assert "seed=2: solve step: no robust profile" in text
    text = markdown(sweep, [row(0, 0.006, 0.011)])
    assert "worst 0.60 % (seed=0, robust), target <= 0.5 %: **NOT met**" in text
    assert "| all | 1 | 6/1000 (0.60 %) |" in text
    # no model_rate yet, nor what the torque was solved with
    assert text.rstrip().endswith("| 30.0 % (30.0 %–30.0 %) | n/a | n/a | 0 |")
    own = [row(0, 0.001, 0.0047) | {"robust_model_rate": r} for r in (0.001, 0.002)]
    assert "| 30.0 % (30.0 %–30.0 %) | 0.150 %, 0.200 % | n/a | 0 |" in markdown(sweep, own)
    # the tightenings and k the torques were solved with, in order of first appearance
    solved = [
        row(seed, 0.001, 0.0047) | {"solved_tightening": method, "solved_k": k}
        for seed, (method, k) in enumerate(
            [("centred", 3.0), ("centred", 3.21), ("quantile", 3.0), ("centred", 3.11)]
        )
    ]
    assert "| n/a | centred k 3–3.21 ×3, quantile k 3 ×1 | 0 |" in markdown(sweep, solved)
    # plan rounds whose first torque was refused by its own tail's check (played, not returned)
    rounds = [r | {"first_round_tail_refused": seed in (1, 3)} for seed, r in enumerate(solved)]
    expected = "| centred k 3–3.21 ×3, quantile k 3 ×1; first round refused by its tail check ×2 |"
    assert expected in markdown(sweep, rounds)
    no_round = [r | {"first_round_tail_refused": False} for r in solved]
    assert "| n/a | centred k 3–3.21 ×3, quantile k 3 ×1 | 0 |" in markdown(sweep, no_round)


def test_sweep_figure_names_each_column_by_its_values() -> None:
    """The figure's columns are labelled by their option values, one per line and wrapped (the
    options' names once repeated in every label, rotated, and long ones ran into each other),
    the axes' names below; a premium below zero stays in view."""
    rows = [
        {
            "seed": seed,
            "generation.variability": line,
            "case": case,
            "profile": profile,
            "robust_heldout_rate": 0.001,
            "robust_heldout_upper_95": 0.004,
            "premium": -0.002 if case == "samples 60, 90" else 0.03,
        }
        for seed in (0, 1)
        for line in ("paper", "line-30")
        for case in ("samples 60, 90", "horizon 200, samples 70, 130")
        for profile in ("robust-fb", "robust-pd")
    ]
    fig = figure(rows, ["seed", "generation.variability", "case"])
    premium, lowest = fig.axes[1], fig.axes[-1]
    ticks = [t.get_text() for t in lowest.get_xticklabels()]
    assert len(ticks) == 8
    assert ticks[0] == "paper\nsamples 60, 90\nrobust-fb"
    assert ticks[3] == "paper\nhorizon 200,\nsamples 70, 130\nrobust-pd"
    assert lowest.get_xlabel() == "generation.variability / case / profile"
    assert premium.get_ylim()[0] < -0.2


def test_sweep_figure_draws_each_calibration_ratio_with_its_interval() -> None:
    """The lowest panel: every finite ratio of a leaf at its constraint samples (whatever they
    are) at its value with its 95 % interval as the error bar, one colour per sample; a ratio
    without an interval is a bare point, a diverged one (null, or beyond 1000 as report.md says)
    is left out, so the 0.8-1.25 band stays readable."""
    base = {"robust_heldout_rate": 0.001, "robust_heldout_upper_95": 0.004, "premium": 0.3}
    rows = [
        base
        | {"seed": 0, "case": "paper", "ratio_50": 1.2, "ratio_50_low": 1.1}
        | {"ratio_50_high": 1.3, "ratio_100": 1.05, "ratio_100_low": 1.0, "ratio_100_high": 1.1},
        base | {"seed": 1, "case": "paper", "ratio_50": 2e40, "ratio_100": 0.9},
        base
        | {"seed": 0, "case": "late", "ratio_70": None, "ratio_130": 1.4}
        | {"ratio_130_low": 1.3, "ratio_130_high": 1.5},
    ]
    fig = figure(rows, ["seed", "case"])
    ax = fig.axes[-1]
    fig.draw_without_rendering()  # the legend sits beside the panel, over none of its points
    assert ax.get_legend().get_window_extent().x0 >= ax.get_window_extent().x1
    points = sorted(
        (round(float(line.get_ydata()[0]), 6), line.get_color())
        for line in ax.lines
        if len(line.get_ydata()) == 1 and line.get_marker() == "o"
    )
    assert [p for p, _ in points] == [0.9, 1.05, 1.2, 1.4]
    colours = dict((p, c) for p, c in points)
    assert colours[1.05] == colours[0.9] != colours[1.2] != colours[1.4]
    bars = sorted(
        tuple(round(float(v), 6) for v in np.ravel(segments.get_segments())[1::2])
        for segments in ax.collections
        if hasattr(segments, "get_segments") and len(segments.get_segments()) == 1
    )
    assert (1.0, 1.1) in bars and (1.1, 1.3) in bars and (1.3, 1.5) in bars
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert labels == ["sample 50", "sample 100", "sample 130", "0.8-1.25"]


def test_sweep_figure_without_the_held_out_check_draws_its_premiums() -> None:
    """A sweep whose base skips the held-out check (heldout_runs = 0): each leaf's premium is
    drawn, no rate, and the columns say "not checked", where they said every leaf "failed"
    and drew nothing; a refused profile beside them is still counted as refused."""
    rows = [
        {"seed": 0, "case": "a", "profile": "robust", "premium": 0.3},
        {"seed": 1, "case": "a", "profile": "robust", "premium": 0.25},
        {"seed": 0, "case": "b", "profile": "robust", "premium": 0.4},
        {"seed": 1, "case": "b", "profile": "robust", "error": "open loop cannot keep"},
    ]
    fig = figure(rows, ["seed", "case"])
    top, premium, lowest = fig.axes[0], fig.axes[1], fig.axes[-1]
    dots = sorted(tuple(np.round(xy, 6)) for c in premium.collections for xy in c.get_offsets())
    assert dots == [(-0.15, 30.0), (0.15, 25.0), (1.0, 40.0)]
    rates = [xy for c in top.collections for xy in c.get_offsets() if len(c.get_offsets())]
    assert [tuple(xy) for xy in rates] == [(1.0, 0.0)]  # the refused leaf's cross alone
    ticks = [t.get_text() for t in lowest.get_xticklabels()]
    assert ticks == ["a\n(2 not checked of 2)", "b\n(1 refused, 1 not checked of 2)"]


def test_the_verdict_of_a_sweep_without_the_held_out_check_says_so() -> None:
    """sweep.md with heldout_runs = 0: the torques' campaign and premium in the table, "not
    checked" for the held-out columns and no error counted, where the row was all "n/a" with
    its torque counted as an error."""
    sweep = {"axes": ["seed"], "steps": "", "executor": "ray", "wall_s": 1.0, "heldout_seeds": [7]}
    rows = [
        {"leaf": f"seed={s}", "seed": s, "profile": "robust", "premium": p, "robust_100": n}
        | {"campaign_runs": 100}
        for s, p, n in ((0, 0.3, 0), (1, 0.2, 2))
    ]
    text = markdown(sweep, rows)
    assert "- 2 robust torque(s) not checked on held-out machines (heldout_runs = 0)" in text
    assert "every robust torque returned" not in text and "## Errors" not in text
    expected = (
        "| all | 2 | not checked | not checked | not checked | 2/200 | 25.0 % (20.0 %–30.0 %) |"
    )
    assert expected in text
    assert text.rstrip().endswith("| n/a | n/a | 0 |")
