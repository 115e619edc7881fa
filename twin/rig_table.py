"""A rig's table as read from its file (`crank import`, twin/rig_import.py): a CSV with a header
row, a Parquet file or a foreign MCAP, the columns an ImportSpec maps as float arrays, and the
error every rig-data refusal raises."""

from __future__ import annotations

import csv
import warnings
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from common.errors import CrankError
from twin.rig_mcap import LOG_TIME, read_mcap_columns

if TYPE_CHECKING:
    from twin.rig_import import ImportSpec


class RigDataError(CrankError, ValueError):
    """Rig data that cannot become a dataset; the message names the row, column or option."""


def read_table(path: Path, spec: ImportSpec) -> dict[str, np.ndarray]:
    """The columns `spec` maps, from a CSV (header row, comma-separated), a Parquet file or a
    foreign MCAP (twin/rig_mcap.py: columns TOPIC.FIELD, `t=log_time`), as float arrays.

    Raises:
      RigDataError: the file is missing or unreadable, a column is absent, a cell not a number.
    """
    wanted = list(dict.fromkeys(spec.columns.values()))
    if not path.is_file():
        raise RigDataError(f"rig data not found: {path}")
    suffix = path.suffix.lower()
    if suffix == ".mcap":
        if spec.columns["t"] != LOG_TIME or spec.units.get("t", "s") != "s":
            raise RigDataError(
                f"{path}: in an MCAP the time is the log time, in s: map t={LOG_TIME}, no unit"
            )
        return read_mcap_columns(
            path, wanted, theta=spec.columns["theta"], tau=spec.columns["tau"], error=RigDataError
        )
    if suffix == ".parquet":
        return _read_parquet(path, wanted)
    if suffix != ".csv":
        raise RigDataError(f"{path}: rig data must be .csv, .parquet or .mcap, got {path.suffix!r}")
    with path.open(newline="") as f:
        header = [h.strip() for h in next(csv.reader(f), [])]
    _check_columns(path, header, wanted)
    index = [header.index(c) for c in wanted]
    try:  # numpy's C parser: twice as fast as the csv module alone
        with warnings.catch_warnings():  # "input contained no data": the row count says so
            warnings.simplefilter("ignore", UserWarning)
            values = np.loadtxt(
                path, delimiter=",", skiprows=1, usecols=index, ndmin=2, comments=None,
                quotechar='"',
            )  # fmt: skip
    except ValueError:  # name the first bad cell
        with path.open(newline="") as f:
            reader = csv.reader(f)
            next(reader)
            for r, row in enumerate(reader):
                if not row:
                    continue  # numpy skips blank lines too
                for column, i in zip(wanted, index, strict=True):
                    if not _number(row, i):
                        cell = row[i] if i < len(row) else ""
                        raise RigDataError(
                            f"{path}: line {r + 2}, column {column!r}: {cell!r} is not a number"
                        ) from None
        raise RigDataError(f"{path}: not a table of numbers under its header") from None
    return {c: values[:, k] for k, c in enumerate(wanted)}


def _number(row: list[str], i: int) -> bool:
    try:
        float(row[i])
    except (ValueError, IndexError):
        return False
    return True


def _read_parquet(path: Path, wanted: list[str]) -> dict[str, np.ndarray]:
    try:
        import pyarrow.parquet as pq
    except ModuleNotFoundError:
        raise RigDataError("Parquet needs pyarrow: pip install pyarrow (or export a CSV)") from None
    try:
        table = pq.read_table(path)
    except Exception as exc:  # pyarrow's errors have no common base
        reason = " ".join(str(exc).split())[:120]
        raise RigDataError(f"{path}: not a Parquet file ({reason})") from None
    _check_columns(path, table.column_names, wanted)
    try:
        return {c: table.column(c).to_numpy(zero_copy_only=False).astype(float) for c in wanted}
    except (TypeError, ValueError) as exc:
        raise RigDataError(f"{path}: a mapped column is not numeric ({exc})") from None


def _check_columns(path: Path, header: list[str], wanted: list[str]) -> None:
    for column in wanted:
        if column not in header:
            raise RigDataError(
                f"{path}: no column {column!r} (columns: {', '.join(header) or 'none'})"
            )
