"""`crank solve` as a library call: checkpoint in, ocp.json and its figures out."""

from __future__ import annotations

import hashlib
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from common.atomic import check_writable, writes
from common.figures import save_figure
from common.jsonio import recorded_path
from control.config import OCPConfig
from control.figures import nominal_figure, robust_figure
from control.ocp import NominalOCP
from control.ocp_file import read_ocp, write_ocp
from control.robust import Iteration, solve_robust
from ppann.checkpoint import CheckpointError, load
from ppann.model import PPANN


def figure_paths(out: Path) -> dict[str, Path]:
    """Where the figures of ocp.json at `out` go: <stem>.nominal.png, <stem>.robust.png."""
    return {name: out.with_name(f"{out.stem}.{name}.png") for name in ("nominal", "robust")}


@writes("out", inputs=("model_path",), suffix=".json")
def solve_file(
    model_path: str | Path,
    out: str | Path,
    *,
    config: OCPConfig,
    on_iteration: Callable[[Iteration], None] | None = None,
) -> dict[str, Any]:
    """Solve the nominal and robust OCP on a PPANN checkpoint and write ocp.json and figures.

    Nothing is written unless both solves succeed.

    Raises:
      CheckpointError: unreadable checkpoint, or not a PPANN (the black box has no physics).
      OCPError, RobustError: the solves failed; nothing is written.
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
    started = time.perf_counter()
    ocp = NominalOCP(model, config)
    build_s = time.perf_counter() - started
    result = solve_robust(model, config, ocp=ocp, on_iteration=on_iteration)
    written = write_ocp(
        out,
        result,
        config=config,
        dt=ocp.dt,
        model={
            "path": recorded_path(model_path, artifact=out),
            "sha256": hashlib.sha256(model_path.read_bytes()).hexdigest(),
            "kind": payload["kind"],
        },
        variability=payload.get("variability"),
        build_s=build_s,
    )
    loaded = read_ocp(out)
    paths = figure_paths(out)
    save_figure(nominal_figure(loaded), paths["nominal"])
    save_figure(robust_figure(loaded), paths["robust"])
    return written
