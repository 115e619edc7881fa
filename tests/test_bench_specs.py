"""Every sweep spec in bench/ (the documented studies) still reads: a default flipped after a spec
was written must not make two of its cases the same run (sessions 25 and 27 flipped two, and
three specs were refused until they stated the defaults they compared)."""

from __future__ import annotations

import importlib.util
import itertools
from pathlib import Path

import pytest

from crank.sweep_spec import read_spec

SPECS = sorted((Path(__file__).resolve().parent.parent / "bench").glob("*.toml"))


def test_the_bench_specs_are_found() -> None:
    assert len(SPECS) >= 20


@pytest.mark.parametrize("spec", SPECS, ids=lambda path: path.name)
def test_a_bench_spec_reads_into_distinct_leaves(spec: Path) -> None:
    _, leaves = read_spec(spec)
    assert len(leaves) >= 1


def test_the_drawn_tasks_spec_is_its_draw() -> None:
    """bench/random_tasks_sweep.toml is what bench/random_tasks.py draws from its root (the
    pre-registered tasks can be drawn again), and every task lies in the ranges it states."""
    bench = SPECS[0].parent
    loaded = importlib.util.spec_from_file_location("random_tasks", bench / "random_tasks.py")
    module = importlib.util.module_from_spec(loaded)
    loaded.loader.exec_module(module)
    tasks = module.draw_tasks(20261284, 8)
    text = module.spec(tasks, root=20261284, heldout_seed=20261285)
    assert text == (bench / "random_tasks_sweep.toml").read_text()
    _, leaves = read_spec(bench / "random_tasks_sweep.toml")
    assert [leaf.config.seed for leaf in leaves] == list(range(8))
    assert [module.task_of(module.task_name(i, t)) for i, t in enumerate(tasks)] == list(
        enumerate(tasks)
    )  # a name reads back as its task (the tables and the figure read them)
    for task, leaf in zip(tasks, leaves, strict=True):
        ocp, n = leaf.config.ocp, task["horizon"]
        assert (ocp.horizon, list(ocp.constraint_samples), ocp.height) == (
            n,
            task["constraint_samples"],
            task["height"],
        )
        assert 120 <= n <= 220 and 1 <= len(ocp.constraint_samples) <= 3
        assert all(0.3 * n <= k <= 0.7 * n for k in ocp.constraint_samples)
        assert all(b - a >= 10 for a, b in itertools.pairwise(ocp.constraint_samples))
        assert 0.075 <= ocp.height <= 0.085
