"""The dataset file contract: MCAP with JSON messages, JSON-schema schemas and zstd chunks.

Channels (message `log_time` = simulated time in ns, `sequence` = sample index):
  /slider_crank/measurement  {t, episode, theta, omega, tau, slider_position}: what a learner
                              may use.
  /slider_crank/truth        {t, episode, crank_angle, backlash_angle, disturbance_force,
                              loop_closure_error, motor_frictionloss, motor_damping,
                              slider_frictionloss, slider_damping, backlash_width}: ground truth.
Metadata `run` (written first, so a crash keeps it): every value JSON-encoded; seed, duration, rate,
the resolved config, each episode's machine draw and initial state, versions and the MJCF's sha256.
Attachment `model.xml`: the compiled MJCF of the run.

Rig data (`crank import`, twin/rig_import.py) has the measurement channel and the `run` record
only: no truth channel and no model.xml, which learners do not need.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import fields
from pathlib import Path

import numpy as np
import orjson
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer
from zstandard import ZstdError

from common.atomic import atomic_path
from common.errors import CrankError
from twin import __version__
from twin.dataset import (
    MEASUREMENT_FIELDS,
    TRUTH_FIELDS,
    Dataset,
    GroundTruth,
    measurement_arrays,
    truth_arrays,
)
from twin.mcap_chunks import topic_messages

MEASUREMENT_TOPIC = "/slider_crank/measurement"
TRUTH_TOPIC = "/slider_crank/truth"
RUN_METADATA = "run"
MODEL_ATTACHMENT = "model.xml"
CHANNELS = (
    (MEASUREMENT_TOPIC, "slider_crank.Measurement", MEASUREMENT_FIELDS),
    (TRUTH_TOPIC, "slider_crank.Truth", TRUTH_FIELDS),
)
"""(topic, schema title, field names) of the contract's channels."""

_DESCRIPTIONS = {
    "t": "simulated time in s, running across episodes",
    "episode": "episode index; a fresh machine draw and initial state per episode",
    "theta": "motor encoder angle in rad, unwrapped",
    "omega": "motor speed in rad/s",
    "tau": "motor torque in N·m applied from this sample to the next",
    "slider_position": "slider position in m, 0 at bottom dead centre, 0.1 at top dead centre",
    "crank_angle": "crank angle in rad (motor angle + backlash angle)",
    "backlash_angle": "angle of the crank relative to the motor shaft in rad",
    "disturbance_force": "unmeasured white-noise force on the slider in N, held to the next sample",
    "loop_closure_error": "distance between rod tip and slider pin in m",
    "motor_frictionloss": "Coulomb friction of the motor in N·m",
    "motor_damping": "viscous damping of the motor in N·m·s/rad",
    "slider_frictionloss": "Coulomb friction of the slider in N",
    "slider_damping": "viscous damping of the slider in N·s/m",
    "backlash_width": "width of the backlash gap in rad",
}


class ContractError(CrankError, ValueError):
    """A file is not a dataset MCAP, or breaks the contract; the message names what is wrong."""


def message_schema(
    title: str, names: tuple[str, ...], *, extra: dict[str, dict] | None = None
) -> bytes:
    """JSON schema of a contract channel's messages; `extra` adds tagged properties (e.g. a
    replay's run, profile and mode) that readers of the contract ignore."""
    props = {
        n: {"type": "integer" if n == "episode" else "number", "description": _DESCRIPTIONS[n]}
        for n in names
    } | (extra or {})
    schema = {"title": title, "type": "object", "properties": props, "required": list(props)}
    return json.dumps(schema).encode()


def write_dataset(
    path: str | Path,
    dataset: Dataset,
    truth: GroundTruth | None,
    *,
    run: dict,
    model_xml: str | None,
    on_progress: Callable[[int], None] | None = None,
) -> None:
    """Write `dataset` and `truth` to `path` atomically (nothing at `path` unless complete).

    Args:
      truth: the twin's ground truth; None for rig data (no truth channel).
      run: the run's metadata; each value is stored JSON-encoded.
      model_xml: the compiled MJCF, attached as model.xml; None for rig data (no twin).
      on_progress: called with the number of samples just written.
    """
    columns = {MEASUREMENT_TOPIC: {k: v.tolist() for k, v in measurement_arrays(dataset).items()}}
    if truth is not None:
        columns[TRUTH_TOPIC] = {k: v.tolist() for k, v in truth_arrays(truth).items()}
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        writer = Writer(f, compression=CompressionType.ZSTD)
        writer.start(profile="", library=f"crank-twin {__version__}")
        writer.add_metadata(RUN_METADATA, {k: json.dumps(v) for k, v in run.items()})
        if model_xml is not None:
            writer.add_attachment(0, 0, MODEL_ATTACHMENT, "application/xml", model_xml.encode())
        channels = {}
        for topic, title, names in CHANNELS:
            if topic not in columns:
                continue
            schema_id = writer.register_schema(title, "jsonschema", message_schema(title, names))
            channels[topic] = writer.register_channel(topic, "json", schema_id)
        rows = {topic: list(zip(*cols.values(), strict=True)) for topic, cols in columns.items()}
        keys = {topic: tuple(cols) for topic, cols in columns.items()}
        log_times = np.round(dataset.t * 1e9).astype(np.int64).tolist()
        step = 5000
        for start in range(0, len(log_times), step):
            stop = min(start + step, len(log_times))
            for k in range(start, stop):
                for topic, channel in channels.items():
                    writer.add_message(
                        channel,
                        log_time=log_times[k],
                        data=orjson.dumps(dict(zip(keys[topic], rows[topic][k], strict=True))),
                        publish_time=log_times[k],
                        sequence=k,
                    )
            if on_progress is not None:
                on_progress(stop - start)
        writer.finish()


