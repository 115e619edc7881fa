"""The held-out check's second stage (replay/heldout_stages.py): the machines it plays are the
same draw's next ones, its counts those of one pass over all of them, and the check's verdicts
are the staged design's."""

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from control.ocp_file import OCPFile
from ppann.model import constant_ppann
from replay.campaign import draw_machines, play
from replay.config import ReplayConfig
from replay.heldout import heldout_check, heldout_file
from replay.heldout_stages import extend
from replay.rates import heldout_verdict_text
from replay.staged import StagedError, decide, design
from twin.physics import SliderCrank
from twin.variability import Variability

SEED = 11


def _below(physics: SliderCrank, ocp: OCPFile, runs: int) -> np.ndarray:
    """Each of the first `runs` held-out machines of SEED below the height at any constraint
    sample under the robust torque, in one pass."""
    config = ReplayConfig(runs=runs, seed=SEED, modes=("open",))
    machines = draw_machines(config, ocp.horizon, held_out=True)
    replay = play(physics, ocp, profile="robust", mode="open", machines=machines, config=config)
    x = replay.slider_position[:, [k - 1 for k in ocp.config.constraint_samples]]
    return (x < ocp.config.height).any(axis=1)


def _lowest(physics: SliderCrank, ocp: OCPFile, runs: int) -> np.ndarray:
    config = ReplayConfig(runs=runs, seed=SEED, modes=("open",))
    machines = draw_machines(config, ocp.horizon, held_out=True)
    replay = play(physics, ocp, profile="robust", mode="open", machines=machines, config=config)
    return replay.slider_position[:, [k - 1 for k in ocp.config.constraint_samples]].min(axis=1)


@pytest.mark.parametrize("batch", [7, 40])
def test_the_second_stage_counts_what_one_pass_over_all_machines_counts(
    physics: SliderCrank, ocp: OCPFile, batch: int
) -> None:
    """A height that a quarter of 60 machines go below; the target the first 20 machines' rate,
    so that they cannot decide (a rate exactly on the target, its bound above it): the second
    stage plays machines 20-59 in batches and its count, listed machines and verdict are a
    single pass's over all 60."""
    height = float(np.quantile(_lowest(physics, ocp, 60), 0.25))
    lowered = dataclasses.replace(ocp, config=dataclasses.replace(ocp.config, height=height))
    reference = _below(physics, lowered, 60)
    first = int(reference[:20].sum())
    assert 1 <= first < 20  # the design below needs a target strictly inside (0, 1)
    target = first / 20
    plan = design((20, 60), target=target)
    assert decide(plan, [first]) == "next"
    calls: list[tuple] = []
    staged = extend(
        physics,
        lowered,
        judged={"robust": ("open", first)},
        config=ReplayConfig(runs=20, seed=SEED, modes=("open",)),
        extend_to=60,
        batch=batch,
        listed_most=50,
        target=target,
        on_extend=lambda *a: calls.append(("extend", *a)),
        on_machines=lambda *a: calls.append(("played", *a)),
    )
    entry = staged["profiles"]["robust"]
    assert entry["counts"] == [first, int(reference.sum())]
    assert entry["machines"] == [20, 60]
    assert entry["violating_machines"] == (np.flatnonzero(reference[20:]) + 20).tolist()
    assert entry["verdict"] == decide(plan, entry["counts"])
    assert staged["thresholds"] == list(plan.thresholds)
    sizes = [min(batch, 60 - s) for s in range(20, 60, batch)]
    assert calls == [("extend", "robust", "open", 40)] + [
        ("played", "robust", "open", n) for n in sizes
    ]


