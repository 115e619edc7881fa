"""The chain as a library: an in-process `crank run` on a short configuration succeeds, records
its resolved configuration and streams, and the same seed reproduces every artifact's numbers."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch
from mcap.reader import make_reader

from common.atomic import OutputError
from common.errors import ConfigError
from common.jsonio import without_wall_clock
from crank.chain import STAGES_FILE, Hooks, RunConfig, run_chain
from crank.resume import resumed_config
from tests.conftest import LATE_MPC
from twin.mcap_dataset import read_dataset
from twin.plan_config import PlanConfig

SHORT = RunConfig.for_seed(
    0,
    generation={"seconds": 12.0, "episode_seconds": 2.0},
    train={"max_epochs": 3, "sigma_epochs": 20},
    # A 12 s model is too uncertain for a 3σ profile; 0.5σ still exercises the robust loop. Its
    # 6 machines of 2 s leave the line too open for any allowance at the default confidence
    # (tests/test_tightening.py covers that), so this chain takes the fitted line as it is.
    # Every robust profile: every stage then carries four (the held-out check two loops). Its
    # Monte-Carlo's mean slider sits ~20 mm below the plan at sample 50, so the centred
    # tightening (the default) refuses the open loop (33 mm asked); eq. 16's k·σ about the plan
    # still exercises that loop.
    ocp={
        "tightening": "gaussian",
        "k_sigma": 0.5,
        "mc_samples": 200,
        "confidence": 0.0,
        "profiles": ("robust", "robust-fb", "robust-pd"),
    },
    replay={"runs": 4},
    heldout_runs=20,
    # 20 machines measure a spread to ~±30 %: the check's predictions need not be 10 000 draws
    heldout_trajectories=1000,
    calibration_runs=20,  # the model report's observed σ: from as many machines as the check's
    baselines=False,
    plan={"episodes": 0},  # one round: the default's plan round is tests/test_plan_round.py's
)
BRIEF = replace(SHORT, figures=False)
"""SHORT writing no figure (RunConfig.figures): for the tests that check a chain's numbers, not
its figures, which this file's chains and tests/test_cli.py's run check; tests/test_sweep.py
checks that a chain without them computes the same numbers."""


class _StoppedError(Exception):
    """Stands for Ctrl-C or a crash between two stages."""


def _stop_at_replay(text: str) -> None:
    if text == "replaying on the twin":
        raise _StoppedError


@pytest.fixture(scope="module")
def two_runs(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, dict]:
    """The same run twice: "a" straight through; "b" stopped before its replay and resumed, so
    that every test comparing the two also checks that a resumed run is the run."""
    root = tmp_path_factory.mktemp("chain")
    report = run_chain(SHORT, root / "a", argv=[])
    b = root / "b"
    with pytest.raises(_StoppedError):
        run_chain(SHORT, b, argv=[], hooks=Hooks(on_stage=_stop_at_replay))
    assert set(json.loads((b / STAGES_FILE).read_text())) == {"generate", "train", "solve"}
    assert not (b / "replay.mcap").exists() and not (b / "report.md").exists()
    trained = (b / "model.pt").stat().st_mtime_ns
    stages: list[str] = []
    told: list[tuple[str, str, int]] = []  # what the playing stages count, in order
    hooks = Hooks(
        on_stage=stages.append,
        on_total=lambda stage, n: told.append(("total", stage, n)),
        on_runs=lambda stage, n: told.append(("played", stage, n)),
    )
    run_chain(SHORT, b, argv=[], hooks=hooks, resume=True)
    # the replay: 4 machines x 4 profiles x 2 loops, each run as logged; the held-out check:
    # 20 machines x 4 profiles x 2 loops, a batch (all 20) per profile and loop
    assert told == [
        ("total", "replay", 32),
        *[("played", "replay", 1)] * 32,
        ("total", "heldout", 160),
        *[("played", "heldout", 20)] * 8,
    ]
    assert stages[:3] == [
        "generating the dataset: done before, kept",
        "training the PPANN: done before, kept",
        "solving the nominal and robust OCP: done before, kept",
    ]
    assert stages[3] == "replaying on the twin"
    assert (b / "model.pt").stat().st_mtime_ns == trained  # not trained again
    assert not (b / STAGES_FILE).exists()
    return root / "a", b, report


def test_resume_refuses_a_finished_or_foreign_folder(two_runs, tmp_path: Path) -> None:
    a, _, _ = two_runs
    with pytest.raises(OutputError, match="finished"):
        run_chain(SHORT, a, resume=True)
    with pytest.raises(OutputError, match="not a run folder"):
        run_chain(SHORT, tmp_path, resume=True)
    other = tmp_path / "other"
    other.mkdir()
    (other / "config.json").write_text((a / "config.json").read_text())
    with pytest.raises(ConfigError, match="another run's configuration"):
        run_chain(SHORT.with_seed(1), other, resume=True)


def test_run_config_round_trips_through_config_json(two_runs) -> None:
    a, _, _ = two_runs
    assert resumed_config(a) == SHORT
    assert RunConfig.from_dict(json.loads(json.dumps(RunConfig().as_dict()))) == RunConfig()
    broken = SHORT.as_dict()
    del broken["ocp"]["height"], broken["train"]
    with pytest.raises(ConfigError, match="lacks the key 'train'"):
        RunConfig.from_dict(broken)
    broken = SHORT.as_dict() | {"ocp": {**SHORT.ocp.as_dict(), "heigth": 0.08}}
    with pytest.raises(ConfigError, match="heigth"):
        RunConfig.from_dict(broken)
    # a config.json from before early stopping on every machine trained on the paper's tail
    old = SHORT.as_dict()
    del old["train"]["early_stopping"]
    assert RunConfig.from_dict(old).train.early_stopping == "tail"
    assert SHORT.train.early_stopping == "machines"


def test_a_config_json_from_before_the_pair_reads_as_it_ran() -> None:
    """One from before the pair was the default (session 62) ran one round of eq. 14's z_K, as
    did one from before either setting existed: read without the keys, they are so again."""
    default = RunConfig().as_dict()
    assert default["plan"]["episodes"] == 240 and default["train"]["mean_wrap"] is True
    del default["plan"], default["train"]["mean_wrap"]
    before = RunConfig.from_dict(default)
    assert before.plan.episodes == 0 and before.train.mean_wrap is False
    assert before == replace(
        RunConfig(), plan=PlanConfig(episodes=0), train=replace(RunConfig().train, mean_wrap=False)
    )


def test_a_config_json_from_before_the_trapezoid_reads_as_it_ran() -> None:
    """One from before the trapezoid angle update was the default (session 88) stepped by eq. 4's
    forward Euler: read without the key, it does so again."""
    default = RunConfig().as_dict()
    assert default["train"]["angle_update"] == "trapezoid"
    del default["train"]["angle_update"]
    before = RunConfig.from_dict(default)
    assert before == replace(RunConfig(), train=replace(RunConfig().train, angle_update="euler"))


def test_a_config_json_from_before_the_second_stage_reads_as_it_ran() -> None:
    """One from before the held-out check's second stage (session 93) looked once: read without
    the key, it does so again; crank run's defaults play 9000 more where 1000 cannot decide."""
    from crank.config_file import build, defaults

    assert build(defaults(), source="defaults").heldout_second_stage == 9000
    given = replace(RunConfig(), heldout_runs=1000, heldout_second_stage=9000).as_dict()
    del given["heldout_second_stage"]
    assert RunConfig.from_dict(given) == replace(RunConfig(), heldout_runs=1000)
    assert RunConfig().heldout_second_stage == 0