MCAP_MAGIC = b"\x89MCAP0\r\n"


def open_reader(f, path: Path):
    """An MCAP reader and its summary for the open file `f`; ContractError naming `path` if it is
    not an MCAP, was cut short or has no summary."""
    head = f.read(len(MCAP_MAGIC))
    if head != MCAP_MAGIC:
        raise ContractError(f"{path}: not an MCAP file (no MCAP magic at its start)")
    f.seek(-len(MCAP_MAGIC), 2)
    if f.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
        raise ContractError(f"{path}: MCAP is truncated (no footer; was its writer interrupted?)")
    f.seek(0)
    try:
        reader = make_reader(f)
        summary = reader.get_summary()
    except (McapError, ValueError, EOFError) as exc:
        raise ContractError(f"{path}: not an MCAP file ({exc})") from None
    if summary is None:
        raise ContractError(f"{path}: MCAP has no summary (was its writer interrupted?)")
    return reader, summary


def _check_path(path: str | Path) -> Path:
    path = Path(path)
    if not path.exists():
        raise ContractError(f"dataset not found: {path}")
    if not path.is_file():
        raise ContractError(f"dataset path is not a file: {path}")
    return path


def _read_topic(path: str | Path, topic: str, names: tuple[str, ...]) -> dict[str, np.ndarray]:
    path = _check_path(path)
    with open(path, "rb") as f:
        reader, summary = open_reader(f, path)
        topics = {c.topic: c for c in summary.channels.values()}
        for required in (MEASUREMENT_TOPIC, topic):  # the truth channel only to read it
            if required not in topics:
                raise ContractError(f"{path}: missing channel {required}")
        if topics[topic].message_encoding != "json":
            raise ContractError(
                f"{path}: channel {topic} has encoding {topics[topic].message_encoding!r}, "
                "expected 'json'"
            )
        try:
            datas = topic_messages(f, summary, topic)
            if datas is None:  # the library's reader, decoding each message as it comes
                datas = (m.data for _, _, m in reader.iter_messages(topics=[topic]))
            rows = [orjson.loads(data) for data in datas]
        except orjson.JSONDecodeError as exc:
            raise ContractError(f"{path}: a message on {topic} is not JSON ({exc})") from None
        except (McapError, ZstdError, ValueError, EOFError) as exc:  # a damaged chunk
            reason = " ".join(str(exc).split())[:160]
            raise ContractError(f"{path}: corrupt MCAP data on {topic} ({reason})") from None
    if not rows:
        raise ContractError(f"{path}: channel {topic} has no messages")
    out = {}
    for name in names:
        try:
            out[name] = np.array(
                [r[name] for r in rows], dtype=np.int64 if name == "episode" else float
            )
        except KeyError:
            raise ContractError(f"{path}: a message on {topic} lacks field {name!r}") from None
        except (TypeError, ValueError):
            raise ContractError(f"{path}: field {name!r} on {topic} is not numeric") from None
        bad = np.flatnonzero(~np.isfinite(out[name]))
        if bad.size:
            raise ContractError(
                f"{path}: field {name!r} on {topic} is not finite at {bad.size} message(s), "
                f"first at index {bad[0]} ({out[name][bad[0]]})"
            )
    if len(out["t"]) > 1 and not np.all(np.diff(out["t"]) > 0):
        raise ContractError(f"{path}: t on {topic} is not strictly increasing")
    return out


def read_run(path: str | Path, *, required: bool = True) -> dict:
    """The `run` metadata record of a dataset file, values decoded from JSON; {} for a file
    without one if not `required` (another tool's measurements)."""
    path = _check_path(path)
    with open(path, "rb") as f:
        reader, _ = open_reader(f, path)
        for record in reader.iter_metadata():
            if record.name == RUN_METADATA:
                try:
                    return {k: json.loads(v) for k, v in record.metadata.items()}
                except json.JSONDecodeError:
                    raise ContractError(f"{path}: metadata {RUN_METADATA!r} is not JSON") from None
    if not required:
        return {}
    raise ContractError(f"{path}: missing metadata record {RUN_METADATA!r}")


def has_model_xml(path: str | Path) -> bool:
    """Whether a dataset file carries its twin's MJCF (rig data has none)."""
    path = _check_path(path)
    with open(path, "rb") as f:
        _, summary = open_reader(f, path)
        return any(a.name == MODEL_ATTACHMENT for a in summary.attachment_indexes)


def read_model_xml(path: str | Path) -> str:
    """The MJCF attached to a dataset file as model.xml."""
    path = _check_path(path)
    with open(path, "rb") as f:
        reader, _ = open_reader(f, path)
        for attachment in reader.iter_attachments():
            if attachment.name == MODEL_ATTACHMENT:
                return attachment.data.decode()
    raise ContractError(f"{path}: missing attachment {MODEL_ATTACHMENT!r}")


def read_dataset(path: str | Path) -> Dataset:
    """Load the measurement channel and run metadata of a dataset file. A learner needs only the
    measurement channel: a file without a `run` record reads with `run` = {} (the paper's
    geometry, no twin).

    Raises:
      ContractError: one line naming the file and what is missing or malformed.
    """
    run = read_run(path, required=False)
    columns = _read_topic(path, MEASUREMENT_TOPIC, MEASUREMENT_FIELDS)
    return Dataset(**columns, run=run)


def read_truth(path: str | Path) -> GroundTruth:
    """Load the ground-truth channel of a dataset file (not for learners)."""
    columns = _read_topic(path, TRUTH_TOPIC, TRUTH_FIELDS)
    return GroundTruth(**{f.name: columns[f.name] for f in fields(GroundTruth)})
