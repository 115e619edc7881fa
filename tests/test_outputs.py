"""Outputs that cannot be corrupted: one writer per output (a lock), no output over an input, no
folder left behind by a refused step, click's usage errors as one line, run names that stay in
--logs."""

from __future__ import annotations

import json
import multiprocessing
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest
from mcap.reader import make_reader

from common.atomic import OutputError, lock_path, output_lock
from common.jsonio import recorded_path, without_wall_clock
from control.config import OCPConfig
from control.ocp import NominalOCP
from control.ocp_file import FAILED_FORMAT, OCPFileError, read_ocp
from control.solve import failed_path
from crank.chain import STAGES_FILE
from replay.config import ReplayConfig
from tests.checkpoints import constant_checkpoint
from tests.conftest import Written, crank, start_crank
from twin.mcap_dataset import read_run


def _one_line(result: subprocess.CompletedProcess[str], match: str) -> None:
    assert result.returncode == 2, result.stderr
    assert "Traceback" not in result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and match in lines[0], result.stderr


def test_a_live_lock_refuses_and_a_stale_one_is_taken_over(tmp_path: Path) -> None:
    out = tmp_path / "sub" / "r.mcap"
    sleeper = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        out.parent.mkdir()
        lock_path(out).write_text(f"{sleeper.pid}\n")
        held = f"another crank process \\(pid {sleeper.pid}\\)"
        with pytest.raises(OutputError, match=held), output_lock(out):
            pass
    finally:
        sleeper.kill()
        sleeper.wait()
    # The same lock once its process is gone: stale, taken over, and removed afterwards.
    with output_lock(out):
        assert lock_path(out).read_text().strip() != str(sleeper.pid)
    assert not lock_path(out).exists()
    # A folder made only for the lock goes again when the step leaves it empty.
    fresh = tmp_path / "a" / "b" / "x.json"
    with pytest.raises(RuntimeError), output_lock(fresh):
        raise RuntimeError("the step failed")
    assert not (tmp_path / "a").exists()


def test_temporaries_of_a_killed_writer_are_removed_and_a_live_ones_kept(tmp_path: Path) -> None:
    gone = subprocess.run(
        [sys.executable, "-c", "import os; print(os.getpid())"],
        check=True,
        capture_output=True,
        text=True,
    )
    dead = tmp_path / f".x.json.{int(gone.stdout)}.k3j_x.partial"
    live = tmp_path / f".x.png.{os.getpid()}.a1b2.partial"
    recover_me = tmp_path / "replay.mcap.partial"  # a crashed campaign's: kept for `recover`
    for path in (dead, live, recover_me):
        path.write_text("half")
    with output_lock(tmp_path / "x.json"):
        pass
    assert not dead.exists() and live.exists() and recover_me.exists()


def _replay(ocp: Path, out: Path, barrier, results) -> None:
    from replay.files import replay_file

    config = ReplayConfig(runs=3, seed=int(out.stem[-1]) if out.stem[-1].isdigit() else 0)
    barrier.wait()
    try:
        replay_file(ocp, out, config=config, nthread=1)
        results.put("ok")
    except OutputError as exc:
        results.put(f"refused: {exc}")


def test_two_concurrent_replays_to_one_output(tmp_path: Path, ocp_path: Path) -> None:
    """Two replays to the same --out released together: exactly one writes it, the file reads
    back whole, and the other is refused naming the writer."""
    context = multiprocessing.get_context("fork")
    barrier, results = context.Barrier(2), context.Queue()
    out = tmp_path / "r.mcap"
    workers = [
        context.Process(target=_replay, args=(ocp_path, out, barrier, results)) for _ in "ab"
    ]
    for w in workers:
        w.start()
    for w in workers:
        w.join(timeout=240)
    outcomes = sorted(results.get(timeout=5) for _ in workers)
    assert outcomes[0] == "ok", outcomes
    assert outcomes[1].startswith("refused: ") and "another crank process" in outcomes[1]
    with out.open("rb") as f:  # the winner's log is whole: indexed, every run in it
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.statistics.message_count > 0
    assert read_run(out)["episodes_planned"] == 3 * 2 * len(ReplayConfig().modes)
    assert not lock_path(out).exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "r.mcap",
        "r.png",
        "r.rrd",
        "r.stats.json",
    ]


