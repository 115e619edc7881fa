"""The campaign as a Rerun recording (`.rrd`), with a default blueprint.

Timelines: `sample` (the OCP's 1-based k) and `time` (t_k = (k − 1) Ts). Entities:

  /mechanism/<profile>           crank and rod (line strip), slider (box) of run 0 in the first
                                 mode, animated; `/mechanism/constraint` marks the height
  /slider/<profile>/<mode>/runs  measured slider position of every run (one series per run), m
  /slider/<profile>/<mode>/predicted_lower, predicted_upper   the PPANN's mean ∓ kσ
  /slider/<profile>/<mode>/constraint   the height at the constraint samples
  /torque/<profile>/<mode>/runs  torque applied in every run, N·m; /torque/<profile>/planned
  /fig12/<profile>_<mode>        paper Fig. 12 as a 2D plot: all runs and the constraint boxes
                                 (x: t in ms, y: −slider in mm, since 2D views point y down)

Bulk data goes through `send_columns`; the file is written beside its target and renamed.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from common.atomic import atomic_path
from common.errors import CrankError
from control.ocp_file import OCPFile, predicted_band
from replay.campaign import PROFILES, Campaign
from twin.physics import CRANK_LENGTH, ROD_LENGTH

APPLICATION_ID = "crank_replay"
COLORS = {"nominal": (31, 119, 180), "robust": (214, 39, 40)}
OFFSET = {"nominal": -0.12, "robust": 0.12}
"""x position of each profile's mechanism in the 3D view, m."""


def _timelines(n: int, dt: float, *, at: np.ndarray | None = None) -> list[rr.TimeColumn]:
    k = np.arange(n) if at is None else np.asarray(at)
    return [rr.TimeColumn("sample", sequence=k + 1), rr.TimeColumn("time", duration=k * dt)]


def _mechanism(rec: rr.RecordingStream, campaign: Campaign, ocp: OCPFile) -> None:
    mode = campaign.config.modes[0]
    n, dt = ocp.horizon, ocp.dt
    for profile in PROFILES:
        replay = campaign.replays[profile, mode]
        x0 = OFFSET[profile]
        angle = replay.crank_angle[0]
        pin = np.stack([x0 + CRANK_LENGTH * np.sin(angle), 0 * angle, CRANK_LENGTH * np.cos(angle)])
        slider_z = replay.slider_position[0] + ROD_LENGTH - CRANK_LENGTH
        tip = np.stack([np.full(n, x0), 0 * angle, slider_z])
        axis = np.tile([[x0], [0.0], [0.0]], (1, n))
        strips = np.stack([axis.T, pin.T, tip.T], axis=1)  # (n, 3 points, xyz)
        rec.send_columns(
            f"/mechanism/{profile}/linkage",
            indexes=_timelines(n, dt),
            columns=rr.LineStrips3D.columns(strips=list(strips)).partition([1] * n),
        )
        rec.send_columns(
            f"/mechanism/{profile}/slider",
            indexes=_timelines(n, dt),
            columns=rr.Boxes3D.columns(
                centers=tip.T, half_sizes=np.tile([0.025, 0.02, 0.012], (n, 1))
            ),
        )
        rec.log(
            f"/mechanism/{profile}",
            rr.Boxes3D(
                centers=[[x0, 0, ROD_LENGTH - CRANK_LENGTH + 0.05]],
                half_sizes=[[0.03, 0.001, 0.075]],
                colors=[(*COLORS[profile], 40)],
                labels=[f"{profile}, run 0, {mode} loop"],
            ),
            static=True,
        )
    z = ocp.config.height + ROD_LENGTH - CRANK_LENGTH
    rec.log(
        "/mechanism/constraint",
        rr.LineStrips3D([[[-0.2, 0, z], [0.2, 0, z]]], colors=[(0, 0, 0)], labels=["height"]),
        static=True,
    )


