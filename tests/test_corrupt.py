"""Damaged inputs are refused in one line naming what is wrong: zeroed bytes inside an MCAP,
non-finite samples, a checkpoint cut short, NaN weights."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from ppann.checkpoint import CheckpointError, load, save
from ppann.model import PPANN
from tests.conftest import Written, crank
from twin.mcap_dataset import ContractError, read_dataset, write_dataset
from twin.physics import load_model


def test_zeroed_bytes_inside_an_mcap_never_escape_as_a_traceback(
    tmp_path: Path, paper_dataset: Written
) -> None:
    """64 zeroed bytes at five places of the file: each read either refuses with a ContractError
    or returns finite data (the bytes hit a part no reader checks); inside the compressed
    measurement chunks it is the decompression failure, named as corrupt data."""
    original = paper_dataset.path.read_bytes()
    messages = []
    for fraction in (0.1, 0.3, 0.5, 0.7, 0.9):
        damaged = bytearray(original)
        at = int(len(original) * fraction)
        damaged[at : at + 64] = bytes(64)
        path = tmp_path / f"z{fraction}.mcap"
        path.write_bytes(bytes(damaged))
        try:
            dataset = read_dataset(path)
        except ContractError as exc:
            messages.append(str(exc))
            continue
        assert np.all(np.isfinite(dataset.omega))
    assert any("corrupt MCAP data" in m for m in messages), messages
    result = crank("inspect", str(tmp_path / "z0.1.mcap"))
    assert result.returncode == 2 and "Traceback" not in result.stderr
    assert result.stderr.count("\n") == 1 and result.stderr.startswith("error: ")


@pytest.mark.parametrize(("field", "value"), [("omega", math.nan), ("slider_position", math.inf)])
def test_non_finite_samples_are_refused_naming_the_field(
    tmp_path: Path, paper_dataset: Written, field: str, value: float
) -> None:
    column = getattr(paper_dataset.dataset, field).copy()
    column[1234] = value
    dataset = dataclasses.replace(paper_dataset.dataset, **{field: column})
    path = tmp_path / "bad.mcap"
    write_dataset(path, dataset, paper_dataset.truth, run={"seed": 0}, model_xml=load_model()[1])
    with pytest.raises(ContractError, match=f"field '{field}' .* not finite .* index 1234"):
        read_dataset(path)


def test_a_cut_checkpoint_and_nan_weights_are_refused(tmp_path: Path) -> None:
    model = PPANN()
    good = tmp_path / "m.pt"
    save(good, model, kind="ppann", extra={"history": {}})
    cut = tmp_path / "cut.pt"
    cut.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    with pytest.raises(CheckpointError, match="not a checkpoint, or a damaged one"):
        load(cut)
    with torch.no_grad():
        model.mean_nets["B"][0].weight[0, 0] = math.nan
    save(tmp_path / "nan.pt", model, kind="ppann", extra={"history": {}})
    with pytest.raises(CheckpointError, match=r"tensor 'mean_nets\.B\.0\.weight' holds NaN or inf"):
        load(tmp_path / "nan.pt")
    load(good)  # the intact one still loads
    other = tmp_path / "other.pt"  # a pickle of something else (a dataset passed as --model)
    other.write_bytes(b"\x80\x02" + bytes(range(40)))
    with pytest.raises(CheckpointError) as refused:
        load(other)
    line = str(refused.value)
    assert line.startswith(f"{other}: not a checkpoint, or a damaged one (")
    # torch's advice to load it with weights_only=False (code execution) is not passed on
    assert "weights_only" not in line and "arbitrary code" not in line, line