def test_in_process_run_writes_every_artifact(two_runs) -> None:
    a, _, report = two_runs
    for name in (
        "config.json",
        "dataset.mcap",
        "model.pt",
        "model.report.json",
        "ocp.json",
        "replay.mcap",
        "replay.stats.json",
        "heldout.json",
        "report.json",
        "report.md",
    ):
        assert (a / name).is_file(), name
    config = json.loads((a / "config.json").read_text())
    assert config["generation"]["seconds"] == 12.0 and config["heldout_runs"] == 20
    assert config["streams"]["root_seed"] == 0
    assert config["heldout_streams"]["root_seed"] == SHORT.heldout_seed
    heldout = json.loads((a / "heldout.json").read_text())
    assert heldout["runs"] == 20 and heldout["modes"] == ["open", "closed"]
    assert (heldout["mc_samples"], heldout["tail_draws"]) == (1000, 2000)  # the run's setting
    assert heldout["pd"] == {"kp": SHORT.replay.kp, "kd": SHORT.replay.kd}
    assert list(heldout["profiles"]) == ["nominal", "robust", "robust-fb", "robust-pd"]
    assert set(heldout["holds"]) == {"robust", "robust-fb", "robust-pd"}
    for name, loop in (("robust", "open"), ("robust-fb", "closed"), ("robust-pd", "closed")):
        rate = heldout["profiles"][name][loop]["rate"]
        assert heldout["holds"][name] == (rate <= heldout["target_rate"])
        # 20 machines cannot confirm 0.5 % (0 of 598 would): never "holds"
        assert heldout["verdicts"][name] == ("unconfirmed" if rate <= 0.005 else "fails")
    for entry in (e for played in heldout["profiles"].values() for e in played.values()):
        assert 0 <= entry["violating_runs"] <= 20
        assert entry["rate_upper_95"] >= entry["rate"]
        assert set(entry["samples"]["50"]["predicted"]) == {
            "step",
            "trajectory",
            "machine",
            "mixed",
        }
    assert report["heldout"]["runs"] == 20
    estimated = report["estimated_seconds"]  # said before, beside what it took
    assert set(estimated) == set(report["wall_seconds"])
    assert all(0 < low <= high for low, high in estimated.values())
    assert "Wall time [s] (estimated beforehand)" in (a / "report.md").read_text()
    ocp = json.loads((a / "ocp.json").read_text())
    assert ocp["variability"]["name"] == "paper"
    assert ocp["config"]["mc_mode"] == "mixed"
    assert len(ocp["robust"]["tightening"]) == 2 and len(ocp["robust-fb"]["tightening"]) == 2
    assert ocp["robust-pd"]["gain_theta"] == [SHORT.ocp.pd_kp] * 149
    assert ocp["robust-pd"]["gain_omega"] == [SHORT.ocp.pd_kd] * 149
    stats = json.loads((a / "replay.stats.json").read_text())
    assert set(stats["claims"]) == {"robust", "robust-fb", "robust-pd"}
    assert stats["claims"]["robust-fb"]["loop"] == stats["claims"]["robust-pd"]["loop"] == "closed"
    text = (a / "report.md").read_text()
    assert "The robust-fb torque" in text and "ocp.robust-fb.png" in text
    ppann = json.loads((a / "model.report.json").read_text())["models"]["ppann"]
    for name, estimate in ppann["machine_sigma"].items():  # a bound is above its estimate
        assert ppann["machine_sigma_upper"][name] > estimate
        assert ppann["line_mean_se"][name] > 0


