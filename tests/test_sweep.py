"""`crank sweep`: a 2 x 2 grid on Ray gives the numbers of the same chains run one by one,
trains each model once, survives a killed worker, records a failing step and goes on, and a
killed sweep resumes without redoing finished steps. Short chains (tests/test_chain.py's SHORT)."""

from __future__ import annotations

import contextlib
import json
import os
import re
import shutil
import signal
import threading
import time
import tomllib
from dataclasses import replace
from pathlib import Path

import pytest
import torch

from common.errors import ConfigError
from common.jsonio import without_wall_clock
from common.resources import ResourceError
from crank.chain import Hooks, RunConfig, run_chain
from crank.console import HELDOUT_SEED
from crank.study import run_rows
from crank.sweep import RESULT, execute, leaf_results, run_node, run_sweep
from crank.sweep_estimate import disk_estimate
from crank.sweep_report import failure, markdown, rows_of
from crank.sweep_spec import graph, leaves_of, node_key
from ppann.checkpoint import save
from ppann.model import constant_ppann
from tests.conftest import LATE_MPC, crank, start_crank
from tests.forkserver import Command
from tests.test_chain import SHORT

SPEC = """
[base]
figures = false  # compared with chains that write them: the same numbers
heldout_runs = 20
calibration_runs = 20
heldout_trajectories = 1000
baselines = false
[base.generation]
seconds = 12.0
episode_seconds = 2.0
[base.train]
max_epochs = 3
sigma_epochs = 20
[base.ocp]
k_sigma = 0.5
mc_samples = 200
confidence = 0.0
tightening = "gaussian"  # tests/test_chain.py SHORT: the centred default refuses a 12 s model
tail_check = false  # one leaf's torque puts 60 % of its own Monte-Carlo below (control/tail.py)
[base.replay]
runs = 4
[base.plan]
episodes = 0  # SHORT's one round
"""
GRID = (
    SPEC
    + """
[grid]
seed = [0, 1]
"ocp.constraint_samples" = [[50, 100], [60, 90]]
"""
)
TASKS = [(50, 100), (60, 90)]
CHECKED = [(0, TASKS[0]), (1, TASKS[1])]
"""The leaves run again one by one as chains: each seed and each task once, one of them the
second task solved on a model the sweep shares (the other two leaves are the same code on a
model or a task checked here; running them too cost ~35 s of the suite)."""


def _chain_config(seed: int, samples: tuple[int, int]) -> RunConfig:
    """The chain a leaf of GRID stands for, built without the spec: SHORT at `seed` on the task
    `samples`, checked on the default held-out machines (the spec's base does not set them),
    with the default robust profile alone and no tail check (the spec's)."""
    config = SHORT.with_seed(seed)
    ocp = replace(config.ocp, constraint_samples=samples, profiles=("robust",), tail_check=False)
    return replace(config, ocp=ocp, heldout_seed=HELDOUT_SEED)


def _kill_first_training(out: Path, killed: list[int], stop: threading.Event) -> None:
    """SIGKILL the Ray worker of the first model step seen running (its pid file)."""
    while not stop.is_set():
        for pid_file in (out / "model").glob("*.partial/worker.pid"):
            try:
                pid = int(pid_file.read_text())
            except (OSError, ValueError):
                continue
            time.sleep(1.0)  # mid-training, not at its first line
            os.kill(pid, signal.SIGKILL)
            killed.append(pid)
            return
        time.sleep(0.05)


@pytest.fixture(scope="module")
def swept(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict, list[int], Path]:
    """The 2 x 2 sweep on a local Ray (one training worker killed mid-way), and two of its leaves
    (CHECKED) run one by one as chains in this process with torch on the workers' one thread."""
    root = tmp_path_factory.mktemp("sweep")
    (root / "grid.toml").write_text(GRID)
    out = root / "out"
    killed: list[int] = []
    stop = threading.Event()
    watcher = threading.Thread(target=_kill_first_training, args=(out, killed, stop), daemon=True)
    watcher.start()
    try:
        sweep = run_sweep(root / "grid.toml", out, executor="ray", workers=2)
    finally:
        stop.set()
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        for seed, samples in CHECKED:
            name = f"seed-{seed}-{samples[0]}-{samples[1]}"
            run_chain(_chain_config(seed, samples), root / "chains" / name, argv=[])
    finally:
        torch.set_num_threads(threads)
    return out, sweep, killed, root / "chains"


