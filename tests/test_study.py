"""The seed study: one row per seed read back from its run folder, resume without redoing finished
seeds, a seed whose chain fails recorded with its one-line error, and the seed parser."""

from __future__ import annotations

import json
import re
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager, contextmanager
from dataclasses import replace

import pytest
from matplotlib.colors import to_rgba

from common.errors import ConfigError
from crank.chain import Hooks
from crank.study import parse_seeds, run_study
from tests.test_chain import BRIEF
from twin.variability import Variability

LINE_15 = Variability.resolve("line-15")


def _recorded(events: list[tuple]) -> Callable[[int], AbstractContextManager[Hooks]]:
    """A study's `progress` that records when each seed's block opens and closes and, between,
    its chain's stage lines and playing stages' totals."""

    @contextmanager
    def progress(seed: int) -> Iterator[Hooks]:
        events.append(("open", seed))
        try:
            yield Hooks(
                on_stage=lambda text: events.append((seed, text)),
                on_total=lambda stage, n: events.append((seed, stage, n)),
            )
        finally:
            events.append(("closed", seed))

    return progress


def test_study_rows_resume_and_files(tmp_path) -> None:
    out = tmp_path / "study"
    events: list[tuple] = []
    study = run_study(BRIEF, (0, 1), out, progress=_recorded(events))
    # each seed's chain runs inside its own block, one seed after the other
    assert events[:2] == [("open", 0), (0, "generating the dataset")]
    first = events[: events.index(("closed", 0)) + 1]
    assert (0, "replay", 4 * 4 * 2) in first and (0, "heldout", 20 * 4 * 2) in first
    assert events[len(first) : len(first) + 2] == [("open", 1), (1, "generating the dataset")]
    assert events[-1] == ("closed", 1) and [e for e in events if e[0] == "open"] == [
        ("open", 0),
        ("open", 1),
    ]
    rows = {(r["seed"], r["profile"]): r for r in study["rows"]}
    # one row per seed and robust profile, each judged in its own loop
    assert set(rows) == {(s, p) for s in (0, 1) for p in ("robust", "robust-fb", "robust-pd")}
    assert rows[0, "robust"]["error"] is None  # the configuration test_chain runs to the end
    for (seed, profile), row in rows.items():
        if row["error"] is not None:  # a 12 s toy model may not settle: then it says why
            if (out / f"seed-{seed}" / "error.txt").exists():
                assert (out / f"seed-{seed}" / "error.txt").read_text().strip() == row["error"]
            continue
        loop = {"robust": "open", "robust-fb": "closed", "robust-pd": "closed"}[profile]
        assert row["loop"] == loop
        heldout = json.loads((out / f"seed-{seed}" / "heldout.json").read_text())
        assert row["robust_heldout_rate"] == heldout["profiles"][profile][loop]["rate"]
        assert row["heldout_runs"] == 20
        ocp = json.loads((out / f"seed-{seed}" / "ocp.json").read_text())[profile]
        assert (row["solved_tightening"], row["solved_k"]) == (
            ocp["tightening_method"],
            ocp["k_sigma"],
        )
        assert row["solved_with"] == f"{ocp['tightening_method']} k {ocp['k_sigma']:g}"
        for k, entry in heldout["profiles"][profile][loop]["samples"].items():
            interval = entry["predicted"][row["mc_mode"]]["ratio_ci95"]
            assert [row[f"ratio_{k}_low"], row[f"ratio_{k}_high"]] == interval
            assert interval[0] < row[f"ratio_{k}"] < interval[1]
    for name in ("study.json", "study.csv", "study.md", "study.png"):
        assert (out / name).stat().st_size > 0
    text = (out / "study.md").read_text()
    assert "| seed | profile |" in text and "- robust-fb closed loop on held-out" in text
    assert "| premium | solved with |" in text
    # the campaign's counts are of its 4 machines a profile and loop (BRIEF's), not of 100
    assert "| robust /4 | nominal /4 |" in text and "open loop 0/4 campaign runs on" in text
    assert all(r["campaign_runs"] == 4 for r in rows.values() if r["error"] is None)
    assert "| pred/obs σ @50 | pred/obs σ @50 95 % from | pred/obs σ @50 95 % to |" in text
    assert "- robust-pd closed loop on held-out" in text
    stamp = (out / "seed-0" / "report.md").stat().st_mtime_ns
    with pytest.raises(ConfigError, match="already exists"):
        run_study(BRIEF, (0, 1), out)
    # resumed with other settings: refused before anything is run or written
    written = (out / "study.json").read_bytes()
    more = replace(BRIEF, replay=replace(BRIEF.replay, runs=5))
    line = replace(
        BRIEF,
        generation=replace(BRIEF.generation, variability=LINE_15),
        replay=replace(BRIEF.replay, variability=LINE_15),
    )
    for other, message in (
        (more, "replay.runs = 4, this study asks 5"),
        (line, "generation.variability.name = 'paper', this study asks 'line-15'"),
    ):
        with pytest.raises(ConfigError, match=re.escape(f"seed-0 ran with {message}")):
            run_study(other, (0, 1), out, resume=True)
    assert (out / "study.json").read_bytes() == written
    events.clear()  # with figures (no number changes): the finished seeds are the study's
    again = run_study(
        replace(BRIEF, figures=True), (0, 1), out, resume=True, progress=_recorded(events)
    )
    assert (out / "seed-0" / "report.md").stat().st_mtime_ns == stamp  # not redone
    assert events == []  # no chain ran
    assert again["rows"] == study["rows"]


