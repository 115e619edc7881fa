"""The threads this process's compiled rollouts run on: MuJoCo's (twin/stepping.py) and the
Monte-Carlo's C kernel (ppann/kernel.py), the one setting a caller with one CPU turns down, as
`torch.set_num_threads` is torch's."""

from __future__ import annotations

import os

from common.checks import check_count

_rollout_threads: int | None = None


def set_rollout_threads(count: int | None) -> None:
    """The threads a rollout of this process runs on when its caller does not say (None: every
    core). A sweep's Ray worker holds one CPU and sets 1: with each step on every core, two
    workers and a held-out check made six threads on two cores, and a data step took 648 s
    against 80 s alone (session 24)."""
    global _rollout_threads
    if count is not None:
        check_count("rollout threads", count, error=ValueError)
    _rollout_threads = count


def rollout_threads() -> int:
    """The threads a rollout runs on by default: `set_rollout_threads`' count, else every core."""
    return _rollout_threads if _rollout_threads is not None else (os.cpu_count() or 1)
