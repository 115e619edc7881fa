"""Shared fixtures: the twin, and one default 90 s dataset written to MCAP and read back."""

from __future__ import annotations

import os
import subprocess
from dataclasses import dataclass
from pathlib import Path

import pytest

from control.mpc_config import MPCConfig
from control.ocp_file import OCPFile, read_ocp
from control.solvers import keep_solvers
from replay.config import ReplayConfig
from replay.files import output_paths, replay_file
from tests.forkserver import Command, ForkServer, Fresh
from tests.order import longest_first, read_record
from tests.replay_ocp import write_ocp
from twin import PAPER_SECONDS
from twin.dataset import Dataset, GenerationConfig, GroundTruth, generate
from twin.mcap_dataset import read_dataset, read_truth, write_dataset
from twin.physics import SliderCrank, load_model

LATE = 60.0
"""A deadline no MPC step misses, however busy the machine: where a test checks the MPC's own
answer, or compares two runs of it, not the deadline rule (a step over 2 ms applies the previous
solution instead, so under load, e.g. beside another test worker, a run's numbers would depend on
the wall clock)."""
LATE_MPC = MPCConfig(deadline=LATE)


SOLVERS_KEPT = 8
"""NLPs whose IPOPT solvers a test process keeps (control/solvers.py): several tests run a chain
and then the same chain another way (a sweep's leaf, a resume, a study's row) to compare them, and
build the same NLPs again; ~250 MB each."""


FILE_SECONDS = pytest.StashKey[dict[str, float]]()
"""Seconds per test file of the recorded run (tests/order.py)."""


def pytest_configure(config: pytest.Config) -> None:
    """The test process keeps the solvers of the last SOLVERS_KEPT NLPs it built (the processes
    it starts keep none, as a `crank` command does).

    Under pytest-xdist (one worker per core, pyproject.toml) each worker and every process it
    starts computes on one thread (torch's, and MuJoCo's and the Monte-Carlo kernel's rollouts,
    common/threads.py): two workers of torch's two threads each on two cores ran
    oversubscribed. A model trained in a test and one trained by a `crank` subprocess the test
    starts then use the same thread count (a PPANN's last bits depend on it, ppann/fit.py)."""
    keep_solvers(SOLVERS_KEPT)
    try:  # read here, where a bad record stops the run with one line before a worker starts
        config.stash[FILE_SECONDS] = read_record()
    except ValueError as exc:
        raise pytest.UsageError(f"{exc} (python bench/suite_time.py --record writes it)") from None
    if os.environ.get("PYTEST_XDIST_WORKER") is None:
        return
    for name in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "CRANK_ROLLOUT_THREADS"):
        os.environ[name] = "1"
    import torch

    torch.set_num_threads(1)


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """The longest test files first (tests/order.py): the order xdist hands them to workers."""
    longest_first(items, config.stash[FILE_SECONDS])


@pytest.fixture(scope="session")
def physics() -> SliderCrank:
    return SliderCrank(load_model()[0])


@dataclass(frozen=True)
class Written:
    path: Path
    dataset: Dataset
    truth: GroundTruth
    loaded: Dataset
    loaded_truth: GroundTruth


@pytest.fixture(scope="session")
def paper_dataset(tmp_path_factory: pytest.TempPathFactory, physics: SliderCrank) -> Written:
    """The paper's dataset: 90 s, seed 0, 9 episodes of 10 s."""
    dataset, truth, _ = generate(GenerationConfig(seconds=PAPER_SECONDS), physics=physics)
    path = tmp_path_factory.mktemp("paper") / "dataset.mcap"
    _, xml = load_model()
    write_dataset(path, dataset, truth, run={"seed": 0}, model_xml=xml)
    return Written(path, dataset, truth, read_dataset(path), read_truth(path))


@pytest.fixture(scope="session")
def ocp_path(tmp_path_factory: pytest.TempPathFactory, physics: SliderCrank) -> Path:
    """The synthetic ocp.json of tests/replay_ocp.py (nominal and robust profiles)."""
    return write_ocp(tmp_path_factory.mktemp("replay") / "ocp.json", physics)


@pytest.fixture(scope="session")
def ocp(ocp_path: Path) -> OCPFile:
    return read_ocp(ocp_path)


@pytest.fixture(scope="session")
def campaign_files(tmp_path_factory: pytest.TempPathFactory, ocp_path: Path) -> dict[str, Path]:
    """A 6-run campaign of `ocp_path`: its MCAP, Rerun recording and statistics."""
    out = tmp_path_factory.mktemp("campaign") / "replay.mcap"
    replay_file(ocp_path, out, config=ReplayConfig(runs=6, seed=5))
    return output_paths(out)


_commands: ForkServer | Fresh | None = None


def start_crank(
    *args: str,
    cwd: Path | None = None,
    env: dict[str, str] | None = None,
    new_session: bool = False,
) -> Command:
    """Start `crank ARGS` in a process of its own (`python -m crank`, as a user would): forked
    from this test process's fork server (tests/forkserver.py: the heavy libraries imported
    once), or, where $CRANK_TEST_FORKSERVER is 0, in a fresh interpreter."""
    global _commands
    if _commands is None:
        fork = os.environ.get("CRANK_TEST_FORKSERVER", "1") != "0"
        _commands = ForkServer() if fork else Fresh()
    return _commands.start(list(args), cwd=cwd, env=env, new_session=new_session)


def crank(
    *args: str, cwd: Path | None = None, env: dict[str, str] | None = None, timeout: float = 300
) -> subprocess.CompletedProcess[str]:
    """Run `crank ARGS` to its end (`start_crank`): its exit code, stdout and stderr."""
    return start_crank(*args, cwd=cwd, env=env).communicate(timeout)


def pytest_unconfigure(config: pytest.Config) -> None:
    if _commands is not None:
        _commands.close()
