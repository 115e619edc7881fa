"""The order in which the suite's files go to the workers: the longest first.

pytest-xdist's `--dist loadfile` runs each test file on one worker and hands the files out in the
collection's order (`--no-loadscope-reorder`, pyproject.toml); by default it orders them by their
number of tests, so a file of 3 tests and 60-98 s (one 40-epoch training) started last and the
other worker waited for it (3-57 s of a 10-15 minute suite in session 67's runs). Here the files
are ordered by the seconds they took in a recorded run (`tests/file_seconds.json`, written by
`python bench/suite_time.py --record` from pytest's JUnit XML): the longest first, so the last
files to start are the short ones and both workers end together. A file the record does not name
(a new one) goes after the recorded ones, in collection order; the order changes no test's
outcome.
"""

from __future__ import annotations

import json
import math
import xml.etree.ElementTree as ElementTree
from collections import defaultdict
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from common.atomic import atomic_path

RECORD = Path(__file__).with_name("file_seconds.json")
FORMAT = "crank-file-seconds"


def read_record(path: Path = RECORD) -> dict[str, float]:
    """Seconds per test file name of the recorded run ({} if there is no record).

    Raises:
      ValueError: the file is not such a record, or a time is not a finite number >= 0.
    """
    if not path.is_file():
        return {}
    record = json.loads(path.read_text())
    if not isinstance(record, dict) or record.get("format") != FORMAT:
        raise ValueError(f"{path}: not a {FORMAT} record")
    seconds = record.get("seconds")
    if not isinstance(seconds, dict):
        raise ValueError(f"{path}: 'seconds' must be a table of file name to seconds")
    for name, value in seconds.items():
        if not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0:
            raise ValueError(f"{path}: {name} took {value!r} s, not a finite number >= 0")
    return {name: float(value) for name, value in seconds.items()}


def longest_first(items: list[Any], seconds: Mapping[str, float]) -> None:
    """Sort `items` (pytest's, or anything with a `path`) in place by their file's recorded
    seconds, longest first; the tests of a file keep their order, and unrecorded files keep
    theirs after the recorded ones."""
    items.sort(key=lambda item: -seconds.get(item.path.name, -1.0))


def junit_seconds(xml_path: Path) -> dict[str, float]:
    """Seconds per test file name in a pytest JUnit XML report: each test case's time summed
    (setup, call and teardown: a module fixture counts in the first test that asks for it)."""
    totals: dict[str, float] = defaultdict(float)
    for case in ElementTree.parse(xml_path).getroot().iter("testcase"):
        module = case.get("classname", "").split(".")
        # classname is "tests.test_x" for a function, "tests.test_x.TestClass" for a method
        name = next((part for part in module if part.startswith("test_")), None)
        if name is None:
            raise ValueError(f"{xml_path}: a test case of classname {case.get('classname')!r}")
        totals[f"{name}.py"] += float(case.get("time", "0"))
    return dict(totals)


def write_record(
    seconds: Mapping[str, float], *, reference_us: float, wall_s: float, path: Path = RECORD
) -> None:
    """Write the record (longest file first), with the run's wall time and reference."""
    ordered = dict(sorted(((k, round(v, 1)) for k, v in seconds.items()), key=lambda kv: -kv[1]))
    record = {
        "format": FORMAT,
        "written_by": "python bench/suite_time.py --record",
        "wall_s": round(wall_s),
        "reference_us": round(reference_us, 2),
        "seconds": ordered,
    }
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(record, indent=1) + "\n")
