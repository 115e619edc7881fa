"""Model kinds trained side by side (ppann/fit.py `fit_all`) equal them trained one after
another to the last bit, report their progress per kind, and give torch its threads back."""

from __future__ import annotations

import io
import math
from contextlib import redirect_stderr

import pytest
import torch

from crank.console import EpochBars
from ppann.fit import fit_all
from ppann.kinds import KINDS
from ppann.train import make_splits
from ppann.train_config import TrainConfig
from tests.test_ppann import synthetic

CONFIG = TrainConfig(max_epochs=3, patience=10, batch_size=256, horizon=5, sigma_epochs=5)


def _fit(workers: int) -> tuple[dict, list, list]:
    data = synthetic(seconds=4.0)
    calls: list[tuple[str, str, int]] = []
    done: list[str] = []
    fitted = fit_all(
        data,
        kinds=KINDS,
        config=CONFIG,
        splits=make_splits(data, CONFIG),
        workers=workers,
        on_epoch=lambda kind, phase, epoch, loss: calls.append((kind, phase, epoch)),
        on_done=done.append,
    )
    return fitted, calls, done


def test_side_by_side_equals_one_after_another_to_the_last_bit() -> None:
    threads = torch.get_num_threads()
    alone, alone_calls, alone_done = _fit(workers=1)
    together, together_calls, together_done = _fit(workers=2)
    assert torch.get_num_threads() == threads  # given back
    assert list(together) == list(KINDS)
    for kind in KINDS:
        a, b = alone[kind].model.state_dict(), together[kind].model.state_dict()
        assert a.keys() == b.keys()
        for name in a:
            assert torch.equal(a[name], b[name]), (kind, name)
        assert alone[kind].history.train == together[kind].history.train
        assert alone[kind].history.sigma == together[kind].history.sigma
        # every kind's own calls arrive in its own order, whatever the interleaving
        mine = [c for c in together_calls if c[0] == kind]
        assert mine == [c for c in alone_calls if c[0] == kind]
    assert sorted(together_done) == sorted(alone_done) == sorted(KINDS)
    ppann_phases = [phase for kind, phase, _ in together_calls if kind == "ppann"]
    assert ppann_phases == ["mean"] * 3 + ["sigma"] * CONFIG.phase2_epochs  # two passes
    assert all(math.isfinite(v) for v in together["ppann"].history.sigma)


def test_a_kind_that_fails_stops_the_others_at_their_next_epoch() -> None:
    data = synthetic(seconds=4.0)
    config = TrainConfig(max_epochs=200, patience=200, batch_size=256, horizon=5)
    calls: list[tuple[str, int]] = []

    def on_epoch(kind: str, phase: str, epoch: int, loss: float) -> None:
        calls.append((kind, epoch))
        if kind == "physics" and epoch == 2:
            raise KeyboardInterrupt  # as Ctrl-C in a progress callback

    with pytest.raises(KeyboardInterrupt):
        fit_all(
            data,
            kinds=("ppann", "physics"),
            config=config,
            splits=make_splits(data, config),
            workers=2,
            on_epoch=on_epoch,
        )
    ppann_epochs = [epoch for kind, epoch in calls if kind == "ppann"]
    assert len(ppann_epochs) < 50  # not the 200 it would have run: it stopped with physics


def test_epoch_bars_keep_one_bar_per_kind_when_calls_interleave() -> None:
    bars = EpochBars({"mean": 10, "sigma": 5})
    log = io.StringIO()
    with redirect_stderr(log):  # not a terminal: LineBars, one line when each closes
        bars("ppann", "mean", 0, 1.0)
        bars("blackbox", "mean", 0, 2.0)
        bars("ppann", "mean", 1, 0.5)
        bars("blackbox", "mean", 1, 1.5)
        assert set(bars.bars) == {"ppann", "blackbox"}
        bars.done("blackbox")
        bars("ppann", "sigma", 0, 0.1)  # a new phase closes the kind's previous bar
        bars.close()
    lines = log.getvalue().splitlines()
    assert lines == [
        "blackbox mean: done, 2 epochs in 0.0 s (loss=1.5)",
        "ppann mean: done, 2 epochs in 0.0 s (loss=0.5)",
        "ppann sigma: done, 1 epochs in 0.0 s (loss=0.1)",
    ]
    assert bars.bars == {}
