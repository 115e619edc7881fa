"""The CLI as a user meets it: datasets from `crank generate`, one-line errors for bad input (the
whole table of bad inputs is tests/test_bad_inputs.py)."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest
from mcap.writer import Writer

from crank.progress import LineBar, Progress
from tests.conftest import crank
from twin.mcap_dataset import (
    MEASUREMENT_TOPIC,
    TRUTH_TOPIC,
    read_dataset,
    read_model_xml,
    read_run,
)


def test_generate_writes_a_contract_dataset(tmp_path: Path) -> None:
    out = tmp_path / "ds.mcap"
    result = crank(
        "generate", "--seconds", "3", "--seed", "4", "--episode-seconds", "1.5", "--out", str(out)
    )
    assert result.returncode == 0, result.stderr
    data = read_dataset(out)
    assert len(data) == 1500 and set(data.episode) == {0, 1}
    run = read_run(out)
    assert run["seed"] == 4 and run["seconds"] == 3.0 and run["rate_hz"] == 500.0
    assert len(run["mjcf_sha256"]) == 64 and run["project_version"]
    assert [e["machine"]["backlash_width"] > 0 for e in run["episodes"]] == [True, True]
    assert run["config"]["variability"]["disturbance_amplitude"] == 30.0
    assert "<mujoco" in read_model_xml(out)
    assert (tmp_path / "ds.coverage.png").stat().st_size > 0
    assert (tmp_path / "ds.excitation.png").stat().st_size > 0
    inspected = crank("inspect", str(out))
    assert inspected.returncode == 0 and "theta_bins_covered_of_12" in inspected.stdout


def test_run_writes_config_and_report(tmp_path: Path) -> None:
    """3 s of data (from a config file) train a PPANN too uncertain for a robust profile, the
    open loop's and its fallback tube's alike: the chain runs to the robust OCP and stops there
    with one line naming both reasons, leaving no ocp.json or report; config.json holds the
    file's values under the flags given."""
    settings = tmp_path / "crank.toml"  # a config file, and a flag that overrides it
    settings.write_text(
        "heldout_runs = 50\nheldout_trajectories = 500\n[generation]\nseconds = 3.0\n"
        "episode_seconds = 1.0\n"  # 3 machines: one would bound nothing (ppann/confidence.py)
        "[ocp]\nheight = 0.081\n[plan]\nepisodes = 0\n"  # one round: the refusal's line
        "[train]\nmean_wrap = false\n"  # eq. 14's z_K: with mean_wrap this model has a tube
    )
    args = ["--config", str(settings), "--heldout-runs", "7", "--logs", str(tmp_path)]
    result = crank("run", *args, "--name", "r1")
    assert result.returncode == 2
    last = result.stderr.strip().splitlines()[-1]
    assert last.startswith("error: robust: the model's tightening")
    assert "; robust-fb: the model's tightening" in last and "the closed loop cannot keep" in last
    assert "to try the closed loop" not in last  # the fallback was that closed loop
    run_dir = tmp_path / "r1"
    config = json.loads((run_dir / "config.json").read_text())
    assert config["seed"] == 0 and config["generation"]["seconds"] == 3.0
    assert config["ocp"]["height"] == 0.081 and config["heldout_runs"] == 7
    assert config["heldout_trajectories"] == 500
    assert config["ocp"]["horizon"] == 150 and config["ocp"]["mc_seed"] == 0
    assert config["ocp"]["mc_samples"] == 1000 and config["ocp"]["mc_mode"] == "mixed"
    assert config["streams"]["root_seed"] == 0 and "replay_machines" in config["streams"]["streams"]
    assert config["generation"]["variability"]["name"] == "paper"
    assert (run_dir / "dataset.mcap").is_file() and (run_dir / "model.pt").is_file()
    assert not (run_dir / "ocp.json").exists() and not (run_dir / "report.json").exists()
    failed = json.loads((run_dir / "ocp.failed.json").read_text())  # what the solve had
    assert failed["status"] == "failed" and len(failed["nominal"]["tau"]) == 150
    assert {it["profile"] for it in failed["robust_iterations"]} == {"robust", "robust-fb"}
    log = (run_dir / "run.log").read_text()  # what the terminal showed, without bar frames
    first, second = log.splitlines()[:2]  # said before the work starts
    assert first.startswith("estimated time on an idle 2-core machine: ") and "train " in first
    assert second == "generating the dataset ..." and "\r" not in log
    assert log.splitlines()[-1] == result.stderr.strip().splitlines()[-1]
    again = crank("run", *args, "--name", "r1")
    assert again.returncode == 2 and "already exists" in again.stderr
    assert (run_dir / "run.log").read_text() == log  # another run's folder is never written