def test_a_failing_seed_is_a_row_with_its_error(tmp_path) -> None:
    """k_sigma 3 on a 12 s model: no robust profile; the study records it and goes on."""
    failing = replace(BRIEF, ocp=replace(BRIEF.ocp, k_sigma=3.0, profiles=("robust",), fallback=()))
    events: list[tuple] = []
    study = run_study(failing, (0,), tmp_path / "study", progress=_recorded(events))
    assert events[-2:] == [(0, "solving the nominal and robust OCP"), ("closed", 0)]
    (row,) = study["rows"]
    assert row["seed"] == 0 and "no robust profile" in row["error"]
    assert "no robust profile" in (tmp_path / "study" / "seed-0" / "error.txt").read_text()
    assert "error:" in (tmp_path / "study" / "study.md").read_text()


@pytest.mark.parametrize(
    ("text", "seeds"),
    [("0-3", (0, 1, 2, 3)), ("4", (4,)), ("0,5, 7", (0, 5, 7)), ("1-2,9", (1, 2, 9))],
)
def test_parse_seeds(text: str, seeds: tuple[int, ...]) -> None:
    assert parse_seeds(text) == seeds


def _study(rows: list[dict], *, tightening: str, heldout_seed: int) -> dict:
    """A study.json of the paper line's robust open loop (1000 mixed trajectories, confidence
    0.95) over `rows`' seeds, for `markdown`."""
    ocp = {"mc_mode": "mixed", "mc_samples": 1000, "tightening": tightening}
    return {
        "seeds": [r["seed"] for r in rows],
        "rows": rows,
        "target_heldout_rate": 0.005,
        "config": {
            "generation": {"variability": {"name": "paper"}},
            "ocp": ocp | {"profiles": ["robust"], "confidence": 0.95},
            "heldout_seed": heldout_seed,
            "replay": {"runs": 100},
        },
    }


def test_the_verdict_names_seeds_whose_bound_cannot_confirm_the_target() -> None:
    """A worst seed at 0.2 % meets 0.5 %; a seed at 2 of 1000 (bound 0.63 %) is named as too
    few machines to confirm it, one at 0 of 1000 (0.30 %) is not."""
    from crank.study import markdown
    from replay.rates import rate_upper

    def row(seed: int, below: int) -> dict:
        return {
            "seed": seed,
            "profile": "robust",
            "error": None,
            "robust_100": 0,
            "robust_heldout_rate": below / 1000,
            "robust_heldout_upper_95": rate_upper(below, 1000),
        }

    study = _study([row(0, 0), row(1, 2)], tightening="gaussian", heldout_seed=7)
    text = markdown(study)
    assert (
        "- robust open loop on held-out machines: worst seed 0.20 % (target <= 0.5 %): **met**"
        in text
    )
    expected = "  - on 1 seed(s) the held-out verdict does not confirm it (worst 95 % bound 0.63 %)"
    assert expected in text
    study["rows"] = [row(0, 0), row(1, 1)]  # 1 of 1000: bound 0.47 %
    assert "does not confirm" not in markdown(study)


def test_machines_below_under_several_seeds_are_named() -> None:
    """Every seed's torque plays the same held-out machines: those below under more than one
    seed are named with how many, most first; one seed's alone, or none listed, say nothing."""
    from crank.study import markdown

    def row(seed: int, machines: list[int] | None) -> dict:
        return {
            "seed": seed,
            "profile": "robust",
            "error": None,
            "robust_100": 0,
            "robust_heldout_rate": len(machines or []) / 4000,
            "robust_heldout_upper_95": 0.002,
            "robust_heldout_machines": machines,
        }

    rows = [row(5, [3106, 3128]), row(6, [3128, 3229, 3106]), row(7, [3128, 12])]
    study = _study(rows, tightening="centred", heldout_seed=20261167)
    text = markdown(study)
    assert (
        "  - the same held-out machines below under several seeds' torques: 3128 (3 of 3 "
        "seeds), 3106 (2 of 3 seeds); the seeds' counts are not independent" in text
    )
    study["rows"] = [row(5, [1]), row(6, None), row(7, [2])]
    assert "several seeds" not in markdown(study)