def test_sweep_equals_its_chains_run_one_by_one(swept) -> None:
    out, sweep, _, chains = swept
    assert len(sweep["rows"]) == 4 and not any(r.get("error") for r in sweep["rows"])
    for leaf in leaves_of(tomllib.loads(GRID), source="grid"):
        chain = _chain_config(leaf.options["seed"], tuple(leaf.options["ocp.constraint_samples"]))
        assert leaf.config == replace(chain, figures=False), leaf.name
    checked = [
        row
        for row in sweep["rows"]
        if (row["seed"], tuple(row["ocp.constraint_samples"])) in CHECKED
    ]
    assert len(checked) == len(CHECKED)
    for row in checked:
        samples = row["ocp.constraint_samples"]
        chain = chains / f"seed-{row['seed']}-{samples[0]}-{samples[1]}"
        (expected,) = run_rows(chain, chain / "ocp.json")
        got = {k: row[k] for k in expected}
        assert {k: v for k, v in got.items() if k != "wall_s"} == {
            k: v for k, v in expected.items() if k != "wall_s"
        }, row["leaf"]
        leaf, solve = out / "leaf" / row["leaf_key"], out / "solve" / row["solve_key"]
        plans = [
            without_wall_clock(json.loads((d / "ocp.json").read_text())) for d in (solve, chain)
        ]
        for key in ("nominal", "robust", "robust_iterations"):
            assert plans[0][key] == plans[1][key], (row["leaf"], key)
        ours, theirs = (json.loads((d / "report.json").read_text()) for d in (leaf, chain))
        checked = [without_wall_clock(r["heldout"]) for r in (ours, theirs)]
        assert checked[0].pop("ocp") == str(solve / "ocp.json")  # the plan it checked, by path
        assert checked[1].pop("ocp") == "ocp.json"
        assert checked[0] == checked[1]
        assert ours["replay"]["table"] == theirs["replay"]["table"]
    # the chains wrote their figures, the sweep's steps none (its base: figures = false)
    for chain in chains.iterdir():
        names = {p.name for p in chain.glob("*.png")}
        assert {"dataset.coverage.png", "model.maps.png", "ocp.robust.png", "replay.png"} <= names
    assert sorted(p.name for p in out.rglob("*.png")) == ["sweep.png"]


def test_a_sweep_over_tasks_trains_each_model_once(swept) -> None:
    out, sweep, _, _ = swept
    models = [d for d in (out / "model").iterdir() if d.is_dir()]
    assert len(models) == 2 and not any(d.name.endswith(".partial") for d in models)
    assert sweep["step_counts"] == {"data": 2, "model": 2, "solve": 4, "leaf": 4}
    for kind, count in (("data", 2), ("solve", 4), ("leaf", 4)):
        finished = [d for d in (out / kind).iterdir() if (d / RESULT).is_file()]
        assert len(finished) == count, kind
    for model in models:  # each model serves both tasks of its seed
        result = json.loads((model / RESULT).read_text())
        assert len(result["leaves"]) == 2 and result["torch_threads"] == 1
    assert (out / "sweep.md").is_file() and (out / "sweep.png").stat().st_size > 10_000
    csv_lines = (out / "sweep.csv").read_text().splitlines()
    assert len(csv_lines) == 5 and "robust_heldout_rate" in csv_lines[0]


def test_a_killed_worker_is_retried_and_the_sweep_completes(swept) -> None:
    out, sweep, killed, _ = swept
    assert len(killed) == 1, "the watcher did not catch a training to kill"
    attempts = {p.stem: p.read_text().count("\n") for p in (out / "model").glob("*.attempts")}
    assert sorted(attempts.values()) == [1, 2]  # the killed step ran again; the other once
    retried = next(key for key, n in attempts.items() if n == 2)
    assert json.loads((out / "model" / retried / RESULT).read_text())["attempts"] == 2
    assert all(not r.get("error") for r in sweep["rows"])


