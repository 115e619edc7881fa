"""The campaign as a Rerun recording (`.rrd`), with a default blueprint.

Timelines: `sample` (the OCP's 1-based k) and `time` (t_k = (k − 1) Ts). Entities, with
<loop> = <profile>/<mode> for every profile and mode the campaign played:

  /mechanism/<loop>              crank and rod (line strip) and slider (box) of run 0, animated
  /mechanism/constraint          the height, across all mechanisms
  /slider/<loop>/runs            measured slider position of every run (one series per run), m
  /slider/<loop>/band            the PPANN's mean ∓ kσ in that loop, shaded (BAND_LINES series
                                 spread evenly between the bounds: Rerun 0.41 plots no filled
                                 area), within the stroke (control.figures.predicted_band)
  /slider/<loop>/planned         the plan's slider position
  /slider/<loop>/constraint      the height at the constraint samples (markers)
  /torque/<loop>/runs            torque applied in every run, N·m; /torque/<profile>/planned

Reference items (band, plan, height) are light on the viewer's dark theme; runs take their
profile's colour. The blueprint has two tabs: "replay" (the mechanisms from the front, one slider
plot per profile and loop, the torques) and "Fig. 12" (the paper's zoom on each constraint
sample, one plot per profile, loop and sample, with axes). Legends are hidden: with one series
per run they would cover the data; the view titles say what is drawn. Playback starts on open,
at PLAYBACK_SPEED, looping.

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
from control.figures import predicted_band
from control.ocp_file import OCPFile
from replay.campaign import Campaign

APPLICATION_ID = "crank_replay"
COLORS = {
    "nominal": (31, 119, 180),
    "robust": (214, 39, 40),
    "robust-fb": (44, 160, 44),
    "robust-pd": (148, 103, 189),
}
REFERENCE = (235, 235, 235)
"""The plan and the band: light grey on the dark theme."""
HEIGHT = (255, 200, 0)
"""The constraint: amber."""
BAND_LINES = 21
SPACING = 0.12
"""x distance between two mechanisms in the 3D view, m."""
PLAYBACK_SPEED = 0.1
"""A 0.3 s manoeuvre then takes 3 s to watch."""
ZOOM_SAMPLES = 12
"""Fig. 12 tab: samples shown either side of a constraint sample."""
ZOOM_BELOW = 5e-3
"""Fig. 12 tab: the y-axis starts this far below the height, m."""


def _timelines(n: int, dt: float, *, at: np.ndarray | None = None) -> list[rr.TimeColumn]:
    k = np.arange(n) if at is None else np.asarray(at)
    return [rr.TimeColumn("sample", sequence=k + 1), rr.TimeColumn("time", duration=k * dt)]


def _loop(profile: str, mode: str) -> str:
    return f"{profile}/{mode}"


def _label(profile: str, mode: str) -> str:
    return f"{profile}, {mode} loop"


def _mechanism(rec: rr.RecordingStream, campaign: Campaign, ocp: OCPFile) -> None:
    n, dt = ocp.horizon, ocp.dt
    l1, l2 = ocp.geometry.crank_length, ocp.geometry.rod_length
    loops = list(campaign.replays)
    for i, (profile, mode) in enumerate(loops):
        replay = campaign.replays[profile, mode]
        x0 = SPACING * (i - (len(loops) - 1) / 2)
        angle = replay.crank_angle[0]
        pin = np.stack([x0 + l1 * np.sin(angle), 0 * angle, l1 * np.cos(angle)])
        slider_z = replay.slider_position[0] + l2 - l1
        tip = np.stack([np.full(n, x0), 0 * angle, slider_z])
        axis = np.tile([[x0], [0.0], [0.0]], (1, n))
        strips = np.stack([axis.T, pin.T, tip.T], axis=1)  # (n, 3 points, xyz)
        path = f"/mechanism/{_loop(profile, mode)}"
        rec.log(f"{path}/linkage", rr.LineStrips3D.from_fields(colors=[REFERENCE]), static=True)
        rec.send_columns(
            f"{path}/linkage",
            indexes=_timelines(n, dt),
            columns=rr.LineStrips3D.columns(strips=list(strips)).partition([1] * n),
        )
        rec.log(
            f"{path}/slider",
            rr.Boxes3D.from_fields(colors=[COLORS[profile]], fill_mode="solid"),
            static=True,
        )
        rec.send_columns(
            f"{path}/slider",
            indexes=_timelines(n, dt),
            columns=rr.Boxes3D.columns(
                centers=tip.T, half_sizes=np.tile([0.025, 0.02, 0.012], (n, 1))
            ),
        )
        rec.log(
            f"{path}/guide",
            rr.Boxes3D(
                centers=[[x0, 0, l2]],  # the stroke's middle
                half_sizes=[[0.03, 0.001, l1 + 0.025]],
                colors=[(*COLORS[profile], 60)],
            ),
            static=True,
        )
    z = ocp.config.height + l2 - l1
    half = SPACING * len(loops) / 2
    rec.log(
        "/mechanism/constraint",
        rr.LineStrips3D(
            [[[-half, 0, z], [half, 0, z]]], colors=[HEIGHT], radii=[0.001], labels=["height"]
        ),
        static=True,
    )


def _lines(
    rec: rr.RecordingStream,
    path: str,
    values: np.ndarray,
    *,
    n: int,
    dt: float,
    colors: list[tuple[int, ...]],
    widths: list[float],
    names: list[str],
) -> None:
    """Series (one per row of `values`, (series, n)) under one entity."""
    rec.log(path, rr.SeriesLines(colors=colors, widths=widths, names=names), static=True)
    rec.send_columns(
        path,
        indexes=_timelines(n, dt),
        columns=rr.Scalars.columns(scalars=values.T.ravel()).partition([len(values)] * n),
    )


def band_lines(lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """The band between two bounds (N,) as BAND_LINES series (BAND_LINES, N) spread evenly from
    the lower to the upper one."""
    return lower + np.linspace(0.0, 1.0, BAND_LINES)[:, None] * (upper - lower)


def _series(rec: rr.RecordingStream, campaign: Campaign, ocp: OCPFile) -> None:
    n, dt = ocp.horizon, ocp.dt
    c = ocp.config
    at = np.array(c.constraint_samples) - 1
    for (profile, mode), replay in campaign.replays.items():
        runs, loop = replay.runs, _loop(profile, mode)
        run_style = {
            "colors": [(*COLORS[profile], 110)] * runs,
            "widths": [1.0] * runs,
            "names": [f"run {i:03d}" for i in range(runs)],
        }
        _lines(rec, f"/slider/{loop}/runs", replay.slider_position, n=n, dt=dt, **run_style)
        _lines(rec, f"/torque/{loop}/runs", replay.tau, n=n, dt=dt, **run_style)
        planned = ocp.profiles[profile]
        if replay.predicted_sigma is not None:  # the PPANN's spread under the law played
            band = predicted_band(planned, replay.predicted_sigma, c.k_sigma, geometry=ocp.geometry)
            _lines(
                rec,
                f"/slider/{loop}/band",
                band_lines(*band),
                n=n,
                dt=dt,
                colors=[(*REFERENCE, 45)] * BAND_LINES,
                widths=[3.0] * BAND_LINES,
                names=[f"PPANN ∓{c.k_sigma:g}σ"] * BAND_LINES,
            )
        _lines(
            rec,
            f"/slider/{loop}/planned",
            planned.slider[None],
            n=n,
            dt=dt,
            colors=[REFERENCE],
            widths=[2.0],
            names=["plan"],
        )
        path = f"/slider/{loop}/constraint"
        rec.log(
            path,
            rr.SeriesPoints(colors=[HEIGHT], markers=["down"], marker_sizes=[8], names=["height"]),
            static=True,
        )
        rec.send_columns(
            path,
            indexes=_timelines(n, dt, at=at),
            columns=rr.Scalars.columns(scalars=np.full(len(at), c.height)),
        )
    for profile in dict.fromkeys(p for p, _ in campaign.replays):
        tau = ocp.profiles[profile].tau[None]
        _lines(
            rec,
            f"/torque/{profile}/planned",
            tau,
            n=n,
            dt=dt,
            colors=[REFERENCE],
            widths=[2.0],
            names=["planned"],
        )


def blueprint(campaign: Campaign, ocp: OCPFile) -> rrb.Blueprint:
    """The "replay" and "Fig. 12" tabs of the module docstring."""
    c = ocp.config
    top = ocp.geometry.stroke_top
    loops = list(campaign.replays)
    profiles = list(dict.fromkeys(p for p, _ in loops))
    hidden = rrb.PlotLegend(visible=False)
    slider_views = [
        rrb.TimeSeriesView(
            origin=f"/slider/{_loop(p, m)}",
            name=f"slider [m], {_label(p, m)}: runs, plan ∓{c.k_sigma:g}σ, height",
            axis_y=rrb.ScalarAxis(range=(0.0, top + 0.005)),
            plot_legend=hidden,
        )
        for p, m in loops
    ]
    torque_views = [
        rrb.TimeSeriesView(
            origin="/torque",
            contents=f"/torque/{p}/**",
            name=f"torque [N·m], {p}: plan, applied per run",
            plot_legend=hidden,
        )
        for p in profiles
    ]
    zoom = []
    for p, m in loops:
        for k in c.constraint_samples:
            # the time timeline (the one the time panel shows), in seconds
            first, last = max(1, k - ZOOM_SAMPLES), min(ocp.horizon, k + ZOOM_SAMPLES)
            window = rr.encodings.TimeRange(
                start=rrb.TimeRangeBoundary.absolute(seconds=(first - 1) * ocp.dt),
                end=rrb.TimeRangeBoundary.absolute(seconds=(last - 1) * ocp.dt),
            )
            zoom.append(
                rrb.TimeSeriesView(
                    origin=f"/slider/{_loop(p, m)}",
                    name=f"{_label(p, m)}, sample {k} [m]",
                    axis_x=rrb.TimeAxis(view_range=window),
                    axis_y=rrb.ScalarAxis(range=(c.height - ZOOM_BELOW, top + 0.002)),
                    plot_legend=hidden,
                )
            )
    middle = ocp.geometry.rod_length - ocp.geometry.crank_length / 2
    return rrb.Blueprint(
        rrb.Tabs(
            rrb.Horizontal(
                rrb.Spatial3DView(
                    origin="/mechanism",
                    name="run 0, left to right: " + ", ".join(f"{p} {m}" for p, m in loops),
                    eye_controls=rrb.EyeControls3D(
                        position=(0.0, -1.4, middle),
                        look_target=(0.0, 0.0, middle),
                        eye_up=(0.0, 0.0, 1.0),
                    ),
                ),
                rrb.Grid(*slider_views, *torque_views, grid_columns=2),
                column_shares=[2, 3],
                name="replay",
            ),
            rrb.Grid(*zoom, grid_columns=len(c.constraint_samples), name="Fig. 12"),
        ),
        rrb.TimePanel(
            timeline="time", playback_speed=PLAYBACK_SPEED, loop_mode="all", play_state="playing"
        ),
        collapse_panels=False,
    )


def write_recording(
    path: str | Path, campaign: Campaign, ocp: OCPFile, *, recording_id: str
) -> None:
    """Write the campaign's `.rrd` atomically."""
    with atomic_path(path) as tmp:
        rec = rr.RecordingStream(APPLICATION_ID, recording_id=recording_id)
        rec.save(tmp, default_blueprint=blueprint(campaign, ocp))
        _mechanism(rec, campaign, ocp)
        _series(rec, campaign, ocp)
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