def test_the_figure_puts_each_seeds_calibration_with_its_interval_on_the_band() -> None:
    """study.png's third panel: each seed's slider ratio at each constraint sample at that seed
    (the samples side by side), its bar the held-out interval, the 0.8-1.25 band behind; a ratio
    that diverged is left out, not drawn at 1e38."""
    from crank.study_figure import figure

    def row(seed: int, at50: float, at100: float) -> dict:
        return {
            "seed": seed,
            "profile": "robust",
            "error": None,
            "robust_heldout_rate": 0.0,
            "robust_heldout_upper_95": 0.0007,
            "premium": 0.31,
            "ratio_50": at50,
            "ratio_50_low": at50 - 0.03,
            "ratio_50_high": at50 + 0.04,
            "ratio_100": at100,
            "ratio_100_low": at100 - 0.05,
            "ratio_100_high": at100 + 0.06,
        }

    fig = figure([row(0, 1.15, 1.22), row(4, 1.14, 1.27), row(9, 1.13, 1e38)])
    assert len(fig.axes) == 3  # rates, premium, calibration (no seed refused)
    calibration = fig.axes[2]
    marks = {}
    for container in calibration.containers:
        if not len(container.lines[0].get_xdata()):  # the legend's handles
            continue
        (x,), (y,) = container.lines[0].get_data()
        if container.lines[2]:  # the interval's bar: from its low to its high end
            (segment,) = container.lines[2][0].get_segments()
            marks[round(x, 3)] = (y, segment[0][1], segment[1][1])
    assert sorted(marks) == [-0.02, 0.02, 3.98, 4.02, 8.98]  # seed 9's sample 100: no mark
    expected = {
        -0.02: (1.15, 1.12, 1.19),
        0.02: (1.22, 1.17, 1.28),
        3.98: (1.14, 1.11, 1.18),
        4.02: (1.27, 1.22, 1.33),
        8.98: (1.13, 1.10, 1.17),
    }
    for x, (value, low, high) in expected.items():
        assert marks[x] == pytest.approx((value, low, high), abs=1e-12)
    assert calibration.patches[0].get_y() == pytest.approx(0.8)  # the band
    assert calibration.patches[0].get_height() == pytest.approx(0.45)
    assert [t.get_text() for t in calibration.get_legend().get_texts()] == [
        "sample 50",
        "sample 100",
        "0.8-1.25",
    ]


def test_the_figure_names_each_rate_as_machines_below_out_of_those_played() -> None:
    """study.png's first panel says "k/n" over each bound's mark, so a rate of 0 (a bar of no
    height) still reads as what it was measured on; upright where profiles stand side by side,
    and nothing for a row that does not say how many machines it played."""
    from crank.study_figure import figure

    def row(seed: int, profile: str, below: int, runs: int | None) -> dict:
        entry = {
            "seed": seed,
            "profile": profile,
            "error": None,
            "robust_heldout_rate": below / (runs or 1000),
            "robust_heldout_upper_95": 0.0015,
            "premium": 0.05,
        }
        return entry if runs is None else entry | {"heldout_runs": runs}

    one = figure(
        [row(0, "robust-pd", 0, 2000), row(1, "robust-pd", 3, 4000), row(2, "robust-pd", 1, None)]
    )
    texts = [(t.get_text(), t.get_rotation()) for t in one.axes[0].texts]
    assert texts == [("0/2000", 0.0), ("3/4000", 0.0)]
    (label,) = [t for t in one.axes[0].texts if t.get_text() == "3/4000"]
    assert label.xy == pytest.approx((1.0, 0.15))  # over the bound's mark, in %
    two = figure([row(0, "robust", 7, 4000), row(0, "robust-fb", 0, 1000)])
    assert [(t.get_text(), t.get_rotation()) for t in two.axes[0].texts] == [
        ("7/4000", 90.0),
        ("0/1000", 90.0),
    ]


