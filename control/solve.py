"""`crank solve` as a library call: checkpoint in, ocp.json and its figures out."""

from __future__ import annotations

import contextlib
import hashlib
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from common.atomic import check_writable, writes
from common.figures import save_figure
from common.jsonio import recorded_path
from control.config import OCPConfig, OCPConfigError
from control.figures import nominal_figure, robust_figure
from control.ocp import NominalOCP
from control.ocp_file import read_ocp
from control.ocp_write import write_failed, write_ocp
from control.profiles import solve_profiles
from control.robust import Iteration, RobustError
from ppann.checkpoint import CheckpointError, load
from ppann.model import PPANN


def failed_path(out: Path) -> Path:
    """Where a failed robust solve leaves what it solved: <stem>.failed.json."""
    return out.with_name(f"{out.stem}.failed.json")


def _model_record(model_path: Path, out: Path, payload: dict[str, Any]) -> dict[str, Any]:
    return {
        "path": recorded_path(model_path, artifact=out),
        "sha256": hashlib.sha256(model_path.read_bytes()).hexdigest(),
        "kind": payload["kind"],
    }


def figure_paths(out: Path, names: tuple[str, ...]) -> dict[str, Path]:
    """Where the figures of the profiles `names` of ocp.json at `out` go: <stem>.<name>.png
    (ocp.nominal.png, ocp.robust.png, ocp.robust-fb.png)."""
    return {name: out.with_name(f"{out.stem}.{name}.png") for name in names}


@writes("out", inputs=("model_path",), suffix=".json")
def solve_file(
    model_path: str | Path,
    out: str | Path,
    *,
    config: OCPConfig,
    on_iteration: Callable[[Iteration], None] | None = None,
    on_fallback: Callable[[str], None] | None = None,
    figures: bool = True,
) -> dict[str, Any]:
    """Solve the nominal OCP and each robust profile of `config.profiles` on a PPANN
    checkpoint and write ocp.json and (unless `figures` is false) its figures.

    A robust profile without a robust torque is refused (ocp.json says why) while another one
    is solved; where every one is refused, `config.fallback`'s are solved (control/profiles.py
    solve_profiles; `on_fallback` is told before). Nothing is written at `out` unless the
    nominal and at least one robust solve succeed. When every robust profile fails, the nominal
    plan and the margin histories go to <stem>.failed.json (`failed_path`) and the error says
    so.

    Raises:
      CheckpointError: unreadable checkpoint, or not a PPANN (the black box has no physics).
      OCPError: the nominal solve failed; nothing is written.
      RobustError: every robust loop failed; only <stem>.failed.json is written.
      OutputError: `out` cannot be written.
    """
    model_path, out = Path(model_path), Path(out)
    check_writable(out)
    model, payload = load(model_path)
    if not isinstance(model, PPANN):
        raise CheckpointError(f"{model_path}: a {payload['kind']} model; solve needs a PPANN")
    data_dt = payload.get("dt")
    if data_dt is not None and abs(data_dt - model.config.dt) > 1e-12:
        raise CheckpointError(
            f"{model_path}: trained on samples {data_dt:g} s apart but integrates at "
            f"{model.config.dt:g} s"
        )
    limit = payload.get("torque_limit")
    if limit is not None and config.torque_limit > limit + 1e-12:
        raise OCPConfigError(
            f"torque_limit {config.torque_limit:g} N·m exceeds the actuator limit {limit:g} N·m "
            f"of the twin {model_path} was trained on"
        )
    started = time.perf_counter()
    ocp = NominalOCP(model, config)
    build_s = time.perf_counter() - started
    try:
        solved = solve_profiles(
            model, config, ocp=ocp, on_iteration=on_iteration, on_fallback=on_fallback
        )
    except RobustError as exc:
        if exc.partials:  # keep the nominal plan and the margin history
            failed = failed_path(out)
            try:
                write_failed(
                    failed,
                    exc.partials,
                    error=str(exc),
                    config=config,
                    dt=ocp.dt,
                    model=_model_record(model_path, out, payload),
                    geometry=model.geometry,
                    variability=payload.get("variability"),
                )
                kept = f"the nominal plan and the margin history are in {failed}"
            except OSError as not_written:  # a full disk: the solver's error stays the news
                kept = f"the nominal plan could not be kept ({not_written})"
            exc.args = (f"{exc}; {kept}",)
        raise
    with contextlib.suppress(FileNotFoundError):  # a failure's leftovers from an earlier solve
        failed_path(out).unlink()
    written = write_ocp(
        out,
        solved,
        config=config,
        dt=ocp.dt,
        model=_model_record(model_path, out, payload),
        geometry=model.geometry,
        variability=payload.get("variability"),
        build_s=build_s,
        engine=ocp.engine,
    )
    loaded = read_ocp(out)
    for name, path in figure_paths(out, loaded.names if figures else ()).items():
        figure = nominal_figure(loaded) if name == "nominal" else robust_figure(loaded, name)
        save_figure(figure, path)
    return written