def test_a_failing_step_is_recorded_and_the_sweep_goes_on(tmp_path: Path) -> None:
    """A model folder whose checkpoint is garbage: both solves on it fail with the checkpoint's
    one-line error, the leaves after them are not run, and the sweep returns every result."""
    leaves = leaves_of(
        {"base": {"seed": 0}, "grid": {"ocp.horizon": [150, 140]}} | _spec_tables(),
        source="test",
    )
    nodes = graph(leaves)
    broken = tmp_path / "out"
    model = next(n for n in nodes if n.kind == "model")
    data = next(n for n in nodes if n.kind == "data")
    for node in (data, model):  # made by hand: a dataset (reused) and a bad checkpoint
        (broken / node.kind / node.key).mkdir(parents=True)
        (broken / node.kind / node.key / RESULT).write_text(
            json.dumps({"kind": node.kind, "key": node.key, "summary": {}, "seconds": 0.0})
        )
    (broken / "model" / model.key / "model.pt").write_text("not a checkpoint\n")
    results = execute(nodes, broken, executor="sequential")
    solves = [results[n.id] for n in nodes if n.kind == "solve"]
    bad = f"{broken}/model/{model.key}/model.pt: not a checkpoint, or a damaged one"
    assert [s["error"].startswith(bad) for s in solves] == [True, True]
    assert all("\n" not in s["error"] for s in solves)
    leaf_errors = [results[n.id]["error"] for n in nodes if n.kind == "leaf"]
    assert leaf_errors == ["not run: its solve step failed"] * 2
    rows = rows_of(leaf_results(leaves, broken), broken)
    assert [r["failed_step"] for r in rows] == ["solve", "solve"]
    assert all(
        (broken / "solve" / f"{n.key}.error.json").is_file() for n in nodes if n.kind == "solve"
    )
    found = run_node(model, broken)  # a finished step is found, not redone
    assert found["key"] == model.key and found["found"] is True


def test_a_solve_without_a_robust_torque_is_refused_not_failed(tmp_path: Path) -> None:
    """A model whose open-loop spread exceeds the stroke (test_ocp's wide line, k 3): the solve
    step is recorded as refused with the model's reason, the leaf after it is not run because
    the solve has no robust torque, and the row counts as refused, not failed."""
    base = _spec_tables()["base"]
    base["ocp"] = {"confidence": 0.0, "fallback": []}  # k 3, 1000 mixed trajectories, no tube
    leaves = leaves_of({"base": base, "grid": {"seed": [0]}}, source="test")
    nodes = graph(leaves)
    out = tmp_path / "out"
    for node in (n for n in nodes if n.kind in ("data", "model")):  # made by hand
        (out / node.kind / node.key).mkdir(parents=True)
        (out / node.kind / node.key / RESULT).write_text(
            json.dumps({"kind": node.kind, "key": node.key, "summary": {}, "seconds": 0.0})
        )
    model = next(n for n in nodes if n.kind == "model")
    wide = constant_ppann(z_mean=(0.0, 0.0, -0.9), z_sigma=(0.2, 0.35, 0.35))
    save(out / "model" / model.key / "model.pt", wide, kind="ppann", extra={})
    results = execute(nodes, out, executor="sequential")
    (solve,) = [results[n.id] for n in nodes if n.kind == "solve"]
    assert solve["refused"] is True and "open loop cannot keep this spread" in solve["error"]
    (leaf,) = [results[n.id] for n in nodes if n.kind == "leaf"]
    assert leaf["error"] == "not run: its solve step has no robust torque" and leaf["refused"]
    rows = rows_of(leaf_results(leaves, out), out)
    assert [failure(r) for r in rows] == ["refused"]
    sweep = {"axes": ["seed"], "steps": "", "executor": "sequential", "wall_s": 1.0}
    text = markdown(sweep | {"heldout_seeds": [7]}, rows)
    assert "- seed=0: robust refused: the model's tightening of the slider" in text


def _spec_tables() -> dict:
    return {"base": tomllib.loads(SPEC)["base"] | {"seed": 0}}