@pytest.mark.parametrize(
    ("command", "existing", "match"),
    [
        # The formats differ, so the suffix check is what refuses these two first.
        (["solve", "--model", "m.pt", "--out", "m.pt"], "m.pt", "must end in .json, got m.pt"),
        (["train", "--data", "d.mcap", "--out", "d.mcap"], "d.mcap", "must end in .pt"),
        (
            ["generate", "--model", "m.mcap", "--out", "./m.mcap"],
            "m.mcap",
            "would overwrite the model_path",
        ),
        (["recover", "b.mcap", "b.mcap"], "b.mcap", "would overwrite the broken"),
        (
            [
                "heldout",
                "--ocp",
                "o.json",
                "--model",
                "m.pt",
                "--variability",
                "paper",
                "--out",
                "o.json",
            ],
            "o.json",
            "would overwrite the ocp_path",
        ),
    ],
)
def test_an_output_over_an_input_is_refused(
    tmp_path: Path, command: list[str], existing: str, match: str
) -> None:
    """The input keeps its bytes, the command says which input it would have destroyed."""
    (tmp_path / existing).write_bytes(b"precious input")
    if "m.pt" in command and existing != "m.pt":
        (tmp_path / "m.pt").write_bytes(b"model")
    before = sorted(p.name for p in tmp_path.iterdir())
    _one_line(crank(*command, cwd=tmp_path), match)
    assert (tmp_path / existing).read_bytes() == b"precious input"
    assert sorted(p.name for p in tmp_path.iterdir()) == before


_LOADED = """
import sys
from crank.cli import main
sys.argv = ["crank", *sys.argv[1:]]
try:
    main()
except SystemExit as exit:
    code = exit.code
heavy = [m for m in ("torch", "casadi", "matplotlib", "rerun") if m in sys.modules]
print(code, ",".join(heavy) or "none")
"""


def _refused_before_loading(command: list[str], *, cwd: Path) -> str:
    """Run `crank COMMAND` in a fresh interpreter; assert exit 2 with torch, CasADi,
    matplotlib and Rerun never imported, and one error line; return that line."""
    result = subprocess.run(
        [sys.executable, "-c", _LOADED, *command],
        capture_output=True,
        text=True,
        cwd=cwd,
        timeout=120,
        check=False,
    )
    assert result.stdout.split() == ["2", "none"], (command, result.stdout, result.stderr)
    (line,) = result.stderr.strip().splitlines()
    assert line.startswith("error: "), line
    return line


@pytest.mark.parametrize(
    "command",
    [
        ["generate", "--out", "d.txt"],
        ["train", "--data", "d.mcap", "--out", "d.mcap"],
        ["solve", "--model", "m.pt", "--out", "m.pt"],
        ["replay", "--ocp", "o.json", "--out", "o.json"],
        ["heldout", "--ocp", "o.json", "--model", "m.pt", "--out", "m.pt"],
        ["recover", "b.mcap", "b.mcap"],
    ],
)
def test_a_bad_output_is_refused_before_the_steps_modules_load(
    tmp_path: Path, command: list[str]
) -> None:
    """The CLI makes the step's output checks (common.atomic.check_output) before it imports
    the step: exit 2 with torch, CasADi, matplotlib and Rerun never loaded (~1 s where the same
    refusal from inside the step took 6-9 s of imports on a 2-core machine)."""
    for name in ("d.mcap", "m.pt", "o.json", "b.mcap"):
        (tmp_path / name).write_bytes(b"input")
    line = _refused_before_loading(command, cwd=tmp_path)
    assert "must end in" in line or "would overwrite" in line


def test_a_run_or_study_that_cannot_start_is_refused_before_the_chain_loads(
    tmp_path: Path, read_only: Path
) -> None:
    """`crank run` into a run folder that exists, `crank run` and `crank study` into a
    read-only place: exit 2 with one line before the chain's modules load (torch, CasADi,
    matplotlib, Rerun: 8 s of imports on a 2-core machine), and nothing written."""
    logs = tmp_path / "logs"
    (logs / "r").mkdir(parents=True)
    cases = [
        (["run", "--logs", str(logs), "--name", "r"], f"run folder already exists: {logs / 'r'}"),
        (["run", "--logs", f"{read_only}/logs", "--name", "r"], "Read-only file system"),
        (["study", "--seeds", "0", "--out", f"{read_only}/s"], "Read-only file system"),
    ]
    for command, match in cases:
        line = _refused_before_loading(command, cwd=tmp_path)
        assert match in line, line
    assert list(logs.iterdir()) == [logs / "r"] and not any((logs / "r").iterdir())
    assert not any(read_only.iterdir())


