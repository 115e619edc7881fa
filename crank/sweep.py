"""`crank sweep`: the leaves of a spec (crank/sweep_spec.py) run as a graph of shared steps, on
Ray (local by default, a cluster with `address`) or one after another in this process.

Every step writes into `<out>/<kind>/<key>.partial/` and renames it to `<out>/<kind>/<key>/` once
its result.json is written, so a step folder without `.partial` is complete and a resumed sweep
(or a retried task) keeps it. A step that raises is recorded in `<out>/<kind>/<key>.error.json`
with its one-line error (its files moved to `<key>.failed/`), the steps after it are not run, and
the sweep goes on; a resumed sweep tries failed steps again. Each start of a step appends a line
to `<out>/<kind>/<key>.attempts`.
On Ray each step is a task of 1 CPU with torch pinned to 1 thread; a task whose worker dies is
retried (MAX_RETRIES). On a cluster, `out` must be on a filesystem every node shares.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
import signal
import socket
import time
import traceback
from collections.abc import Callable
from pathlib import Path
from typing import Any

from common.atomic import atomic_path
from common.checks import check_choice
from common.errors import ConfigError, CrankError, NoSolutionError
from common.jsonio import write_json
from crank import stages
from crank.chain import Hooks, RunConfig
from crank.estimate import run_time
from crank.sweep_estimate import disk_estimate, time_estimate
from crank.sweep_spec import KINDS, Leaf, Node, folder, graph

RESULT = "result.json"
SPEC_COPY = "sweep.toml"
MAX_RETRIES = 3
EXECUTORS = ("ray", "sequential")
COMMAND = "crank sweep"


def check_executor(executor: str) -> None:
    """Refuse an executor that is not one of EXECUTORS (ConfigError)."""
    check_choice("executor", executor, EXECUTORS)


def run_node(node: Node, out: str | Path, *ancestors: dict[str, Any]) -> dict[str, Any]:
    """Make `node`'s folder (or find it made) and return its result; never raises for a step
    that fails, it returns {"error": ...}. `ancestors` are the results of the steps before it."""
    out = Path(out)
    final = folder(out, node.kind, node.key)
    if (final / RESULT).is_file():  # made by an earlier invocation (a resume): found
        return json.loads((final / RESULT).read_text()) | {"found": True}
    lost = next((a for a in ancestors if a.get("error")), None)
    if lost is not None:
        why = "has no robust torque" if lost.get("refused") else "failed"
        error = f"not run: its {lost['kind']} step {why}"
        record = {"kind": node.kind, "key": node.key, "error": error, "upstream": True}
        return record | ({"refused": True} if lost.get("refused") else {})
    final.parent.mkdir(parents=True, exist_ok=True)
    with (out / node.kind / f"{node.key}.attempts").open("a") as log:
        log.write(f"{time.time():.3f} {socket.gethostname()} {os.getpid()}\n")
    partial = final.with_name(node.key + ".partial")
    failed = final.with_name(node.key + ".failed")
    for earlier in (partial, failed):  # a killed attempt's files, a failed one's
        shutil.rmtree(earlier, ignore_errors=True)
    partial.mkdir(parents=True)
    (partial / "worker.pid").write_text(f"{os.getpid()}\n")
    (out / node.kind / f"{node.key}.error.json").unlink(missing_ok=True)
    started = time.perf_counter()
    try:
        summary = _work(node, out, partial, ancestors)
    except Exception as exc:  # recorded, and the sweep goes on
        error = str(exc) if isinstance(exc, CrankError) else repr(exc)
        error = error.splitlines()[0].replace(str(partial), str(failed))  # its files are kept
        record = {"kind": node.kind, "key": node.key, "error": error}
        if isinstance(exc, NoSolutionError):  # the model's answer, not a fault: refused
            record["refused"] = True
        if not isinstance(exc, CrankError):
            record["traceback"] = traceback.format_exc()
        (partial / "worker.pid").unlink()
        os.replace(partial, failed)
        write_json(out / node.kind / f"{node.key}.error.json", record, indent=2)
        return record
    attempts = (out / node.kind / f"{node.key}.attempts").read_text().count("\n")
    result = {
        "kind": node.kind,
        "key": node.key,
        "summary": summary,
        "seconds": time.perf_counter() - started,
        "attempts": attempts,
        "host": socket.gethostname(),
        "torch_threads": _torch_threads(),
        "leaves": list(node.leaves),
    }
    write_json(partial / "config.json", node.config.resolved(command=COMMAND, argv=[]), indent=2)
    write_json(partial / RESULT, result, indent=2)
    (partial / "worker.pid").unlink()
    os.replace(partial, final)
    return result


def _work(node: Node, out: Path, here: Path, ancestors: tuple[dict, ...]) -> dict[str, Any]:
    config, hooks = node.config, Hooks()
    keys = dict(zip(KINDS, node.ancestors, strict=False))
    made = {kind: folder(out, kind, key) for kind, key in keys.items()}
    if node.kind == "data":
        return stages.generate(config, here, hooks=hooks)
    if node.kind == "model":
        return stages.train(config, made["data"] / stages.DATASET, here, hooks=hooks)
    if node.kind == "solve":
        if config.plan.episodes:
            return _solve_with_plan(config, made, here, hooks=hooks)
        return stages.solve(config, made["model"] / stages.MODEL, here, hooks=hooks)
    data, trained, solved = (a["summary"] for a in ancestors)
    solved = dict(solved)  # a solve's result may be shared by several leaves: not changed
    plan_round = solved.pop("plan_round", None)
    ocp, model = made["solve"] / stages.OCP, made["model"] / stages.MODEL
    if plan_round is not None:  # the solve step trained the model its torque is of
        model, trained = made["solve"] / stages.MODEL, plan_round["trained"]
    resolved = config.resolved(command=COMMAND, argv=[])
    seconds = {
        k: a["seconds"] for k, a in zip(("generate", "train", "solve"), ancestors, strict=True)
    }
    t0 = time.perf_counter()
    stats = stages.replay(config, ocp, here, resolved=resolved, hooks=hooks, nthread=1)
    seconds["replay"] = time.perf_counter() - t0
    checked = None
    if config.heldout_runs:
        t0 = time.perf_counter()
        checked = stages.heldout(config, ocp, model, here, hooks=hooks)
        seconds["heldout"] = time.perf_counter() - t0
    seconds["total"] = sum(seconds.values())  # of this leaf's steps, some shared with others
    report = stages.write_report(
        here,
        resolved=resolved,
        dataset=data,
        trained=trained,
        solved=solved,
        stats=stats,
        checked=checked,
        plan_round=plan_round,
        seconds=seconds,
        estimated={name: span.as_list() for name, span in run_time(config).items()},
    )
    return {"report": "report.json", "claim": report["replay"]["claim"]}


def _solve_with_plan(
    config: RunConfig, made: dict[str, Path], here: Path, *, hooks: Hooks
) -> dict[str, Any]:
    """A solve step with the plan round (crank/chain.py): the model step's model solved into
    `here`/round-0/, its torque played on fresh machines (plan.mcap), a model trained on those
    episodes and the dataset, and solved; its summary carries the round's under "plan_round"."""
    first = here / stages.FIRST_ROUND
    solved = stages.solve_first_round(config, made["model"] / stages.MODEL, first, hooks=hooks)
    planned = stages.plan(config, made["data"] / stages.DATASET, first / stages.OCP, here)
    trained = stages.train_again(config, here / stages.PLAN_DATASET, here, hooks=hooks)
    final = stages.solve(config, here / stages.MODEL, here, hooks=hooks)
    return final | {"plan_round": {"first_solve": solved, "plan": planned, "trained": trained}}