def test_same_seed_reproduces_every_artifact(two_runs) -> None:
    a, b, _ = two_runs
    da, db = read_dataset(a / "dataset.mcap"), read_dataset(b / "dataset.mcap")
    for name in ("theta", "omega", "tau", "slider_position"):
        assert np.array_equal(getattr(da, name), getattr(db, name)), name
    # Byte for byte: the dataset, and the checkpoint (saved from memory, the data path relative
    # to it), so both ocp.json record the same model hash.
    assert (a / "dataset.mcap").read_bytes() == (b / "dataset.mcap").read_bytes()
    assert (a / "model.pt").read_bytes() == (b / "model.pt").read_bytes()
    wa = torch.load(a / "model.pt", weights_only=True)["state_dict"]
    wb = torch.load(b / "model.pt", weights_only=True)["state_dict"]
    assert all(torch.equal(wa[k], wb[k]) for k in wa)
    assert float(wa["machine_sigma"].max()) > 0
    oa = json.loads((a / "ocp.json").read_text())
    ob = json.loads((b / "ocp.json").read_text())
    assert oa["model"]["sha256"] == ob["model"]["sha256"]
    for profile in ("nominal", "robust", "robust-fb", "robust-pd"):
        for key in ("tau", "slider", "slider_sigma", "tightening"):
            assert oa[profile][key] == ob[profile][key], (profile, key)
    sa = json.loads((a / "replay.stats.json").read_text())
    sb = json.loads((b / "replay.stats.json").read_text())
    assert sa["profiles"] == sb["profiles"]
    ha = json.loads((a / "heldout.json").read_text())
    hb = json.loads((b / "heldout.json").read_text())
    assert ha["profiles"] == hb["profiles"]