def _kill_mid_step(
    args: list[str], out: Path, *, after: float, until: Callable[[], bool] | None = None
) -> None:
    """Run `crank ARGS`, SIGKILL it `after` seconds into the step that writes `out` (once its
    output lock exists, and `until` holds), and wait for it."""
    process = start_crank(*args)
    deadline = time.monotonic() + 120

    def ready() -> bool:
        return lock_path(out).exists() and (until is None or until())

    while not ready() and time.monotonic() < deadline:
        assert process.poll() is None, "finished before it could be killed"
        time.sleep(0.1)
    time.sleep(after)
    assert process.poll() is None, "finished before it could be killed"
    process.kill()
    process.wait()


def test_a_killed_train_or_solve_leaves_nothing_that_looks_complete(tmp_path: Path) -> None:
    """SIGKILL mid-training and mid-solve: none of the step's outputs appear (no checkpoint, no
    report, no ocp.json, no figure), and a rerun takes the stale lock over and writes them."""
    data = tmp_path / "d.mcap"
    assert crank("generate", "--seconds", "6", "--out", str(data)).returncode == 0
    model = tmp_path / "m.pt"
    _kill_mid_step(["train", "--data", str(data), "--out", str(model)], model, after=4.0)
    assert not list(tmp_path.glob("m.*")), sorted(p.name for p in tmp_path.iterdir())
    rerun = crank("train", "--data", str(data), "--out", str(model), "--epochs", "2")
    assert rerun.returncode == 0, rerun.stderr
    assert model.is_file() and (tmp_path / "m.report.json").is_file()

    ppann = tmp_path / "c.pt"
    constant_checkpoint(ppann)
    ocp = tmp_path / "ocp.json"
    slow = ["--mc-samples", "50000"]  # ~2 s per Monte-Carlo: killed inside the robust loop
    _kill_mid_step(["solve", "--model", str(ppann), "--out", str(ocp), *slow], ocp, after=2.0)
    assert not list(tmp_path.glob("ocp*")), sorted(p.name for p in tmp_path.iterdir())
    rerun = crank("solve", "--model", str(ppann), "--out", str(ocp))
    assert rerun.returncode == 0, rerun.stderr
    assert read_ocp(ocp).premium("robust") > 0


def test_sigterm_stops_a_step_as_ctrl_c_does(tmp_path: Path) -> None:
    """SIGTERM (kill, a scheduler's stop) mid-training: the command stops as on Ctrl-C, in
    one line and exit status 143, and leaves nothing, not even its lock (SIGKILL's, above, is
    left for the next run to take over)."""
    data = tmp_path / "d.mcap"
    assert crank("generate", "--seconds", "6", "--out", str(data)).returncode == 0
    model = tmp_path / "m.pt"
    process = start_crank("train", "--data", str(data), "--out", str(model))
    deadline = time.monotonic() + 120
    while not lock_path(model).exists():
        assert process.poll() is None and time.monotonic() < deadline, "not training"
        time.sleep(0.1)
    time.sleep(2.0)
    os.kill(process.pid, signal.SIGTERM)
    ended = process.communicate(timeout=60)
    assert ended.returncode == 143, ended.stderr
    assert ended.stderr.splitlines()[-1] == (
        "error: terminated (SIGTERM); no unfinished file was put at a target path"
    )
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "d.coverage.png",
        "d.excitation.png",
        "d.mcap",
    ]


def test_a_killed_run_leaves_a_folder_without_its_report(tmp_path: Path) -> None:
    """SIGKILL mid-chain: the run folder keeps its config and the stages that finished, and says
    it did not finish by lacking report.json; the same command is refused, --resume goes on."""
    run_dir = tmp_path / "r"
    short = tmp_path / "crank.toml"  # tests/test_chain.py SHORT's training: the chain, sooner;
    # no fallback, so that the refusal ends the run with the hint to the tube
    short.write_text(
        "figures = false\ncalibration_runs = 20\n"
        "[train]\nmax_epochs = 3\nsigma_epochs = 20\n[ocp]\nfallback = []\n[plan]\nepisodes = 0\n"
    )
    args = ["run", "--seconds", "12", "--config", str(short), "--logs", str(tmp_path)]
    args += ["--name", "r"]
    stages = run_dir / STAGES_FILE

    def generated() -> bool:  # killed in training, however slow the machine (a fixed 8 s after
        # the run's lock fell inside generation on a machine busy with a sweep, session 45)
        return stages.exists() and "generate" in json.loads(stages.read_text())

    _kill_mid_step(args, run_dir, after=1.0, until=generated)
    assert (run_dir / "config.json").is_file()
    assert not (run_dir / "report.json").exists() and not (run_dir / "report.md").exists()
    again = crank(*args)
    assert again.returncode == 2 and "already exists" in again.stderr
    # --resume continues it: the dataset is kept, and this 12 s model meets the same one-line
    # refusal of the robust OCP as an uninterrupted run (test_cli.py), logged after the first try
    first_log = (run_dir / "run.log").read_text() if (run_dir / "run.log").exists() else ""
    dataset = (run_dir / "dataset.mcap").stat().st_mtime_ns
    resumed = crank("run", "--resume", str(run_dir))
    assert resumed.returncode == 2 and "Traceback" not in resumed.stderr
    assert "generating the dataset: done before, kept" in resumed.stderr
    last = resumed.stderr.strip().splitlines()[-1]
    assert last.startswith("error: the model's tightening")
    assert last.endswith(f"crank run --resume {run_dir} --profiles robust-fb")  # the next step
    assert (run_dir / "dataset.mcap").stat().st_mtime_ns == dataset
    log = (run_dir / "run.log").read_text()
    assert log.startswith(first_log) and "done before, kept" in log


