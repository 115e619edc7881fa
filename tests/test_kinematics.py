"""The twin's slider follows the paper's kinematics, and its initial states close the loop."""

from __future__ import annotations

import mujoco
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from twin.physics import STATE_SPEC, SliderCrank
from twin.stepping import simulate
from twin.variability import Variability

RIGID = Variability.none(backlash_width=0.0)  # zero backlash, no disturbance, nominal friction


@settings(max_examples=25, deadline=None)
@given(
    theta0=st.floats(0.0, 2 * np.pi),
    torque=st.floats(0.8, 1.2),
    direction=st.sampled_from([-1.0, 1.0]),
)
def test_slider_follows_the_formula_over_a_full_turn(
    physics: SliderCrank, theta0: float, torque: float, direction: float
) -> None:
    """Turned through a full revolution by a steady torque, the simulated slider position equals
    l1 cos(theta) + l2 cos(phi) + l1 - l2 of the measured motor angle within 1e-6 m.

    (The equality constraint's residual grows with the centripetal load: about 2.4e-6 m at
    3 N·m / 30 rad/s, 1.3e-5 m at the dataset's 90 rad/s; tests/test_dataset.py bounds that.)
    """
    n = 1000
    runs = simulate(
        physics,
        RIGID,
        draws=[RIGID.nominal()],
        initial_states=physics.initial_state(theta0)[None],
        tau=np.full((1, n), direction * torque),
        disturbance=np.zeros((1, n)),
    )
    theta = physics.sensor(runs.sensordata[0], "theta")
    slider = physics.sensor(runs.sensordata[0], "slider_position")
    turned = np.abs(theta - theta0)
    assert turned.max() > 2 * np.pi, "the crank did not complete a turn"
    turn = turned <= 2 * np.pi
    np.testing.assert_allclose(
        slider[turn], physics.geometry.slider_position(theta[turn]), rtol=0, atol=1e-6
    )


@settings(max_examples=50, deadline=None)
@given(theta=st.floats(-20.0, 20.0), omega=st.floats(-60.0, 60.0))
def test_initial_state_closes_the_loop(physics: SliderCrank, theta: float, omega: float) -> None:
    model = physics.model
    data = mujoco.MjData(model)
    mujoco.mj_setState(model, data, physics.initial_state(theta, omega), STATE_SPEC)
    mujoco.mj_forward(model, data)
    # Constraint rows of the loop closure: position and velocity violation both ~ 0.
    rows = data.efc_type == mujoco.mjtConstraint.mjCNSTR_EQUALITY
    assert np.abs(data.efc_pos[rows]).max() < 1e-12
    assert np.abs(data.efc_vel[rows]).max() < 1e-10
    assert physics.sensor(data.sensordata, "slider_position") == physics.geometry.slider_position(
        theta
    )
    assert physics.sensor(data.sensordata, "omega") == omega
