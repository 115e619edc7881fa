"""A resumed sweep goes on from the steps it made, or says why it cannot.

A sweep's steps are keyed by everything they depend on (crank/sweep_spec.py `node_key`): the
settings each step uses, and the twin by the sha256 of its MJCF's bytes. Resumed after its twin was
edited (or in another checkout whose `models/slider_crank.xml`, the default, has other bytes), or
after its folder's sweep.toml was edited by hand, the keys change from the step that sees the
change down: the resume would find none of those finished steps and make them all again beside the
old ones, in the same folder, under the same leaf names (hours of work, its start line saying only
how much is left). It is refused instead, before anything is written, naming what changed: the twin
(both sha256s), or the settings of the leaves (crank/sweep.py `run_sweep`). Leaves added to
sweep.toml by hand resume as new ones; leaves taken out of it are no longer the sweep's and are not
checked.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from common.errors import ConfigError
from crank.run_twin import made_on
from crank.sweep import RESULT
from crank.sweep_spec import KINDS, Leaf, folder, mjcf_sha


def check_resumable(out: Path, leaves: list[Leaf]) -> None:
    """Refuse to resume the sweep folder `out` on `leaves` (its sweep.toml read again) where a
    leaf it recorded in sweep.json, still in `leaves`, has finished steps under keys `leaves`
    no longer give them.

    Raises:
      ConfigError: naming the number of such steps and what changed.
    """
    record = out / "sweep.json"
    if not record.is_file():  # stopped before its first sweep.json: nothing was made
        return
    now = {leaf.name: leaf for leaf in leaves}
    keys = {(kind, key) for leaf in leaves for kind, key in zip(KINDS, leaf.steps, strict=True)}
    stale: dict[tuple[str, str], dict[str, Any]] = {}
    for entry in json.loads(record.read_text())["leaves"]:
        if entry["name"] not in now:
            continue
        for kind, key in entry["steps"].items():
            if (kind, key) not in keys and (folder(out, kind, key) / RESULT).is_file():
                stale.setdefault((kind, key), entry)
    if not stale:
        return
    kinds = ", ".join(f"{sum(k == kind for k, _ in stale)} {kind}" for kind in KINDS)
    (kind, key), entry = next(iter(stale.items()))
    cause = _cause(out, entry, now[entry["name"]], kind, key)
    raise ConfigError(
        f"cannot resume {out}: {len(stale)} finished steps ({kinds}) would not be used and would "
        f"be made again, since {cause}; put back what changed, or run the sweep into a new folder"
    )


def _cause(out: Path, entry: dict[str, Any], leaf: Leaf, kind: str, key: str) -> str:
    """What changed for the recorded leaf `entry` (now `leaf`), one of whose finished steps is
    `kind`/`key`: its twin's bytes, else its settings."""
    path = Path(leaf.config.model_path)
    dataset = folder(out, "data", entry["steps"]["data"]) / "dataset.mcap"
    if dataset.is_file() and path.is_file():
        recorded = made_on(dataset)
        if recorded is not None and (sha := mjcf_sha(str(path))) != recorded:
            return (
                f"the twin {path} is not the one leaf {entry['name']!r} was made on (sha256 "
                f"{sha[:12]}…, its dataset's {recorded[:12]}…)"
            )
    changed = _differ(entry["config"], leaf.config.as_dict())
    if changed:
        return f"the settings of leaf {entry['name']!r} changed ({', '.join(changed)})"
    now = leaf.steps[KINDS.index(kind)]
    return f"the {kind} step of leaf {entry['name']!r} is keyed {now} now, not {key}"


def _differ(before: Any, after: Any, prefix: str = "") -> list[str]:
    """The dotted names of the settings in which the config dicts `before` and `after` differ."""
    if isinstance(before, dict) and isinstance(after, dict):
        names: list[str] = []
        for name in sorted(before.keys() | after.keys()):
            names += _differ(before.get(name), after.get(name), f"{prefix}{name}.")
        return names
    if json.dumps(before, default=str) != json.dumps(after, default=str):
        return [prefix.rstrip(".")]
    return []