def test_same_seed_gives_the_same_bytes_but_the_documented_wall_clock(two_runs) -> None:
    """The reproducibility rule of common/jsonio.py, file by file of the two run folders."""
    a, b, _ = two_runs
    names = sorted(p.name for p in a.iterdir())
    assert names == sorted(p.name for p in b.iterdir())
    checked = []
    for name in names:
        if name.endswith((".rrd", ".md", ".log")):
            continue  # outside the rule (Rerun's ids and clock; wall times for people)
        if name.endswith(".json"):
            x, y = (json.loads((d / name).read_text()) for d in (a, b))
            assert without_wall_clock(x) == without_wall_clock(y), name
        elif name == "replay.mcap":
            x, y = (_campaign_records(d / name) for d in (a, b))
            assert x == y, name
        else:
            assert (a / name).read_bytes() == (b / name).read_bytes(), name
        checked.append(name)
    assert {
        "dataset.mcap",
        "model.pt",
        "ocp.json",
        "replay.stats.json",
        "ocp.robust.png",
        "ocp.robust-fb.png",
        "ocp.robust-pd.png",
    } <= set(checked)
    ocp = json.loads((a / "ocp.json").read_text())
    assert ocp["model"]["path"] == "model.pt"  # relative to the run folder


def _campaign_records(path: Path) -> tuple[list, list, list]:
    """Messages, metadata and attachments of a campaign log; ocp.json without wall clock."""
    with path.open("rb") as f:
        reader = make_reader(f)
        messages = [(c.topic, m.log_time, m.data) for _, c, m in reader.iter_messages()]
        metadata = [(m.name, dict(m.metadata)) for m in reader.iter_metadata()]
        attached = [
            (x.name, without_wall_clock(json.loads(x.data)) if x.name == "ocp.json" else x.data)
            for x in reader.iter_attachments()
        ]
    return messages, metadata, attached


def test_run_refuses_an_existing_folder(two_runs) -> None:
    a, _, _ = two_runs
    with pytest.raises(OutputError, match="already exists"):
        run_chain(SHORT, a)


def test_compare_plays_every_profile_under_every_controller(two_runs, tmp_path: Path) -> None:
    """`crank compare` on the short run: one row per profile and controller (robust-pd, sized for
    the fixed PD, has its own law in the closed-PD row and no closed-LQR one); on the run's own
    campaign and held-out machines its open and own-law rows are the run's replay.stats.json and
    heldout.json to the last digit; the MPC rows carry step times; compare.md has the verdict."""
    from crank.compare import CONTROLLERS, compare_runs

    a, _, _ = two_runs
    said: list[str] = []
    counts: list[tuple[str, str, int]] = []
    result = compare_runs(
        [a],
        tmp_path / "cmp",
        runs=4,
        heldout_runs=20,
        heldout_seed=SHORT.heldout_seed,
        hooks=Hooks(
            on_stage=lambda text: (said.append(text), counts.append(("line", text, 0))),
            on_total=lambda stage, n: counts.append(("total", stage, n)),
            on_runs=lambda stage, n: counts.append(("played", stage, n)),
        ),
    )
    # progress: a line per profile and loop of the held-out check as it finishes
    assert sum(line.startswith("  robust-fb ") for line in said) == 4
    # each stage's total (4 profiles, each in the LQR's 3 loops and the PD's) before it plays; the
    # campaign's 4 machines at a time, the held-out ones in one batch open and closed loop and
    # a machine's worth of the MPC's steps at a time (20 machines, 150 samples)
    for stage, machines, batch in (("campaign", 4, (4,)), ("held-out", 20, (20,))):
        mine = [(kind, n) for kind, name, n in counts if name == stage]
        assert mine[0] == ("total", machines * 4 * 4)
        loops = ["open", "closed", "mpc"] * 4 + ["closed"] * 4  # the LQR's, then the PD's
        mpc = (1,) * machines
        assert [n for _, n in mine[1:]] == [
            n for m in loops for n in (mpc if m == "mpc" else batch)
        ]
    assert counts.index(("total", "held-out", 320)) > max(
        i for i, c in enumerate(counts) if c[1] == "campaign"
    )
    # each stage's line after its bar's total (the bar before it closed first), before its plays
    for stage, line in (("campaign", "campaign machines"), ("held-out", "held-out machines")):
        heading = next(i for i, c in enumerate(counts) if c[0] == "line" and line in c[1])
        assert counts[heading - 1][:2] == ("total", stage)
    (scenario,) = result["scenarios"]
    rows = {(r["profile"], r["controller"]): r for r in scenario["rows"]}
    names = ("nominal", "robust", "robust-fb")
    assert set(rows) == {(p, c) for p in (*names, "robust-pd") for c in CONTROLLERS} - {
        ("robust-pd", "closed-LQR")
    }
    stats = json.loads((a / "replay.stats.json").read_text())
    heldout = json.loads((a / "heldout.json").read_text())
    for (profile, controller), row in rows.items():
        own = "closed-PD" if profile == "robust-pd" else "closed-LQR"
        mode = {"open": "open", own: "closed"}.get(controller)
        if mode is None:
            continue
        played = stats["profiles"][profile][mode]
        assert row["below_campaign"] == played["violating_runs"]
        assert row["effort_applied"] == played["effort"]["applied_mean"]
        held = heldout["profiles"][profile][mode]
        assert row["heldout_rate"] == held["rate"]
    for profile in names:
        assert rows[profile, "mpc"]["mpc"]["steps"] == 4 * 149
        assert (
            rows[profile, "closed-PD"]["theta_rms_mrad"]
            != rows[profile, "closed-LQR"]["theta_rms_mrad"]
        )
        assert rows[profile, "open"]["premium"] == rows[profile, "mpc"]["premium"]
    assert scenario["spread"] == pytest.approx(0.05)
    text = (tmp_path / "cmp" / "compare.md").read_text()
    assert "- robust-fb under closed-LQR:" in text and "- robust-fb under mpc:" in text
    assert "- robust-pd under closed-PD:" in text and "- robust-pd under mpc" not in text
    assert (tmp_path / "cmp" / "compare.png").stat().st_size > 10_000
    with pytest.raises(ConfigError, match="already exists"):
        compare_runs([a], tmp_path / "cmp", runs=4, heldout_runs=20, heldout_seed=1)
    with pytest.raises(ConfigError, match="not a finished run folder"):
        compare_runs([tmp_path], tmp_path / "other", heldout_seed=1)
    assert not (tmp_path / "other").exists()


