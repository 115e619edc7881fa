"""A draft's own-tail check run beside the aware loop's next solves (control/aware.py `iterate`,
session 50).

The open-loop aware loop checks its first draft near the fixed point before its full solve
(control/profiles.py `_draft_raise`): 500 lines of the model's own tail, 0.03-0.04 s on two
threads, a second stage of 2000 more where the rate sits within two standard errors of the
target (0.11-0.13 s), 0.2-1.2 nominal solves of the loop's time in session 48's benchmark.
Whatever the check answers, the loop's next solves from that draft are the ones it would make
at the same k; only a raised k sends it back to the draft. So the check runs on a thread of its
own while the loop makes its next draft (not a full solve), that draft's record held back; then
the loop waits for the answer: the draft is recorded if k stays, dropped and the loop taken back
to the checked draft if k is raised. One draft and its Monte-Carlo (~45 ms on the default
models) is about the check's time (35-45 ms on one thread, with its raise's prediction); a
second draft or a full solve beside a check that raised cost the pair 40-80 ms for nothing
(session 50, bench/beside.md), and the loop cannot return without the answer anyway. The
loop's path, its records and its result are those of the check made in line
(tests/test_beside.py); what changes is the wall time.

It runs where the process has more than one core to give (`common.threads.rollout_threads() >
1`) and the compiled kernel (`wanted`): IPOPT holds one, the check the other while the loop
solves (its rollouts on CHECK_THREADS thread), every core once the loop waits for it. CasADi
lets go of Python's GIL inside a solve and takes it back between its function calls, so the
check must spend its time in the compiled kernel, where the GIL is free, or the two slow each
other.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any

from common.threads import rollout_threads, threads_here
from ppann import kernel

CHECK_THREADS = 1
"""Threads of the rollouts of a check run beside the loop while it solves (its IPOPT holds the
other core)."""


def wanted(beside: bool | None) -> bool:
    """Whether the check runs beside the loop: `beside` where given, else where this process
    has more than one core for its rollouts (a sweep's one-CPU worker does not) and they run
    compiled (ppann/kernel.py; NumPy's rollout would hold the GIL between its array steps)."""
    if beside is not None:
        return beside
    return rollout_threads() > 1 and kernel.load() is not None


class Pending:
    """A check under way on `pool`'s thread: `check(*draft)`, the number of solves the loop
    had made at the draft checked (`solves`), that draft (`draft`: the solution and its
    Monte-Carlo), and the record of the draft made beside it (`held`). Its rollouts run
    on CHECK_THREADS threads while the loop solves, on the process's (every core unless set)
    once the loop waits for its `answer`."""

    def __init__(
        self,
        pool: ThreadPoolExecutor,
        check: Callable[..., float | None],
        draft: tuple[Any, Any],
        *,
        solves: int,
    ) -> None:
        self.draft = draft
        self.solves = solves
        self.held: list[tuple[Any, ...]] = []
        self._all = rollout_threads()
        self._waiting = threading.Event()
        self._future: Future[float | None] = pool.submit(self._run, check, *draft)

    def answer(self) -> float | None:
        """The check's answer, waiting for it; its exception, if it raised one."""
        self._waiting.set()
        return self._future.result()

    def _threads(self) -> int:
        return self._all if self._waiting.is_set() else CHECK_THREADS

    def _run(self, check: Callable[..., float | None], *arguments: Any) -> float | None:
        with threads_here(self._threads):
            return check(*arguments)
