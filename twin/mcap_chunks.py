"""The messages of one topic of an indexed MCAP, read from its chunks with `struct`: what
`mcap`'s `SeekingReader.iter_messages(topics=[topic])` yields, in its order, without building a
record object per message or ordering them through a heap of Python comparisons.

A dataset's two channels are 2 messages a sample: through `mcap` 1.6's reader `read_dataset`
took 7.7 s on the 720 s default dataset (360 000 samples), most of it per-record Python
(`Message.read`, `ReadDataStream`) and the log-time heap; with this walk 1.5 s
(`bench/bench_read.py`, session 69). `crank train` reads its dataset once, `crank run` three
times (train, the plan round, the second training), `crank inspect` both channels.

The order is the library's: by log time, ties by file position (chunk offset, then place in the
chunk). The library merges chunks in a heap keyed by each chunk index's first log time, which
gives that order whenever every chunk's index starts no later than its messages; that is checked,
and the messages are then sorted stably by log time in file order. Anything this walk does not
read exactly as the library would — no chunk index, a compression other than zstd or none, a
record running past its chunk, a message record shorter than its header, a channel the summary
does not name, two indexes of one chunk, a chunk index later than its messages, any error while
reading — returns None, and the caller reads the file with the library, which then gives the
result or the error it always gave (tests/test_mcap_chunks.py: the same bytes, order and
errors as the library's).
"""

from __future__ import annotations

import io
import struct
from typing import IO

import numpy as np
import zstandard
from mcap.data_stream import ReadDataStream
from mcap.records import Channel, Chunk, ChunkIndex, Schema
from mcap.summary import Summary

_RECORD = struct.Struct("<BQ")
"""A record's opcode and length."""
_MESSAGE = struct.Struct("<HIQQ")
"""A message record's channel id, sequence, log time and publish time (22 bytes)."""
_SCHEMA, _CHANNEL, _MESSAGE_OPCODE = 0x03, 0x04, 0x05
_HEADER = 1 + 8
"""A record's opcode and length, before its fields (a chunk's in the file, a message's in a
chunk)."""


class _UnusualError(Exception):
    """Something the library reads its own way: leave the file to it."""


def topic_messages(f: IO[bytes], summary: Summary, topic: str) -> list[bytes] | None:
    """The data of every message on `topic` of the MCAP open in `f` (`summary`: its summary), in
    the library's order; None where the library should read the file (the module's docstring)."""
    try:
        return _read(f, summary, topic)
    except Exception:  # any: the library reads the file again and says what is wrong
        return None


def _read(f: IO[bytes], summary: Summary, topic: str) -> list[bytes] | None:
    if not summary.chunk_indexes:
        return None
    wanted = {cid for cid, channel in summary.channels.items() if channel.topic == topic}
    chunks = [index for index in summary.chunk_indexes if _may_hold(index, summary, wanted)]
    offsets = [index.chunk_start_offset for index in chunks]
    if len(set(offsets)) != len(offsets):
        return None
    known = set(summary.channels)
    times: list[int] = []
    datas: list[bytes] = []
    for index in sorted(chunks, key=lambda c: c.chunk_start_offset):
        f.seek(index.chunk_start_offset + _HEADER)
        chunk = Chunk.read(ReadDataStream(f))
        if chunk.compression == "zstd":
            data = zstandard.decompress(chunk.data, chunk.uncompressed_size)
        elif chunk.compression == "":
            data = chunk.data
        else:
            return None
        first = len(times)
        _walk(data, wanted, known, times, datas)
        if len(times) > first and min(times[first:]) < index.message_start_time:
            return None  # the library's heap would take this chunk later than its messages
    order = np.argsort(np.asarray(times, dtype=np.uint64), kind="stable")
    return [datas[i] for i in order]


def _may_hold(index: ChunkIndex, summary: Summary, wanted: set[int]) -> bool:
    """Whether the library reads this chunk for the topic (mcap.reader's
    `_chunks_matching_topics`: every chunk without message indexes, else those naming one of
    the topic's channels)."""
    if not index.message_index_offsets:
        return True
    for channel_id in index.message_index_offsets:
        if channel_id not in summary.channels:
            raise _UnusualError
        if channel_id in wanted:
            return True
    return False


def _walk(
    data: bytes, wanted: set[int], known: set[int], times: list[int], datas: list[bytes]
) -> None:
    """Append the log time and data of each message of `wanted` channels in one chunk's records;
    schemas and channels are read as the library reads them (so that a damaged one fails here
    as there)."""
    view = memoryview(data)
    size, position = len(data), 0
    unpack_record, unpack_message = _RECORD.unpack_from, _MESSAGE.unpack_from
    while position < size:
        if position + _HEADER > size:
            raise _UnusualError
        opcode, length = unpack_record(data, position)
        body, end = position + _HEADER, position + _HEADER + length
        if end > size:
            raise _UnusualError
        if opcode == _MESSAGE_OPCODE:
            if length < _MESSAGE.size:
                raise _UnusualError
            channel_id, _sequence, log_time, _publish = unpack_message(data, body)
            if channel_id not in known:
                raise _UnusualError  # the library's summary look-up fails on it
            if channel_id in wanted:
                times.append(log_time)
                datas.append(bytes(view[body + _MESSAGE.size : end]))
        elif opcode in (_SCHEMA, _CHANNEL):
            stream = ReadDataStream(io.BytesIO(view[body:end]))
            (Schema if opcode == _SCHEMA else Channel).read(stream)
            if stream.count != length:
                raise _UnusualError
        position = end