def test_the_figure_of_a_study_without_the_held_out_check_draws_its_premiums() -> None:
    """`crank study --heldout-runs 0`: each profile's premium is drawn in its colour, and the two
    held-out panels say the check was skipped (they said "no seed has a robust profile")."""
    from control.figures import COLORS
    from crank.study_figure import figure

    rows = [
        {"seed": 0, "profile": "robust", "error": None, "premium": 0.521},
        {"seed": 0, "profile": "robust-fb", "error": None, "premium": 0.012},
        {"seed": 1, "profile": "robust", "error": "RobustError: refused"},
    ]
    fig = figure(rows)
    top, premium, calibration = fig.axes[:3]
    heights = {round(p.get_x() + p.get_width() / 2, 3): p.get_height() for p in premium.patches}
    assert heights == pytest.approx({-0.2: 52.1, 0.2: 1.2})
    assert [p.get_facecolor() for p in premium.patches] == [
        pytest.approx(to_rgba(COLORS[name])) for name in ("robust", "robust-fb")
    ]
    for axis in (top, calibration):
        assert [t.get_text() for t in axis.texts] == ["no held-out check (--heldout-runs 0)"]
    assert not premium.texts and not top.patches
    legend = [t.get_text() for t in premium.get_legend().get_texts()]
    assert legend == ["robust (open loop)", "robust-fb (closed loop)"]


def test_the_verdict_of_a_study_without_the_held_out_check_says_so() -> None:
    """study.md of `crank study --heldout-runs 0`: one line saying there is no rate to judge
    (it said nothing above the table), and none where the check ran."""
    from crank.study import markdown

    row = {"seed": 0, "profile": "robust", "error": None, "robust_100": 0, "premium": 0.3}
    study = _study([row], tightening="centred", heldout_seed=7)
    study["config"]["heldout_runs"] = 0
    text = markdown(study)
    assert "- no held-out check (--heldout-runs 0): no rate to judge\n" in text
    assert "on held-out machines: worst seed" not in text
    study["config"]["heldout_runs"] = 1000
    assert "no held-out check" not in markdown(study)


def test_a_row_of_a_staged_check_counts_every_machine_it_played() -> None:
    """A torque the first 1000 machines could not judge (3 below) and a second stage of 9000 more
    (13 below in all): its row's rate, bound and machines are of all 10 000, the first stage's
    count beside; a first stage that decided, or no second stage, leaves the row as it was."""
    from crank.study import _second_stage
    from replay.rates import rate_upper

    first = {"violating_runs": 3, "violating_machines": [369, 675, 835]}
    staged = {
        "loop": "open",
        "machines": [1000, 10_000],
        "counts": [3, 13],
        "verdict": "holds",
        "violating_machines": [1186, 4056, 4593, 5406, 6190, 6462, 7275, 7813, 8427, 8466],
    }

    def heldout(entry: dict | None) -> dict:
        return {"staged": {"profiles": {"robust": entry}}} if entry is not None else {}

    assert _second_stage(heldout(staged), "robust", first) == {
        "heldout_runs": 10_000,
        "heldout_first_runs": 1000,
        "robust_heldout_first_below": 3,
        "robust_heldout_rate": 0.0013,
        "robust_heldout_upper_95": rate_upper(13, 10_000),
        "robust_heldout_machines": [369, 675, 835, *staged["violating_machines"]],
    }
    # more machines below than heldout.json lists: none listed rather than a part
    assert (
        _second_stage(heldout(staged | {"violating_machines": None}), "robust", first)[
            "robust_heldout_machines"
        ]
        is None
    )
    decided = heldout(staged | {"machines": [1000], "counts": [1]})
    assert _second_stage(decided, "robust", first) == {}
    assert _second_stage(heldout(None), "robust", first) == {}
    assert _second_stage(heldout(staged), "robust-fb", first) == {}  # a profile it did not judge


def test_the_verdict_of_a_staged_check_decides_whether_a_seed_is_confirmed() -> None:
    """36 of 10 000 after 3 of 1000: one look's bound on 10 000 would confirm it (0.48 %), the
    staged design (thresholds 1, 34) does not, and study.md names it; 13 of 10 000 it confirms;
    a row without a verdict is judged by its bound."""
    from crank.study import confirmed, markdown
    from replay.rates import rate_upper

    def row(seed: int, below: int, said: str) -> dict:
        return {
            "seed": seed,
            "profile": "robust",
            "error": None,
            "robust_100": 0,
            "robust_heldout_rate": below / 10_000,
            "robust_heldout_upper_95": rate_upper(below, 10_000),
            "robust_heldout_verdict": said,
        }

    assert rate_upper(36, 10_000) < 0.005
    study = _study(
        [row(0, 13, "holds"), row(1, 36, "unconfirmed")], tightening="centred", heldout_seed=7
    )
    text = markdown(study)
    assert "worst seed 0.36 % (target <= 0.5 %): **met**" in text
    assert (
        "  - on 1 seed(s) the held-out verdict does not confirm it (worst 95 % bound 0.48 %)"
        in text
    )
    study["rows"] = [row(0, 13, "holds")]
    assert "does not confirm" not in markdown(study)
    bare = {"robust_heldout_upper_95": 0.0047}
    assert confirmed(bare) and not confirmed({"robust_heldout_upper_95": 0.0063})
    assert not confirmed(bare | {"robust_heldout_verdict": "unconfirmed"})
