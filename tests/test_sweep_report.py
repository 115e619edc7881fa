"""crank/sweep_report.py: the sweep's verdict and figure from result rows, against exact
text (no sweep runs here; tests/test_sweep.py runs them)."""

from __future__ import annotations

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
    assert "- 1 of them with a 95 % bound above the target (worst 0.77 %)" in text
    assert "seed=2: solve step: no robust profile" in text
    text = markdown(sweep, [row(0, 0.006, 0.011)])
    assert "worst 0.60 % (seed=0, robust), target <= 0.5 %: **NOT met**" in text
    assert "| all | 1 | 6/1000 (0.60 %) |" in text
    assert text.rstrip().endswith("| 30.0 % (30.0 %–30.0 %) | n/a | 0 |")  # no model_rate yet
    own = [row(0, 0.001, 0.0047) | {"robust_model_rate": r} for r in (0.001, 0.002)]
    assert "| 30.0 % (30.0 %–30.0 %) | 0.150 %, 0.200 % | 0 |" in markdown(sweep, own)


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
    bottom = fig.axes[1]
    ticks = [t.get_text() for t in bottom.get_xticklabels()]
    assert len(ticks) == 8
    assert ticks[0] == "paper\nsamples 60, 90\nrobust-fb"
    assert ticks[3] == "paper\nhorizon 200,\nsamples 70, 130\nrobust-pd"
    assert bottom.get_xlabel() == "generation.variability / case / profile"
    assert bottom.get_ylim()[0] < -0.2
