"""`crank recover`: an indexed, readable MCAP from what a crashed campaign writer left.

The campaign log (replay/campaign_log.py) closes its chunk and flushes after each run, and writes
the run's `replay_run` record after its messages: the runs whose record made it are complete, and
are kept; the messages of a run cut short are dropped.
"""

from __future__ import annotations

import json
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO

import zstandard
from mcap.exceptions import McapError
from mcap.records import Attachment, Channel, Header, Message, Metadata, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer

from common.atomic import atomic_path, check_writable, writes
from common.errors import CrankError
from replay.campaign_log import REPLAY_RUN_METADATA
from twin import __version__
from twin.mcap_dataset import MCAP_MAGIC, RUN_METADATA


class RecoverError(CrankError, ValueError):
    """A file cannot be recovered (not an MCAP, or nothing readable in it)."""


@dataclass(frozen=True)
class Recovery:
    """What `recover` kept."""

    runs: int
    messages: int
    dropped_messages: int
    complete: bool
    """Whether the broken file was in fact complete (it had its footer)."""


_READ_ERRORS = (McapError, EOFError, struct.error, zstandard.ZstdError, ValueError, OSError)


def _records(f: BinaryIO) -> tuple[list[Any], bool]:
    """Every record readable from the start of `f`, and whether the file ended properly."""
    records: list[Any] = []
    try:
        for record in StreamReader(f, skip_magic=False).records:
            records.append(record)
    except _READ_ERRORS:
        return records, False
    return records, True


@writes("fixed", inputs=("broken",), suffix=".mcap")
def recover(broken: str | Path, fixed: str | Path) -> Recovery:
    """Rebuild an indexed, readable MCAP at `fixed` from what a crashed writer left in `broken`.

    Keeps the header, attachments, schemas, channels and the messages of every run whose
    `replay_run` record was written; drops the messages of a run cut short.

    Raises:
      RecoverError: `broken` is missing, is not an MCAP, or holds no header.
      OutputError: `fixed` cannot be written.
    """
    broken, fixed = Path(broken), Path(fixed)
    if not broken.is_file():
        raise RecoverError(f"file not found: {broken}")
    check_writable(fixed)
    with open(broken, "rb") as f:
        if f.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
            raise RecoverError(f"{broken}: not an MCAP file (no MCAP magic at its start)")
        f.seek(0)
        records, complete = _records(f)
    header = next((r for r in records if isinstance(r, Header)), None)
    if header is None or not header.library.startswith(("crank-replay", "crank-recover")):
        written_by = "no header" if header is None else f"written by {header.library!r}"
        raise RecoverError(f"{broken}: not a campaign log of crank replay ({written_by})")
    schemas = [r for r in records if isinstance(r, Schema)]
    channels = [r for r in records if isinstance(r, Channel)]
    metadata = [r for r in records if isinstance(r, Metadata)]
    attachments = [r for r in records if isinstance(r, Attachment)]
    messages = [r for r in records if isinstance(r, Message)]
    if not any(m.name == RUN_METADATA for m in metadata):
        raise RecoverError(f"{broken}: no `{RUN_METADATA}` metadata record; nothing to recover")
    done = {json.loads(m.metadata["episode"]) for m in metadata if m.name == REPLAY_RUN_METADATA}
    # Every message of episode e has sequence e * n + k (dataset channels and Foxglove's alike).
    run = next(m for m in metadata if m.name == RUN_METADATA)
    n = json.loads(run.metadata["samples_per_run"])
    keep = [m for m in messages if m.sequence // n in done]
    with atomic_path(fixed) as tmp, open(tmp, "wb") as out:
        writer = Writer(out, compression=CompressionType.ZSTD)
        writer.start(profile="", library=f"crank-recover {__version__}")
        schema_ids = {}
        for s in {s.id: s for s in schemas}.values():
            schema_ids[s.id] = writer.register_schema(s.name, s.encoding, s.data)
        channel_ids = {}
        for c in {c.id: c for c in channels}.values():
            channel_ids[c.id] = writer.register_channel(
                c.topic, c.message_encoding, schema_ids.get(c.schema_id, 0), c.metadata
            )
        for m in metadata:
            writer.add_metadata(m.name, m.metadata)
        for a in attachments:
            writer.add_attachment(a.create_time, a.log_time, a.name, a.media_type, a.data)
        for m in keep:
            writer.add_message(
                channel_ids[m.channel_id],
                log_time=m.log_time,
                data=m.data,
                publish_time=m.publish_time,
                sequence=m.sequence,
            )
        writer.finish()
    return Recovery(
        runs=len(done),
        messages=len(keep),
        dropped_messages=len(messages) - len(keep),
        complete=complete,
    )