def _sweep_until(tmp_path: Path, kind: str) -> tuple[Command, Path]:
    """A one-leaf sweep on Ray, in a session of its own, once its `kind` step has finished: a
    second task would add a solve and a leaf and test nothing more (the steps a leaf shares:
    the fixture's sweep, above)."""
    spec = tmp_path / "task.toml"
    spec.write_text(SPEC + '\n[grid]\n"ocp.constraint_samples" = [[50, 100]]\n')
    out = tmp_path / "out"
    process = start_crank("sweep", str(spec), "--out", str(out), "--workers", "2", new_session=True)
    deadline = time.monotonic() + 300
    while not list((out / kind).glob(f"*/{RESULT}")):
        if process.poll() is not None or time.monotonic() > deadline:
            os.killpg(process.pid, signal.SIGKILL)
            raise AssertionError(f"no {kind} step finished")
        time.sleep(0.1)
    return process, out


def test_a_killed_sweep_resumes_without_redoing_finished_steps(tmp_path: Path) -> None:
    process, out = _sweep_until(tmp_path, "model")
    os.killpg(process.pid, signal.SIGKILL)  # the sweep and its local Ray
    process.wait()
    assert not (out / "sweep.md").exists()
    (model,) = [d for d in (out / "model").iterdir() if (d / RESULT).is_file()]
    made = (model / RESULT).stat().st_mtime_ns
    resumed = crank("sweep", "--resume", str(out), "--executor", "sequential", timeout=600)
    assert resumed.returncode == 0, resumed.stderr
    assert (model / RESULT).stat().st_mtime_ns == made
    for kind in ("data", "model"):
        (attempts,) = (out / kind).glob("*.attempts")
        assert attempts.read_text().count("\n") == 1, f"the {kind} step ran again"
    assert not list(out.glob("*/*.partial"))
    rows = (out / "sweep.csv").read_text().splitlines()
    assert len(rows) == 2 and "wrote" in resumed.stdout
    # its progress line says it was found, not made
    assert re.search(rf"model {model.name} \(.*\): found finished \(made in", resumed.stderr)
    # sweep.md says what the resume found and what it made (1 data, 1 model, 1 solve, 1 leaf)
    report = (out / "sweep.md").read_text()
    found = re.search(r"; (\d+) found finished by a resume, (\d+) made by it", report)
    assert found is not None and int(found[1]) >= 2 and int(found[1]) + int(found[2]) == 4


def test_sigterm_stops_a_sweep_on_ray_as_ctrl_c_does(tmp_path: Path) -> None:
    """SIGTERM to the sweep's process (a scheduler's stop) once its first step is done: Ray is
    shut down and the sweep ends in one line saying how to go on, exit status 143 (Ray's own
    handler, which ray.init installs, aborted the driver with a stack dump: -6)."""
    process, out = _sweep_until(tmp_path, "data")
    try:
        os.kill(process.pid, signal.SIGTERM)
        ended = process.communicate(timeout=120)
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(process.pid, signal.SIGKILL)  # whatever is left of it and its Ray
    assert ended.returncode == 143, ended.stderr
    assert ended.stderr.splitlines()[-1] == (
        "error: terminated (SIGTERM); no unfinished file was put at a target path; "
        f"continue it with: crank sweep --resume {out}"
    )
    assert not (out / "sweep.md").exists()


def test_a_ray_worker_gives_torch_and_the_rollouts_one_thread(monkeypatch) -> None:
    """A sweep's worker holds one CPU: its steps train on one torch thread and step MuJoCo's
    rollouts (data, replays, held-out check, plan round) on one thread (session 24: a data step
    on every core beside two others took 648 s against 80 s)."""
    import crank.sweep as sweep
    from twin.stepping import rollout_threads, set_rollout_threads

    seen = {}
    monkeypatch.setattr(
        sweep,
        "run_node",
        lambda *_: seen.update(torch=torch.get_num_threads(), rollout=rollout_threads()) or {},
    )
    threads = torch.get_num_threads()
    try:
        sweep._pinned_node(None, "out")  # type: ignore[arg-type]
    finally:
        torch.set_num_threads(threads)
        set_rollout_threads(None)
    assert seen == {"torch": 1, "rollout": 1}