def _torch_threads() -> int | None:
    import sys

    torch = sys.modules.get("torch")
    return torch.get_num_threads() if torch is not None else None


def _pinned_node(node: Node, out: str, *ancestors: dict[str, Any]) -> dict[str, Any]:
    """run_node in a Ray worker: 1 CPU, so torch and MuJoCo's rollouts get 1 thread each (several
    workers share the machine's cores; oversubscribed, training ran ~3x slower, a data step 8x)."""
    import torch

    from twin.stepping import set_rollout_threads

    torch.set_num_threads(1)
    set_rollout_threads(1)
    return run_node(node, out, *ancestors)


Progress = Callable[[Node, dict[str, Any], int, int], None]
"""Called after each step with the node, its result, the steps done and the steps in all."""


def execute(
    nodes: list[Node],
    out: Path,
    *,
    executor: str = "ray",
    address: str | None = None,
    workers: int | None = None,
    on_done: Progress | None = None,
) -> dict[str, dict[str, Any]]:
    """Run `nodes` (ancestors first, as `graph` orders them) and return each node's result."""
    check_executor(executor)
    report = on_done or (lambda *_: None)
    results: dict[str, dict[str, Any]] = {}
    if executor == "sequential":
        for node in nodes:
            ancestors = [results[a] for a in node.ancestor_ids]
            results[node.id] = run_node(node, out, *ancestors)
            report(node, results[node.id], len(results), len(nodes))
        return results
    ray = _ray()
    started_here = not ray.is_initialized()
    if started_here:
        _init_ray(ray, address=address, workers=workers)
    try:
        task = ray.remote(num_cpus=1, max_retries=MAX_RETRIES, retry_exceptions=False)(_pinned_node)
        refs: dict[str, Any] = {}
        for node in nodes:
            parents = [refs[a] for a in node.ancestor_ids]
            refs[node.id] = task.remote(node, str(out), *parents)
        by_ref = {ref: nodes_id for nodes_id, ref in refs.items()}
        named = {node.id: node for node in nodes}
        pending = list(refs.values())
        while pending:
            ready, pending = ray.wait(pending, num_returns=1)
            node = named[by_ref[ready[0]]]
            try:
                results[node.id] = ray.get(ready[0])
            except ray.exceptions.RayError as exc:  # retries used up, or an ancestor's were
                results[node.id] = {"kind": node.kind, "key": node.key, "error": _last_line(exc)}
            report(node, results[node.id], len(results), len(nodes))
    finally:
        if started_here:
            ray.shutdown()
    return results


