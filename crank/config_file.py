"""One file for the whole chain: `crank run --config crank.toml`, and `crank config --show`.

The file is TOML with the shape of `defaults()` (print it with `crank config --show`): top-level
`seed`, `heldout_runs`, `heldout_seed`, `heldout_second_stage`, `heldout_trajectories`,
`calibration_runs`, `model`, `baselines`, `figures`, and one table per stage —
`[generation]` (with `variability`, a scenario name or a range file, `drift`, and
`[generation.excitation]`), `[train]`, `[ocp]` (any constraint samples, the robust loop's
settings), `[replay]` and `[plan]` (the plan round, twin/plan_data.py). Every key is optional;
a key the defaults do not have, or a value of another type, is refused naming the key. The
stages' seeds are the root `seed` (one seed for the chain, crank/chain.py). Values resolve as
defaults ← file ← command-line flags given explicitly; the resolved configuration is what the
run folder's config.json holds.
"""

from __future__ import annotations

import json
import tomllib
from dataclasses import MISSING, fields
from pathlib import Path
from typing import TYPE_CHECKING, Any

from common.errors import ConfigError, CrankError
from control.config import OCPConfig
from control.mpc_config import MPCConfig
from crank.console import HELDOUT_RUNS, HELDOUT_SEED
from ppann.train_config import CALIBRATION_RUNS, TrainConfig
from replay.config import ReplayConfig
from replay.rates import SECOND_STAGE
from replay.spread_interval import CALIBRATION_TRAJECTORIES
from twin import MODEL_PATH
from twin.dataset import GenerationConfig
from twin.excitation import Excitation
from twin.plan_config import PlanConfig
from twin.variability import Variability

if TYPE_CHECKING:
    from crank.chain import RunConfig

SEEDED = {"train": "seed", "ocp": "mc_seed", "replay": "seed"}
"""The stage fields that are the root seed, and so are not keys of the file."""


def _field_defaults(cls: type, *, skip: tuple[str, ...] = ()) -> dict[str, Any]:
    out = {}
    for f in fields(cls):
        if f.name in skip or f.default is MISSING:
            continue
        out[f.name] = list(f.default) if isinstance(f.default, tuple) else f.default
    return out


def defaults() -> dict[str, Any]:
    """Every key of the file with what `crank run` uses when neither file nor flag sets it."""
    return {
        "seed": 0,
        "heldout_runs": HELDOUT_RUNS,
        "heldout_seed": HELDOUT_SEED,
        "heldout_second_stage": SECOND_STAGE,
        "heldout_trajectories": CALIBRATION_TRAJECTORIES,
        "calibration_runs": CALIBRATION_RUNS,
        "model": str(MODEL_PATH),
        "baselines": True,
        "figures": True,
        "generation": {
            **_field_defaults(GenerationConfig, skip=("seed",)),
            "variability": "paper",
            "drift": True,
            "excitation": _field_defaults(Excitation),
        },
        "train": _field_defaults(TrainConfig, skip=(SEEDED["train"],)),
        "ocp": _field_defaults(OCPConfig, skip=(SEEDED["ocp"],)),
        "replay": {
            **_field_defaults(ReplayConfig, skip=(SEEDED["replay"], "variability")),
            "mpc": _field_defaults(MPCConfig),
        },
        "plan": _field_defaults(PlanConfig),
    }


def read_values(path: str | Path, *, base: dict[str, Any] | None = None) -> dict[str, Any]:
    """The file's values merged onto `base` (`defaults()` if none), every key and type checked.

    Raises:
      ConfigError: the file cannot be read or parsed, a key is unknown, a value has another type.
    """
    path = Path(path)
    try:
        given = tomllib.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise ConfigError(f"cannot read config {path}: {exc.strerror or exc}") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ConfigError(f"config {path} is not TOML: {exc}") from None
    return follow_dataset(
        merge(defaults() if base is None else base, given, source=str(path)), given
    )


def follow_dataset(values: dict[str, Any], *given: dict[str, Any]) -> dict[str, Any]:
    """`values` with the replays' operating time the dataset's (replay.max_start_time =
    generation.max_start_time) unless one of the `given` layers sets replay.max_start_time
    itself: the machines a torque is checked on have run as long as those it was learnt from,
    from a file as from the command line or the library (crank/chain.py RunConfig.for_seed).
    Before this a file's `[generation] max_start_time = 0` replayed on machines of 60 s."""
    if any("max_start_time" in layer.get("replay", {}) for layer in given):
        return values
    replay = {**values["replay"], "max_start_time": values["generation"]["max_start_time"]}
    return {**values, "replay": replay}


