"""report.md's wording: the held-out loop as played, and ratios of a runaway Monte-Carlo."""

from __future__ import annotations

import pytest

from crank.report import train_summary
from crank.report_heldout import heldout_lines


def _heldout(mode: str, ratio: float) -> dict:
    entry = {
        "violating_runs": 0,
        "rate": 0.0,
        "rate_upper_95": 0.003,
        "samples": {
            "50": {
                "observed_sigma": 5e-4,
                "lowest": 0.081,
                "skew": 0.1,
                "predicted": {"mixed": {"ratio": 0.95}, "trajectory": {"ratio": ratio}},
            }
        },
    }
    return {
        "runs": 1000,
        "seed": 7,
        "modes": [mode],
        "mc_samples": 1000,
        "target_rate": 0.005,
        "holds": {"robust": True} if mode == "open" else {},
        "profiles": {"nominal": {mode: entry}, "robust": {mode: entry}},
    }


@pytest.mark.parametrize(
    ("mode", "words"),
    [
        ("open", "open loop"),
        ("closed", "closed loop under its LQR gains"),
        ("mpc", "under the online MPC"),
    ],
)
def test_heldout_says_the_loop_it_was_played_in(mode: str, words: str) -> None:
    text = "\n".join(heldout_lines(_heldout(mode, 1.1)))
    own = " (the loop it was tightened for)" if mode == "open" else ""
    assert f"- {words}{own}, the robust torque left" in text
    assert (mode == "open") == ("open loop" in text)
    assert "| robust | " + mode + " | 50 |" in text


def test_a_pd_tube_under_its_pd_is_in_the_loop_it_was_tightened_for() -> None:
    """Under the fixed PD, robust-pd (sized for it: in `holds`) is in its own loop, robust-fb
    (sized for its LQR: not in `holds`) is not."""
    heldout = _heldout("closed", 1.1)
    entry = heldout["profiles"]["robust"]["closed"]
    heldout["profiles"] = {"nominal": {"closed": entry}, "robust-fb": {"closed": entry}}
    heldout["profiles"]["robust-pd"] = {"closed": entry}
    heldout["feedback"], heldout["holds"] = "pd", {"robust-pd": True}
    text = "\n".join(heldout_lines(heldout))
    assert "under the fixed PD (the loop it was tightened for), the robust-pd torque" in text
    assert "under the fixed PD, the robust-fb torque" in text
    heldout["feedback"], heldout["holds"] = "lqr", {"robust-fb": True, "robust-pd": True}
    text = "\n".join(heldout_lines(heldout))
    tightened = " (the loop it was tightened for), the"
    assert f"- closed loop under its fixed PD{tightened} robust-pd torque" in text
    assert f"- closed loop under its LQR gains{tightened} robust-fb torque" in text


def test_the_machines_below_are_placed_in_the_line() -> None:
    """A robust torque's few machines below the height, each with its extremes in the line
    (heldout.json version 7); a file without placements (before 7) says nothing more."""
    heldout = _heldout("open", 1.1)
    entry = dict(heldout["profiles"]["robust"]["open"], violating_runs=1, violating_machines=[9])
    where = {
        "range_position": {"motor_frictionloss": 0.036, "slider_damping": 0.5},
        "start_s": 30.0,
        "start_share": 0.5,
        "force_mean_N": 1.2,
        "force_mean_z": 0.7,
    }
    heldout["profiles"]["robust"] = {"open": entry}
    assert "machine 9" not in "\n".join(heldout_lines(heldout))
    entry["violating_placements"] = [where]
    text = "\n".join(heldout_lines(heldout))
    assert (
        "  - machine 9 below: motor_frictionloss at 4 % of its range, mean slider force +1.2 N\n"
        in text
    )


def test_a_runaway_ratio_is_named_not_printed_in_full() -> None:
    text = "\n".join(heldout_lines(_heldout("closed", 1.46e68)))
    assert "diverged (1.5e+68)" in text and "| 0.95 |" in text
    assert "146" not in text.replace("1.46e68", "")
    calibration = {
        mode: {"theta": {"median": ratio}, "slider_position": {"median": 1.0}}
        for mode, ratio in (
            ("step", 0.2),
            ("trajectory", 1.46e68),
            ("machine", 0.8),
            ("mixed", 0.9),
        )
    }
    ppann = {"rmse_10_step": {"theta": 0.05, "omega": 4.8}, "train_seconds": 1.0}
    report = {"models": {"ppann": ppann}, "calibration": calibration}
    rows = train_summary(report)
    assert rows["σ predicted/observed (trajectory)"] == "θ diverged (1.5e+68), slider 1.00"
    assert rows["σ predicted/observed (mixed)"] == "θ 0.90, slider 1.00"
    assert "slider force σ (fitted)" not in rows
    ppann["lever_sigma"] = 17.26
    assert train_summary(report)["slider force σ (fitted)"] == "17.3 N"
    assert "residual's mean, of phase 2's power" not in rows
    ppann["residual_mean_share"] = 0.0635
    assert train_summary(report)["residual's mean, of phase 2's power"] == "6.3 %"


