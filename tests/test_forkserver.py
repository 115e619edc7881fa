"""The suite's `crank` commands forked from tests/forkserver.py's server behave as `python -m
crank` in a fresh interpreter: the same exit code, output and files; the working directory and
environment each command is given; a command that can be killed, and one that overruns its
timeout killed."""

from __future__ import annotations

import os
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

from tests.forkserver import ForkServer, Fresh
from twin.dataset import MEASUREMENT_FIELDS
from twin.mcap_dataset import read_dataset


@pytest.fixture(scope="module")
def server():
    forked = ForkServer()
    yield forked
    forked.close()


def _without_wall_clock(stdout: str) -> list[str]:
    return [line for line in stdout.splitlines() if "wall_seconds" not in line]


def test_a_forked_command_is_the_fresh_interpreters(server: ForkServer, tmp_path: Path) -> None:
    usage = ["solve", "--seed", "1.5"]
    forked, fresh = (way.start(usage, cwd=tmp_path).communicate(60) for way in (server, Fresh()))
    assert forked.returncode == fresh.returncode == 2
    assert forked.stderr == fresh.stderr and forked.stderr.startswith("error: Invalid value")
    assert forked.stdout == fresh.stdout == ""
    runs = {}
    for name, way in (("forked", server), ("fresh", Fresh())):
        (tmp_path / name).mkdir()
        args = ["generate", "--seconds", "1", "--out", "d.mcap", "--no-figures"]
        runs[name] = way.start(args, cwd=tmp_path / name).communicate(120)  # cwd: relative out
        assert runs[name].returncode == 0, runs[name].stderr
    assert _without_wall_clock(runs["forked"].stdout) == _without_wall_clock(runs["fresh"].stdout)
    forked_data, fresh_data = (read_dataset(tmp_path / n / "d.mcap") for n in ("forked", "fresh"))
    for field in MEASUREMENT_FIELDS:
        np.testing.assert_array_equal(getattr(forked_data, field), getattr(fresh_data, field))
    assert sorted(p.name for p in (tmp_path / "forked").iterdir()) == ["d.mcap"]


def test_each_command_takes_the_environment_it_is_given(server: ForkServer, tmp_path: Path) -> None:
    env = dict(os.environ, CRANK_ROLLOUT_THREADS="zero")
    args = ["generate", "--seconds", "1", "--out", str(tmp_path / "d.mcap")]
    refused = server.start(args, env=env).communicate(60)
    assert refused.returncode == 2
    assert (
        refused.stderr.strip()
        == "error: $CRANK_ROLLOUT_THREADS must be an integer >= 1, got 'zero'"
    )
    assert not any(tmp_path.iterdir())
    assert (
        "CRANK_ROLLOUT_THREADS" not in os.environ or os.environ["CRANK_ROLLOUT_THREADS"] != "zero"
    )
    # the next command has this process's environment again, not the one before
    assert server.start(["--version"]).communicate(60).returncode == 0


def test_a_command_can_be_killed_and_an_overrun_is_killed(
    server: ForkServer, tmp_path: Path
) -> None:
    long = ["generate", "--seconds", "300", "--out", str(tmp_path / "d.mcap")]
    command = server.start(long)
    time.sleep(1.0)
    assert command.poll() is None
    command.kill()
    assert command.wait(30) == -9
    overrun = server.start(long)
    with pytest.raises(subprocess.TimeoutExpired):
        overrun.communicate(timeout=1.0)
    assert overrun.returncode == -9
    # commands that ended while another was asked for are not lost
    quick = [server.start(["--version"]) for _ in range(3)]
    assert [q.communicate(60).returncode for q in reversed(quick)] == [0, 0, 0]