@pytest.mark.parametrize(
    ("command", "match"),
    [
        (["solve", "--seed", "1.5"], "Invalid value for '--seed'"),
        (["replay", "--runs", "many"], "Invalid value for '--runs'"),
        (["generate", "--bogus"], "No such option: --bogus"),
        (["nosuchcommand"], "No such command 'nosuchcommand'"),
        (["run", "--seed"], "Option '--seed' requires an argument"),
    ],
)
def test_usage_errors_are_one_line(tmp_path: Path, command: list[str], match: str) -> None:
    _one_line(crank(*command, cwd=tmp_path), match)
    assert not any(tmp_path.iterdir())


def test_a_killed_generate_leaves_nothing_that_looks_complete(tmp_path: Path) -> None:
    """SIGKILL mid-way: no dataset at the target, only the dead writer's lock and temporaries;
    a rerun takes the stale lock over, removes them and writes the dataset."""
    out = tmp_path / "d.mcap"
    _kill_mid_step(["generate", "--seconds", "300", "--out", str(out)], out, after=3.0)
    assert lock_path(out).exists() and not out.exists()
    assert not list(tmp_path.glob("*.png"))
    result = crank("generate", "--seconds", "1", "--out", str(out))
    assert result.returncode == 0, result.stderr
    assert read_run(out)["seconds"] == 1.0
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "d.coverage.png",
        "d.excitation.png",
        "d.mcap",
    ]


@pytest.mark.parametrize(
    ("command", "match"),
    [
        (["generate", "--seconds", "1", "--out", "o/d.txt"], "must end in .mcap, got o/d.txt"),
        (["train", "--data", "d.mcap", "--out", "o/m.txt"], "must end in .pt, got o/m.txt"),
        (["solve", "--model", "m.pt", "--out", "o/ocp.txt"], "must end in .json, got o/ocp.txt"),
        (["replay", "--ocp", "x.json", "--out", "o/r.json"], "must end in .mcap, got o/r.json"),
        (["heldout", "--out", "o/h.csv"], "must end in .json, got o/h.csv"),
        (["recover", "d.mcap", "o/f.txt"], "must end in .mcap, got o/f.txt"),
    ],
)
def test_an_output_of_the_wrong_format_is_refused(
    tmp_path: Path, command: list[str], match: str
) -> None:
    for name in ("d.mcap", "m.pt", "x.json"):
        (tmp_path / name).write_bytes(b"input")
    _one_line(crank(*command, cwd=tmp_path), match)
    assert not (tmp_path / "o").exists()


def test_recover_refuses_a_file_that_is_not_a_campaign_log(
    tmp_path: Path, paper_dataset: Written
) -> None:
    result = crank("recover", str(paper_dataset.path), str(tmp_path / "f.mcap"))
    _one_line(result, "not a campaign log of crank replay (written by 'crank-twin")
    assert not any(tmp_path.iterdir())


def _tmpfs(tmp_path: Path, options: str):
    """A 200 KB tmpfs mounted with `options` (needs root and mount; skipped otherwise)."""
    mount = tmp_path / "tiny"
    mount.mkdir()
    done = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", f"size=200k,{options}", "tmpfs", str(mount)],
        capture_output=True,
        check=False,
    )
    if done.returncode != 0:
        pytest.skip(f"cannot mount a small tmpfs here: {done.stderr.decode().strip()}")
    try:
        yield mount
    finally:
        subprocess.run(["umount", str(mount)], check=False)


@pytest.fixture
def full_disk(tmp_path: Path):
    yield from _tmpfs(tmp_path, "rw")


@pytest.fixture
def read_only(tmp_path: Path):
    yield from _tmpfs(tmp_path, "ro")


