"""`crank verify`: runs of a profile recorded on a machine, checked against the plan. The twin
plays the rig (tests/rig_runs.py): its runs go out as a 1 kHz table in a rig's units and signs,
come back through `crank import`, and must count and spread exactly as the twin's own replay of
the same machines does."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from common.jsonio import without_wall_clock
from replay.campaign import Replay
from replay.statistics import replay_statistics
from replay.verify import VerifyError
from replay.verify_report import output_paths, verify_file
from tests.conftest import crank
from tests.rig_runs import import_runs, play_runs
from twin.physics import SliderCrank

HEIGHT, SAMPLES = 0.052, [50, 60]
"""A task on the synthetic plan that some of its runs break and some keep (its own, 0.08 m at
samples 50 and 100, every run of it breaks)."""
RUNS = 12


@pytest.fixture(scope="module")
def split_ocp(ocp_path: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The synthetic plan with HEIGHT at SAMPLES; robust-fb: robust's torque tightened for the
    closed loop, its gains tripled so that the clip acts on some samples."""
    payload = json.loads(ocp_path.read_text())
    payload["config"] |= {"height": HEIGHT, "constraint_samples": SAMPLES}
    closed = dict(payload["robust"], loop="closed")
    for key in ("gain_theta", "gain_omega"):
        closed[key] = [3.0 * g for g in closed[key]]
    payload["robust-fb"] = closed
    payload["config"]["profiles"] = ["robust", "robust-fb"]
    payload["profiles"] = ["nominal", "robust", "robust-fb"]
    for name in ("nominal", "robust", "robust-fb"):
        payload[name]["heights"] = [HEIGHT] * len(SAMPLES)
    path = tmp_path_factory.mktemp("verify") / "ocp.json"
    path.write_text(json.dumps(payload))
    return path


@pytest.fixture(scope="module")
def played(physics: SliderCrank, split_ocp: Path) -> dict[str, Replay]:
    return {
        mode: play_runs(
            physics, split_ocp, profile=name, mode=mode, runs=RUNS, seed=3
        )
        for mode, name in (("open", "robust"), ("closed", "robust-fb"))
    }  # fmt: skip


@pytest.mark.parametrize(("mode", "profile"), [("open", "robust"), ("closed", "robust-fb")])
def test_the_runs_count_and_spread_as_the_twins_replay(
    split_ocp: Path, played: dict[str, Replay], tmp_path: Path, mode: str, profile: str
) -> None:
    """Through the rig's table and `crank import`, each run played the law to 1e-9 N·m (closed
    loop: the tracking law with its clip), and below-height counts, lowest slider and observed σ
    at the constraint samples are the twin replay's own statistics."""
    from control.ocp_file import read_ocp

    replay = played[mode]
    ocp = read_ocp(split_ocp)
    runs = import_runs(replay, tmp_path / "runs.mcap")
    stats = verify_file(split_ocp, runs, tmp_path / "verify.json", profile=profile)
    twin = replay_statistics(replay, ocp)
    assert stats["ocp"]["loop"] == mode and len(stats["runs"]) == RUNS
    assert max(r["played_rms"] for r in stats["runs"]) < 1e-9
    if mode == "closed":
        assert 0 < np.mean(np.abs(replay.tau) == 10.0) < 0.5  # the clip acted on some samples
    for k in SAMPLES:
        s, t = stats["samples"][str(k)], twin["constraint"][str(k)]
        assert s["below"] == twin["violations"][str(k)]
        assert s["lowest"] == pytest.approx(t["lowest"], abs=1e-12)
        assert s["observed_mean"] == pytest.approx(t["mean"], abs=1e-12)
        observed = replay.slider_position[:, k - 1].std(ddof=1)
        assert s["observed_sigma"] == pytest.approx(observed, rel=1e-9)
        plan = ocp.profiles[profile]
        assert s["predicted_sigma"] == plan.sigma_in(mode)[k - 1]
        assert s["ratio"] == pytest.approx(s["predicted_sigma"] / observed, rel=1e-9)
        low, high = s["observed_sigma_ci95"]
        assert low < observed < high
    assert stats["violating_runs"] == twin["violating_runs"]
    if mode == "open":  # the task splits the open-loop runs: the claim fails on them
        assert 0 < stats["violating_runs"] < RUNS and stats["verdict"] == "fails"
    below = [r["below"] for r in stats["runs"]]
    expected = np.any(replay.slider_position[:, [k - 1 for k in SAMPLES]] < HEIGHT, axis=1)
    assert below == expected.tolist()
    assert all(p.is_file() for p in output_paths(tmp_path / "verify.json").values())


