"""The threads this process's compiled rollouts run on: MuJoCo's (twin/stepping.py) and the
Monte-Carlo's C kernel (ppann/kernel.py), the one setting a caller with one CPU turns down, as
`torch.set_num_threads` is torch's; $CRANK_ROLLOUT_THREADS gives a process's default."""

from __future__ import annotations

import os
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager

from common.checks import check_count
from common.errors import ConfigError

_rollout_threads: int | None = None
_here = threading.local()


def set_rollout_threads(count: int | None) -> None:
    """The threads a rollout of this process runs on when its caller does not say (None: every
    core). A sweep's Ray worker holds one CPU and sets 1: with each step on every core, two
    workers and a held-out check made six threads on two cores, and a data step took 648 s
    against 80 s alone (session 24)."""
    global _rollout_threads
    if count is not None:
        check_count("rollout threads", count, error=ValueError)
    _rollout_threads = count


ENVIRONMENT = "CRANK_ROLLOUT_THREADS"
"""The process default when `set_rollout_threads` has not set one: for a `crank` command started
beside others (the test suite's workers set 1 for theirs and what they start)."""


@contextmanager
def threads_here(count: int | Callable[[], int]) -> Iterator[None]:
    """Within the block, this thread's rollouts run on `count` threads (or on what `count()`
    answers at each rollout), whatever the process's setting (control/beside.py: a check beside
    the loop's IPOPT solves takes the other core, and every core once the loop waits for it)."""
    if not callable(count):
        check_count("rollout threads", count, error=ValueError)
    before = getattr(_here, "count", None)
    _here.count = count
    try:
        yield
    finally:
        _here.count = before


def rollout_threads() -> int:
    """The threads a rollout runs on by default: this thread's `threads_here` count, else
    `set_rollout_threads`' count, else $CRANK_ROLLOUT_THREADS, else every core.

    Raises:
      ConfigError: $CRANK_ROLLOUT_THREADS is not an integer >= 1 (one line on the CLI).
    """
    here = getattr(_here, "count", None)
    if here is not None:
        return here() if callable(here) else here
    if _rollout_threads is not None:
        return _rollout_threads
    given = os.environ.get(ENVIRONMENT)
    if given is None:
        return os.cpu_count() or 1
    if not (given.isascii() and given.isdigit()) or int(given) < 1:
        raise ConfigError(f"${ENVIRONMENT} must be an integer >= 1, got {given!r}")
    return int(given)