def _last_line(exc: BaseException) -> str:
    """Ray's error text ends with the cause (a worker that died, the exception raised)."""
    lines = [line.strip() for line in str(exc).splitlines() if line.strip()]
    return lines[-1] if lines else repr(exc)


def _ray() -> Any:
    try:
        import ray
    except ImportError:
        raise ConfigError(
            "crank sweep runs on Ray: pip install 'crank-twin[sweep]' "
            "(or --executor sequential to run the steps one after another)"
        ) from None
    return ray


def _init_ray(ray: Any, *, address: str | None, workers: int | None) -> None:
    """A local Ray instance on this machine's cores (or `workers`), or the cluster at `address`;
    workers start with 1 thread for OpenMP and MKL."""
    env = {"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    options: dict[str, Any] = {
        "runtime_env": {"env_vars": env},
        "include_dashboard": False,
        "log_to_driver": False,
        "logging_level": logging.ERROR,
    }
    ours = signal.getsignal(signal.SIGTERM)  # crank's: stops as Ctrl-C (Ray's aborts: exit -6)
    local = {} if address else {"num_cpus": workers or os.cpu_count() or 1}
    ray.init(address=address, **local, **options)  # address None: a local instance
    if callable(ours):
        signal.signal(signal.SIGTERM, ours)


def leaf_results(leaves: list[Leaf], out: Path) -> list[tuple[Leaf, list[dict[str, Any]]]]:
    """Each leaf with its steps' records read back from the sweep folder (result.json or
    .error.json; a step never reached is {"error": "not run"})."""
    out_rows = []
    for leaf in leaves:
        records = []
        for kind, key in zip(KINDS, leaf.steps, strict=True):
            done, failed = folder(out, kind, key) / RESULT, out / kind / f"{key}.error.json"
            if done.is_file():
                records.append(json.loads(done.read_text()))
            elif failed.is_file():
                records.append(json.loads(failed.read_text()))
            else:
                records.append({"kind": kind, "key": key, "error": "not run"})
        out_rows.append((leaf, records))
    return out_rows


def steps_left(nodes: list[Node], out: Path) -> list[Node]:
    """The steps of `nodes` that have no result in the sweep folder `out` yet."""
    return [n for n in nodes if not (folder(out, n.kind, n.key) / RESULT).is_file()]


