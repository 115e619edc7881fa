"""twin/mcap_chunks.py reads a topic's messages as `mcap`'s reader does: the same bytes in the
same order (log time, ties by file position) on a dataset, on files whose log times run out of
order or tie across chunks, uncompressed or without message indexes; files it leaves to the
library read as before, and a damaged file fails with the library's error."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import CompressionType, IndexType, Writer

import twin.mcap_dataset as mcap_dataset
from tests.conftest import Written
from twin.mcap_chunks import topic_messages
from twin.mcap_dataset import (
    MEASUREMENT_TOPIC,
    TRUTH_TOPIC,
    ContractError,
    read_dataset,
    read_truth,
)


def _both(path: Path, topic: str) -> tuple[list[bytes] | None, list[bytes]]:
    """The walk's messages and the library's for `topic` of `path`."""
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        walked = topic_messages(f, summary, topic)
        library = [m.data for _, _, m in reader.iter_messages(topics=[topic])]
    return walked, library


def _library_only(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(mcap_dataset, "topic_messages", lambda *_: None)


def _same(a: object, b: object) -> None:
    for field in dataclasses.fields(a):  # type: ignore[arg-type]
        x, y = getattr(a, field.name), getattr(b, field.name)
        if isinstance(x, np.ndarray):
            assert x.dtype == y.dtype and np.array_equal(x, y), field.name
        else:
            assert x == y, field.name


def test_a_dataset_reads_as_the_library_reads_it(
    paper_dataset: Written, monkeypatch: pytest.MonkeyPatch
) -> None:
    for topic in (MEASUREMENT_TOPIC, TRUTH_TOPIC):
        walked, library = _both(paper_dataset.path, topic)
        assert walked is not None and len(library) == 45_000
        assert walked == library, topic
    fast = read_dataset(paper_dataset.path), read_truth(paper_dataset.path)
    _library_only(monkeypatch)
    slow = read_dataset(paper_dataset.path), read_truth(paper_dataset.path)
    _same(fast[0], slow[0])
    _same(fast[1], slow[1])


def _shuffled(path: Path, **writer: object) -> None:
    """Two channels, 600 messages each, log times drawn from 0-99 ns (so ties within and across
    chunks, and out of order in the file), in chunks of ~2 kB."""
    rng = np.random.default_rng(4)
    with open(path, "wb") as f:
        out = Writer(f, chunk_size=2048, **writer)  # type: ignore[arg-type]
        out.start()
        schema = out.register_schema("s", "jsonschema", b"{}")
        channels = [out.register_channel(t, "json", schema) for t in ("/a", "/b")]
        for k in range(1200):
            time = int(rng.integers(0, 100))
            channel = channels[k % 2]
            out.add_message(channel, log_time=time, data=b'{"k": %d}' % k, publish_time=time)
        out.finish()


@pytest.mark.parametrize(
    "writer",
    [
        {},
        {"compression": CompressionType.NONE},
        {"index_types": IndexType.CHUNK},  # no message indexes: every chunk is read
    ],
    ids=["zstd", "uncompressed", "no-message-indexes"],
)
def test_log_times_out_of_order_and_tied_come_in_the_librarys_order(
    tmp_path: Path, writer: dict
) -> None:
    path = tmp_path / "shuffled.mcap"
    _shuffled(path, **writer)
    for topic in ("/a", "/b"):
        walked, library = _both(path, topic)
        assert len(library) == 600
        assert walked is not None and walked == library
    times = []
    with open(path, "rb") as f:
        times = [m.log_time for _, _, m in make_reader(f).iter_messages(topics=["/a"])]
    assert len(set(times)) < len(times)  # ties there were


@pytest.mark.parametrize(
    "writer", [{"use_chunking": False}, {"index_types": IndexType.NONE}], ids=["flat", "no-index"]
)
def test_a_file_without_chunk_indexes_is_left_to_the_library(tmp_path: Path, writer: dict) -> None:
    path = tmp_path / "flat.mcap"
    _shuffled(path, **writer)
    walked, library = _both(path, "/a")
    assert walked is None and len(library) == 600


def test_a_damaged_dataset_fails_as_the_library_fails(
    tmp_path: Path, paper_dataset: Written, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Zeroed bytes at nine places: the same ContractError, or the same data, either way."""
    original = paper_dataset.path.read_bytes()
    outcomes = {True: [], False: []}
    paths = []
    for fraction in np.linspace(0.05, 0.95, 9):
        damaged = bytearray(original)
        at = int(len(original) * fraction)
        damaged[at : at + 64] = bytes(64)
        paths.append(tmp_path / f"z{fraction:.2f}.mcap")
        paths[-1].write_bytes(bytes(damaged))
    for walk in (True, False):
        if not walk:
            _library_only(monkeypatch)
        for path in paths:
            try:
                outcomes[walk].append(read_dataset(path).omega)
            except ContractError as exc:
                outcomes[walk].append(str(exc))
    assert any(isinstance(o, str) for o in outcomes[False])
    for fast, slow in zip(outcomes[True], outcomes[False], strict=True):
        if isinstance(slow, str):
            assert fast == slow
        else:
            assert np.array_equal(fast, slow)


def test_a_chunk_index_later_than_its_messages_is_left_to_the_library(tmp_path: Path) -> None:
    """The summary's first chunk index set to start after its messages (the library's heap then
    takes that chunk late): the walk leaves the file to the library."""
    path = tmp_path / "late.mcap"
    _shuffled(path)
    data = bytearray(path.read_bytes())
    footer = len(data) - 8 - (1 + 8 + 20)  # the footer record before the closing magic
    assert data[footer] == 0x02
    position = int.from_bytes(data[footer + 9 : footer + 17], "little")  # summary_start
    while data[position] != 0x08:  # the first chunk index
        position += 1 + 8 + int.from_bytes(data[position + 1 : position + 9], "little")
    data[position + 9 : position + 17] = (10**6).to_bytes(8, "little")  # message_start_time
    path.write_bytes(bytes(data))
    walked, library = _both(path, "/a")
    assert walked is None and len(library) == 600