def _mcap_with(path: Path, topics: list[str], message: dict) -> Path:
    with open(path, "wb") as f:
        writer = Writer(f)
        writer.start()
        writer.add_metadata("run", {"seed": "0"})
        schema = writer.register_schema("s", "jsonschema", b"{}")
        for topic in topics:
            channel = writer.register_channel(topic, "json", schema)
            writer.add_message(
                channel, log_time=0, data=json.dumps(message).encode(), publish_time=0
            )
        writer.finish()
    return path


_MEASURED = {"t": 0.0, "episode": 0, "theta": 0.0, "omega": 0.0, "tau": 0.0, "slider_position": 0.0}


def _assert_one_line_error(result, match: str) -> None:
    assert result.returncode != 0
    assert "Traceback" not in result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith("error: ") and match in lines[0], lines[0]


def test_generate_unwritable_output(tmp_path: Path) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("a file where a directory should be")
    result = crank("generate", "--seconds", "1", "--out", str(blocker / "ds.mcap"))
    _assert_one_line_error(result, "cannot write to")
    folder = tmp_path / "folder.mcap"
    folder.mkdir()
    result = crank("generate", "--seconds", "1", "--out", str(folder))
    _assert_one_line_error(result, "is a directory")
    result = crank("generate", "--seconds", "1", "--out", str(tmp_path))
    _assert_one_line_error(result, "it must end in .mcap")


@pytest.mark.parametrize(
    ("make", "match"),
    [
        (lambda d: d / "absent.mcap", "dataset not found"),
        (
            lambda d: (d / "text.mcap").write_text("not an mcap") and d / "text.mcap",
            "not an MCAP file",
        ),
        (  # a learner needs no truth channel (rig data has none); the twin's files carry it
            lambda d: _mcap_with(d / "one.mcap", [MEASUREMENT_TOPIC], _MEASURED),
            f"missing channel {TRUTH_TOPIC}",
        ),
        (
            lambda d: _mcap_with(d / "short.mcap", [MEASUREMENT_TOPIC, TRUTH_TOPIC], {"t": 0.0}),
            "lacks field 'episode'",
        ),
    ],
)
def test_inspect_bad_file(tmp_path: Path, make, match: str) -> None:
    result = crank("inspect", str(make(tmp_path)))
    _assert_one_line_error(result, match)


def _dataset(tmp_path: Path, *, seconds: str = "4") -> Path:
    out = tmp_path / "ds.mcap"
    result = crank(
        "generate",
        "--seconds",
        seconds,
        "--episode-seconds",
        "2",
        "--out",
        str(out),
        "--no-figures",
    )
    assert result.returncode == 0, result.stderr
    return out


def test_train_writes_checkpoints_and_report(tmp_path: Path) -> None:
    import torch

    from ppann.checkpoint import load

    data = _dataset(tmp_path)
    out = tmp_path / "m" / "model.pt"
    result = crank(
        "train", "--data", str(data), "--out", str(out), "--epochs", "3", "--sigma-epochs", "10"
    )
    assert result.returncode == 0, result.stderr
    payload = torch.load(out, weights_only=True)
    assert payload["kind"] == "ppann" and len(payload["history"]["sigma"]) == 10
    assert payload["train_config"]["max_epochs"] == 3 and len(payload["data_fingerprint"]) == 64
    model, _ = load(out)
    assert model.config.mean_hidden == 100
    for kind in ("physics", "blackbox"):
        assert load(out.with_name(f"model.{kind}.pt"))[1]["kind"] == kind
    report = json.loads((out.parent / "model.report.json").read_text())
    assert set(report["models"]) == {"ppann", "physics", "blackbox"}
    assert set(report["calibration"]) >= {"n_runs", "step", "trajectory"}
    for name in ("maps", "validation", "bands", "calibration"):
        assert (out.parent / f"model.{name}.png").stat().st_size > 0


