"""The suite's files go to the workers longest first (tests/order.py): the record names files that
exist, the order is the record's, the JUnit times are summed per file exactly, a bad record is
refused."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import pytest

from tests.order import FORMAT, RECORD, junit_seconds, longest_first, read_record, write_record


@dataclass(frozen=True)
class FakeItem:
    path: Path
    name: str


def test_the_record_names_test_files_that_exist() -> None:
    seconds = read_record()
    assert len(seconds) >= 20  # a record of the whole suite
    for name in seconds:
        assert (RECORD.parent / name).is_file(), f"{name} in {RECORD.name} is not a test file"


def test_files_are_ordered_longest_first_and_keep_their_tests_order() -> None:
    seconds = {"test_b.py": 30.0, "test_c.py": 90.0, "test_d.py": 0.5}
    items = [
        FakeItem(Path("tests/test_a.py"), "a1"),  # not recorded: after the recorded files
        FakeItem(Path("tests/test_b.py"), "b1"),
        FakeItem(Path("tests/test_b.py"), "b2"),
        FakeItem(Path("tests/test_c.py"), "c1"),
        FakeItem(Path("tests/test_e.py"), "e1"),  # not recorded either: keeps its place after a
        FakeItem(Path("tests/test_c.py"), "c2"),
        FakeItem(Path("tests/test_d.py"), "d1"),
    ]
    longest_first(items, seconds)
    assert [i.name for i in items] == ["c1", "c2", "b1", "b2", "d1", "a1", "e1"]


def test_this_session_collected_the_files_in_the_records_order(
    request: pytest.FixtureRequest,
) -> None:
    """The conftest hook ran: in this process's collection (each xdist worker collects the whole
    suite, and the scheduler hands files out in that order) no file comes before a longer one."""
    # (--ff and --nf are the cache plugin's: without it, `-p no:cacheprovider`, neither exists)
    reordered = ("failedfirst", "newfirst")
    if any(request.config.getoption(name, default=False) for name in reordered):
        pytest.skip("--ff/--nf put their tests first, after the order")
    seconds = read_record()
    files: list[str] = []
    for item in request.session.items:
        if item.path.name not in files:
            files.append(item.path.name)
    assert "test_order.py" in files
    recorded = [seconds.get(name, -1.0) for name in files]
    assert recorded == sorted(recorded, reverse=True), files


def test_junit_times_are_summed_per_file(tmp_path: Path) -> None:
    xml = tmp_path / "junit.xml"
    xml.write_text(
        """<?xml version="1.0" encoding="utf-8"?>
<testsuites><testsuite name="pytest" tests="4">
<testcase classname="tests.test_sweep" name="test_one" time="164.125" />
<testcase classname="tests.test_sweep" name="test_two[a-b]" time="0.500" />
<testcase classname="tests.test_ocp.TestRefusals" name="test_three" time="2.25">
<skipped message="x" /></testcase>
<testcase classname="tests.test_ocp" name="test_four" time="1.0" />
</testsuite></testsuites>"""
    )
    assert junit_seconds(xml) == {"test_sweep.py": 164.625, "test_ocp.py": 3.25}


def test_a_written_record_reads_back_longest_first(tmp_path: Path) -> None:
    path = tmp_path / "file_seconds.json"
    write_record(
        {"test_a.py": 1.04, "test_b.py": 20.26}, reference_us=7.123, wall_s=650.4, path=path
    )
    assert read_record(path) == {"test_a.py": 1.0, "test_b.py": 20.3}
    record = json.loads(path.read_text())
    assert list(record["seconds"]) == ["test_b.py", "test_a.py"]
    assert record["wall_s"] == 650 and record["reference_us"] == 7.12
    assert [p.name for p in tmp_path.iterdir()] == ["file_seconds.json"]  # no temporary left
    assert read_record(tmp_path / "absent.json") == {}


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ({"format": "other", "seconds": {}}, "not a crank-file-seconds record"),
        ({"format": FORMAT, "seconds": [1, 2]}, "must be a table"),
        ({"format": FORMAT, "seconds": {"test_a.py": -1}}, "not a finite number >= 0"),
        ({"format": FORMAT, "seconds": {"test_a.py": "9"}}, "not a finite number >= 0"),
        ({"format": FORMAT, "seconds": {"test_a.py": math.nan}}, "not a finite number >= 0"),
    ],
)
def test_a_bad_record_is_refused(tmp_path: Path, content: dict, message: str) -> None:
    path = tmp_path / "file_seconds.json"
    path.write_text(json.dumps(content))
    with pytest.raises(ValueError, match=message):
        read_record(path)