REPLACED = {
    "ocp.feedback": 'replaced by ocp.profiles: feedback = "lqr" is profiles = ["robust-fb"], '
    'and both are ["robust", "robust-fb"]',
}
"""Keys of earlier versions, with what took their place."""


def merge(base: dict[str, Any], given: dict[str, Any], *, source: str) -> dict[str, Any]:
    """`base` with `given`'s values, checked key by key against `base` (dotted names in errors)."""
    return _merge(base, given, source, prefix="")


def _merge(base: dict[str, Any], given: dict[str, Any], source: str, prefix: str) -> dict:
    out = dict(base)
    for key, value in given.items():
        name = prefix + key
        if key not in base:
            hint = ""
            if prefix[:-1] in SEEDED and key == SEEDED[prefix[:-1]]:
                hint = " (every stage uses the top-level seed)"
            elif name in REPLACED:
                hint = f" ({REPLACED[name]})"
            raise ConfigError(f"{source}: unknown key {name!r}{hint}")
        default = base[key]
        if isinstance(default, dict):
            if not isinstance(value, dict):
                raise ConfigError(f"{source}: {name} must be a table, got {value!r}")
            out[key] = _merge(default, value, source, prefix=name + ".")
        elif not _same_type(default, value):
            raise ConfigError(
                f"{source}: {name} must be {_type_name(default)}, got {json.dumps(value)}"
            )
        else:
            out[key] = float(value) if isinstance(default, float) else value
    return out


def _same_type(default: Any, value: Any) -> bool:
    if isinstance(default, bool) or isinstance(value, bool):
        return isinstance(default, bool) and isinstance(value, bool)
    if isinstance(default, float):
        return isinstance(value, int | float)
    if isinstance(default, list):
        return isinstance(value, list) and all(
            _same_type(default[0], v) if default else True for v in value
        )
    return isinstance(value, type(default))


def _type_name(default: Any) -> str:
    if isinstance(default, list):
        return f"a list of {_items_name(default[0])}" if default else "a list"
    return {bool: "true or false", int: "an integer", float: "a number", str: "a string"}.get(
        type(default), type(default).__name__
    )


def _items_name(default: Any) -> str:
    """What a list of `default`'s kind holds, in the plural: "integers", not "an integer"."""
    return {bool: "true or false values", int: "integers", float: "numbers", str: "strings"}.get(
        type(default), f"{type(default).__name__} values"
    )


def build(values: dict[str, Any], *, source: str = "config") -> RunConfig:
    """The RunConfig of merged values (the shape of `defaults()`).

    Raises:
      CrankError: a value out of range, with the file's name before the stage's message.
    """
    from crank.chain import RunConfig  # the engines: not for `crank config --show`

    try:
        gen = dict(values["generation"])
        variability = Variability.resolve(gen.pop("variability"), drift=gen.pop("drift"))
        excitation = Excitation(**gen.pop("excitation"))
        replay = dict(values["replay"])
        replay["modes"] = tuple(replay["modes"])
        replay["mpc"] = MPCConfig(**replay["mpc"])
        return RunConfig.for_seed(
            values["seed"],
            generation={**gen, "variability": variability, "excitation": excitation},
            train=values["train"],
            ocp=values["ocp"],
            replay=replay,
            plan=values["plan"],
            heldout_runs=values["heldout_runs"],
            heldout_seed=values["heldout_seed"],
            heldout_second_stage=values["heldout_second_stage"],
            heldout_trajectories=values["heldout_trajectories"],
            calibration_runs=values["calibration_runs"],
            model_path=values["model"],
            baselines=values["baselines"],
            figures=values["figures"],
        )
    except CrankError as exc:
        raise type(exc)(f"{source}: {exc}") from None


def to_toml(values: dict[str, Any], *, header: str = "") -> str:
    """`values` (the shape of `defaults()`) as TOML: scalars first, then one table each."""
    lines = [f"# {line}" if line else "#" for line in header.splitlines()]
    if lines:
        lines.append("")
    lines += _table(values, prefix="")
    return "\n".join(lines).rstrip() + "\n"


def _table(values: dict[str, Any], prefix: str) -> list[str]:
    lines = [f"{k} = {_toml_value(v)}" for k, v in values.items() if not isinstance(v, dict)]
    for key, value in values.items():
        if isinstance(value, dict):
            lines += ["", f"[{prefix}{key}]", *_table(value, prefix=f"{prefix}{key}.")]
    return lines


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, list):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    return json.dumps(value, ensure_ascii=False) if isinstance(value, str) else str(value)
