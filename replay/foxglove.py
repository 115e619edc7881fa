"""What a campaign log carries for Foxglove beside the dataset channels: the mechanism for the 3D
panel, the plan and its band for the Plot panel, and the layout that shows them (FOXGLOVE_LAYOUT,
shipped with the package).

  /slider_crank/tf     foxglove.FrameTransforms, one per sample: frames crank, rod and slider in
                       `world` (the MJCF's: motor axis y, z up, the crank up at theta = 0), from the
                       run's crank angle (motor + backlash) and slider position.
  /slider_crank/scene  foxglove.SceneUpdate, once per run: crank, rod and slider as boxes locked to
                       their frames, the slide, and the constraint height as a red plate.
  /slider_crank/plan   slider_crank.Plan, one per sample: the profile's planned slider position,
                       the PPANN's band (plan ∓ kσ under the law the run played, within the
                       stroke; absent where it has no prediction, replay/laws.py) and the
                       height, tagged like the measurement (run, profile, mode, sample).

Foxglove picks its schemas by name ("foxglove.FrameTransforms" with JSON encoding and a JSON
schema); the schemas written here are the subset of Foxglove's that the messages use.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from control.figures import predicted_band
from control.ocp_file import OCPFile
from twin.geometry import Geometry

TF_TOPIC = "/slider_crank/tf"
SCENE_TOPIC = "/slider_crank/scene"
PLAN_TOPIC = "/slider_crank/plan"
FOXGLOVE_LAYOUT = Path(__file__).with_name("foxglove_layout.json")

_NUMBER = {"type": "number"}
_VECTOR = {"type": "object", "properties": {k: _NUMBER for k in "xyz"}}
_QUATERNION = {"type": "object", "properties": {k: _NUMBER for k in "xyzw"}}
_TIME = {
    "type": "object",
    "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}},
}
_POSE = {"type": "object", "properties": {"position": _VECTOR, "orientation": _QUATERNION}}
_COLOR = {"type": "object", "properties": {k: _NUMBER for k in "rgba"}}
SCHEMAS: dict[str, dict[str, Any]] = {
    "foxglove.FrameTransforms": {
        "type": "object",
        "properties": {
            "transforms": {
                "type": "array",
                "items": {
                    "title": "foxglove.FrameTransform",
                    "type": "object",
                    "properties": {
                        "timestamp": _TIME,
                        "parent_frame_id": {"type": "string"},
                        "child_frame_id": {"type": "string"},
                        "translation": _VECTOR,
                        "rotation": _QUATERNION,
                    },
                },
            }
        },
    },
    "foxglove.SceneUpdate": {
        "type": "object",
        "properties": {
            "deletions": {"type": "array", "items": {"type": "object"}},
            "entities": {
                "type": "array",
                "items": {
                    "title": "foxglove.SceneEntity",
                    "type": "object",
                    "properties": {
                        "timestamp": _TIME,
                        "frame_id": {"type": "string"},
                        "id": {"type": "string"},
                        "lifetime": _TIME,
                        "frame_locked": {"type": "boolean"},
                        "cubes": {
                            "type": "array",
                            "items": {
                                "title": "foxglove.CubePrimitive",
                                "type": "object",
                                "properties": {"pose": _POSE, "size": _VECTOR, "color": _COLOR},
                            },
                        },
                    },
                },
            },
        },
    },
    "slider_crank.Plan": {
        "type": "object",
        "properties": {
            **{k: {"type": "integer"} for k in ("episode", "run", "sample")},
            **{k: {"type": "string"} for k in ("profile", "mode")},
            "t": {"type": "number", "description": "time of the log, s"},
            "planned": {"type": "number", "description": "planned slider position, m"},
            "lower": {
                "type": "number",
                "description": "plan - k sigma of the PPANN under the law played (absent: none)",
            },
            "upper": {"type": "number", "description": "plan + k sigma, m"},
            "height": {"type": "number", "description": "the constraint's height, m"},
        },
    },
}
CHANNELS = {
    TF_TOPIC: "foxglove.FrameTransforms",
    SCENE_TOPIC: "foxglove.SceneUpdate",
    PLAN_TOPIC: "slider_crank.Plan",
}
"""Topic -> schema name."""


def schema_bytes(name: str) -> bytes:
    return json.dumps({"title": name, **SCHEMAS[name]}).encode()


UNUSED_PRIMITIVES = ("arrows", "spheres", "cylinders", "lines", "triangles", "texts", "models")
"""SceneEntity fields Foxglove's schema requires, empty here (the bodies are cubes)."""


def slide_base(geometry: Geometry) -> float:
    """World z of the slider pin at position 0 (bottom dead centre: l2 - l1 above the axis)."""
    return geometry.rod_length - geometry.crank_length


