"""`crank replay`: play an ocp.json on the twin and write the campaign's files.

Beside `<out>.mcap` (the campaign log): `<stem>.stats.json` (replay/statistics.py),
`<stem>.png` (paper Fig. 12) and `<stem>.rrd` (the Rerun recording). Inputs are checked before
any simulation; each file is written beside its target and renamed when complete.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from common.atomic import check_writable, writes
from common.errors import ConfigError
from common.figures import save_figure
from common.jsonio import recorded_path
from control.mpc_config import check_fits
from control.ocp_file import OCPFile, OCPFileError, read_ocp
from replay.campaign import Replay, draw_machines, run_campaign
from replay.campaign_log import CampaignLog, campaign_header, check_not_partial
from replay.config import ReplayConfig, check_campaign_memory
from replay.figures import replay_figure
from replay.laws import plays_own_law
from replay.recording import write_recording
from replay.statistics import campaign_statistics, write_statistics
from twin.physics import MODEL_PATH, SAMPLE_RATE, SliderCrank, load_model
from twin.rig_import import RIG_SCENARIO
from twin.variability import Variability

if TYPE_CHECKING:
    from ppann.model import PPANN


def output_paths(out: str | Path) -> dict[str, Path]:
    """Every file a campaign writes, by kind."""
    out = Path(out)
    stem = out.with_suffix("")
    return {
        "mcap": out,
        "stats": Path(f"{stem}.stats.json"),
        "figure": Path(f"{stem}.png"),
        "rrd": Path(f"{stem}.rrd"),
    }


def plan_model(
    ocp_path: str | Path, *, override: str | Path | None = None, ocp: OCPFile | None = None
) -> PPANN:
    """The PPANN an ocp.json was solved on (the mpc mode predicts with it): the checkpoint it
    names (relative to its folder), or `override`, which must be that same file (sha256).
    `ocp`: the file already read, if it was.

    Raises:
      CheckpointError: the checkpoint is missing, another file than the plan's, or not a PPANN.
    """
    import hashlib

    from ppann.checkpoint import CheckpointError, load
    from ppann.model import PPANN

    ocp = ocp if ocp is not None else read_ocp(ocp_path)
    record = ocp.raw.get("model") or {}
    path = plan_model_path(ocp_path, override=override, ocp=ocp)
    if not path.is_file():
        raise CheckpointError(
            f"the MPC and the prediction of a law other than a profile's own use the PPANN "
            f"{ocp_path} was solved on, and {path} is not there (give it with --ppann)"
        )
    digest = hashlib.sha256(path.read_bytes()).hexdigest()
    if record.get("sha256") not in (None, digest):
        raise CheckpointError(
            f"{path} is not the checkpoint {ocp_path} was solved on (sha256 {digest[:12]}…, "
            f"the plan's {record['sha256'][:12]}…)"
        )
    model, payload = load(path)
    if not isinstance(model, PPANN):
        raise CheckpointError(f"{path}: a {payload['kind']} model; the MPC needs a PPANN")
    return model


def plan_model_path(
    ocp_path: str | Path, *, override: str | Path | None = None, ocp: OCPFile | None = None
) -> Path:
    """Where `plan_model` reads the plan's PPANN: `override`, or the checkpoint ocp.json names
    (relative to its folder).

    Raises:
      CheckpointError: ocp.json names none and there is no `override`.
    """
    from ppann.checkpoint import CheckpointError

    if override is not None:
        return Path(override)
    record = (ocp if ocp is not None else read_ocp(ocp_path)).raw.get("model") or {}
    if "path" not in record:
        raise CheckpointError(f"{ocp_path} names no checkpoint; give the PPANN with --ppann")
    named = Path(record["path"])
    return named if named.is_absolute() else Path(ocp_path).parent / named


def prediction_model(
    ocp_path: str | Path, *, override: str | Path | None, ocp: OCPFile
) -> PPANN | None:
    """The plan's PPANN for a prediction the campaign can do without: None if ocp.json's
    checkpoint is gone or another file (its rows then have no predicted σ); a wrong `override`
    is an error."""
    from ppann.checkpoint import CheckpointError

    if override is not None:
        return plan_model(ocp_path, override=override, ocp=ocp)
    try:
        return plan_model(ocp_path, ocp=ocp)
    except CheckpointError:
        return None


def ocp_variability(ocp_path: str | Path) -> Variability:
    """The variability scenario recorded in an ocp.json (the training dataset's; the default
    twin's for a model trained on no dataset).

    Raises:
      ConfigError: the plan's model was trained on rig data (`crank import`): there is no
        scenario of the twin to replay it on unless the user names one.
    """
    raw = read_ocp(ocp_path).raw.get("variability")
    if raw is None:  # a model of no dataset (a test's constant PPANN): the default twin
        return Variability()
    if raw == RIG_SCENARIO:
        raise ConfigError(
            f"{ocp_path} was solved on a model trained on rig data (crank import): the twin is "
            "not that machine; give --variability (e.g. paper) to replay it on the twin anyway"
        )
    return Variability.from_dict(raw)


@writes("out", inputs=("ocp_path", "model_path", "ppann"), suffix=".mcap")
def replay_file(
    ocp_path: str | Path,
    out: str | Path,
    *,
    config: ReplayConfig,
    model_path: str | Path = MODEL_PATH,
    resolved: dict[str, Any] | None = None,
    nthread: int | None = None,
    on_run: Callable[[int], None] | None = None,
    on_start: Callable[[int], None] | None = None,
    ppann: str | Path | None = None,
    figures: bool = True,
) -> dict[str, Any]:
    """Play both profiles of `ocp_path` in every mode of `config`; write the campaign's files
    (the figure unless `figures` is false).

    Args:
      ppann: the checkpoint the mpc mode predicts with (default: the one ocp.json names).
      resolved: the command's resolved configuration, attached to the log as config.json
        (default: the replay config).
      on_run: called with the runs just logged (each run of every profile and mode).
      on_start: called with the runs the campaign will log (runs x profiles x modes) once every
        input has been checked, before the first run.

    Returns:
      The statistics written to `<stem>.stats.json`.
    """
    out = Path(out)
    paths = output_paths(out)
    ocp = read_ocp(ocp_path)
    check_campaign_memory(config.runs, modes=len(config.modes), horizon=ocp.horizon)
    for path in paths.values():
        check_writable(path)
    check_not_partial(out)
    predictor = None
    if "mpc" in config.modes:
        check_fits(config.mpc, ocp.horizon)
        predictor = plan_model(ocp_path, override=ppann, ocp=ocp)
    elif "closed" in config.modes and not all(
        plays_own_law(p, config) for p in ocp.profiles.values()
    ):  # the prediction under the replay's PD runs the PPANN's Monte-Carlo (replay/laws.py)
        predictor = prediction_model(ocp_path, override=ppann, ocp=ocp)
    model, model_xml = load_model(model_path)
    physics = SliderCrank(model)
    ocp.geometry.check_same(physics.geometry, this=str(ocp_path), that=f"the twin {model_path}")
    if abs(ocp.dt * SAMPLE_RATE - 1.0) > 1e-9:
        raise OCPFileError(
            f"{ocp_path}: dt {ocp.dt} s differs from the twin's {1 / SAMPLE_RATE} s samples"
        )
    if ocp.config.torque_limit > physics.torque_limit + 1e-12:
        raise OCPFileError(
            f"{ocp_path}: solved with |τ| <= {ocp.config.torque_limit:g} N·m but the twin's "
            f"actuator saturates at {physics.torque_limit:g} N·m (the replay would clip it)"
        )

    if on_start is not None:
        on_start(config.runs * len(ocp.names) * len(config.modes))
    started = time.perf_counter()
    logging = 0.0
    resolved = resolved if resolved is not None else {"replay": config.as_dict()}
    attachments = {
        "model.xml": ("application/xml", model_xml.encode()),
        "ocp.json": ("application/json", Path(ocp_path).read_bytes()),
        "config.json": ("application/json", json.dumps(resolved, indent=1).encode()),
    }
    machines = draw_machines(config, ocp.horizon)
    header = campaign_header(config, physics=physics, n_samples=ocp.horizon, model_path=model_path)
    with CampaignLog(
        out, header=header, attachments=attachments, n_samples=ocp.horizon, ocp=ocp
    ) as log:

        def write(replay: Replay) -> None:
            nonlocal logging
            t0 = time.perf_counter()
            log.write_replay(replay, machines, on_run=on_run)
            logging += time.perf_counter() - t0

        campaign = run_campaign(
            physics,
            ocp,
            config=config,
            machines=machines,
            nthread=nthread,
            on_replay=write,
            model=predictor,
        )
        t0 = time.perf_counter()
        log.finish()
        logging += time.perf_counter() - t0

    timing = {"simulate_s": campaign.wall_time, "log_s": logging}
    stats = campaign_statistics(
        campaign, ocp, ocp_path=recorded_path(ocp_path, artifact=paths["stats"]), timing=timing
    )
    if figures:
        save_figure(replay_figure(campaign, ocp, stats), paths["figure"])
    t0 = time.perf_counter()
    write_recording(
        paths["rrd"], campaign, ocp, recording_id=f"replay-seed{config.seed}-{out.stem}"
    )
    timing["rerun_s"] = time.perf_counter() - t0
    timing["total_s"] = time.perf_counter() - started
    write_statistics(paths["stats"], stats)
    return stats
