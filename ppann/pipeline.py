"""`crank train`: fit the PPANN and both baselines on a dataset, save checkpoints, and write the
validation report (JSON + PNGs) beside them.

Outputs for `--out logs/model.pt`:
  model.pt, model.physics.pt, model.blackbox.pt   checkpoints (torch.load(weights_only=True))
  model.report.json                              the report (keys in docs/ppann.md)
  model.maps.png, model.validation.png, model.bands.png, model.calibration.png   figures
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch

from common.atomic import check_writable, writes
from common.figures import save_figure
from common.jsonio import recorded_path, write_json
from ppann import checkpoint
from ppann import figures as plots
from ppann.confidence import DEFAULT_CONFIDENCE
from ppann.fit import Fitted, fit_all
from ppann.inversion import calibration_of, line_bounds
from ppann.kinds import KINDS
from ppann.machine import sigma_upper
from ppann.model import Z_NAMES, PPANNConfig
from ppann.report import (
    bands,
    calibration,
    free_run,
    inside_3sigma,
    prediction_rmse,
    twin_replay,
    validation_segment,
)
from ppann.train import make_splits
from ppann.train_config import CALIBRATION_RUNS, TrainConfig
from twin.dataset import Dataset, check_step
from twin.mcap_dataset import has_model_xml, read_dataset, read_model_xml
from twin.physics import SliderCrank, compile_mjcf
from twin.rig_import import RIG_SCENARIO


def sibling(out: Path, suffix: str) -> Path:
    return out.with_name(f"{out.stem}.{suffix}")


def check_rate(dataset: Dataset, *, source: str) -> None:
    """Refuse data at another rate than the PPANN's step dt (eq. 4 steps once per sample).

    Raises:
      ConfigError: the rates in the message (twin/dataset.py check_step).
    """
    check_step(dataset, step=PPANNConfig.dt, stepper="the PPANN steps", source=source)


@writes("out", inputs=("data_path",), suffix=".pt")
def train_and_report(
    data_path: str | Path,
    out: str | Path,
    *,
    config: TrainConfig,
    mc_samples: int = 100,
    calibration_runs: int = CALIBRATION_RUNS,
    baselines: bool = True,
    figures: bool = True,
    on_epoch: Callable[[str, str, int, float], None] | None = None,
    on_trained: Callable[[str], None] | None = None,
    on_stage: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Train (the kinds side by side where torch has a thread for each: ppann/fit.py
    `fit_all`), save and report (its figures unless `figures` is false); returns the report
    dict."""
    out = Path(out)
    check_writable(out)
    dataset = read_dataset(data_path)
    check_rate(dataset, source=str(data_path))
    splits = make_splits(dataset, config)
    print_stage = on_stage or (lambda _: None)
    kinds = KINDS if baselines else KINDS[:1]
    workers = min(len(kinds), torch.get_num_threads())
    print_stage(f"training {', '.join(kinds)}" + (" side by side" if workers > 1 else ""))
    fitted: dict[str, Fitted] = fit_all(
        dataset,
        kinds=kinds,
        config=config,
        splits=splits,
        workers=workers,
        on_epoch=on_epoch,
        on_done=on_trained,
    )
    print_stage("validating")
    segment = validation_segment(dataset, config.validation_fraction)
    measured = np.stack([dataset.theta, dataset.omega], -1)[segment.start : segment.stop]
    t = dataset.t[segment.start : segment.stop] - dataset.t[segment.start]
    ppann = fitted["ppann"].model
    mc = bands(ppann, dataset, segment, n=mc_samples, seed=config.seed)
    # The twin the dataset was generated on: its compiled MJCF travels in the file. Rig data
    # (crank import) has none: no twin to calibrate against.
    replay, geometry = None, dataset.geometry
    if has_model_xml(data_path):
        print_stage("replaying the validation torque on the twin")
        physics = SliderCrank(
            compile_mjcf(read_model_xml(data_path), source=f"{data_path}:model.xml")[0]
        )
        physics.geometry.check_same(
            dataset.geometry, this=f"{data_path}:model.xml", that=f"{data_path}'s run record"
        )
        replay = twin_replay(
            dataset, segment, physics=physics, n_runs=calibration_runs, seed=config.seed
        )
    fingerprint = checkpoint.fingerprint(dataset)
    report: dict[str, Any] = {
        "dataset": {
            "path": recorded_path(data_path, artifact=out),
            "fingerprint": fingerprint,
            "n_samples": len(dataset),
            "validation_start": segment.start,
            "validation_seconds": segment.length * float(dataset.t[1] - dataset.t[0]),
        },
        "train_config": config.as_dict(),
        "models": {},
        "monte_carlo": {
            "n_samples": mc_samples,
            **{mode: {"inside_3sigma": inside_3sigma(b, measured)} for mode, b in mc.items()},
        },
        "calibration": None
        if replay is None
        else {
            "n_runs": calibration_runs,
            "observed_sigma_final": {
                "theta": float(replay.theta[:, -1].std(ddof=1)),
                "slider_position": float(replay.slider_position[:, -1].std(ddof=1)),
            },
            **{mode: calibration(b, replay, geometry=geometry) for mode, b in mc.items()},
        },
    }
    for kind, f in fitted.items():
        entry = prediction_rmse(f.model, dataset, segment) | {
            "train_seconds": f.seconds,
            "epochs": len(f.history.train),
            "best_epoch": f.history.best_epoch,
        }
        entry["phase1_converged"] = len(f.history.train) < config.max_epochs
        if kind != "blackbox":
            j, b, k = (float(v) for v in f.model.physical.detach())
            entry["physical"] = {"J_m": j, "B_m": b, "K_m": k}
            if f.model.config.coulomb:  # the Coulomb friction: motor N·m, slider N
                motor, load = (float(v) for v in f.model.coulomb.detach())
                entry["physical"] |= {"C_m": motor, "F_m": load}
        if kind == "ppann":
            entry["machine_sigma"] = dict(zip(Z_NAMES, f.model.machine_sigma.tolist(), strict=True))
            entry["machine_offsets"] = f.history.machine_offsets
            entry["spread_data"] = f.history.spread_data  # machines and episodes of phase 2
            if f.history.lever_sigma is not None:  # the slider force (ppann/lever.py), N
                entry["lever_sigma"] = f.history.lever_sigma
            if f.history.residual_mean_share is not None:  # ppann/residual_mean.py
                entry["residual_mean_share"] = f.history.residual_mean_share
            if f.history.plan_fit is not None:  # phase 1 over the plan episodes whole
                entry["plan_fit"] = f.history.plan_fit
            # What the training machines leave open about the line (ppann/machine.py): the
            # bounds the robust OCP allows for at its default confidence 0.95, from as many
            # machines as phase 2 saw (ppann/confidence.py; one machine bounds nothing).
            # Calibrated by simulation for few machines (ppann/inversion.py: `bounds_calibrated`).
            machines = int(f.model.spread_machines)
            sigma, profile = f.model.machine_sigma.numpy(), f.model.machine_profile.numpy()
            if machines == 1:
                upper, radius, calibrated = sigma_upper(sigma, profile, np.inf), None, False
            else:
                upper, radius, calibrated = line_bounds(
                    machine_sigma=sigma,
                    profile=profile,
                    machines=machines,
                    confidence=DEFAULT_CONFIDENCE,
                    calibration=calibration_of(f.model),
                )
            entry["machine_sigma_upper"] = dict(zip(Z_NAMES, upper.tolist(), strict=True))
            line_se = f.model.common_covariance.diagonal().clamp(min=0).sqrt().tolist()
            entry["line_mean_se"] = dict(zip(Z_NAMES, line_se, strict=True))
            entry["line_mean_quantile"] = None if radius is None else float(radius.max())
            entry["line_mean_radius"] = None if radius is None else radius.tolist()
            entry["bounds_calibrated"] = calibrated
            # The crank's angle to the motor, from the measured slider (ppann/transmission.py).
            q = f.model.transmission.tolist()
            entry["transmission_rad"] = {"q01": q[1], "median": q[50], "q99": q[99]}
        report["models"][kind] = entry
        path = out if kind == "ppann" else sibling(out, f"{kind}.pt")
        checkpoint.save(
            path,
            f.model,
            kind=kind,
            extra={
                "history": f.history.as_dict(),
                "train_config": config.as_dict(),
                "data_fingerprint": fingerprint,
                # Relative to the checkpoint's folder: the same training gives the same bytes
                # wherever it runs (and the folder can move).
                "data_path": os.path.relpath(Path(data_path).resolve(), out.resolve().parent),
                "loss_scale": splits.scale.tolist(),
                # a dataset without a twin (rig data, another tool's file) is a real machine
                "variability": (
                    dataset.run["config"]["variability"] if replay is not None else RIG_SCENARIO
                ),
                "dt": float(dataset.t[1] - dataset.t[0]),
                # the twin's actuator limit: no plan on this model may ask for more
                "torque_limit": dataset.run.get("torque_limit"),
            },
        )
    if figures:
        save_figure(plots.network_maps(ppann), sibling(out, "maps.png"))
        predictions = {k: free_run(f.model, dataset, segment) for k, f in fitted.items()}
        save_figure(plots.validation(t, measured, predictions), sibling(out, "validation.png"))
        save_figure(plots.monte_carlo_bands(t, measured, mc, replay), sibling(out, "bands.png"))
        if replay is not None:
            save_figure(plots.sigma_ratio(t, mc, replay), sibling(out, "calibration.png"))
    write_json(sibling(out, "report.json"), report, indent=2)
    return report