def test_a_leafs_replays_run_as_long_as_its_datasets_machines() -> None:
    """A grid over the dataset's operating time replays each leaf on machines of its own
    time; a case that sets the replays' own keeps it."""
    spec = {
        "grid": {"generation.max_start_time": [0.0, 20.0]},
        "cases": [{"name": "follow"}, {"name": "fixed", "replay": {"max_start_time": 60.0}}],
    }
    got = {
        (leaf.config.generation.max_start_time, leaf.options["case"]): (
            leaf.config.replay.max_start_time
        )
        for leaf in leaves_of(spec, source="spec")
    }
    assert got == {
        (0.0, "follow"): 0.0,
        (20.0, "follow"): 20.0,
        (0.0, "fixed"): 60.0,
        (20.0, "fixed"): 60.0,
    }


def test_the_graph_shares_each_step_between_the_leaves_that_agree_on_it() -> None:
    """Seeds x cases: a case changing the task shares the model, one changing the training does
    not, one changing only the replay shares the solve; keys follow what each step reads."""
    spec = tomllib.loads(
        SPEC
        + """
[grid]
seed = [0, 1]
[[cases]]
name = "paper"
[[cases]]
name = "task"
ocp = { height = 0.079 }
[[cases]]
name = "longer training"
train = { max_epochs = 4 }
[[cases]]
name = "more replays"
replay = { runs = 8 }
"""
    )
    leaves = leaves_of(spec, source="spec")
    nodes = graph(leaves)
    counts = {kind: sum(n.kind == kind for n in nodes) for kind in ("data", "model", "solve")}
    assert counts == {"data": 2, "model": 4, "solve": 6}
    assert sum(n.kind == "leaf" for n in nodes) == len(leaves) == 8
    by_name = {leaf.name: leaf for leaf in leaves}
    keys = {
        name: [node_key(kind, leaf.config) for kind in ("data", "model", "solve", "leaf")]
        for name, leaf in by_name.items()
    }
    paper, task = keys["seed=0 case=paper"], keys["seed=0 case=task"]
    longer, replays = keys["seed=0 case=longer training"], keys["seed=0 case=more replays"]
    assert task[:2] == paper[:2] and task[2] != paper[2]
    assert longer[0] == paper[0] and longer[1] != paper[1]
    assert replays[:3] == paper[:3] and replays[3] != paper[3]
    assert keys["seed=1 case=paper"][0] != paper[0]
    order = [n.kind for n in nodes]
    assert order == sorted(order, key=("data", "model", "solve", "leaf").index)
    assert by_name["seed=1 case=task"].config.ocp.height == 0.079
    assert by_name["seed=1 case=task"].config.ocp.mc_seed == 1  # the root seed reaches every stage


def test_the_checks_monte_carlo_size_keys_the_leaf_alone() -> None:
    """`heldout_trajectories` changes what the held-out step computes, nothing upstream; at its
    default it is left out of the key (sweep folders of before it resume as they were)."""
    base = RunConfig.for_seed(0, heldout_runs=1000)
    small = replace(base, heldout_trajectories=1000)
    for kind in ("data", "model", "solve"):
        assert node_key(kind, small) == node_key(kind, base)
    assert node_key("leaf", small) != node_key("leaf", base)


def test_the_reports_calibration_runs_key_the_model_and_figures_no_step() -> None:
    """`calibration_runs` changes the model step's report (and so every step after it), not the
    data; left out at its default. `figures` changes no number: no step's key."""
    base = RunConfig.for_seed(0, heldout_runs=1000)
    fewer = replace(base, calibration_runs=20)
    assert node_key("data", fewer) == node_key("data", base)
    for kind in ("model", "solve", "leaf"):
        assert node_key(kind, fewer) != node_key(kind, base)
        assert node_key(kind, replace(base, figures=False)) == node_key(kind, base)


@pytest.fixture
def tiny_disk(tmp_path: Path):
    from tests.test_outputs import _tmpfs

    yield from _tmpfs(tmp_path, "rw")


def test_a_sweep_that_cannot_fit_on_the_disk_is_refused_before_it_starts(tiny_disk: Path) -> None:
    """The estimate from measured sizes (a 12 s dataset alone is ~0.86 MB, over 200 KB)."""
    spec = tiny_disk.parent / "grid.toml"
    spec.write_text(GRID)
    nodes = graph(leaves_of(tomllib.loads(GRID), source="grid"))
    expected = disk_estimate(nodes)
    assert 5e6 < expected < 20e6  # 2 datasets, 2 models, 4 solves, 4 short campaigns
    with pytest.raises(ResourceError, match=r"needs about 0.0\d+ GB of disk.* GB free"):
        run_sweep(spec, tiny_disk / "out", executor="sequential")
    assert list(tiny_disk.iterdir()) == []