def check_disk(todo: list[Node], out: Path) -> float:
    """Refuse a sweep whose files (of the steps `todo`, not made yet) cannot fit on `out`'s
    filesystem; return the estimate.

    Raises:
      ResourceError: the estimate exceeds the free space, both in the message.
    """
    from common.resources import ResourceError

    needed = disk_estimate(todo)
    existing = next(p for p in (out, *out.parents) if p.exists())
    free = shutil.disk_usage(existing).free
    if needed > free:
        raise ResourceError(
            f"the sweep needs about {needed / 1e9:.3g} GB of disk for its files, "
            f"{existing} has {free / 1e9:.3g} GB free"
        )
    return needed


def run_sweep(
    spec: str | Path | None,
    out: str | Path,
    *,
    executor: str = "ray",
    address: str | None = None,
    workers: int | None = None,
    resume: bool = False,
    on_start: Callable[[dict[str, Any]], None] | None = None,
    on_done: Progress | None = None,
) -> dict[str, Any]:
    """Run the sweep of the spec file `spec` into `out` (which must not exist), or with `resume`
    continue the sweep in `out` from its own copy of the spec (`spec` must then be None); write
    sweep.json, sweep.csv, sweep.md and sweep.png; return sweep.json's content with the rows.

    Raises:
      ConfigError: a bad spec, an unknown executor, or a resume whose finished steps its spec
        keys no more (crank/sweep_resume.py); nothing has started.
      OutputError: `out` exists (without resume), or is not a sweep folder (with resume).
    """
    from common.atomic import OutputError, check_writable
    from crank.sweep_report import write_results
    from crank.sweep_spec import read_spec
    from twin.physics import MJCFNotFoundError

    out = Path(out).absolute()  # Ray's workers run in folders of their own
    check_executor(executor)
    if resume:
        if spec is not None:
            raise ConfigError("a resumed sweep runs its folder's own sweep.toml; give no spec")
        spec = out / SPEC_COPY
        if not spec.is_file():
            raise OutputError(f"nothing to resume: {out} is not a sweep folder (no {SPEC_COPY})")
    elif spec is None:
        raise ConfigError("give the sweep's spec file (or --resume a sweep folder)")
    elif out.exists():
        raise OutputError(f"sweep folder already exists: {out} (use --resume to continue it)")
    try:
        text, leaves = read_spec(spec)
    except MJCFNotFoundError as error:  # moved with its folder: its steps know the twin's bytes
        hint = f", named in {spec}: point `model` there at a copy of it (its bytes key the steps)"
        raise MJCFNotFoundError(f"{error}{hint if resume else ''}") from None
    if resume:
        from crank.sweep_resume import check_resumable

        check_resumable(out, leaves)
    nodes = graph(leaves)
    if executor == "ray":
        _ray()  # the extra is installed, before anything is written
    todo = steps_left(nodes, out)
    disk = check_disk(todo, out)
    if not resume:
        check_writable(out / SPEC_COPY)
        with atomic_path(out / SPEC_COPY) as tmp:
            tmp.write_text(text)
    counts = {kind: sum(n.kind == kind for n in nodes) for kind in KINDS}
    sweep: dict[str, Any] = {
        "format": "crank-sweep",
        "version": 1,
        "spec": SPEC_COPY,
        "executor": executor,
        "address": address,
        "axes": list(leaves[0].options),
        "steps": ", ".join(f"{n} {kind}" for kind, n in counts.items()),
        "step_counts": counts,
        "disk_estimate_bytes": disk,
        "serial_seconds_estimate": time_estimate(todo).as_list(),
        "steps_run": len(todo),  # this invocation's; the others were found finished (resume)
        "heldout_seeds": sorted({leaf.config.heldout_seed for leaf in leaves}),
        "leaves": [
            {
                "name": leaf.name,
                "options": leaf.options,
                "steps": dict(zip(KINDS, leaf.steps, strict=True)),
                "config": leaf.config.as_dict(),
            }
            for leaf in leaves
        ],
    }
    write_json(out / "sweep.json", sweep, indent=2)
    if on_start:
        on_start(sweep)
    started = time.perf_counter()
    execute(nodes, out, executor=executor, address=address, workers=workers, on_done=on_done)
    sweep["wall_s"] = time.perf_counter() - started
    rows = write_results(out, sweep, leaf_results(leaves, out))
    write_json(out / "sweep.json", sweep, indent=2)
    return sweep | {"rows": rows}