def _series(rec: rr.RecordingStream, campaign: Campaign, ocp: OCPFile) -> None:
    n, dt = ocp.horizon, ocp.dt
    c = ocp.config
    at = np.array(c.constraint_samples) - 1
    for (profile, mode), replay in campaign.replays.items():
        runs = replay.runs
        color = COLORS[profile]
        names = [f"run {i:03d}" for i in range(runs)]
        for quantity, values in (("slider", replay.slider_position), ("torque", replay.tau)):
            path = f"/{quantity}/{profile}/{mode}/runs"
            rec.log(
                path,
                rr.SeriesLines(colors=[(*color, 90)] * runs, widths=[1.0] * runs, names=names),
                static=True,
            )
            rec.send_columns(
                path,
                indexes=_timelines(n, dt),
                columns=rr.Scalars.columns(scalars=values.T.ravel()).partition([runs] * n),
            )
        planned = getattr(ocp, profile)
        band = dict(zip(("lower", "upper"), predicted_band(planned, mode, c.k_sigma), strict=True))
        for side in ("lower", "upper"):
            path = f"/slider/{profile}/{mode}/predicted_{side}"
            rec.log(
                path,
                rr.SeriesLines(colors=[(0, 0, 0)], widths=[2.0], names=[f"PPANN {side}"]),
                static=True,
            )
            rec.send_columns(
                path,
                indexes=_timelines(n, dt),
                columns=rr.Scalars.columns(scalars=band[side]),
            )
        path = f"/slider/{profile}/{mode}/constraint"
        rec.log(
            path,
            rr.SeriesPoints(
                colors=[(0, 0, 0)], markers=["down"], marker_sizes=[8], names=["height"]
            ),
            static=True,
        )
        rec.send_columns(
            path,
            indexes=_timelines(n, dt, at=at),
            columns=rr.Scalars.columns(scalars=np.full(len(at), c.height)),
        )
    for profile in PROFILES:
        path = f"/torque/{profile}/planned"
        rec.log(
            path, rr.SeriesLines(colors=[(0, 0, 0)], widths=[2.0], names=["planned"]), static=True
        )
        rec.send_columns(
            path,
            indexes=_timelines(n, dt),
            columns=rr.Scalars.columns(scalars=getattr(ocp, profile).tau),
        )


def _figure12(rec: rr.RecordingStream, campaign: Campaign, ocp: OCPFile) -> None:
    c = ocp.config
    t_ms = 1e3 * np.arange(ocp.horizon) * ocp.dt
    for (profile, mode), replay in campaign.replays.items():
        strips = [np.stack([t_ms, -1e3 * s], axis=1) for s in replay.slider_position]
        rec.log(
            f"/fig12/{profile}_{mode}/runs",
            rr.LineStrips2D(strips, colors=[(*COLORS[profile], 120)], radii=[0.15]),
            static=True,
        )
        mins = [[1e3 * (k - 1) * ocp.dt - 1.0, -1e3 * c.height] for k in c.constraint_samples]
        sizes = [[2.0, 1e3 * c.height + 5.0]] * len(mins)
        rec.log(
            f"/fig12/{profile}_{mode}/constraint",
            rr.Boxes2D(
                mins=mins, sizes=sizes, colors=[(0, 0, 0)], labels=["slider < height"] * len(mins)
            ),
            static=True,
        )


def blueprint(campaign: Campaign) -> rrb.Blueprint:
    """Mechanism beside slider and torque plots; a tab with Fig. 12."""
    slider_views = [
        rrb.TimeSeriesView(
            origin=f"/slider/{profile}",
            name=f"slider position, {profile} [m]",
            axis_y=rrb.ScalarAxis(range=(0.0, 0.105)),
        )
        for profile in PROFILES
    ]
    return rrb.Blueprint(
        rrb.Tabs(
            rrb.Horizontal(
                rrb.Spatial3DView(origin="/mechanism", name="mechanism (run 0)"),
                rrb.Vertical(
                    *slider_views,
                    rrb.TimeSeriesView(origin="/torque", name="torque [N·m]"),
                ),
                name="replay",
            ),
            rrb.Grid(
                *(
                    rrb.Spatial2DView(origin=f"/fig12/{p}_{m}", name=f"Fig. 12: {p}, {m} loop")
                    for p, m in campaign.replays
                ),
                name="Fig. 12",
            ),
        ),
        collapse_panels=False,
    )


def write_recording(
    path: str | Path, campaign: Campaign, ocp: OCPFile, *, recording_id: str
) -> None:
    """Write the campaign's `.rrd` atomically."""
    with atomic_path(path) as tmp:
        rec = rr.RecordingStream(APPLICATION_ID, recording_id=recording_id)
        rec.save(tmp, default_blueprint=blueprint(campaign))
        _mechanism(rec, campaign, ocp)
        _series(rec, campaign, ocp)
        _figure12(rec, campaign, ocp)
        rec.flush()
        rec.disconnect()


class RecordingError(CrankError, ValueError):
    """A file is not a readable Rerun recording."""


def rerun_version() -> str:
    return rr.__version__


def check_recording(path: str | Path) -> list[str]:
    """The application ids of the recordings in an `.rrd`, read with rerun's own reader.

    Raises:
      RecordingError: the file is not an RRD, is truncated, or holds no recording.
    """
    from rerun.chunk import RrdReader

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            entries = RrdReader(path).recordings()
    except (RuntimeError, OSError, ValueError) as exc:
        raise RecordingError(f"{path}: not a readable Rerun recording ({exc})") from None
    if not entries:
        raise RecordingError(f"{path}: holds no recording")
    return [e.application_id for e in entries]
