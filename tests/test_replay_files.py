"""Replay files: the campaign log read back through the dataset loader, SIGKILL + recover, the
Rerun recording, one-line errors for a bad ocp.json and the CLI."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from control.figures import predicted_band
from control.ocp_file import OCPFile
from replay.campaign import run_campaign
from replay.campaign_log import partial_path
from replay.config import ReplayConfig, ReplayConfigError
from replay.files import output_paths, replay_file
from replay.recording import BAND_LINES, band_lines, check_recording
from tests.conftest import crank
from tests.replay_ocp import N
from twin.geometry import PAPER
from twin.mcap_dataset import ContractError, read_dataset, read_run, read_truth
from twin.physics import MJCFNotFoundError, SliderCrank


def test_campaign_log_reads_back_through_the_dataset_loader(
    physics: SliderCrank, ocp: OCPFile, campaign_files: dict[str, Path]
) -> None:
    path = campaign_files["mcap"]
    dataset, truth, run = read_dataset(path), read_truth(path), read_run(path)
    assert run["kind"] == "replay-campaign" and run["config"]["runs"] == 6
    assert len(dataset) == 4 * 6 * N
    assert np.array_equal(np.unique(dataset.episode), np.arange(24))
    campaign = run_campaign(physics, ocp, config=ReplayConfig(runs=6, seed=5))
    order = [("nominal", "open"), ("nominal", "closed"), ("robust", "open"), ("robust", "closed")]
    for block, key in enumerate(order):
        replay = campaign.replays[key]
        rows = slice(block * 6 * N, (block + 1) * 6 * N)
        np.testing.assert_array_equal(dataset.theta[rows], replay.theta.ravel())
        np.testing.assert_array_equal(dataset.tau[rows], replay.tau.ravel())
        np.testing.assert_array_equal(truth.disturbance_force[rows], replay.disturbance.ravel())
    # every message is tagged; one metadata record per run; OCP and config attached
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        reader = make_reader(f)
        first = next(reader.iter_messages())[2]
        tags = json.loads(first.data)
        runs = [m for m in reader.iter_metadata() if m.name == "replay_run"]
        attachments = {a.name for a in reader.iter_attachments()}
    assert {tags["run"], tags["profile"], tags["mode"], tags["sample"]} == {0, "nominal", "open", 1}
    assert len(runs) == 24
    assert json.loads(runs[7].metadata["machine"]) == campaign.machines.draws[1].as_dict()
    assert attachments == {"model.xml", "ocp.json", "config.json"}


def test_a_campaign_tells_what_it_will_play_then_each_run_as_it_is_logged(
    ocp_path: Path, tmp_path: Path
) -> None:
    """on_start: runs x profiles x modes once the inputs are checked (never for a bad input);
    on_run: 1 after each run, as many times as there are runs."""
    told: list[tuple[str, int]] = []
    hooks = {
        "on_start": lambda n: told.append(("start", n)),
        "on_run": lambda n: told.append(("run", n)),
    }
    out = tmp_path / "r.mcap"
    with pytest.raises(MJCFNotFoundError):
        replay_file(
            ocp_path, out, config=ReplayConfig(runs=2), model_path=tmp_path / "none.xml", **hooks
        )
    assert told == [] and not partial_path(out).exists()
    config = ReplayConfig(runs=2, seed=3, modes=("open", "closed"))
    replay_file(ocp_path, out, config=config, figures=False, **hooks)
    assert told == [("start", 2 * 2 * 2)] + [("run", 1)] * 8  # 2 machines, 2 profiles, 2 modes


def test_rrd_reads_back_with_reruns_reader(campaign_files: dict[str, Path]) -> None:
    from rerun.chunk import RrdReader

    path = campaign_files["rrd"]
    assert check_recording(path) == ["crank_replay"]
    reader = RrdReader(path)
    assert len(reader.blueprints()) == 1
    summary = reader.store().summary()
    lines = {line.split()[0]: line for line in summary.splitlines()}
    for entity in (
        "/mechanism/nominal/open/linkage",
        "/mechanism/robust/closed/slider",
        "/slider/nominal/open/runs",
        "/slider/robust/closed/band",
        "/slider/robust/open/planned",
        "/torque/robust/closed/runs",
        "/torque/nominal/planned",
    ):
        assert f"rows={N}" in lines[entity], lines.get(entity)
        assert "timelines=['sample', 'time']" in lines[entity] or "'sample'" in lines[entity]
    assert (
        "/slider/nominal/open/constraint" in lines
        and "rows=2" in lines["/slider/nominal/open/constraint"]
    )


def test_rerun_band_is_shaded_between_the_bounds_and_inside_the_stroke() -> None:
    """The drawn band stays within the stroke (a predicted 3σ above top dead centre is drawn at
    the stroke's end) and its Rerun series run evenly from the lower to the upper bound."""
    profile = SimpleNamespace(slider=np.array([0.02, 0.0, 0.1]))
    sigma = np.array([0.003, 0.002, 0.004])
    lower, upper = predicted_band(profile, sigma, 3.0, geometry=PAPER)
    assert np.allclose(lower, [0.011, 0.0, 0.088], rtol=0, atol=1e-15)
    assert np.allclose(upper, [0.029, 0.006, PAPER.stroke_top], rtol=0, atol=1e-15)
    lines = band_lines(lower, upper)
    assert lines.shape == (BAND_LINES, 3)
    assert np.array_equal(lines[0], lower) and np.allclose(lines[-1], upper, rtol=0, atol=1e-15)
    assert np.allclose(np.diff(lines, axis=0), (upper - lower) / (BAND_LINES - 1))


KILLER = textwrap.dedent(
    """
    import os, signal, sys
    from mcap.writer import Writer
    from replay.config import ReplayConfig
    from replay.files import replay_file

    # SIGKILL in the middle of writing run 7: a run is 150 messages on each of the two dataset
    # channels, then 150 transforms, 1 scene and 150 plan rows for Foxglove
    limit, written, add_message = 6 * 601 + 300, 0, Writer.add_message

    def counting(self, *args, **kwargs):
        global written
        written += 1
        if written == limit:
            os.kill(os.getpid(), signal.SIGKILL)
        return add_message(self, *args, **kwargs)

    Writer.add_message = counting
    replay_file(sys.argv[1], sys.argv[2], config=ReplayConfig(runs=4, seed=6))
    """
)


def test_killed_campaign_is_recovered_with_every_completed_run(
    physics: SliderCrank, ocp: OCPFile, ocp_path: Path, tmp_path: Path
) -> None:
    out = tmp_path / "replay.mcap"
    root = Path(__file__).resolve().parent.parent
    killed = subprocess.run(
        [sys.executable, "-c", KILLER, str(ocp_path), str(out)],
        cwd=root,
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert killed.returncode == -signal.SIGKILL, killed.stderr
    broken = partial_path(out)
    assert broken.exists() and not out.exists()
    with pytest.raises(ContractError, match="truncated"):
        read_dataset(broken)
    fixed = tmp_path / "fixed.mcap"
    result = crank("recover", str(broken), str(fixed))
    assert result.returncode == 0, result.stderr
    assert "6 complete runs" in result.stdout
    dataset = read_dataset(fixed)
    assert np.array_equal(np.unique(dataset.episode), np.arange(6))
    campaign = run_campaign(physics, ocp, config=ReplayConfig(runs=4, seed=6))
    first = np.concatenate(
        [
            campaign.replays["nominal", "open"].theta.ravel(),
            campaign.replays["nominal", "closed"].theta[:2].ravel(),
        ]
    )
    np.testing.assert_array_equal(dataset.theta, first)
    # a new campaign refuses to overwrite the crashed one's partial file
    again = crank("replay", "--ocp", str(ocp_path), "--out", str(out), "--runs", "2")
    assert again.returncode == 2 and "crank recover" in again.stderr


@pytest.mark.parametrize("fraction", [0.3, 0.55, 0.8])
def test_recover_keeps_the_complete_runs_before_any_cut(
    campaign_files: dict[str, Path], tmp_path: Path, fraction: float
) -> None:
    from replay.recover import recover

    full = campaign_files["mcap"].read_bytes()
    broken = tmp_path / "cut.mcap"
    broken.write_bytes(full[: int(fraction * len(full))])  # mid-record, mid-chunk
    result = recover(broken, tmp_path / "fixed.mcap")
    assert not result.complete and 0 < result.runs < 24
    recovered, reference = (
        read_dataset(tmp_path / "fixed.mcap"),
        read_dataset(campaign_files["mcap"]),
    )
    assert np.array_equal(np.unique(recovered.episode), np.arange(result.runs))
    np.testing.assert_array_equal(
        recovered.slider_position, reference.slider_position[: result.runs * N]
    )
    from mcap.reader import make_reader

    from replay.foxglove import TF_TOPIC

    with open(tmp_path / "fixed.mcap", "rb") as f:  # Foxglove's channels keep the same runs
        summary = make_reader(f).get_summary()
    counts = {c.topic: summary.statistics.channel_message_counts.get(i, 0)
              for i, c in summary.channels.items()}  # fmt: skip
    assert counts[TF_TOPIC] == result.runs * N


def _broken_ocp(ocp_path: Path, tmp_path: Path, edit) -> Path:
    raw = json.loads(ocp_path.read_text())
    edit(raw)
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(raw).replace("Infinity", "NaN"))
    return path


@pytest.mark.parametrize(
    ("edit", "match"),
    [
        (lambda r: r["robust"].pop("tau"), "missing key 'robust.tau'"),
        (lambda r: r["robust"].pop("gain_omega"), "missing key 'robust.gain_omega'"),
        (lambda r: r["nominal"]["theta"].pop(), "nominal.theta has 149 values, expected 150"),
        (lambda r: r["nominal"]["tau"].__setitem__(3, float("inf")), "non-finite value at index 3"),
        (
            lambda r: r["config"].__setitem__("torque_limit", 12.0),
            "solved with |τ| <= 12 N·m but the twin's actuator saturates at 10 N·m",
        ),
    ],
)
def test_replay_rejects_a_bad_ocp_json_in_one_line(
    ocp_path: Path, tmp_path: Path, edit, match: str
) -> None:
    bad = _broken_ocp(ocp_path, tmp_path, edit)
    out = tmp_path / "out" / "replay.mcap"
    out.parent.mkdir()
    result = crank("replay", "--ocp", str(bad), "--out", str(out), "--runs", "2")
    assert result.returncode == 2
    assert result.stderr.count("\n") == 1 and match in result.stderr, result.stderr
    assert list(out.parent.iterdir()) == []  # nothing half-written, not even a .partial


def test_replay_config_validation() -> None:
    with pytest.raises(ReplayConfigError, match="runs must be an integer"):
        ReplayConfig(runs=2.5)  # type: ignore[arg-type]
    with pytest.raises(ReplayConfigError, match="modes repeat"):
        ReplayConfig(modes=("open", "open"))
    assert replace(ReplayConfig(), runs=3).runs == 3


def test_cli_replay_writes_every_file_and_view_explains(ocp_path: Path, tmp_path: Path) -> None:
    out = tmp_path / "campaign" / "replay.mcap"
    result = crank("replay", "--ocp", str(ocp_path), "--out", str(out), "--runs", "3")
    assert result.returncode == 0, result.stderr
    assert "robust" in result.stdout and "below@50" in result.stdout
    paths = output_paths(out)
    assert all(p.is_file() for p in paths.values())
    stats = json.loads(paths["stats"].read_text())
    assert stats["format"] == "crank-replay-stats" and stats["version"] == 3
    assert stats["config"]["runs"] == 3
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    view = crank("view", str(paths["rrd"]), env=env, timeout=120)
    assert view.returncode == 0 and "no display" in view.stdout and "rerun" in view.stdout
    garbage = tmp_path / "garbage.rrd"
    garbage.write_text("not a recording")
    bad = crank("view", str(garbage))
    assert bad.returncode == 2 and "not a readable Rerun recording" in bad.stderr