def test_train_rejects_non_finite_data(tmp_path: Path) -> None:
    from dataclasses import replace

    from twin.mcap_dataset import read_truth, write_dataset

    data = _dataset(tmp_path, seconds="2")
    dataset = read_dataset(data)
    tau = dataset.tau.copy()
    tau[77] = float("nan")
    bad = tmp_path / "nan.mcap"
    write_dataset(
        bad, replace(dataset, tau=tau), read_truth(data), run=dataset.run, model_xml="<mujoco/>"
    )
    out = tmp_path / "m" / "model.pt"
    result = crank("train", "--data", str(bad), "--out", str(out))
    # The dataset reader refuses it, before training's own check (ppann/data.py) is reached.
    _assert_one_line_error(result, "field 'tau' on /slider_crank/measurement is not finite")
    assert "first at index 77 (nan)" in result.stderr
    assert not out.exists()


def test_train_rejects_a_too_short_dataset(tmp_path: Path) -> None:
    data = _dataset(tmp_path, seconds="0.2")
    result = crank("train", "--data", str(data), "--out", str(tmp_path / "model.pt"))
    _assert_one_line_error(result, "too short")


def test_version_and_command_list() -> None:
    version = crank("--version")
    assert version.returncode == 0, version.stderr
    assert re.fullmatch(r"crank \d+\.\d+\.\d+ \(mujoco .*, torch 2\.13\.0.*\)\n", version.stdout)
    listed = crank("--help").stdout.split("Commands:")[1].strip().splitlines()
    assert len(listed) >= 10
    for line in listed:  # one short line each, never cut mid-sentence ("Nominal OCP (eqs.")
        assert line.endswith(".") and not line.endswith("..."), line
        assert len(line) <= 80


def test_progress_off_a_terminal_prints_lines_not_frames(capsys: pytest.CaptureFixture) -> None:
    bar = LineBar(total=3, desc="PPANN phase1", unit="epoch", interval=0.0)
    for _ in range(3):
        bar.set_postfix(loss="0.5")
        bar.update(1)
    bar.close()
    bar.close()
    err = capsys.readouterr().err
    assert "\r" not in err
    lines = err.splitlines()
    assert len(lines) == 3
    for n, line in enumerate(lines[:2], start=1):
        assert re.fullmatch(
            rf"PPANN phase1: {n}/3 epochs, \d+ s left at this rate \(loss=0\.5\)", line
        )
    assert re.fullmatch(
        r"PPANN phase1: done, 3 epochs in \d+\.\d s \(loss=0\.5\)", err.splitlines()[-1]
    )
    quick = LineBar(total=2, desc="replay", unit="run", delay=60.0)
    quick.update(2)
    quick.close()
    assert capsys.readouterr().err == ""


def test_a_bar_closed_by_an_error_or_ctrl_c_says_where_it_stopped_not_done(
    capsys: pytest.CaptureFixture,
) -> None:
    """An interrupted run's bars said "done, 1 epochs", which reads as finished (an epoch bar
    ends early by design, so the count alone cannot tell): a step ended by an error or Ctrl-C
    says where it stopped, each model's epochs in `crank run`'s chain included."""
    from crank.chain import RunConfig
    from crank.chain_progress import chain_progress

    bar = LineBar(total=60, desc="ppann mean", unit="epoch")
    bar.update(7)
    bar.close(stopped=True)
    assert re.fullmatch(
        r"ppann mean: stopped at 7/60 epochs after \d+\.\d s\n", capsys.readouterr().err
    )
    with pytest.raises(KeyboardInterrupt), Progress(10, "held-out", unit="machine") as held:
        held.update(3)
        held.bar.delay = 0.0  # shown at once, not after 2 s
        raise KeyboardInterrupt
    assert re.fullmatch(
        r"held-out: stopped at 3/10 machines after \d+\.\d s\n", capsys.readouterr().err
    )
    config = RunConfig()
    with pytest.raises(KeyboardInterrupt), chain_progress(config) as hooks:
        hooks.on_stage("training")
        hooks.on_epoch("ppann", "mean", 0, 0.5)
        hooks.on_epoch("blackbox", "mean", 0, 0.7)
        hooks.on_epoch("blackbox", "mean", 1, 0.6)
        raise KeyboardInterrupt
    epochs = config.train.max_epochs
    assert re.fullmatch(
        rf"training \.\.\.\n"
        rf"ppann mean: stopped at 1/{epochs} epochs after \d+\.\d s \(loss=0\.5\)\n"
        rf"blackbox mean: stopped at 2/{epochs} epochs after \d+\.\d s \(loss=0\.6\)\n",
        capsys.readouterr().err,
    )
    with chain_progress(config) as hooks:  # ended as it should: "done"
        hooks.on_epoch("ppann", "mean", 0, 0.5)
    assert capsys.readouterr().err.startswith("ppann mean: done, 1 epochs in ")