def test_a_lead_in_is_refused_at_the_start_and_found_by_the_torque(
    split_ocp: Path, played: dict[str, Replay], tmp_path: Path
) -> None:
    """Runs recorded 25 samples before the profile starts: lined up at their start they did not
    play it (the error says where they do); lined up by their torque they give the numbers of
    the runs without the lead-in."""
    replay = played["open"]
    plain = verify_file(split_ocp, import_runs(replay, tmp_path / "a.mcap"), tmp_path / "a.json")
    lead = import_runs(replay, tmp_path / "b.mcap", lead=25)
    with pytest.raises(VerifyError, match=r"run 1 \(episode 0\) did not play profile robust.*"
                       r"it is nearest from its sample 26 \(t = 0.05 s"):  # fmt: skip
        verify_file(split_ocp, lead, tmp_path / "b.json")
    assert not (tmp_path / "b.json").exists()
    found = verify_file(split_ocp, lead, tmp_path / "b.json", align="torque")
    assert [r["offset"] for r in found["runs"]] == [25] * RUNS
    assert found["runs"][0]["start_s"] == pytest.approx(0.05)
    for k in map(str, SAMPLES):
        for key in ("below", "lowest", "observed_mean", "observed_sigma", "ratio"):
            assert found["samples"][k][key] == pytest.approx(plain["samples"][k][key], abs=1e-12)


def test_runs_of_another_law_are_refused(
    split_ocp: Path, played: dict[str, Replay], tmp_path: Path
) -> None:
    """Open-loop runs are not the closed loop's (nor closed-loop runs the open loop's torque):
    counting them would say nothing of the profile asked for."""
    for mode, profile in (("open", "robust-fb"), ("closed", "robust")):
        runs = import_runs(played[mode], tmp_path / f"{mode}.mcap")
        with pytest.raises(VerifyError, match=f"did not play profile {profile}: its torque is"):
            verify_file(split_ocp, runs, tmp_path / "v.json", profile=profile)
        # a tolerance wide enough takes them (the check is a tolerance, not a guess)
        verify_file(split_ocp, runs, tmp_path / "v.json", profile=profile, played_tolerance=1.0)


def test_runs_that_stop_early_are_compared_as_far_as_they_go(
    split_ocp: Path, played: dict[str, Replay], tmp_path: Path
) -> None:
    short = import_runs(played["open"], tmp_path / "s.mcap", keep=80)  # 79 samples imported
    stats = verify_file(split_ocp, short, tmp_path / "s.json")
    assert {r["samples"] for r in stats["runs"]} == {79}
    cut = import_runs(played["open"], tmp_path / "c.mcap", keep=55)
    with pytest.raises(VerifyError, match="has 54 samples; the constraint's last is sample 60"):
        verify_file(split_ocp, cut, tmp_path / "c.json")


def test_the_same_runs_give_the_same_file(
    split_ocp: Path, played: dict[str, Replay], tmp_path: Path
) -> None:
    runs = import_runs(played["closed"], tmp_path / "r.mcap")
    texts = []
    for name in ("one", "two"):
        verify_file(split_ocp, runs, tmp_path / name / "v.json", profile="robust-fb")
        texts.append(without_wall_clock(json.loads((tmp_path / name / "v.json").read_text())))
    assert texts[0] == texts[1]


def test_the_command_prints_the_verdict_and_writes_three_files(
    split_ocp: Path, played: dict[str, Replay], tmp_path: Path
) -> None:
    runs = import_runs(played["open"], tmp_path / "r.mcap")
    out = tmp_path / "v" / "verify.json"
    done = crank("verify", str(split_ocp), str(runs), "--profile", "nominal", "--out", str(out))
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert lines[0].split() == ["sample", "below", "lowest", "mm", "mean", "obs/pred", "mm",
                                "3σ", "obs/pred", "mm", "σ", "pred/obs", "(95", "%)", "mean",
                                "offset", "σ"]  # fmt: skip
    stats = json.loads(out.read_text())
    assert stats["verdict"] is None and stats["ocp"]["profile"] == "nominal"
    assert lines[-2].endswith("; the nominal profile claims nothing")
    assert lines[-1] == f"wrote {out}, {out.with_suffix('.md')}, {out.with_suffix('.png')}"
    report = out.with_suffix(".md").read_text()
    assert "# crank verify: profile nominal on 12 recorded runs" in report
    assert sorted(p.name for p in out.parent.iterdir()) == [
        "verify.json",
        "verify.md",
        "verify.png",
    ]
