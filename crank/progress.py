"""Progress on stderr: a tqdm bar on a terminal, plain lines otherwise (a pipe, a log file), and
`Progress`, the bar a long step shows only after 2 s."""

from __future__ import annotations

import os
import sys
import time
from typing import Any

from tqdm import tqdm


class LineBar:
    """tqdm's update/set_postfix/close for a stderr that is not a terminal (a pipe, a log file):
    a plain line at most every `interval` seconds (done, total, time left at the rate so far) and
    one when done — or, closed by an error or Ctrl-C, where it stopped —, never carriage-return
    frames; nothing at all for work done within `delay` seconds (as tqdm's delay)."""

    def __init__(
        self, *, total: int, desc: str, unit: str, delay: float = 0.0, interval: float = 10.0
    ) -> None:
        self.total, self.desc, self.unit, self.interval = total, desc, unit, interval
        self.delay = delay
        self.n, self.postfix, self.closed = 0, "", False
        self.started = self.shown = time.monotonic()

    def update(self, n: int) -> None:
        self.n += n
        now = time.monotonic()
        if now - self.shown >= self.interval and self.n < self.total:
            self.shown = now
            left = (now - self.started) / self.n * (self.total - self.n)
            self._line(f"{self.n}/{self.total} {self.unit}s, {left:.0f} s left at this rate")

    def set_postfix(self, **values: str) -> None:
        self.postfix = ", ".join(f"{k}={v}" for k, v in values.items())

    def close(self, *, stopped: bool = False) -> None:
        """Its last line: "done", or with `stopped` (its step ended by an error or Ctrl-C) how
        far it got, which a "done" would misreport (an epoch bar ends early by design, so a
        short count alone cannot tell)."""
        if not self.closed:
            self.closed = True
            took = time.monotonic() - self.started
            if took < self.delay:
                return
            if stopped:
                self._line(f"stopped at {self.n}/{self.total} {self.unit}s after {took:.1f} s")
            else:
                self._line(f"done, {self.n} {self.unit}s in {took:.1f} s")

    def _line(self, text: str) -> None:
        extra = f" ({self.postfix})" if self.postfix else ""
        print(f"{self.desc}: {text}{extra}", file=sys.stderr, flush=True)


def _terminal_columns() -> int:
    """stderr's width in columns; 0 when it is not a terminal, or a terminal of no size (a pty
    nobody sized, as `script` and some CI runners make: tqdm draws nothing at all on it)."""
    if not sys.stderr.isatty():
        return 0
    try:
        return os.get_terminal_size(sys.stderr.fileno()).columns
    except (OSError, ValueError):
        return 0


def close_bar(bar: Any, *, stopped: bool) -> None:
    """Close a bar of `progress_bar`; `stopped` if its step ended by an error or Ctrl-C (a
    LineBar's last line then says where it stopped; tqdm's, `leave=False`, leaves none)."""
    if isinstance(bar, LineBar):
        bar.close(stopped=stopped)
    else:
        bar.close()


def progress_bar(*, total: int, desc: str, unit: str, delay: float = 0.0) -> Any:
    """A tqdm bar on a terminal, a LineBar otherwise (also on a terminal of no width)."""
    if _terminal_columns() == 0:
        return LineBar(total=total, desc=desc, unit=unit, delay=delay)
    return tqdm(total=total, desc=desc, unit=unit, unit_scale=True, delay=delay, leave=False)


class Progress:
    """A progress bar on stderr, created at its first update and shown only if the step takes
    more than 2 s, so short runs print nothing but their result. It closes once full (its line
    given back to the next stage's bar) or, if not `close_when_full`, when its `with` ends: the
    step's last lines (`echo`) then come before its "done"."""

    def __init__(
        self, total: int, desc: str, *, unit: str = "sample", close_when_full: bool = True
    ) -> None:
        self.total, self.desc, self.unit, self.bar = total, desc, unit, None
        self.close_when_full = close_when_full

    def start(self, total: int) -> None:
        """The total, once the step knows it; the bar's clock starts now, not at the first
        update (which may come only after a whole batch)."""
        self.total = total
        self.update(0)

    def update(self, n: int) -> None:
        if self.bar is None:
            self.bar = progress_bar(total=self.total, desc=self.desc, unit=self.unit, delay=2.0)
        self.bar.update(n)
        if self.close_when_full and self.bar.n >= self.total:
            self.bar.close()

    def more(self, n: int) -> None:
        """`n` more to do than the total said (a held-out check's second stage): a bar of its
        own where this one closed when full, else this one's total raised."""
        if self.bar is not None and self.close_when_full and self.bar.n >= self.total:
            self.bar, self.total = None, n
            self.update(0)
            return
        self.total += n
        if self.bar is not None:
            self.bar.total = self.total
            if isinstance(self.bar, tqdm):
                self.bar.refresh()

    def echo(self, text: str) -> None:
        """A line on stderr that leaves the bar whole (tqdm's `write` while one is drawn)."""
        if isinstance(self.bar, tqdm) and not self.bar.disable:
            tqdm.write(text, file=sys.stderr)
        else:
            print(text, file=sys.stderr, flush=True)

    def __enter__(self) -> Progress:
        return self

    def close(self, *, stopped: bool = False) -> None:
        """Close the bar, if shown; `stopped` if the step ended by an error or Ctrl-C."""
        if self.bar is not None:
            close_bar(self.bar, stopped=stopped)

    def __exit__(self, kind: type[BaseException] | None, *exc: object) -> None:
        self.close(stopped=kind is not None)


class StageBars:
    """A bar per playing stage, for stages that come one after another (`crank compare`'s
    campaign and held-out machines of each run): `start(stage, total)` closes the bar before —
    its "done" after that stage's last line — and opens the stage's; `echo` writes a line
    through the open bar; the block's end closes the last one."""

    def __init__(self, *, unit: str) -> None:
        self.unit = unit
        self.bar: Progress | None = None

    def start(self, stage: str, total: int) -> None:
        self.close()
        self.bar = Progress(0, stage, unit=self.unit, close_when_full=False)
        self.bar.start(total)

    def update(self, _stage: str, n: int) -> None:
        if self.bar is not None:
            self.bar.update(n)

    def echo(self, text: str) -> None:
        if self.bar is None:
            print(text, file=sys.stderr, flush=True)
        else:
            self.bar.echo(text)

    def close(self, *, stopped: bool = False) -> None:
        if self.bar is not None:
            self.bar.close(stopped=stopped)
            self.bar = None

    def __enter__(self) -> StageBars:
        return self

    def __exit__(self, kind: type[BaseException] | None, *exc: object) -> None:
        self.close(stopped=kind is not None)