def test_a_decided_first_stage_plays_nothing_more(physics: SliderCrank, ocp: OCPFile) -> None:
    """Every machine below (the fixture's height): the first stage fails it, and no machine of
    a second stage is played."""
    calls: list[tuple] = []
    staged = extend(
        physics,
        ocp,
        judged={"robust": ("open", 20)},
        config=ReplayConfig(runs=20, seed=SEED, modes=("open",)),
        extend_to=60,
        batch=10,
        listed_most=50,
        on_extend=lambda *a: calls.append(a),
        on_machines=lambda *a: calls.append(a),
    )
    assert calls == []
    assert staged["profiles"]["robust"] == {
        "loop": "open",
        "machines": [20],
        "counts": [20],
        "verdict": "fails",
        "violating_machines": None,
    }


def test_the_check_with_a_second_stage_judges_on_all_its_machines(
    physics: SliderCrank, ocp_path: Path, tmp_path: Path
) -> None:
    """None below (the height lowered out of reach): 8 machines cannot confirm 0.5 %, so the
    robust torque is played on 12 more; 20 cannot either, and the verdict says so from both
    counts; the first stage's entries are those of a check without a second stage."""
    data = json.loads(ocp_path.read_text())
    data["config"]["height"] = 0.0
    low = tmp_path / "ocp.json"
    low.write_text(json.dumps(data))
    model = constant_ppann(z_mean=(0.0, 0.0, -0.9), z_sigma=(0.03, 0.05, 0.05))
    kwargs = dict(
        runs=8, seed=SEED, variability=Variability.scenario("paper"), mc_samples=50, tail_draws=300
    )
    one = heldout_check(physics, low, model, **kwargs)
    staged = heldout_check(physics, low, model, extend_to=20, **kwargs)
    assert one["verdicts"] == {"robust": "unconfirmed"} and "staged" not in one
    entry = staged["staged"]["profiles"]["robust"]
    assert entry["counts"] == [0, 0] and entry["machines"] == [8, 20]
    assert staged["verdicts"] == {"robust": "unconfirmed"} and staged["holds"] == {"robust": True}
    assert "0 of 20 machines below (the first 8: 0" in heldout_verdict_text(staged, "robust")
    for result in (one, staged):
        del result["timing"]
    del staged["staged"]
    assert json.dumps(staged, sort_keys=True) == json.dumps(one, sort_keys=True)


def test_the_report_and_terminal_say_the_staged_verdict() -> None:
    """The words of a torque judged in two stages name both counts and the design's risk; one
    decided by its first stage reads as one look."""
    from crank.report_heldout import verdict_words

    plan = design((1000, 10_000))
    entry = {"violating_runs": 2, "rate": 0.002}
    heldout = {
        "runs": 1000,
        "target_rate": 0.005,
        "profiles": {"robust": {"open": entry}},
        "staged": {
            **plan.as_dict(),
            "profiles": {
                "robust": {
                    "loop": "open",
                    "machines": [1000, 10_000],
                    "counts": [2, 18],
                    "verdict": decide(plan, [2, 18]),
                    "violating_machines": None,
                }
            },
        },
    }
    words = verdict_words(entry, heldout, profile="robust")
    assert words.startswith("**holds** on all 10000 machines played: 18 below (0.18 %;")
    assert "the first 1000 had 2" in words and "4.8 %" in words
    assert verdict_words(entry, heldout).startswith("**is not confirmed**")  # another loop's
    text = heldout_verdict_text(heldout, "robust")
    assert text.startswith("holds at <= 0.5 %: 18 of 10000 machines below (the first 1000: 2")
    heldout["staged"]["profiles"]["robust"] |= {"machines": [1000], "counts": [1]}
    assert heldout_verdict_text(heldout, "robust").startswith("holds at <= 0.5 % (95 % bound")


@pytest.mark.parametrize("extend_to", [8, 5, -1, 2.5, True])
def test_a_second_stage_must_be_more_machines(
    ocp_path: Path, tmp_path: Path, extend_to: object
) -> None:
    with pytest.raises(StagedError, match="extend_to"):
        heldout_file(
            ocp_path,
            tmp_path / "heldout.json",
            model=tmp_path / "none.pt",
            runs=8,
            seed=SEED,
            variability=Variability.scenario("paper"),
            extend_to=extend_to,
        )
    assert list(tmp_path.iterdir()) == []