def test_theta_is_calibrated_at_each_constraint_sample_and_the_last() -> None:
    heldout = _heldout("open", 1.1)
    entry = heldout["profiles"]["robust"]["open"] = dict(heldout["profiles"]["robust"]["open"])
    sample = dict(entry["samples"]["50"])
    sample["theta"] = {
        "observed_sigma": 0.012,
        "predicted": {"mixed": {"ratio": 1.07}, "trajectory": {"ratio": 3.5}},
    }
    entry["samples"] = {"50": sample}
    entry["theta_final"] = {
        "observed_sigma": 0.2,
        "predicted": {"mixed": {"ratio": 0.98}, "trajectory": {"ratio": 9.0}},
    }
    heldout["profiles"] = {"robust": {"open": entry}}
    text = "\n".join(heldout_lines(heldout))
    assert "| robust | open | 50 | 12.0 | 1.07 | 3.50 |" in text
    assert "| robust | open | last | 200.0 | 0.98 | 9.00 |" in text
    # a version-2 file (no θ at the samples) gets the slider's table only
    assert "θ σ mrad" not in "\n".join(heldout_lines(_heldout("open", 1.1)))


@pytest.mark.parametrize(
    ("below", "runs", "word"),
    [
        (0, 1000, "**holds**."),
        (0, 100, "**is not confirmed**: within it on these 100 machines, but they are too few"),
        (6, 1000, "**does not hold**."),
    ],
)
def test_heldout_verdict_needs_its_bound_within_the_target(
    below: int, runs: int, word: str
) -> None:
    """0 of 100 is a rate of 0 % with an exact 95 % bound of 2.95 %: not a confirmed 0.5 %."""
    heldout = _heldout("open", 1.1)
    entry = heldout["profiles"]["robust"]["open"] | {"violating_runs": below, "rate": below / runs}
    heldout["profiles"]["robust"]["open"] = entry
    heldout["runs"] = runs
    text = "\n".join(heldout_lines(heldout))
    assert f"Against the target of <= 0.5 % the robust torque {word}" in text


def test_the_models_own_rate_stands_beside_the_observed_one() -> None:
    """heldout.json version 4 carries the model's own rate below the height; report.md puts it
    beside the machines' (an older heldout.json without it reads as before)."""
    heldout = _heldout("open", 1.1)
    before = "\n".join(heldout_lines(heldout))
    assert "own Monte-Carlo" not in before
    own = {"mode": "mixed", "draws": 20000, "rate": 0.0064, "samples": {"50": 0.0064}}
    heldout["profiles"]["robust"]["open"] = {**heldout["profiles"]["robust"]["open"]}
    heldout["profiles"]["robust"]["open"]["model_rate"] = own
    text = "\n".join(heldout_lines(heldout))
    assert "upper bound 0.30 %) (the model's own Monte-Carlo of 20000 trajectories: 0.64 %)" in text


def test_the_calibration_table_gives_each_ratio_its_interval() -> None:
    """heldout.json version 5: the observed σ and each ratio with the interval the machines
    allow; a diverged ratio gets none, and a version-4 file reads as before."""
    heldout = _heldout("open", 2e40)
    sample = heldout["profiles"]["robust"]["open"]["samples"]["50"]
    sample = sample | {
        "observed_sigma_ci95": [4.8e-4, 5.3e-4],
        "predicted": {
            "mixed": {"ratio": 0.95, "ratio_ci95": [0.9, 0.99]},
            "trajectory": {"ratio": 2e40, "ratio_ci95": [1.9e40, 2.1e40]},
        },
    }
    entry = heldout["profiles"]["robust"]["open"] | {"samples": {"50": sample}}
    heldout["profiles"] = {"robust": {"open": entry}}
    text = "\n".join(heldout_lines(heldout))
    assert "| robust | open | 50 | 0.50 (0.48–0.53) | 81.0 | +0.10 | 0.95 (0.90–0.99) |" in text
    assert "| diverged (2.0e+40) |" in text
    assert "(0.48–0.53)" not in "\n".join(heldout_lines(_heldout("open", 1.1)))
