"""The MJCF: names, nominal parameters, and the order of magnitude of the motor-side dynamics."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from twin.dataset import GenerationConfig, generate
from twin.geometry import PAPER, Geometry
from twin.physics import MODEL_PATH, ModelError, SliderCrank, load_model
from twin.variability import Variability

NAMED = {
    "body": mujoco.mjtObj.mjOBJ_BODY,
    "joint": mujoco.mjtObj.mjOBJ_JOINT,
    "geom": mujoco.mjtObj.mjOBJ_GEOM,
    "site": mujoco.mjtObj.mjOBJ_SITE,
    "actuator": mujoco.mjtObj.mjOBJ_ACTUATOR,
    "sensor": mujoco.mjtObj.mjOBJ_SENSOR,
    "equality": mujoco.mjtObj.mjOBJ_EQUALITY,
    "light": mujoco.mjtObj.mjOBJ_LIGHT,
}


@pytest.mark.parametrize("kind", NAMED)
def test_every_element_is_named(physics: SliderCrank, kind: str) -> None:
    model = physics.model
    count = {
        "body": model.nbody,
        "joint": model.njnt,
        "geom": model.ngeom,
        "site": model.nsite,
        "actuator": model.nu,
        "sensor": model.nsensor,
        "equality": model.neq,
        "light": model.nlight,
    }[kind]
    first = 1 if kind == "body" else 0  # Body 0 is the world.
    for i in range(first, count):
        assert mujoco.mj_id2name(model, NAMED[kind], i), f"{kind} {i} has no name"


def test_geometry_matches_the_paper(physics: SliderCrank) -> None:
    """Read from the MJCF's named elements: l1 = 0.05 m, l2 = 0.3 m (paper section 3.1)."""
    model = physics.model
    assert physics.geometry == Geometry.of_model(model) == PAPER
    assert (PAPER.crank_length, PAPER.rod_length) == (0.05, 0.3)
    assert model.body("rod").pos[2] == pytest.approx(PAPER.crank_length)
    assert model.site("rod_tip").pos[2] == pytest.approx(PAPER.rod_length)
    # Slider joint ref makes its qpos the paper's slider position: 0.1 m at top dead centre.
    assert model.qpos0[physics.layout.qpos["slider"]] == pytest.approx(0.1)
    assert PAPER.slider_position(0.0) == pytest.approx(0.1)
    assert PAPER.slider_position(np.pi) == pytest.approx(0.0, abs=1e-15)


def test_collisions_off_and_warmstart_off(physics: SliderCrank) -> None:
    model = physics.model
    assert np.all(model.geom_contype == 0) and np.all(model.geom_conaffinity == 0)
    assert model.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_CONTACT
    assert model.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_WARMSTART


def test_several_substeps_per_sample(physics: SliderCrank) -> None:
    assert physics.substeps == 32
    assert physics.substeps * physics.model.opt.timestep == pytest.approx(0.002)


def test_nominal_variability_is_the_mjcf(physics: SliderCrank) -> None:
    nominal = Variability().nominal()
    model, dof = physics.model, physics.layout.dof
    assert model.dof_frictionloss[dof["motor"]] == pytest.approx(nominal.motor_frictionloss)
    assert model.dof_damping[dof["motor"]] == pytest.approx(nominal.motor_damping)
    assert model.dof_frictionloss[dof["slider"]] == pytest.approx(nominal.slider_frictionloss)
    assert model.dof_damping[dof["slider"]] == pytest.approx(nominal.slider_damping)
    assert physics.nominal_backlash_width == pytest.approx(nominal.backlash_width)


def test_motor_dynamics_recover_the_mjcf_parameters(physics: SliderCrank) -> None:
    """Least squares on simulated data with the rigid slider-crank's equation of motion,

    tau = J0 a + m x'(x' a + x'' w^2) + m g x' + B w + c x'^2 w + Fc sign(w),

    recovers the MJCF's rotor inertia, slider mass and damping; J(theta) = J0 + m x'^2 averages
    the paper's J_m = 3e-3 and varies strongly with theta (position-dependent inertia).
    """
    config = GenerationConfig(seconds=30, variability=Variability.none(backlash_width=0.0))
    data, _, _ = generate(config, physics=physics)
    dt = 0.002
    same = data.episode[2:] == data.episode[:-2]
    alpha = ((data.omega[2:] - data.omega[:-2]) / (2 * dt))[same]
    omega, tau, theta = (v[1:-1][same] for v in (data.omega, data.tau, data.theta))
    h = 1e-5
    x1 = (PAPER.slider_position(theta + h) - PAPER.slider_position(theta - h)) / (2 * h)
    x2 = (
        PAPER.slider_position(theta + h)
        - 2 * PAPER.slider_position(theta)
        + PAPER.slider_position(theta - h)
    ) / h**2
    columns = [
        alpha,
        x1 * (x1 * alpha + x2 * omega**2),
        9.81 * x1,
        omega,
        x1**2 * omega,
        np.sign(omega),
    ]
    (j0, mass, _, b_motor, c_slider, _), *_ = np.linalg.lstsq(np.stack(columns, 1), tau)
    model = physics.model
    crank = model.dof_armature[physics.layout.dof["motor"]] + model.body("crank").inertia[1]
    assert crank < j0 < crank + 0.5e-3  # rotor and crank disc, + hub, crank arm, part of the rod
    assert 0.8 < mass < 0.8 + 0.1 + 0.05  # slider + at most the rod's mass
    assert b_motor == pytest.approx(0.08, rel=0.05)
    assert c_slider == pytest.approx(8.0, rel=0.15)
    inertia = j0 + mass * x1**2
    assert 2.5e-3 < inertia.mean() < 3.5e-3
    assert inertia.max() / inertia.min() > 2.0


@pytest.mark.parametrize(
    ("xml", "match"),
    [
        (
            "<mujoco><worldbody><body><joint type='nope'/></body></worldbody></mujoco>",
            "invalid MJCF .*invalid keyword",
        ),
        ("this is not xml", "invalid MJCF"),
        ("<mujoco/>", "no joint named 'motor'"),
    ],
)
def test_bad_mjcf_is_one_line(tmp_path, xml: str, match: str) -> None:
    path = tmp_path / "bad.xml"
    path.write_text(xml)
    with pytest.raises(ModelError, match=match) as info:
        load_model(path)
    assert "\n" not in str(info.value)


def test_missing_and_unreadable_mjcf(tmp_path) -> None:
    with pytest.raises(ModelError, match="MJCF not found"):
        load_model(tmp_path / "absent.xml")
    with pytest.raises(ModelError, match="cannot read MJCF"):
        load_model(tmp_path)  # a directory


def test_default_model_path_exists() -> None:
    assert MODEL_PATH.is_file()
