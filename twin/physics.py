"""The slider-crank's MuJoCo model and its named physics accessors.

Everything that knows where a quantity lives in MuJoCo's arrays (qpos addresses, sensor slices,
actuator ids, the layout of a full-physics state vector) is resolved here, by name, once. The rest
of the project asks for `theta`, `slider_position` or `backlash_angle`, never for `qpos[3]`.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from common.errors import CrankError
from twin import MODEL_PATH
from twin.geometry import Geometry

SAMPLE_RATE = 500.0
"""Measurement rate in Hz; one sample every 2 ms (paper section 3.2)."""

STATE_SPEC = mujoco.mjtState.mjSTATE_FULLPHYSICS
CONTROL_SPEC = mujoco.mjtState.mjSTATE_CTRL

# Sensors the twin reads, in the order the MJCF declares them.
SENSOR_NAMES = (
    "theta",
    "omega",
    "slider_position",
    "backlash_angle",
    "rod_tip_position",
    "slider_pin_position",
)
JOINT_NAMES = ("motor", "backlash", "rod_pivot", "slider")
ACTUATOR_NAMES = ("motor_torque", "slider_disturbance")


class ModelError(CrankError, ValueError):
    """The MJCF cannot be read, does not compile, or lacks an element the twin needs."""


class MJCFNotFoundError(ModelError):
    """No file at the MJCF's path."""