def _untimed(row: dict) -> dict:
    """A compare row without the MPC's step times (wall clock)."""
    mpc = row.get("mpc") and {k: row["mpc"][k] for k in ("steps", "qp_iterations_max")}
    return row | {"mpc": mpc}


def test_compare_takes_a_sweep_folder_as_its_leaves(swept, tmp_path: Path) -> None:
    """`crank compare SWEEP` compares each finished leaf with its solve and model steps' plan and
    PPANN: a leaf compares row for row as the same chain run one by one (CHECKED); the sweep
    folder stands for its four leaves in the sweep's order; an unfinished leaf is left out."""
    from crank.compare import compare_runs, expand_sweeps

    out, sweep, _, chains = swept
    leaves = expand_sweeps([out])
    assert [p.name for p in leaves] == [row["leaf_key"] for row in sweep["rows"]]
    row = next(
        r for r in sweep["rows"] if (r["seed"], tuple(r["ocp.constraint_samples"])) == CHECKED[0]
    )
    chain = chains / "seed-0-50-100"
    said: list[str] = []
    kwargs = {"runs": 2, "heldout_runs": 5, "heldout_seed": 3, "mpc": LATE_MPC}
    ours = compare_runs(
        [out / "leaf" / row["leaf_key"]],
        tmp_path / "leaf",
        hooks=Hooks(on_stage=said.append),
        **kwargs,
    )
    theirs = compare_runs([chain], tmp_path / "chain", **kwargs)
    assert said[0].startswith(f"{row['leaf']}: 2 campaign machines")
    (a,), (b,) = ours["scenarios"], theirs["scenarios"]
    assert a.pop("run") == str(out / "leaf" / row["leaf_key"]) and b.pop("run") == str(chain)
    rows = [[_untimed(r) for r in s.pop("rows")] for s in (a, b)]
    assert a == b and rows[0] == rows[1] and len(rows[0]) == 2 * 4
    unfinished = tmp_path / "sweep"
    shutil.copytree(out, unfinished)
    (unfinished / "leaf" / leaves[0].name / "report.md").unlink()
    assert [p.name for p in expand_sweeps([unfinished])] == [p.name for p in leaves[1:]]
    for p in leaves:
        (unfinished / "leaf" / p.name / "report.md").unlink(missing_ok=True)
    with pytest.raises(ConfigError, match="has no finished leaf"):
        compare_runs([unfinished], tmp_path / "bad", **kwargs)
    assert not (tmp_path / "bad").exists()


def test_compare_takes_a_plan_round_leafs_model_from_its_solve_step(swept, tmp_path: Path) -> None:
    """A leaf that ran the plan round ([plan] episodes > 0) was solved on the model its solve
    step trained (crank/sweep.py), so the compare plays it with that model, not the model step's
    first-round one; a one-round leaf keeps the model step's."""
    from crank.compare import _run_folder

    out, sweep, _, _ = swept
    copy = tmp_path / "sweep"
    shutil.copytree(out, copy)
    first, second = (copy / "leaf" / row["leaf_key"] for row in sweep["rows"][:2])
    steps = {
        leaf["steps"]["leaf"]: leaf["steps"]
        for leaf in json.loads((copy / "sweep.json").read_text())["leaves"]
    }
    config = json.loads((first / "config.json").read_text())
    config["plan"]["episodes"] = 240
    (first / "config.json").write_text(json.dumps(config))
    solve = copy / "solve" / steps[first.name]["solve"]
    shutil.copy(copy / "model" / steps[first.name]["model"] / "model.pt", solve / "model.pt")
    planned, ocp, model, _ = _run_folder(first)
    assert planned.plan.episodes == 240
    assert (ocp, model) == (solve / "ocp.json", solve / "model.pt")
    _, _, model, _ = _run_folder(second)
    assert model == copy / "model" / steps[second.name]["model"] / "model.pt"
