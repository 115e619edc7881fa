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
    payload = _with_closed_loop(json.loads(ocp_path.read_text()), gains=3.0)
    payload["config"] |= {"height": HEIGHT, "constraint_samples": SAMPLES}
    for name in ("nominal", "robust", "robust-fb"):
        payload[name]["heights"] = [HEIGHT] * len(SAMPLES)
    path = tmp_path_factory.mktemp("verify") / "ocp.json"
    path.write_text(json.dumps(payload))
    return path


def _with_closed_loop(payload: dict, *, gains: float) -> dict:
    """The plan with robust-fb: robust's torque for the closed loop, its gains times `gains`."""
    closed = dict(payload["robust"], loop="closed")
    for key in ("gain_theta", "gain_omega"):
        closed[key] = [gains * g for g in closed[key]]
    payload["robust-fb"] = closed
    payload["config"]["profiles"] = ["robust", "robust-fb"]
    payload["profiles"] = ["nominal", "robust", "robust-fb"]
    return payload


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
        with pytest.raises(VerifyError, match=r"its nearest stretch, from its sample \d+, is"):
            verify_file(split_ocp, runs, tmp_path / "v.json", profile=profile, align="torque")
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


@pytest.fixture(scope="module")
def ppann_path(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A constant PPANN with a machine spread and a transmission error, saved."""
    import torch

    from ppann.checkpoint import save
    from ppann.model import constant_ppann

    model = constant_ppann(z_mean=(0.0, 0.0, -0.9), z_sigma=(0.03, 0.05, 0.05))
    with torch.no_grad():
        model.machine_sigma.copy_(torch.tensor([0.08, 0.05, 0.05], dtype=torch.float64))
        model.transmission.copy_(torch.linspace(-0.01, 0.01, len(model.transmission)))
    path = tmp_path_factory.mktemp("ppann") / "model.pt"
    save(path, model, kind="ppann", extra={"history": {}})
    return path


@pytest.mark.parametrize("profile", ["robust", "robust-fb"])
def test_the_split_is_the_monte_carlo_of_each_part_alone(
    split_ocp: Path, ppann_path: Path, profile: str
) -> None:
    """White part: the step mode's draws; machines: the machine mode's; each in the profile's
    loop (robust-fb: under its own gains, clipped), the slider through the drawn transmission
    error — the Monte-Carlo called directly, with the plan's streams."""
    from common.streams import rng, stream
    from control.ocp_file import read_ocp
    from ppann.checkpoint import load
    from ppann.heads import FusedHeads
    from ppann.montecarlo import Feedback, monte_carlo
    from ppann.transmission import draw
    from replay.verify_split import spread_split

    ocp, model = read_ocp(split_ocp), load(ppann_path)[0]
    plan, seed = ocp.profiles[profile], ocp.config.mc_seed
    split = spread_split(ocp, profile, model, n_samples=400)
    heads = FusedHeads(model)
    law = None
    if plan.loop == "closed":
        gains = np.stack([plan.gain_theta, plan.gain_omega], axis=-1)
        law = Feedback(np.stack([plan.theta, plan.omega], axis=-1), gains, 10.0)
    delta = draw(heads.transmission, (400,), rng(seed, "transmission"))
    assert np.std(delta) > 1e-3
    for part, mode in (("white", "step"), ("machine", "machine")):
        bands = monte_carlo(
            heads,
            [plan.theta[0], plan.omega[0]],
            plan.tau[:-1],
            n_samples=400,
            mode=mode,
            seed=stream(seed, "monte_carlo"),
            feedback=law,
        )
        for k in SAMPLES:
            theta = bands.samples[:, k - 1, 0]
            slider = ocp.geometry.slider_position(theta + delta)
            assert split[k][part] == np.std(slider, ddof=1) > 0
            assert split[k][f"theta_{part}"] == np.std(theta, ddof=1) > 0


def test_runs_read_as_one_machines_beside_the_white_part(
    split_ocp: Path, ppann_path: Path, played: dict[str, Replay], tmp_path: Path
) -> None:
    """With the PPANN, each constraint sample sets the runs' θ spread beside the white part's
    and says where their mean sits in the machines' σ; without it, no split (and the report
    says how to get one)."""
    import hashlib

    runs = import_runs(played["open"], tmp_path / "r.mcap")
    digest = hashlib.sha256(ppann_path.read_bytes()).hexdigest()
    named = json.loads(split_ocp.read_text())  # the plan as a solve on the PPANN names it
    named["model"] = {"path": str(ppann_path), "sha256": digest, "kind": "ppann"}
    plan = tmp_path / "ocp.json"
    plan.write_text(json.dumps(named))
    stats = verify_file(plan, runs, tmp_path / "a" / "v.json")  # the PPANN it names
    assert stats["model"] == {"path": str(ppann_path), "sha256": digest}
    replay = played["open"]
    for k in SAMPLES:
        s = stats["samples"][str(k)]
        theta = replay.theta[:, k - 1]
        assert s["theta"]["observed_sigma"] == pytest.approx(theta.std(ddof=1), rel=1e-9)
        assert s["theta"]["white_ratio"] == pytest.approx(
            s["theta"]["white_sigma"] / theta.std(ddof=1), rel=1e-9
        )
        offset = (replay.slider_position[:, k - 1].mean() - s["predicted_mean"]) / s[
            "machine_sigma"
        ]
        assert s["machine_offset"] == pytest.approx(offset, rel=1e-9)
    assert "## If the runs are one machine's" in (tmp_path / "a" / "v.md").read_text()
    bare = verify_file(split_ocp, runs, tmp_path / "b" / "v.json")  # the plan names no PPANN
    assert bare["model"] is None and bare["samples"]["50"]["machine_offset"] is None
    assert bare["samples"]["50"]["theta"]["white_ratio"] is None
    assert "give it with --ppann" in (tmp_path / "b" / "v.md").read_text()


def test_runs_of_several_machines_are_taken_apart(
    split_ocp: Path, ppann_path: Path, played: dict[str, Replay], tmp_path: Path
) -> None:
    """Twelve runs named to three machines (four each): at each constraint sample θ's spread
    within a machine (pooled, N - M degrees of freedom) and the machines' own (var of the
    machine means less the within variance / 4) equal numpy's to 1e-9, each inside its interval,
    beside the PPANN's white and machine parts; verify.md takes them apart, not one machine's."""
    labels = [7] * 4 + [8] * 4 + [9] * 4
    runs = import_runs(played["open"], tmp_path / "r.mcap", machines=labels)
    named = json.loads(split_ocp.read_text())
    named["model"] = {"path": str(ppann_path), "kind": "ppann"}
    plan = tmp_path / "ocp.json"
    plan.write_text(json.dumps(named))
    stats = verify_file(plan, runs, tmp_path / "a" / "v.json")
    m = stats["machines"]
    assert (m["count"], m["labels"], m["runs"]) == (3, ["7", "8", "9"], [4, 4, 4])
    assert [r["machine"] for r in stats["runs"]] == [str(n) for n in labels]
    for k in SAMPLES:
        groups = played["open"].theta[:, k - 1].reshape(3, 4)
        within = np.sqrt(((groups - groups.mean(1, keepdims=True)) ** 2).sum() / (12 - 3))
        between = np.sqrt(max(groups.mean(1).var(ddof=1) - within**2 / 4, 0.0))
        s = m["samples"][str(k)]
        assert s["within_sigma"] == pytest.approx(within, rel=1e-9)
        assert s["between_sigma"] == pytest.approx(between, rel=1e-9, abs=1e-15)
        assert s["within_sigma_ci95"][0] <= within <= s["within_sigma_ci95"][1]
        assert s["white_sigma"] == stats["samples"][str(k)]["theta"]["white_sigma"]
        assert s["white_ratio"] == pytest.approx(s["white_sigma"] / within, rel=1e-12)
        assert s["machine_sigma"] > 0
    report = (tmp_path / "a" / "v.md").read_text()
    assert "## The runs of 3 machines" in report and "one machine's" not in report
    alone = verify_file(plan, import_runs(played["open"], tmp_path / "s.mcap"), tmp_path / "b.json")
    assert alone["machines"] is None and alone["runs"][0]["machine"] is None
    each = import_runs(played["open"], tmp_path / "e.mcap", machines=list(range(12)))
    apart = verify_file(plan, each, tmp_path / "d" / "v.json")["machines"]
    assert apart["runs"] == [1] * 12 and apart["samples"]["50"]["within_sigma"] is None
    assert "Each machine ran once" in (tmp_path / "d" / "v.md").read_text()
    one = import_runs(played["open"], tmp_path / "o.mcap", machines=[7] * 12)
    assert verify_file(plan, one, tmp_path / "c" / "v.json")["machines"] is None
    assert "## If the runs are one machine's" in (tmp_path / "c" / "v.md").read_text()


def test_a_folder_of_plan_runs_and_check_reads_the_same_anywhere(
    split_ocp: Path, played: dict[str, Replay], tmp_path: Path
) -> None:
    """Paths inside the check's folder are recorded relative to it; a check again without its
    figure leaves no figure of the earlier one beside its numbers."""
    plan = tmp_path / "ocp.json"
    plan.write_bytes(split_ocp.read_bytes())
    runs = import_runs(played["open"], tmp_path / "runs.mcap")
    out = tmp_path / "verify.json"
    stats = verify_file(plan, runs, out)
    assert (stats["ocp"]["path"], stats["data"]["path"]) == ("ocp.json", "runs.mcap")
    assert out.with_suffix(".png").is_file()
    verify_file(plan, runs, out, figures=False)
    assert not out.with_suffix(".png").exists()
    assert "no figure (--no-figures)" in out.with_suffix(".md").read_text()


def test_one_run_is_counted_and_has_no_spread(
    split_ocp: Path, played: dict[str, Replay], tmp_path: Path
) -> None:
    from dataclasses import replace

    replay = played["open"]
    first = replace(
        replay, **{k: getattr(replay, k)[:1] for k in ("theta", "omega", "slider_position", "tau")}
    )
    stats = verify_file(split_ocp, import_runs(first, tmp_path / "one.mcap"), tmp_path / "v.json")
    assert len(stats["runs"]) == 1 and stats["rate_upper_95"] == pytest.approx(0.95)
    for k in SAMPLES:
        s = stats["samples"][str(k)]
        assert s["observed_sigma"] is None and s["ratio"] is None
        assert s["lowest"] == s["observed_mean"] == replay.slider_position[0, k - 1]
    assert stats["violating_runs"] == int(
        np.any(replay.slider_position[0, [k - 1 for k in SAMPLES]] < HEIGHT)
    )


@pytest.fixture(scope="module")
def loop_ocp(ocp_path: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The synthetic plan with robust-fb: robust's torque and gains, for the closed loop."""
    payload = _with_closed_loop(json.loads(ocp_path.read_text()), gains=1.0)
    path = tmp_path_factory.mktemp("loop") / "ocp.json"
    path.write_text(json.dumps(payload))
    return path


def test_a_controller_faster_than_the_plan_is_checked_at_its_rate(
    physics: SliderCrank, loop_ocp: Path, tmp_path: Path
) -> None:
    """A twin machine whose controller evaluates the law 4 times a sample (2 kHz), each row's
    reference held: refused against the once-a-sample law, saying a faster law matches it;
    checked at its rate it is within 0.2 N·m (the states between samples taken on a straight
    line). At the plan's rate the same simulation is the law to 1e-9 N·m."""
    from tests.rig_runs import fast_controller_runs

    plan_rate = fast_controller_runs(
        physics, loop_ocp, tmp_path / "f1.mcap", profile="robust-fb", per_sample=1, runs=4
    )
    stats = verify_file(loop_ocp, plan_rate, tmp_path / "a.json", profile="robust-fb")
    assert max(r["played_rms"] for r in stats["runs"]) < 1e-9
    runs = fast_controller_runs(
        physics, loop_ocp, tmp_path / "f4.mcap", profile="robust-fb", per_sample=4, runs=4
    )
    faster = "within the tolerance of the law evaluated faster than 500 Hz: give the controller"
    with pytest.raises(VerifyError, match=faster):
        verify_file(loop_ocp, runs, tmp_path / "b.json", profile="robust-fb")
    held = verify_file(
        loop_ocp, runs, tmp_path / "b.json", profile="robust-fb", played_tolerance=1.0
    )
    fast = verify_file(loop_ocp, runs, tmp_path / "c.json", profile="robust-fb", control_rate=2000)
    assert fast["control_rate_hz"] == 2000 and held["control_rate_hz"] == 500
    for slow, quick in zip(held["runs"], fast["runs"], strict=True):
        assert quick["played_rms"] < 0.2 < 0.5 < slow["played_rms"]