def _stamp(t: float) -> dict[str, int]:
    ns = round(t * 1e9)
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def _about_y(angle: np.ndarray) -> list[dict[str, float]]:
    half = 0.5 * np.asarray(angle)
    return [
        {"x": 0.0, "y": s, "z": 0.0, "w": c}
        for s, c in zip(np.sin(half).tolist(), np.cos(half).tolist(), strict=True)
    ]


def frame_transforms(
    times: np.ndarray, crank_angle: np.ndarray, slider_position: np.ndarray, *, geometry: Geometry
) -> list[dict[str, Any]]:
    """One foxglove.FrameTransforms message per sample: crank, rod and slider in `world`."""
    l1 = geometry.crank_length
    pin_x, pin_z = l1 * np.sin(crank_angle), l1 * np.cos(crank_angle)
    slider_z = slide_base(geometry) + slider_position
    rod = np.arctan2(-pin_x, slider_z - pin_z)  # about y: the rod's +z towards the slider pin
    messages = []
    crank_q, rod_q = _about_y(crank_angle), _about_y(rod)
    rows = zip(times.tolist(), pin_x.tolist(), pin_z.tolist(), slider_z.tolist(), strict=True)
    for k, (t, px, pz, sz) in enumerate(rows):
        stamp = _stamp(t)
        origin = {"x": 0.0, "y": 0.0, "z": 0.0}
        frames = (
            ("crank", origin, crank_q[k]),
            ("rod", {"x": px, "y": 0.0, "z": pz}, rod_q[k]),
            ("slider", {"x": 0.0, "y": 0.0, "z": sz}, {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}),
        )
        messages.append(
            {
                "transforms": [
                    {
                        "timestamp": stamp,
                        "parent_frame_id": "world",
                        "child_frame_id": child,
                        "translation": translation,
                        "rotation": rotation,
                    }
                    for child, translation, rotation in frames
                ]
            }
        )
    return messages


def _cube(
    center: tuple[float, float, float], size: tuple[float, float, float], rgba: tuple
) -> dict[str, Any]:
    return {
        "pose": {
            "position": dict(zip("xyz", center, strict=True)),
            "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0},
        },
        "size": dict(zip("xyz", size, strict=True)),
        "color": dict(zip("rgba", rgba, strict=True)),
    }


BODY_COLORS = {
    "nominal": (0.3, 0.6, 0.9, 1.0),
    "robust": (0.85, 0.6, 0.2, 1.0),
    "robust-fb": (0.3, 0.75, 0.35, 1.0),
    "robust-pd": (0.6, 0.45, 0.8, 1.0),
}
"""The mechanism's colour per profile, RGBA."""


def scene_update(t: float, *, geometry: Geometry, height: float, profile: str) -> dict[str, Any]:
    """The mechanism's bodies, locked to their frames, and the constraint height."""
    l1, l2 = geometry.crank_length, geometry.rod_length
    base = slide_base(geometry)
    body = BODY_COLORS.get(profile, BODY_COLORS["nominal"])
    parts = {
        "crank": ("crank", [_cube((0, 0, l1 / 2), (0.012, 0.012, l1), body)]),
        "rod": ("rod", [_cube((0, 0, l2 / 2), (0.008, 0.008, l2), body)]),
        "slider": ("slider", [_cube((0, 0, 0), (0.06, 0.04, 0.04), (0.7, 0.7, 0.7, 1.0))]),
        "slide": (
            "world",
            [_cube((0.04, 0, base + l1), (0.005, 0.005, 2 * l1 + 0.06), (0.5, 0.5, 0.5, 0.6))],
        ),
        "height": (
            "world",
            [_cube((0, 0, base + height), (0.12, 0.06, 0.0015), (1.0, 0.2, 0.2, 0.5))],
        ),
    }
    return {
        "deletions": [],
        "entities": [
            {
                "timestamp": _stamp(t),
                "frame_id": frame,
                "id": name,
                "lifetime": {"sec": 0, "nsec": 0},
                "frame_locked": True,
                "metadata": [],
                "cubes": cubes,
                **{kind: [] for kind in UNUSED_PRIMITIVES},
            }
            for name, (frame, cubes) in parts.items()
        ],
    }


def plan_rows(ocp: OCPFile, profile: str, sigma: np.ndarray | None) -> list[dict[str, float]]:
    """Per sample: the planned slider, the PPANN's band ∓ k `sigma` under the law the run
    played (none without `sigma`: replay/laws.py predicted_sigma) and the height."""
    planned = ocp.profiles[profile]
    height = ocp.config.height
    if sigma is None:
        return [{"planned": p, "height": height} for p in planned.slider.tolist()]
    lower, upper = predicted_band(planned, sigma, ocp.config.k_sigma, geometry=ocp.geometry)
    return [
        {"planned": p, "lower": lo, "upper": up, "height": height}
        for p, lo, up in zip(planned.slider.tolist(), lower.tolist(), upper.tolist(), strict=True)
    ]
