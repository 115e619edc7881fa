"""A `crank sweep` spec: a grid (and a list) of chain options, and the graph of shared steps.

The spec is TOML with three tables, every one optional but not all empty::

    [base]                       # crank.toml keys every leaf starts from (crank config --show)
    heldout_runs = 1000
    [base.generation]
    seconds = 180.0

    [grid]                       # dotted key = the values to try; every combination is a leaf
    seed = [0, 1, 2]
    "generation.variability" = ["paper", "line-15"]

    [[cases]]                    # a list of partial configs, each crossed with the grid
    name = "paper task"
    [[cases]]
    name = "edge"
    ocp = { height = 0.075, constraint_samples = [40, 120] }

Each leaf is a whole `RunConfig` (defaults ← base ← grid point ← case), checked like a crank.toml
before anything starts. Leaves share steps: one dataset per (twin, generation config and seed),
one model per (dataset, training config), one solve per (model, OCP config), one leaf per (solve,
replay and held-out config). Each step is a `Node` keyed by a hash of what it depends on, so a
sweep over tasks trains each model once and a resumed sweep finds what it has made by name.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import os
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from common.errors import ConfigError
from crank.config_file import build, defaults, follow_dataset, merge
from ppann.train_config import CALIBRATION_RUNS
from replay.spread_interval import CALIBRATION_TRAJECTORIES

if TYPE_CHECKING:
    from crank.chain import RunConfig

KINDS = ("data", "model", "solve", "leaf")
"""The steps of a leaf, each depending on the one before."""


def folder(out: Path, kind: str, key: str) -> Path:
    """Where a step of `kind` (KINDS) with `key` keeps its files in the sweep folder `out`."""
    return out / kind / key


MAX_LEAVES = 10_000
SECTIONS = ("base", "grid", "cases")


@dataclass(frozen=True)
class Leaf:
    """One chain of the sweep: its options (axis → value, and the case's name), config, and
    the keys of its steps in KINDS order (`node_key`)."""

    name: str
    options: dict[str, Any]
    config: RunConfig
    steps: tuple[str, ...]


@dataclass(frozen=True)
class Node:
    """One shared step: `kind` in KINDS, `key` the hash of everything it depends on, `config` one
    leaf's config (every leaf sharing the node agrees on what the node uses), `ancestors` the
    keys of the steps before it, in KINDS order."""

    kind: str
    key: str
    config: RunConfig
    ancestors: tuple[str, ...]
    leaves: tuple[str, ...]

    @property
    def id(self) -> str:
        return f"{self.kind}/{self.key}"

    @property
    def ancestor_ids(self) -> tuple[str, ...]:
        return tuple(f"{k}/{key}" for k, key in zip(KINDS, self.ancestors, strict=False))


def read_spec(path: str | Path) -> tuple[str, list[Leaf]]:
    """The spec file's text and its leaves, every one checked.

    Raises:
      ConfigError: unreadable or not TOML, an unknown section or key, an empty grid, a value of
        another type, or out of range (naming the leaf); nothing has started.
    """
    path = Path(path)
    if path.is_dir():  # a sweep folder given where the spec goes
        raise ConfigError(
            f"sweep spec {path} is a folder: give its TOML file, or continue a sweep folder with "
            f"--resume {path}"
        )
    try:
        text = path.read_text(encoding="utf-8")
        spec = tomllib.loads(text)
    except OSError as exc:
        raise ConfigError(f"cannot read sweep spec {path}: {exc.strerror or exc}") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ConfigError(f"sweep spec {path} is not TOML: {exc}") from None
    return text, leaves_of(spec, source=str(path))


def leaves_of(spec: dict[str, Any], *, source: str) -> list[Leaf]:
    """Every leaf of a parsed spec (see the module docstring)."""
    unknown = sorted(set(spec) - set(SECTIONS))
    if unknown:
        raise ConfigError(
            f"{source}: unknown section {unknown[0]!r} (a spec has {', '.join(SECTIONS)})"
        )
    base = spec.get("base", {})
    grid = spec.get("grid", {})
    cases = spec.get("cases", [])
    if not isinstance(base, dict) or not isinstance(grid, dict):
        raise ConfigError(f"{source}: [base] and [grid] must be tables")
    if not isinstance(cases, list) or not all(isinstance(c, dict) for c in cases):
        raise ConfigError(f"{source}: cases must be an array of tables ([[cases]])")
    if not grid and not cases:
        raise ConfigError(f"{source}: empty grid: give [grid] values or [[cases]]")
    for axis, values in grid.items():
        if not isinstance(values, list) or not values:
            raise ConfigError(f"{source}: empty grid: [grid] {axis} must be a non-empty list")
    # one look on the held-out machines unless [base] says: leaves compared on one machine count
    values = merge({**defaults(), "heldout_second_stage": 0}, base, source=f"{source} [base]")
    named = [dict(c) for c in cases] or [{}]
    names = [str(c.pop("name", f"case-{i}")) for i, c in enumerate(named)]
    if len(set(names)) != len(names):
        raise ConfigError(f"{source}: two cases share a name: {names}")
    count = len(named) * _product(len(v) for v in grid.values())
    if count > MAX_LEAVES:
        raise ConfigError(f"{source}: {count} leaves, more than {MAX_LEAVES}")
    leaves: list[Leaf] = []
    seen: dict[str, str] = {}
    for point in itertools.product(*grid.values()):
        at = dict(zip(grid, point, strict=True))
        point_layers = [_nested(axis, value) for axis, value in at.items()]
        with_point = values
        for layer in point_layers:
            with_point = merge(with_point, layer, source=f"{source} [grid]")
        for name, case in zip(names, named, strict=True):
            options = at | ({"case": name} if cases else {})
            label = " ".join(f"{k}={_label(v)}" for k, v in options.items())
            leaf_values = merge(with_point, case, source=f"{source} case {name!r}")
            leaf_values = follow_dataset(leaf_values, base, *point_layers, case)
            config = build(leaf_values, source=f"{source}: leaf {label}")
            steps = tuple(node_key(kind, config) for kind in KINDS)
            if steps[-1] in seen:
                raise ConfigError(
                    f"{source}: leaves {seen[steps[-1]]} and {label} are the same run"
                )
            seen[steps[-1]] = label
            leaves.append(Leaf(name=label, options=options, config=config, steps=steps))
    return leaves


def _product(sizes: Any) -> int:
    out = 1
    for size in sizes:
        out *= size
    return out


def _nested(axis: str, value: Any) -> dict[str, Any]:
    out: Any = value
    for part in reversed(axis.split(".")):
        out = {part: out}
    return out


def _label(value: Any) -> str:
    return json.dumps(value) if isinstance(value, list) else str(value)


def node_key(kind: str, config: RunConfig) -> str:
    """The hash of everything the `kind` step of `config`'s chain depends on (12 hex digits)."""
    values = config.as_dict()
    parts: dict[str, Any] = {"mjcf": mjcf_sha(config.model_path)}
    parts["generation"] = values["generation"]
    if KINDS.index(kind) >= 1:
        train = dict(values["train"])
        if not train["residual_mean"]:  # keys of runs without it stay what they were before it
            del train["residual_mean"]
        parts |= {"train": train, "baselines": values["baselines"]}
        if config.calibration_runs != CALIBRATION_RUNS:  # keys stay as before the setting
            parts["calibration_runs"] = config.calibration_runs
    if KINDS.index(kind) >= 2:
        parts["ocp"] = values["ocp"]
        if config.plan.episodes:  # keys of sweeps without the round stay what they were
            parts["plan"] = values["plan"]
    if KINDS.index(kind) >= 3:
        parts |= {k: values[k] for k in ("replay", "heldout_runs", "heldout_seed")}
        if config.heldout_trajectories != CALIBRATION_TRAJECTORIES:  # keys stay as before it
            parts["heldout_trajectories"] = config.heldout_trajectories
        if config.heldout_second_stage:  # keys stay as before the setting
            parts["heldout_second_stage"] = config.heldout_second_stage
    text = json.dumps(parts, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:12]


_MJCF: dict[tuple[str, int, int], str] = {}
"""The sha256 of each MJCF this process read, by its path, modification time and size: a file
edited since is read again (a resume in the same process, crank/sweep_resume.py)."""


def mjcf_sha(model_path: str) -> str:
    """The sha256 of the MJCF at `model_path`, compiled once to refuse a bad one; kept for the
    process while the file's modification time and size stay."""
    try:
        stat = os.stat(model_path)
        key = (model_path, stat.st_mtime_ns, stat.st_size)
    except OSError:  # load_model names it
        key = (model_path, -1, -1)
    if key not in _MJCF:
        from twin.physics import SliderCrank, load_model, model_sha256

        SliderCrank(load_model(model_path)[0])  # a bad MJCF is refused before anything starts
        _MJCF[key] = model_sha256(model_path)
    return _MJCF[key]


def graph(leaves: list[Leaf]) -> list[Node]:
    """The steps of `leaves`, each once, in an order where a step comes after its ancestors."""
    nodes: dict[str, Node] = {}
    for leaf in leaves:
        keys = leaf.steps
        for depth, kind in enumerate(KINDS):
            node_id = f"{kind}/{keys[depth]}"
            known = nodes.get(node_id)
            names = (known.leaves if known else ()) + (leaf.name,)
            nodes[node_id] = Node(
                kind=kind,
                key=keys[depth],
                config=known.config if known else leaf.config,
                ancestors=tuple(keys[:depth]),
                leaves=names,
            )
    return sorted(nodes.values(), key=lambda n: KINDS.index(n.kind))
