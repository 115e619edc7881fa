"""A foreign MCAP (a rig's recording: JSON channels, or ROS 2 with the `[ros2]` extra) as the
columns of a rig table (twin/rig_import.py).

Columns are named `TOPIC.FIELD` (`/motor/state.position`, `/joint_states.position[0]`,
`/slider.pose.position.z`); `log_time` is the log time of the theta column's messages, in s, and
is the table's time base: every other column is resampled onto it from its own messages' log
times, linearly, except the torque, which a command holds until the next (zero-order hold).
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np
import orjson

from twin.mcap_dataset import open_reader

LOG_TIME = "log_time"
_COLUMN = re.compile(r"^(/[^.]*)\.(.+)$")
_STEP = re.compile(r"([A-Za-z_]\w*)|\[(\d+)\]")


def split_column(column: str) -> tuple[str, list[str | int]]:
    """`/topic.a.b[2]` -> ("/topic", ["a", "b", 2]).

    Raises:
      ValueError: not TOPIC.FIELD.
    """
    match = _COLUMN.match(column)
    if not match:
        raise ValueError(f"{column!r} is not TOPIC.FIELD (e.g. /motor.position)")
    topic, path = match.groups()
    steps: list[str | int] = []
    for part in path.split("."):
        tokens = _STEP.findall(part)
        if not tokens or "".join(n or f"[{i}]" for n, i in tokens) != part:
            raise ValueError(f"{column!r}: {part!r} is not a field name")
        steps += [name if name else int(index) for name, index in tokens]
    return topic, steps


def _field(message: Any, steps: list[str | int]) -> float:
    value = message
    for step in steps:
        if isinstance(step, int) or isinstance(value, dict):
            value = value[step]
        else:
            value = getattr(value, step)
    return float(value)


def read_mcap_columns(
    path: Path, columns: list[str], *, theta: str, tau: str, error: type[Exception]
) -> dict[str, np.ndarray]:
    """The `columns` of a foreign MCAP on the time base of the `theta` column (module docstring).

    Raises:
      ContractError: not an MCAP, or one cut short.
      error: a topic or field that is not there, an encoding that cannot be read, a value that
        is not a number.
    """
    from mcap.exceptions import McapError

    with path.open("rb") as f:
        reader, summary = open_reader(f, path)  # ContractError if not a whole MCAP
        factories = _decoders()
        channels = {c.topic: c for c in summary.channels.values()}
        wanted: dict[str, list[tuple[str, list[str | int]]]] = {}
        for column in columns:
            if column == LOG_TIME:
                continue
            try:
                topic, steps = split_column(column)
            except ValueError as exc:
                raise error(f"--map: {exc}") from None
            if topic not in channels:
                raise error(f"{path}: no topic {topic} (topics: {', '.join(sorted(channels))})")
            _check_encoding(path, channels[topic].message_encoding, factories, error)
            wanted.setdefault(topic, []).append((column, steps))
        series: dict[str, tuple[list[float], list[float]]] = {c: ([], []) for c in columns}
        decoders: dict[int, Any] = {}
        try:
            for schema, channel, message in reader.iter_messages(
                topics=list(wanted), log_time_order=True
            ):
                t = message.log_time * 1e-9
                if channel.message_encoding == "json":
                    body = orjson.loads(message.data)
                else:
                    if channel.id not in decoders:
                        decoders[channel.id] = factories[0].decoder_for(
                            channel.message_encoding, schema
                        )
                    body = decoders[channel.id](message.data)
                for column, steps in wanted[channel.topic]:
                    try:
                        value = _field(body, steps)
                    except (KeyError, IndexError, AttributeError, TypeError):
                        raise error(
                            f"{path}: no field {column!r} in a message on {channel.topic}"
                        ) from None
                    except ValueError:
                        raise error(f"{path}: {column!r} is not a number") from None
                    series[column][0].append(t)
                    series[column][1].append(value)
        except error:  # a missing field or a word, named above (error is a ValueError too)
            raise
        except (McapError, ValueError, EOFError) as exc:  # orjson's errors are ValueErrors
            raise error(f"{path}: corrupt MCAP data ({' '.join(str(exc).split())[:120]})") from None
    base = np.array(series[theta][0])
    if base.size == 0:
        raise error(f"{path}: no messages on the theta column's topic ({theta})")
    out = {LOG_TIME: base}
    for column in columns:
        if column == LOG_TIME:
            continue
        t, v = np.array(series[column][0]), np.array(series[column][1])
        if column == theta:
            out[column] = v
        elif column == tau:  # a command holds until the next one
            index = np.clip(np.searchsorted(t, base, side="right") - 1, 0, len(t) - 1)
            out[column] = v[index]
        else:
            out[column] = np.interp(base, t, v)
    return out


def _decoders() -> list[Any]:
    try:
        from mcap_ros2.decoder import DecoderFactory
    except ModuleNotFoundError:
        return []
    return [DecoderFactory()]


def _check_encoding(path: Path, encoding: str, factories: list, error: type[Exception]) -> None:
    if encoding == "json":
        return
    if encoding == "cdr" and factories:
        return
    if encoding == "cdr":
        raise error(
            f"{path}: ROS 2 (cdr) messages need the decoder: pip install 'crank-twin[ros2]'"
        )
    raise error(f"{path}: messages encoded as {encoding!r} cannot be read (json or ROS 2 cdr)")
