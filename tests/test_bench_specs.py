"""Every sweep spec in bench/ (the documented studies) still reads: a default flipped after a spec
was written must not make two of its cases the same run (sessions 25 and 27 flipped two, and
three specs were refused until they stated the defaults they compared)."""

from __future__ import annotations

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