def test_compare_folders_made_apart_merge_into_one(two_runs, tmp_path: Path) -> None:
    """Two compare folders (the same run made twice: a straight, b resumed) merge into one with
    both scenarios, row for row as compared apart; other settings or one folder are refused."""
    from crank.compare import compare_runs, counted, merge_compares

    a, b, _ = two_runs
    kwargs = {"runs": 2, "heldout_runs": 5, "heldout_seed": 3, "mpc": LATE_MPC}
    parts = [compare_runs([run], tmp_path / run.name, **kwargs)["scenarios"] for run in (a, b)]
    merged = merge_compares([tmp_path / "a", tmp_path / "b"], tmp_path / "ab")
    assert merged["scenarios"] == parts[0] + parts[1]
    assert [r["heldout_rate"] for r in parts[0][0]["rows"]] == [
        r["heldout_rate"] for r in parts[1][0]["rows"]
    ]  # the same run, resumed, plays the same
    assert "## Every run pooled" in (tmp_path / "ab" / "compare.md").read_text()
    assert counted(merged) == "2 runs of 1 scenario"  # the terminal's line: not "2 scenarios"
    assert counted({"scenarios": parts[0]}) == "1 run of 1 scenario"
    three = [{"scenario": name} for name in ("paper", "line-15", "paper")]
    assert counted({"scenarios": three}) == "3 runs of 2 scenarios"
    # a folder compared with 3 runs: the merge reads only compare.json, so one is made by hand
    other = json.loads((tmp_path / "a" / "compare.json").read_text()) | {"runs": 3}
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "compare.json").write_text(json.dumps(other))
    with pytest.raises(ConfigError, match="other settings: runs"):
        merge_compares([tmp_path / "b", tmp_path / "other"], tmp_path / "bad")
    with pytest.raises(ConfigError, match="at least two"):
        merge_compares([tmp_path / "a"], tmp_path / "bad")
    with pytest.raises(ConfigError, match="a run is in two"):
        merge_compares([tmp_path / "a", tmp_path / "ab"], tmp_path / "bad")
    assert not (tmp_path / "bad").exists()