def test_a_terminal_of_no_width_gets_plain_lines_where_tqdm_would_draw_nothing() -> None:
    """A pty nobody sized (`script` without a terminal, some CI runners) has 0 columns, on
    which tqdm prints nothing at all: plain lines there; a bar once it has a width, and lines
    off a terminal."""
    import fcntl
    import os
    import pty
    import struct
    import termios
    from contextlib import redirect_stderr
    from io import StringIO

    from tqdm import tqdm

    from crank.progress import progress_bar

    master, follower = pty.openpty()
    try:
        with open(follower, "w", closefd=False) as tty, redirect_stderr(tty):
            assert isinstance(progress_bar(total=2, desc="held-out", unit="machine"), LineBar)
            fcntl.ioctl(follower, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 80, 0, 0))
            bar = progress_bar(total=2, desc="held-out", unit="machine")
            assert isinstance(bar, tqdm)
            bar.close()
        with redirect_stderr(StringIO()):
            assert isinstance(progress_bar(total=2, desc="held-out", unit="machine"), LineBar)
    finally:
        os.close(master)
        os.close(follower)


def test_a_full_progress_bar_closes_at_once_or_when_its_step_ends() -> None:
    """By default a bar closes (says "done") once full; with close_when_full=False only when its
    `with` ends, so the lines its step prints after the last unit come before its "done"."""
    with Progress(4, "replaying", unit="run") as bar:
        bar.update(3)
        assert not bar.bar.closed
        bar.update(1)
        assert bar.bar.closed
    with Progress(4, "held-out", unit="machine", close_when_full=False) as held:
        held.update(4)
        assert not held.bar.closed
    assert held.bar.closed
    with Progress(0, "replaying", unit="run") as late:  # its total known only later
        late.start(2)
        assert late.bar.total == 2 and late.bar.n == 0 and not late.bar.closed


def test_a_bar_told_of_more_goes_on_with_it() -> None:
    """A held-out check's second stage: a bar that closed when full opens a bar of its own for
    the machines to come; one kept open until its step ends raises its total."""
    with Progress(4, "held-out", unit="machine") as bar:
        bar.update(4)
        first = bar.bar
        assert first.closed
        bar.more(9)
        assert bar.bar is not first and bar.bar.total == 9 and bar.bar.n == 0
        bar.update(9)
        assert bar.bar.closed
    with Progress(4, "held-out", unit="machine", close_when_full=False) as held:
        held.update(4)
        held.more(9)
        assert held.bar.total == 13 and held.bar.n == 4 and not held.bar.closed


def test_the_command_line_loads_without_the_heavy_engines() -> None:
    """`crank --help` and `--version` need only the option defaults: importing the CLI pulls in
    neither torch, CasADi, SciPy, Rerun nor matplotlib (it took 3.5 s idle, 12-15 s under load,
    when it did)."""
    heavy = ("torch", "casadi", "scipy", "rerun", "matplotlib")
    probe = f"import sys, crank.cli; print([m for m in {heavy!r} if m in sys.modules])"
    loaded = subprocess.run(
        [sys.executable, "-c", probe], capture_output=True, text=True, check=True
    ).stdout
    assert loaded.strip() == "[]"


def test_heldout_says_what_it_plays_and_about_how_long_once_its_inputs_are_read(
    tmp_path: Path, ocp_path: Path
) -> None:
    """`crank heldout` first names the profiles, loops, machines and root with a time estimate
    (after its inputs are checked: a bad one is still the only line, tests/test_outputs.py),
    then one line per profile played; heldout.json as asked."""
    from tests.checkpoints import constant_checkpoint

    model = tmp_path / "m.pt"
    constant_checkpoint(model)
    out = tmp_path / "h.json"
    result = crank(
        *("heldout", "--ocp", str(ocp_path), "--model", str(model), "--out", str(out)),
        *("--runs", "5", "--seed", "9", "--trajectories", "100"),
    )
    assert result.returncode == 0, result.stderr
    lines = [line for line in result.stderr.splitlines() if not line.startswith("held-out:")]
    assert re.fullmatch(
        r"held-out check: nominal, robust in open on 5 machines of root 9; "
        r"about \d+ s on an idle 2-core machine",
        lines[0],
    ), result.stderr
    assert [line.split(":")[0].strip() for line in lines[1:]] == ["nominal open", "robust open"]
    held = json.loads(out.read_text())
    assert (held["runs"], held["seed"], held["modes"]) == (5, 9, ["open"])