def test_a_read_only_filesystem_is_one_line_for_every_writer(
    tmp_path: Path,
    read_only: Path,
    ocp_path: Path,
) -> None:
    """Every command that writes, pointed at a read-only mount (root's permissions do not stop
    it, as a chmod would not): one line naming the file and the cause, exit 2."""
    model = tmp_path / "m.pt"
    constant_checkpoint(model)
    ro = str(read_only)
    commands = [
        ["generate", "--seconds", "1", "--out", f"{ro}/d.mcap"],
        ["train", "--data", str(tmp_path / "absent.mcap"), "--out", f"{ro}/m.pt"],
        ["solve", "--model", str(model), "--out", f"{ro}/ocp.json"],
        ["replay", "--ocp", str(ocp_path), "--runs", "2", "--out", f"{ro}/r.mcap"],
        ["heldout", "--ocp", str(ocp_path), "--model", str(model), "--out", f"{ro}/h.json"],
        ["run", "--logs", ro, "--name", "r"],
        ["study", "--seeds", "0", "--out", f"{ro}/s"],
    ]
    for command in commands:
        result = crank(*command, cwd=tmp_path)
        _one_line(result, "Read-only file system")
    assert not any(read_only.iterdir())


def test_a_full_disk_is_one_line_and_leaves_no_output(tmp_path: Path, full_disk: Path) -> None:
    """generate (its MCAP does not fit) and solve (ocp.json and one figure fit, the second figure
    does not): one line naming the file, exit 2, and nothing of the step left on the disk."""
    result = crank("generate", "--seconds", "5", "--out", str(full_disk / "d.mcap"))
    _one_line(result, f"cannot write {full_disk / 'd.mcap'}: No space left on device")
    assert not any(full_disk.iterdir())
    model = tmp_path / "m.pt"
    constant_checkpoint(model)
    result = crank("solve", "--model", str(model), "--out", str(full_disk / "ocp.json"))
    assert result.returncode == 2 and "Traceback" not in result.stderr
    last = result.stderr.strip().splitlines()[-1]  # after the robust loop's progress lines
    assert last.startswith("error: cannot write ") and "No space left on device" in last
    assert not any(full_disk.iterdir())


def test_recorded_paths_are_relative_inside_the_artifacts_folder(tmp_path: Path) -> None:
    run = tmp_path / "run"
    assert recorded_path(run / "model.pt", artifact=run / "ocp.json") == "model.pt"
    assert recorded_path(run / "sub" / "d.mcap", artifact=run / "x.json") == "sub/d.mcap"
    outside = tmp_path / "elsewhere" / "model.pt"
    assert recorded_path(outside, artifact=run / "ocp.json") == str(outside)
    assert without_wall_clock(
        {"created": "now", "a": [{"wall_time_s": 1.0, "cost": 2.0}], "timing": {"x_s": 3}}
    ) == {"a": [{"cost": 2.0}]}


def test_a_failed_robust_solve_keeps_the_nominal_plan_and_the_margin_history(
    tmp_path: Path,
) -> None:
    """A line far wider than the stroke, the open loop asked for without a fallback (its tube
    would hold: tests/test_ocp.py): no ocp.json, one error line that names what was kept, and
    <stem>.failed.json with the nominal profile (as ocp.json has it) and every iteration."""
    model = tmp_path / "wide.pt"
    wide = constant_checkpoint(model, z_sigma=(0.3, 0.5, 0.5))
    out = tmp_path / "ocp.json"
    args = ["--out", str(out), "--confidence", "0", "--fallback", "none"]
    result = crank("solve", "--model", str(model), *args)
    assert result.returncode == 2 and "Traceback" not in result.stderr
    last = result.stderr.strip().splitlines()[-1]
    assert last.startswith("error: the model's tightening of the slider at sample ")
    assert last.endswith(f"the nominal plan and the margin history are in {failed_path(out)}")
    assert not out.exists() and not any(tmp_path.glob("ocp.*.png"))
    failed = json.loads(failed_path(out).read_text())
    assert failed["format"] == FAILED_FORMAT and failed["status"] == "failed"
    assert failed["error"] in last and failed["model"]["path"] == "wide.pt"
    nominal = NominalOCP(wide, OCPConfig(confidence=0.0)).solve()
    assert failed["nominal"]["cost"] == nominal.cost
    assert failed["nominal"]["tau"] == nominal.tau.tolist()
    assert len(failed["nominal"]["gain_theta"]) == len(nominal.tau) - 1
    assert len(failed["robust_iterations"]) >= 1
    with pytest.raises(OCPFileError, match="the record of a solve that found no robust torque"):
        read_ocp(failed_path(out))