def test_compare_plays_the_pd_the_runs_replays_played(two_runs, tmp_path: Path) -> None:
    """A run whose replays ran another fixed PD (Kp 10, Kd 0.25; its config.json rewritten, its
    ocp.json's robust-pd still sized for 20, 0.5) is compared under that PD: its closed-PD rows
    are the held-out check's under it, and robust-pd, whose own law is no longer this PD, gets
    a closed-LQR row (its own gains). Runs that played different PDs are refused before any
    replay. (The compare once played the default PD whatever the run's was.)"""
    import shutil

    from crank.compare import compare_runs
    from ppann.checkpoint import load
    from replay.heldout import heldout_check
    from twin.physics import SliderCrank, load_model

    a, _, _ = two_runs
    other = tmp_path / "pd10"
    shutil.copytree(a, other)
    config = json.loads((a / "config.json").read_text())
    config["replay"] |= {"kp": 10.0, "kd": 0.25}
    config["ocp"] |= {"pd_kp": 10.0, "pd_kd": 0.25}
    (other / "config.json").write_text(json.dumps(config))
    with pytest.raises(ConfigError, match=r"different fixed PDs \(Kp 10 Kd 0\.25, Kp 20 Kd 0\.5\)"):
        compare_runs([a, other], tmp_path / "bad", runs=2, heldout_runs=5, heldout_seed=3)
    assert not (tmp_path / "bad").exists()
    result = compare_runs([other], tmp_path / "cmp", runs=2, heldout_runs=10, heldout_seed=3)
    assert result["pd"] == result["scenarios"][0]["pd"] == {"kp": 10.0, "kd": 0.25}
    rows = {(r["profile"], r["controller"]): r for r in result["scenarios"][0]["rows"]}
    assert ("robust-pd", "closed-LQR") in rows
    physics = SliderCrank(load_model(RunConfig.from_dict(config).model_path)[0])
    model, _ = load(other / "model.pt")
    kwargs = {"runs": 10, "seed": 3, "modes": ("closed",), "feedback": "pd"}
    kwargs |= {"variability": RunConfig.from_dict(config).generation.variability}
    held = heldout_check(physics, other / "ocp.json", model, kp=10.0, kd=0.25, **kwargs)
    default = heldout_check(physics, other / "ocp.json", model, **kwargs)
    for name, entry in held["profiles"].items():
        lowest = 1e3 * min(e["lowest"] for e in entry["closed"]["samples"].values())
        assert rows[name, "closed-PD"]["lowest_heldout_mm"] == lowest
        assert rows[name, "closed-PD"]["heldout_rate"] == entry["closed"]["rate"]
        other_pd = default["profiles"][name]["closed"]["samples"]
        assert lowest != 1e3 * min(e["lowest"] for e in other_pd.values())


def test_a_moved_run_is_compared_on_a_copy_of_its_twin(two_runs, tmp_path: Path) -> None:
    """A run folder whose config.json names an MJCF that is gone (moved to another machine or
    checkout): `crank compare` stops before any replay with one line naming the path and the way
    out; `--mjcf` with an edited file is refused, with a byte-for-byte copy the moved run is
    compared, and compare.json names the copy. (It once stopped at a bare "MJCF not found", and
    an MJCF edited since the run was played without a word.)"""
    import shutil

    from crank.compare import compare_runs
    from tests.conftest import crank
    from twin.physics import MODEL_PATH

    a, _, _ = two_runs
    moved = tmp_path / "moved"
    shutil.copytree(a, moved)
    config = json.loads((a / "config.json").read_text())
    gone = tmp_path / "gone" / "slider_crank.xml"
    (moved / "config.json").write_text(json.dumps(config | {"model_path": str(gone)}))
    refused = crank("compare", str(a), str(moved), "--out", str(tmp_path / "bad"))
    assert refused.returncode == 2 and refused.stderr.count("\n") == 1, refused.stderr
    assert refused.stderr.startswith(f"error: MJCF not found: {gone} (the twin of {moved}/")
    assert refused.stderr.rstrip().endswith("…); pass --mjcf with a copy of that twin")
    assert not (tmp_path / "bad").exists()
    edited = tmp_path / "edited.xml"
    edited.write_text(MODEL_PATH.read_text() + "<!-- edited -->\n")
    kwargs = {"runs": 2, "heldout_runs": 2, "heldout_seed": 3, "mpc": LATE_MPC}
    with pytest.raises(ConfigError, match=r"edited\.xml is not the twin .* was generated on"):
        compare_runs([moved], tmp_path / "bad", mjcf=edited, **kwargs)
    copy = tmp_path / "twin.xml"
    shutil.copy(MODEL_PATH, copy)
    merging = crank(
        "compare", "--merge", str(a), str(moved), "--mjcf", str(copy), "--out", str(tmp_path / "x")
    )
    assert (merging.returncode, merging.stderr) == (
        2,
        "error: --mjcf is for replays; --merge joins compare folders and plays none\n",
    )
    (here,) = compare_runs([moved], tmp_path / "cmp", mjcf=copy, **kwargs)["scenarios"]
    assert here["mjcf"] == str(copy) and here["run"] == str(moved)
    assert {r["campaign_runs"] for r in here["rows"]} == {2} and len(here["rows"]) == 15