def test_an_interrupted_run_says_how_to_continue_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Ctrl-C (or SIGTERM) once `crank run` has its folder: the error line, also in run.log,
    names the command that goes on from the stages it finished; before the folder exists, no
    such hint."""
    import crank.chain
    from crank.chain import RunConfig
    from crank.cli_chain import _run
    from crank.console import Terminated, error_line

    def stopped(config: RunConfig, run_dir: Path, **_: object) -> None:
        Path(run_dir).mkdir()
        raise Terminated

    monkeypatch.setattr(crank.chain, "run_chain", stopped)
    run_dir = tmp_path / "r"
    with pytest.raises(Terminated) as stop:
        _run(RunConfig(), run_dir, resume=False)
    line = error_line(stop.value)
    assert line == (
        "error: terminated (SIGTERM); no unfinished file was put at a target path; "
        f"continue it with: crank run --resume {run_dir}"
    )
    assert (run_dir / "run.log").read_text().splitlines()[-1] == line

    def early(config: RunConfig, run_dir: Path, **_: object) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(crank.chain, "run_chain", early)
    with pytest.raises(KeyboardInterrupt) as stop:
        _run(RunConfig(), tmp_path / "never", resume=False)
    assert error_line(stop.value) == (
        "error: interrupted; no unfinished file was put at a target path"
    )
    assert not (tmp_path / "never").exists()


def test_a_study_takes_a_config_file_as_crank_run_does(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """`crank study --config FILE`: the file's settings over the defaults, its seed replaced by
    each of --seeds, the flags given over the file; without a file the study is `crank run`'s
    defaults but for the baselines, which a study leaves out unless its file or flag asks, and
    the held-out check's second stage (its table compares seeds on one machine count)."""
    import crank.study
    from crank.cli import main
    from crank.config_file import build, defaults

    studied: list[Any] = []

    def captured(base: Any, seeds: tuple[int, ...], out: Path, **_: object) -> dict[str, float]:
        studied.append((base, seeds))
        return {"wall_s": 0.0}

    def study(*args: str) -> None:
        monkeypatch.setattr(sys, "argv", ["crank", "study", "--out", str(tmp_path / "s"), *args])
        with pytest.raises(SystemExit) as ended:
            main()
        assert ended.value.code == 0

    monkeypatch.setattr(crank.study, "run_study", captured)
    toml = tmp_path / "line.toml"
    toml.write_text(
        'seed = 7\nbaselines = true\n[generation]\nseconds = 100.0\nvariability = "line-15"\n'
        "[ocp]\nheight = 0.085\nconfidence = 0.8\n"
    )
    study("--seeds", "2,4", "--config", str(toml), "--confidence", "0.9", "--runs", "50")
    base, seeds = studied[-1]
    assert seeds == (2, 4) and base.seed == 2 and base.train.seed == 2
    assert base.ocp.height == 0.085 and base.generation.seconds == 100.0
    assert base.generation.variability.name == "line-15" and base.baselines
    assert base.ocp.confidence == 0.9 and base.replay.runs == 50  # the flags over the file
    study("--seeds", "3")
    base, seeds = studied[-1]
    assert base == replace(
        build({**defaults(), "seed": 3}), baselines=False, heldout_second_stage=0
    )


def test_an_interrupted_study_says_how_to_continue_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """Ctrl-C in `crank study` once its folder exists: exit 130, one line that says to run
    the same command with --resume (a study resumes only with the options it started with)."""
    import crank.study
    from crank.cli import main

    def stopped(base: object, seeds: object, out: Path, **_: object) -> None:
        Path(out).mkdir()
        raise KeyboardInterrupt

    monkeypatch.setattr(crank.study, "run_study", stopped)
    monkeypatch.setattr(
        sys, "argv", ["crank", "study", "--seeds", "0", "--out", str(tmp_path / "s")]
    )
    with pytest.raises(SystemExit) as ended:
        main()
    assert ended.value.code == 130
    assert capsys.readouterr().err.strip().splitlines()[-1] == (
        "error: interrupted; no unfinished file was put at a target path; continue it with the "
        "same command and --resume"
    )
