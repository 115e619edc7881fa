"""The dataset file contract, record by record, and exact round trips."""

from __future__ import annotations

import json
from dataclasses import fields
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.records import Attachment, Chunk, Header, Metadata
from mcap.stream_reader import StreamReader

from twin.mcap_dataset import (
    MEASUREMENT_TOPIC,
    TRUTH_TOPIC,
    ContractError,
    read_dataset,
    read_model_xml,
    read_run,
)
from twin.physics import SliderCrank


def test_round_trip_is_exact(paper_dataset) -> None:
    for name in ("t", "episode", "theta", "omega", "tau", "slider_position"):
        assert np.array_equal(
            getattr(paper_dataset.dataset, name), getattr(paper_dataset.loaded, name)
        ), name
    for f in fields(paper_dataset.truth):
        assert np.array_equal(
            getattr(paper_dataset.truth, f.name), getattr(paper_dataset.loaded_truth, f.name)
        ), f.name
    assert paper_dataset.loaded.episode.dtype == np.int64


def test_run_metadata_comes_first_and_chunks_are_zstd(paper_dataset) -> None:
    with open(paper_dataset.path, "rb") as f:
        records = list(StreamReader(f, emit_chunks=True).records)
    assert isinstance(records[0], Header)
    assert isinstance(records[1], Metadata) and records[1].name == "run"
    assert isinstance(records[2], Attachment) and records[2].name == "model.xml"
    chunks = [r for r in records if isinstance(r, Chunk)]
    assert chunks and {c.compression for c in chunks} == {"zstd"}


def test_channels_schemas_and_log_times(paper_dataset) -> None:
    with open(paper_dataset.path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        topics = {c.topic: c for c in summary.channels.values()}
        assert set(topics) == {MEASUREMENT_TOPIC, TRUTH_TOPIC}
        for channel in topics.values():
            assert channel.message_encoding == "json"
            schema = summary.schemas[channel.schema_id]
            assert schema.encoding == "jsonschema"
            assert json.loads(schema.data)["type"] == "object"
        counts = summary.statistics.channel_message_counts
        assert all(counts[c.id] == 45_000 for c in topics.values())
        messages = [
            (m.log_time, m.sequence, json.loads(m.data))
            for _, _, m in reader.iter_messages(topics=[MEASUREMENT_TOPIC])
        ]
    for k in (0, 1, 12_345, 44_999):
        log_time, sequence, body = messages[k]
        assert sequence == k
        assert log_time == round(body["t"] * 1e9) == 2_000_000 * k


def test_model_attachment_compiles_to_the_same_model(paper_dataset, physics: SliderCrank) -> None:
    import mujoco

    model = mujoco.MjModel.from_xml_string(read_model_xml(paper_dataset.path))
    assert (model.nq, model.nv, model.nu, model.nsensordata) == (
        physics.model.nq,
        physics.model.nv,
        physics.model.nu,
        physics.model.nsensordata,
    )
    assert model.opt.timestep == physics.model.opt.timestep
    assert read_run(paper_dataset.path) == {"seed": 0}


def test_a_truncated_file_is_rejected_in_one_line(paper_dataset, tmp_path: Path) -> None:
    """What a crashed writer leaves: no summary, no footer."""
    data = paper_dataset.path.read_bytes()
    broken = tmp_path / "broken.mcap"
    broken.write_bytes(data[: len(data) // 2])
    with pytest.raises(ContractError, match="truncated") as info:
        read_dataset(broken)
    assert "\n" not in str(info.value) and str(broken) in str(info.value)
