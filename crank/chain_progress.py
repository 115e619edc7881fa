"""What a chain shows on stderr while it runs, for `crank run` and each seed of `crank study`:
a line per stage, a bar per long step (the dataset simulated and written, each model's epochs,
the replay's runs, the held-out machines) and the robust iterations; and `crank train`'s bars."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

from crank.console import EpochBars, show_iteration
from crank.progress import Progress

if TYPE_CHECKING:
    from crank.chain import Hooks, RunConfig
    from ppann.train_config import TrainConfig


@contextmanager
def chain_progress(config: RunConfig, *, prefix: str = "") -> Iterator[Hooks]:
    """Hooks that show `config`'s chain as it runs (each stage's line after `prefix`); every
    bar is closed when the block ends, also when the chain fails."""
    from crank.chain import Hooks  # torch and CasADi: not for `crank --help`

    bars = EpochBars.of(config.train)
    with (
        Progress(config.generation.n_samples, "simulating") as simulated,
        Progress(config.generation.n_samples, "writing MCAP") as written,
        Progress(0, "replaying", unit="run") as replayed,  # the totals once the stage knows them
        Progress(0, "held-out", unit="machine") as checked,
    ):
        played = {"replay": replayed, "heldout": checked}

        def on_stage(text: str) -> None:
            bars.close()  # the previous model's training, if any, has ended
            typer.echo(f"{prefix}{text} ...", err=True)

        try:
            yield Hooks(
                on_stage=on_stage,
                on_simulated=simulated.update,
                on_written=written.update,
                on_epoch=bars,
                on_trained=bars.done,
                on_iteration=show_iteration,
                on_total=lambda stage, total: played[stage].start(total),
                on_runs=lambda stage, n: played[stage].update(n),
                on_more=lambda stage, n: played[stage].more(n),
            )
        except BaseException:
            bars.close(stopped=True)  # where each model's training stopped, not "done"
            raise
        bars.close()


def train_models(*, data: Path, out: Path, config: TrainConfig) -> dict[str, Any]:
    """`train_and_report` with progress bars."""
    from ppann.pipeline import train_and_report

    bars = EpochBars.of(config)
    try:
        return train_and_report(
            data,
            out,
            config=config,
            on_epoch=bars,
            on_trained=bars.done,
            on_stage=lambda _: bars.close(),
        )
    except BaseException:
        bars.close(stopped=True)  # where each model's training stopped, not "done"
        raise
    finally:
        bars.close()