def load_model(path: str | Path | None = None) -> tuple[mujoco.MjModel, str]:
    """Compile the slider-crank MJCF at `path` (default: models/slider_crank.xml).

    Returns:
      The compiled model and the MJCF text MuJoCo writes back for it (`MjSpec.to_xml`), which is
      what a dataset attaches as `model.xml`.

    Raises:
      ModelError: the file is missing or unreadable, is not valid MJCF, or lacks a named element.
    """
    path = Path(path) if path is not None else MODEL_PATH
    try:
        xml = path.read_text()
    except FileNotFoundError:
        raise MJCFNotFoundError(f"MJCF not found: {path}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ModelError(f"cannot read MJCF {path}: {exc}") from None
    return compile_mjcf(xml, source=str(path))


def compile_mjcf(xml: str, *, source: str) -> tuple[mujoco.MjModel, str]:
    """Compile MJCF text (from `source`, named in errors); return the model and its XML.

    Raises:
      ModelError: the text is not valid MJCF or lacks a named element.
    """
    try:
        spec = mujoco.MjSpec.from_string(xml)
        model = spec.compile()
    except ValueError as exc:
        reason = " ".join(str(exc).split())
        raise ModelError(f"invalid MJCF {source}: {reason}") from None
    Layout.of(model)  # Fails early, naming the missing element.
    return model, spec.to_xml()


def model_sha256(path: str | Path | None = None) -> str:
    """sha256 of the MJCF file's bytes (the source, not the compiled model)."""
    path = Path(path) if path is not None else MODEL_PATH
    return hashlib.sha256(path.read_bytes()).hexdigest()


@dataclass(frozen=True)
class Layout:
    """Addresses of the twin's named elements in one compiled model."""

    qpos: dict[str, int]
    dof: dict[str, int]
    joint: dict[str, int]
    actuator: dict[str, int]
    sensor: dict[str, slice]
    nstate: int
    state_qpos: slice
    state_qvel: slice

    @classmethod
    def of(cls, model: mujoco.MjModel) -> Layout:
        def find(kind: mujoco.mjtObj, name: str, what: str) -> int:
            index = mujoco.mj_name2id(model, kind, name)
            if index < 0:
                raise ModelError(f"the MJCF has no {what} named {name!r}")
            return index

        joints = {n: find(mujoco.mjtObj.mjOBJ_JOINT, n, "joint") for n in JOINT_NAMES}
        actuators = {n: find(mujoco.mjtObj.mjOBJ_ACTUATOR, n, "actuator") for n in ACTUATOR_NAMES}
        sensors = {}
        for name in SENSOR_NAMES:
            i = find(mujoco.mjtObj.mjOBJ_SENSOR, name, "sensor")
            adr, dim = int(model.sensor_adr[i]), int(model.sensor_dim[i])
            sensors[name] = slice(adr, adr + dim)
        # A full-physics state is [time, qpos, qvel, act, ...] (mj_getState documentation).
        nstate = mujoco.mj_stateSize(model, STATE_SPEC)
        return cls(
            qpos={n: int(model.jnt_qposadr[j]) for n, j in joints.items()},
            dof={n: int(model.jnt_dofadr[j]) for n, j in joints.items()},
            joint=joints,
            actuator=actuators,
            sensor=sensors,
            nstate=nstate,
            state_qpos=slice(1, 1 + model.nq),
            state_qvel=slice(1 + model.nq, 1 + model.nq + model.nv),
        )


class SliderCrank:
    """A compiled slider-crank model with named accessors.

    Args:
      model: a compiled model; `load_model()` if omitted.
    """

    def __init__(self, model: mujoco.MjModel | None = None) -> None:
        self.model = model if model is not None else load_model()[0]
        self.layout = Layout.of(self.model)
        self.geometry = Geometry.of_model(self.model)
        """Crank and rod lengths, read from the model's named elements (twin/geometry.py)."""
        steps = 1.0 / (SAMPLE_RATE * self.model.opt.timestep)
        if abs(steps - round(steps)) > 1e-9 or round(steps) < 1:
            raise ModelError(
                f"physics timestep {self.model.opt.timestep} s does not divide the "
                f"{1 / SAMPLE_RATE} s sample period into whole substeps"
            )
        self.substeps = round(steps)

    @property
    def torque_limit(self) -> float:
        """Largest motor torque magnitude in N·m (the actuator's ctrlrange)."""
        low, high = self.model.actuator_ctrlrange[self.layout.actuator["motor_torque"]]
        return float(min(-low, high))

    @property
    def nominal_backlash_width(self) -> float:
        """Width of the backlash gap in rad, from the `backlash` joint's range."""
        low, high = self.model.jnt_range[self.layout.joint["backlash"]]
        return float(high - low)

    def initial_state(self, theta: float, omega: float = 0.0) -> np.ndarray:
        """Full-physics state (nstate,) with the loop closed at motor angle `theta`, backlash 0.

        The rod and slider are placed by the model's kinematics (`geometry`); the motor, crank
        and rod turn together at `omega` and the slider moves at dx/dtheta * omega.
        """
        layout = self.layout
        data = mujoco.MjData(self.model)
        l1, l2 = self.geometry.crank_length, self.geometry.rod_length
        phi = float(self.geometry.rod_angle(theta))
        # The rod's absolute angle is -phi; its pivot angle is relative to the crank.
        data.qpos[layout.qpos["motor"]] = theta
        data.qpos[layout.qpos["backlash"]] = 0.0
        data.qpos[layout.qpos["rod_pivot"]] = -phi - theta
        data.qpos[layout.qpos["slider"]] = float(self.geometry.slider_position(theta))
        dphi = l1 * np.cos(theta) / (l2 * np.cos(phi))
        dx = -l1 * np.sin(theta) - l2 * np.sin(phi) * dphi
        data.qvel[layout.dof["motor"]] = omega
        data.qvel[layout.dof["rod_pivot"]] = -(dphi + 1.0) * omega
        data.qvel[layout.dof["slider"]] = dx * omega
        state = np.empty(layout.nstate)
        mujoco.mj_getState(self.model, data, state, STATE_SPEC)
        return state

    def sensor(self, sensordata: np.ndarray, name: str) -> np.ndarray:
        """The sensor `name` from sensordata of shape (..., nsensordata): (...,) or (..., dim)."""
        values = sensordata[..., self.layout.sensor[name]]
        return values[..., 0] if values.shape[-1] == 1 else values

    def loop_closure_error(self, sensordata: np.ndarray) -> np.ndarray:
        """Distance in m between the rod's tip and the slider's pin, shape (...,)."""
        gap = self.sensor(sensordata, "rod_tip_position") - self.sensor(
            sensordata, "slider_pin_position"
        )
        return np.linalg.norm(gap, axis=-1)

    def qpos(self, state: np.ndarray, joint: str) -> np.ndarray:
        """Joint position of `joint` from full-physics states of shape (..., nstate)."""
        return state[..., self.layout.state_qpos][..., self.layout.qpos[joint]]

    def qvel(self, state: np.ndarray, joint: str) -> np.ndarray:
        """Joint velocity of `joint` from full-physics states of shape (..., nstate)."""
        return state[..., self.layout.state_qvel][..., self.layout.dof[joint]]
