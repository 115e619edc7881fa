"""The draft's check run beside the aware loop's next solves (control/beside.py, control/aware.py
`iterate`): the same solves, records and torque as the check made in line, whichever way it
answers; the solves made while it ran dropped where it raises k."""

from __future__ import annotations

import threading
import time
from dataclasses import replace

import numpy as np
import pytest

import control.aware as aware
import control.beside as beside
import control.profiles as profiles
import control.tail as tail
from common.threads import rollout_threads, threads_here
from control.config import OCPConfig
from control.ocp import NominalOCP
from control.robust import solve_robust
from ppann import kernel
from ppann.heads import FusedHeads
from ppann.model import constant_ppann

NARROW = constant_ppann(z_mean=(0.0, 0.0, -0.9), z_sigma=(0.03, 0.05, 0.05))
CONFIG = OCPConfig(mc_samples=100, confidence=0.0)


@pytest.fixture(scope="module")
def plan():
    ocp = NominalOCP(NARROW, CONFIG)
    return ocp, ocp.solve()


def _decided(plan, monkeypatch, *, on: bool):
    ocp, nominal = plan
    monkeypatch.setattr(aware, "wanted", lambda given: on)
    return profiles.solve_decided(NARROW, CONFIG, profile="robust", ocp=ocp, nominal=nominal)


def _path(result) -> list[tuple]:
    return [
        (it.draft, it.k_sigma, tuple(it.margin), tuple(it.tightening)) for it in result.iterations
    ]


@pytest.mark.parametrize("goal", [0.0015, 0.05])
def test_beside_the_loop_the_same_solves_and_torque_as_in_line(plan, monkeypatch, goal) -> None:
    """At a target the draft clearly fails (k raised at the draft) and one it clearly passes:
    the decided torque, every recorded solve (draft or full, its k, margin and tightening) and
    both checks' rates are the same to the bit with the check beside the loop and in line."""
    monkeypatch.setattr(tail, "target", lambda config: goal)
    line = _decided(plan, monkeypatch, on=False)
    side = _decided(plan, monkeypatch, on=True)
    assert (line.k_sigma > 3.0) == (goal < 0.01)  # the raise happened where it should
    np.testing.assert_array_equal(side.robust.tau, line.robust.tau)
    assert _path(side) == _path(line)
    assert [c.rate for c in side.tail_checks] == [c.rate for c in line.tail_checks]
    assert side.tail_checks[0].draft and side.k_sigma == line.k_sigma


@pytest.mark.parametrize("answer", [None, 3.3])
def test_solves_go_on_while_the_check_runs_and_are_dropped_where_it_raises(
    plan, monkeypatch, answer
) -> None:
    """A slow check (0.3 s) of the loop's first draft (NEAR widened so that it is checked):
    beside, the loop makes its next draft while it runs, one and no full solve (dropped where it
    raises k: one IPOPT solve more than the records); the records and torque equal the in-line
    check's either way."""
    ocp, nominal = plan
    monkeypatch.setattr(aware, "NEAR", 1e9)
    base = replace(CONFIG, tail_check=False)
    solves = []
    original = aware.AwareOCP.solve

    def counted(self, *args, **kwargs):
        solves.append(pending_now())
        assert kwargs["draft"] or not solves[-1]  # a full solve waits for the answer
        return original(self, *args, **kwargs)

    started = threading.Event()

    def pending_now() -> bool:
        return started.is_set() and not finished.is_set()

    finished = threading.Event()

    def slow(solution, unc, config):
        started.set()
        time.sleep(0.3)
        finished.set()
        return answer

    monkeypatch.setattr(aware.AwareOCP, "solve", counted)
    runs = {}
    for on in (False, True):
        started.clear(), finished.clear(), solves.clear()
        monkeypatch.setattr(aware, "wanted", lambda given, on=on: on)
        records = []
        result = solve_robust(
            NARROW, base, ocp=ocp, nominal=nominal, draft_check=slow, on_iteration=records.append
        )
        runs[on] = (result, records, list(solves))
    (line, line_records, line_solves), (side, side_records, side_solves) = runs[False], runs[True]
    assert not any(line_solves)  # in line nothing is solved while the check runs
    assert sum(side_solves) == 1  # beside, the loop made one draft meanwhile
    np.testing.assert_array_equal(side.robust.tau, line.robust.tau)
    assert [(r.draft, r.k_sigma, tuple(r.margin)) for r in side_records] == [
        (r.draft, r.k_sigma, tuple(r.margin)) for r in line_records
    ]
    dropped = len(side_solves) - len(line_solves)
    assert dropped == (sum(side_solves) if answer else 0)


