"""Going on with an unfinished `crank run` folder (`crank run --resume RUN`), as it was configured
or with other settings for the stages it has not run yet.

A run folder holds its config.json from the start and, after each finished stage, what that
stage returned (STAGES_FILE); a folder without report.md did not finish. Resuming skips the
recorded stages and runs the rest. The settings of the stages still to run may change
(`CHANGEABLE`: the OCP's, the replays', the held-out check's), e.g. a run whose open-loop
profile was refused on a wide line goes on with `--profiles robust-fb` from its trained model
instead of generating and training again; a setting of a stage already run may not (its
outputs were made with the old one), nor the dataset's, the training's or the plan round's.
A resume that changes settings rewrites config.json with them and appends what changed, and
from which command, to its `resumed` list, so the folder still says how it was made. The twin's
MJCF may be given at another path (`--model`, a folder moved to another machine or checkout)
if its bytes are those the run's dataset was generated from (crank/run_twin.py).
"""

from __future__ import annotations

import json
import sys
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from common.atomic import OutputError
from common.errors import ConfigError
from crank.run_twin import run_twin

if TYPE_CHECKING:
    from crank.chain import RunConfig

STAGES_FILE = "stages.json"
"""What each finished stage of an unfinished run returned (crank run --resume reads it); removed
once report.json and report.md are written."""

CHANGEABLE = {
    "ocp": ("solve", "solved its OCPs"),
    "replay": ("replay", "replayed its profiles"),
    "heldout_runs": ("heldout", "made its held-out check"),
    "heldout_seed": ("heldout", "made its held-out check"),
    "heldout_second_stage": ("heldout", "made its held-out check"),
    "heldout_trajectories": ("heldout", "made its held-out check"),
}
"""The RunConfig fields a resume may change, each with the first stage that uses it (and what
a folder that finished that stage did)."""
MOVED = "model"
"""The config file's key of the twin's MJCF (RunConfig.model_path), which a resume may move to
a copy of the same bytes."""


def check_new_run(run_dir: Path) -> None:
    """A new run's folder must not exist yet (an unfinished one is continued with --resume).

    Raises:
      OutputError: naming the folder.
    """
    if run_dir.exists():
        raise OutputError(f"run folder already exists: {run_dir}")


def resumed_config(run_dir: str | Path) -> RunConfig:
    """The configuration of the run folder `run_dir` (its config.json), to resume it.

    Raises:
      OutputError: not a run folder.
      ConfigError: its config.json is not a run configuration.
    """
    from crank.chain import RunConfig

    return RunConfig.from_dict(_config_json(Path(run_dir)))


def with_settings(config: RunConfig, given: dict[str, Any]) -> RunConfig:
    """`config` with `given`'s values: a partial config file of CHANGEABLE settings and MOVED
    (the shape of crank/config_file.py's `defaults()`, as `crank run`'s flags give them)."""
    unknown = sorted(set(given) - {*CHANGEABLE, MOVED})
    if unknown:
        raise ConfigError(f"a resume cannot change {unknown[0]}: start a new run")
    tables = {"ocp": config.ocp, "replay": config.replay}
    changes: dict[str, Any] = {}
    for key, value in given.items():
        if key == MOVED:
            changes["model_path"] = str(value)
        elif key in tables:
            values = {k: tuple(v) if isinstance(v, list) else v for k, v in value.items()}
            changes[key] = replace(tables[key], **values)
        else:
            changes[key] = value
    return replace(config, **changes)


def resumable(
    config: RunConfig, run_dir: Path, *, argv: list[str] | None = None
) -> tuple[dict[str, Any], dict[str, Any], bool]:
    """An unfinished run folder of `config`: its config.json (with `config`'s settings where a
    CHANGEABLE one differs, and what changed appended to `resumed`), the results its finished
    stages recorded (crank/chain.py `run_chain`), and whether config.json is to be rewritten.

    Raises:
      OutputError: no such folder, not a run folder, or a finished one.
      ConfigError: its config.json is not `config` (but for CHANGEABLE settings of stages it has
        not run), or its twin's MJCF has changed since.
    """
    from crank.chain import RunConfig

    resolved = _config_json(run_dir)
    if (run_dir / "report.md").exists():
        raise OutputError(f"nothing to resume: {run_dir} finished (it has report.md)")
    stored = RunConfig.from_dict(resolved)
    fields = (*CHANGEABLE, "model_path")
    changed = [name for name in fields if getattr(stored, name) != getattr(config, name)]
    try:  # the stored run with the changed settings: `config` itself, or another run
        same = replace(stored, **{name: getattr(config, name) for name in changed}) == config
    except ConfigError:  # e.g. the OCP's seed not the stored root seed
        same = False
    if not same:
        raise ConfigError(f"{run_dir}/config.json is another run's configuration")
    stages = run_dir / STAGES_FILE
    done = json.loads(stages.read_text()) if stages.is_file() else {}
    for name in changed:  # in CHANGEABLE's order: the first stage made is the one named
        if name not in CHANGEABLE:  # the twin moved: checked below against the dataset
            continue
        stage, did = CHANGEABLE[name]
        if stage in done:
            raise ConfigError(
                f"{run_dir} already {did}: its {name} settings cannot change on --resume; "
                f"start a new run"
            )
    if "generate" in done:  # the twin at its path (moved or not) is the dataset's
        run_twin(run_dir / "dataset.mcap", config.model_path, flag="--model")
    if not changed:
        return resolved, done, False
    record = {"argv": sys.argv[1:] if argv is None else argv, "changed": changed}
    kept = {k: resolved[k] for k in ("command", "argv", "project_version") if k in resolved}
    after = kept | config.as_dict() | {"resumed": [*resolved.get("resumed", []), record]}
    return after, done, True


def _config_json(run_dir: Path) -> dict[str, Any]:
    """A run folder's config.json as written (the command, argv and version included)."""
    path = run_dir / "config.json"
    if not path.is_file():
        raise OutputError(f"nothing to resume: {run_dir} is not a run folder (no config.json)")
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise ConfigError(f"{path}: not a run configuration ({exc})") from None
