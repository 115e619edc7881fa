"""The campaign log's Foxglove channels: frames that put crank, rod and slider where MuJoCo has
them, a plan channel equal to ocp.json's plan and band, and a shipped layout that names only
topics and fields the log has."""

from __future__ import annotations

import json
import re
from pathlib import Path

import mujoco
import numpy as np
import pytest
from mcap.reader import make_reader

from control.figures import predicted_band
from control.ocp_file import OCPFile
from replay.foxglove import (
    CHANNELS,
    FOXGLOVE_LAYOUT,
    PLAN_TOPIC,
    SCENE_TOPIC,
    TF_TOPIC,
    frame_transforms,
)
from tests.replay_ocp import N
from twin.physics import SliderCrank


def _rotate_y(q: dict[str, float], v: np.ndarray) -> np.ndarray:
    angle = 2 * np.arctan2(q["y"], q["w"])
    c, s = np.cos(angle), np.sin(angle)
    return np.array([c * v[0] + s * v[2], v[1], -s * v[0] + c * v[2]])


def _vec(d: dict[str, float]) -> np.ndarray:
    return np.array([d["x"], d["y"], d["z"]])


def test_frames_put_the_bodies_where_mujoco_has_them(physics: SliderCrank) -> None:
    """Crank pin, rod tip and slider pin from the transforms equal MuJoCo's sites (x, z; the
    links sit at different y in the MJCF, the frames in the plane y = 0)."""
    model = physics.model
    data = mujoco.MjData(model)
    thetas = np.linspace(-np.pi, 3 * np.pi, 23)
    sites: dict[str, list[np.ndarray]] = {"crank_pin": [], "rod_tip": [], "slider_pin": []}
    angle, slider = [], []
    for theta in thetas:
        state = physics.initial_state(theta)
        mujoco.mj_setState(model, data, state, mujoco.mjtState.mjSTATE_FULLPHYSICS)
        mujoco.mj_forward(model, data)
        for name in sites:
            sites[name].append(data.site(name).xpos.copy())
        angle.append(data.joint("motor").qpos[0] + data.joint("backlash").qpos[0])
        slider.append(data.joint("slider").qpos[0])
    messages = frame_transforms(
        np.arange(len(thetas)) * 2e-3,
        np.array(angle),
        np.array(slider),
        geometry=physics.geometry,
    )
    l1, l2 = physics.geometry.crank_length, physics.geometry.rod_length
    for k, message in enumerate(messages):
        frames = {f["child_frame_id"]: f for f in message["transforms"]}
        assert {f["parent_frame_id"] for f in frames.values()} == {"world"}
        for f in frames.values():
            q = f["rotation"]
            assert np.hypot(np.hypot(q["x"], q["y"]), np.hypot(q["z"], q["w"])) == pytest.approx(1)
        crank_pin = _rotate_y(frames["crank"]["rotation"], np.array([0, 0, l1]))
        rod_tip = _vec(frames["rod"]["translation"]) + _rotate_y(
            frames["rod"]["rotation"], np.array([0, 0, l2])
        )
        slider_pin = _vec(frames["slider"]["translation"])
        for name, got in (
            ("crank_pin", crank_pin),
            ("rod_tip", rod_tip),
            ("slider_pin", slider_pin),
        ):
            np.testing.assert_allclose(got[[0, 2]], sites[name][k][[0, 2]], atol=1e-9, err_msg=name)


def test_campaign_log_carries_the_mechanism_and_the_plan(
    ocp: OCPFile,
    campaign_files: dict[str, Path],
) -> None:
    with open(campaign_files["mcap"], "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        channels = {c.topic: summary.schemas[c.schema_id].name for c in summary.channels.values()}
        assert {t: channels[t] for t in CHANNELS} == CHANNELS
        counts = summary.statistics.channel_message_counts
        by_topic = {c.topic: counts[i] for i, c in summary.channels.items()}
        plans = [json.loads(m.data) for _, _, m in reader.iter_messages(topics=[PLAN_TOPIC])]
    runs = 4 * 6  # 2 profiles x 2 modes x 6 machines
    assert by_topic[TF_TOPIC] == runs * N and by_topic[PLAN_TOPIC] == runs * N
    assert by_topic[SCENE_TOPIC] == runs
    robust_closed = [p for p in plans if p["profile"] == "robust" and p["mode"] == "closed"]
    first = [p for p in robust_closed if p["run"] == 0]
    robust = ocp.profiles["robust"]  # closed under its own gains: the file's closed spread
    lower, upper = predicted_band(
        robust, robust.sigma_in("closed"), ocp.config.k_sigma, geometry=ocp.geometry
    )
    np.testing.assert_array_equal([p["planned"] for p in first], ocp.profiles["robust"].slider)
    np.testing.assert_array_equal([p["lower"] for p in first], lower)
    np.testing.assert_array_equal([p["upper"] for p in first], upper)
    assert [p["sample"] for p in first] == list(range(1, N + 1))
    assert {p["height"] for p in plans} == {ocp.config.height}
    with open(campaign_files["mcap"], "rb") as f:
        scene = json.loads(next(make_reader(f).iter_messages(topics=[SCENE_TOPIC]))[2].data)
    required = {"timestamp", "frame_id", "id", "lifetime", "frame_locked", "metadata", "arrows"}
    required |= {"cubes", "spheres", "cylinders", "lines", "triangles", "texts", "models"}
    assert all(set(e) == required for e in scene["entities"])  # Foxglove's SceneEntity, whole


def test_the_shipped_layout_names_only_what_the_log_has(
    campaign_files: dict[str, Path],
) -> None:
    layout = json.loads(FOXGLOVE_LAYOUT.read_text())
    with open(campaign_files["mcap"], "rb") as f:
        summary = make_reader(f).get_summary()
    fields = {
        c.topic: set(json.loads(summary.schemas[c.schema_id].data)["properties"])
        for c in summary.channels.values()
    }
    paths = [
        p["value"] for config in layout["configById"].values() for p in config.get("paths", [])
    ]
    assert len(paths) == 9  # the runs of each profile, the plan, its band, the height
    for value in paths:  # /topic{field=="value"}.field
        topic, filters, field = re.fullmatch(r"(/[\w/]+)((?:\{[^}]*\})*)\.(\w+)", value).groups()
        assert field in fields[topic], value
        for name in re.findall(r"\{(\w+)==", filters):
            assert name in fields[topic], value
    panels = set(layout["configById"])

    def leaves(node: object) -> set[str]:
        if isinstance(node, str):
            return {node}
        return leaves(node["first"]) | leaves(node["second"])

    assert leaves(layout["layout"]) == panels
    shown = layout["configById"]["3D!mechanism"]["topics"]
    assert set(shown) == {SCENE_TOPIC, TF_TOPIC}