def test_the_check_takes_one_thread_while_the_loop_solves_and_all_once_it_waits(
    plan, monkeypatch
) -> None:
    """The check's rollouts: CHECK_THREADS while the loop solves beside it, the process's once
    the loop waits for the answer (here 3, from $CRANK_ROLLOUT_THREADS)."""
    ocp, nominal = plan
    monkeypatch.setenv("CRANK_ROLLOUT_THREADS", "3")
    monkeypatch.setattr(aware, "wanted", lambda given: True)
    seen = []

    def watching(solution, unc, config):
        seen.append(rollout_threads())
        deadline = time.monotonic() + 10
        while rollout_threads() == seen[0] and time.monotonic() < deadline:
            time.sleep(0.005)
        seen.append(rollout_threads())

    solve_robust(
        NARROW, replace(CONFIG, tail_check=False), ocp=ocp, nominal=nominal, draft_check=watching
    )
    assert seen == [beside.CHECK_THREADS, 3]


def test_a_checks_error_reaches_the_caller(plan, monkeypatch) -> None:
    """An exception in the check beside the loop is raised by the loop, not lost."""
    ocp, nominal = plan
    monkeypatch.setattr(aware, "wanted", lambda given: True)

    def broken(solution, unc, config):
        raise ZeroDivisionError("the check broke")

    with pytest.raises(ZeroDivisionError, match="the check broke"):
        solve_robust(
            NARROW, replace(CONFIG, tail_check=False), ocp=ocp, nominal=nominal, draft_check=broken
        )


def test_threads_here_is_this_threads_alone() -> None:
    """`threads_here` sets the rollouts' threads of the thread it runs in, and only there, and
    restores them after."""
    outside = rollout_threads()
    seen = {}
    with threads_here(outside + 3):
        assert rollout_threads() == outside + 3
        other = threading.Thread(target=lambda: seen.setdefault("other", rollout_threads()))
        other.start(), other.join()
    assert seen["other"] == outside and rollout_threads() == outside
    answers = iter([2, 5])
    with threads_here(lambda: next(answers)):  # asked at each rollout
        assert (rollout_threads(), rollout_threads()) == (2, 5)
    with pytest.raises(ValueError), threads_here(0):
        pass


def test_beside_where_the_process_has_cores_and_the_kernel(monkeypatch) -> None:
    """By default beside where the rollouts have more than one thread and run compiled; as
    given where given."""
    monkeypatch.setattr(kernel, "load", lambda: object())
    monkeypatch.setenv("CRANK_ROLLOUT_THREADS", "2")
    assert beside.wanted(None) and not beside.wanted(False)
    monkeypatch.setenv("CRANK_ROLLOUT_THREADS", "1")
    assert not beside.wanted(None) and beside.wanted(True)
    monkeypatch.setenv("CRANK_ROLLOUT_THREADS", "2")
    monkeypatch.setattr(kernel, "load", lambda: None)
    assert not beside.wanted(None)


def test_a_clone_gives_the_same_numbers_from_a_workspace_of_its_own() -> None:
    heads = FusedHeads(NARROW)
    twin = heads.clone()
    theta, omega = np.linspace(0, 7, 50), np.linspace(-20, 20, 50)
    for a, b in zip(heads(theta, omega), twin(theta, omega), strict=True):
        np.testing.assert_array_equal(a, b)
    assert twin._workspace is not heads._workspace
    assert twin._workspace[50][0] is not heads._workspace[50][0]
