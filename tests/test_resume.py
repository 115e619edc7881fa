"""A run resumed with other settings for the stages it has not made (crank/resume.py): it goes on
from its dataset and model, config.json says what changed and from which command, and a setting
of a stage already made, or of the data or the training, is refused."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from common.errors import ConfigError
from control.ocp_file import read_ocp
from crank.chain import STAGES_FILE, Hooks, run_chain
from crank.resume import resumed_config, with_settings
from crank.study import run_rows
from tests.conftest import crank
from tests.test_chain import BRIEF


class _StoppedError(Exception):
    """Stands for a refused solve, Ctrl-C or a crash before the solve."""


def _stop_at_solve(text: str) -> None:
    if text == "solving the nominal and robust OCP":
        raise _StoppedError


@pytest.fixture(scope="module")
def unsolved(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """BRIEF stopped before its solve: dataset and model made, nothing after."""
    run = tmp_path_factory.mktemp("resume") / "run"
    with pytest.raises(_StoppedError):
        run_chain(BRIEF, run, argv=[], hooks=Hooks(on_stage=_stop_at_solve))
    assert set(json.loads((run / STAGES_FILE).read_text())) == {"generate", "train"}
    return run


def _copy(run: Path, to: Path) -> Path:
    shutil.copytree(run, to)
    return to


def test_a_resume_with_another_profile_goes_on_from_the_model(unsolved, tmp_path: Path) -> None:
    run = _copy(unsolved, tmp_path / "run")
    trained = (run / "model.pt").stat().st_mtime_ns
    changed = with_settings(BRIEF, {"ocp": {"profiles": ["robust-fb"]}, "replay": {"runs": 2}})
    assert changed.ocp.profiles == ("robust-fb",) and changed.replay.runs == 2
    stages: list[str] = []
    run_chain(changed, run, argv=["resumed"], hooks=Hooks(on_stage=stages.append), resume=True)
    assert stages[:3] == [
        "generating the dataset: done before, kept",
        "training the PPANN: done before, kept",
        "solving the nominal and robust OCP",
    ]
    assert (run / "model.pt").stat().st_mtime_ns == trained  # not trained again
    assert (run / "report.md").is_file() and not (run / STAGES_FILE).exists()
    assert read_ocp(run / "ocp.json").robust_names == ("robust-fb",)
    written = json.loads((run / "config.json").read_text())
    assert written["ocp"]["profiles"] == ["robust-fb"] and written["replay"]["runs"] == 2
    assert written["resumed"] == [{"argv": ["resumed"], "changed": ["ocp", "replay"]}]
    assert written["argv"] == []  # the command that made the folder stays
    assert resumed_config(run) == changed
    stats = json.loads((run / "replay.stats.json").read_text())
    assert stats["config"]["runs"] == 2


def test_a_setting_of_a_stage_made_or_of_the_data_is_refused(unsolved, tmp_path: Path) -> None:
    run = _copy(unsolved, tmp_path / "run")
    before = {p.name: p.stat().st_mtime_ns for p in run.iterdir()}
    with pytest.raises(ConfigError, match="another run's configuration"):
        run_chain(BRIEF.with_seed(1), run, resume=True)
    longer = with_settings(BRIEF, {})
    with pytest.raises(ConfigError, match="cannot change generation"):
        with_settings(longer, {"generation": {"seconds": 20.0}})
    done = json.loads((run / STAGES_FILE).read_text())
    (run / STAGES_FILE).write_text(json.dumps(done | {"solve": {}}))  # as if it had solved
    with pytest.raises(ConfigError, match="already solved its OCPs: its ocp settings cannot"):
        run_chain(with_settings(BRIEF, {"ocp": {"confidence": 0.5}}), run, resume=True)
    after = {p.name: p.stat().st_mtime_ns for p in run.iterdir() if p.name != STAGES_FILE}
    assert after == {k: v for k, v in before.items() if k != STAGES_FILE}  # nothing written


def test_the_cli_resumes_with_other_profiles_and_names_what_it_takes(
    unsolved, tmp_path: Path
) -> None:
    run = _copy(unsolved, tmp_path / "run")
    refused = crank("run", "--resume", str(run), "--seconds", "5")
    assert refused.returncode == 2 and "drop --seconds (only --profiles, --fallback, --pd" in (
        refused.stderr
    )
    bad = crank("run", "--resume", str(run), "--runs", "0")
    assert bad.returncode == 2 and "runs must be an integer" in bad.stderr.strip().splitlines()[-1]
    assert "resumed" not in json.loads((run / "config.json").read_text())
    done = crank("run", "--resume", str(run), "--profiles", "robust-pd", "--heldout-runs", "10")
    assert done.returncode == 0, done.stderr
    assert "training the PPANN: done before, kept" in done.stderr
    estimate = next(x for x in done.stderr.splitlines() if x.startswith("estimated time"))
    assert "(solve " in estimate and "train" not in estimate  # what is left to make
    written = json.loads((run / "config.json").read_text())
    assert written["ocp"]["profiles"] == ["robust-pd"] and written["heldout_runs"] == 10
    assert written["resumed"][0]["changed"] == ["ocp", "heldout_runs"]
    assert written["resumed"][0]["argv"][-4:] == ["--profiles", "robust-pd", "--heldout-runs", "10"]
    assert json.loads((run / "heldout.json").read_text())["runs"] == 10


def test_a_moved_run_resumes_on_a_copy_of_its_twin(unsolved, tmp_path: Path) -> None:
    """A folder whose config.json names an MJCF that is gone (moved to another machine or
    checkout) goes on with `--model` naming a byte-for-byte copy, which config.json then records;
    without it, or with an edited file, one line names the twin the dataset was made on and the
    folder is left as it was but for its transcript. (It once stopped at a bare "MJCF not
    found", with no way on.)"""
    from twin.physics import MODEL_PATH

    run = _copy(unsolved, tmp_path / "run")
    config = json.loads((run / "config.json").read_text())
    gone = tmp_path / "gone" / "slider_crank.xml"
    (run / "config.json").write_text(json.dumps(config | {"model_path": str(gone)}))
    before = {p.name: p.stat().st_mtime_ns for p in run.iterdir()}
    stopped = crank("run", "--resume", str(run))
    assert stopped.returncode == 2, stopped.stderr
    (line,) = stopped.stderr.splitlines()
    assert line.startswith(f"error: MJCF not found: {gone} (the twin of {run}/dataset.mcap, ")
    assert line.endswith("…); pass --model with a copy of that twin")
    edited = tmp_path / "edited.xml"
    edited.write_text(MODEL_PATH.read_text() + "<!-- edited -->\n")
    other = crank("run", "--resume", str(run), "--model", str(edited))
    assert other.returncode == 2 and other.stderr.startswith(f"error: {edited} is not the twin ")
    after = {p.name: p.stat().st_mtime_ns for p in run.iterdir() if p.name != "run.log"}
    assert after == before  # but the resumed run's transcript, which says what was refused
    assert (run / "run.log").read_text().splitlines() == [line, other.stderr.strip()]
    copy = tmp_path / "twin.xml"
    shutil.copy(MODEL_PATH, copy)
    moved = with_settings(resumed_config(run), {"model": str(copy)})
    stages: list[str] = []

    def on_stage(text: str) -> None:
        stages.append(text)
        _stop_at_solve(text)

    with pytest.raises(_StoppedError):  # the resume is taken: stopped where the twin is next used
        run_chain(moved, run, argv=["moved"], hooks=Hooks(on_stage=on_stage), resume=True)
    assert stages == [
        "generating the dataset: done before, kept",
        "training the PPANN: done before, kept",
        "solving the nominal and robust OCP",
    ]
    written = json.loads((run / "config.json").read_text())
    assert written["model_path"] == str(copy)
    assert written["resumed"] == [{"argv": ["moved"], "changed": ["model_path"]}]


def test_a_refused_open_loop_ends_with_the_fallback_tube_and_its_report(
    unsolved, tmp_path: Path
) -> None:
    """BRIEF's model asked for the open loop alone at k 2 with the centred tightening: its
    Monte-Carlo's spread needs more than the stroke (refused), so the run solves the fallback
    tube from the same plan and goes on to its replays, its held-out check in the tube's loop
    and a report that says both (resumed from the same model to save a training)."""
    run = _copy(unsolved, tmp_path / "run")
    wide = {"tightening": "centred", "k_sigma": 2.0, "profiles": ["robust"]}
    stages: list[str] = []
    config = with_settings(BRIEF, {"ocp": wide})
    report = run_chain(config, run, argv=[], hooks=Hooks(on_stage=stages.append), resume=True)
    solving = stages.index("solving the nominal and robust OCP")  # said as it happens:
    assert stages[solving + 1] == "robust refused: solving the fallback robust-fb"
    ocp = read_ocp(run / "ocp.json")
    assert ocp.robust_names == ("robust-fb",) and ocp.fallback == ("robust-fb",)
    assert "open loop cannot keep this spread" in ocp.refused["robust"]
    assert report["refused"] == ocp.refused and report["fallback"] == ["robust-fb"]
    heldout = json.loads((run / "heldout.json").read_text())
    assert heldout["modes"] == ["closed"] and set(heldout["profiles"]) == {"nominal", "robust-fb"}
    stats = json.loads((run / "replay.stats.json").read_text())
    assert set(stats["claims"]) == {"robust-fb"} and stats["claim"]["holds"] is None
    text = (run / "report.md").read_text()
    assert f"No robust torque: {ocp.refused['robust']}" in text
    assert "(robust) was refused, so the fallback robust-fb was solved" in text
    rows = run_rows(run, run / "ocp.json")
    assert [(r["profile"], r["error"] is None, r.get("fallback")) for r in rows] == [
        ("robust", False, None),
        ("robust-fb", True, True),
    ]
    # the refusal's figures, as a study's failed seed has them (crank/study.py's third panel)
    assert rows[0]["refused_tightening"] > rows[0]["refused_available"] > 0
