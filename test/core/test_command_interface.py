"""Velocity command <-> acceleration mapping for velocity-interface models."""
import math

import numpy as np
import pytest
from hypothesis import given, strategies as st

from polyc2bf_ros.core.actuation.command_interface import VELOCITY_MODELS, VelocityCommandInterface

finite = st.floats(-10.0, 10.0)
STATES = {
    'unicycle': np.array([1.0, 2.0, 0.3, 0.5, -0.2]),
    'point_mass_2d': np.array([1.0, 2.0, 0.4, -0.1]),
    'point_mass_3d': np.array([1.0, 2.0, 3.0, 0.4, -0.1, 0.2]),
}


def test_unicycle_formulas():
    """u_nom = (v_cmd - v)/tau and v_safe = v + u T on [v, omega]."""
    iface = VelocityCommandInterface('unicycle', tau=0.1, period=0.01)
    state = STATES['unicycle']
    np.testing.assert_allclose(iface.nominal_input(state, (1.5, 0.8)),
                               [(1.5 - 0.5) / 0.1, (0.8 + 0.2) / 0.1])
    np.testing.assert_allclose(iface.safe_command(state, (2.0, -1.0)),
                               [0.5 + 2.0 * 0.01, -0.2 - 1.0 * 0.01])


def test_holonomic_command_is_body_frame():
    """Point mass 2-D: the command is body frame, rotated by the yaw."""
    iface = VelocityCommandInterface('point_mass_2d', tau=0.5, period=0.01)
    at_rest = np.zeros(4)
    # Facing +y: "forward" accelerates along world +y.
    np.testing.assert_allclose(iface.nominal_input(at_rest, (1.0, 0.0), yaw=math.pi / 2),
                               [0.0, 2.0], atol=1e-12)
    # World +x acceleration reads as body -y (to the right) when facing +y.
    np.testing.assert_allclose(iface.safe_command(at_rest, (100.0, 0.0), yaw=math.pi / 2),
                               [0.0, -1.0], atol=1e-12)


def test_3d_rotates_only_horizontally():
    """Point mass 3-D: yaw rotates x/y only; z stays vertical."""
    iface = VelocityCommandInterface('point_mass_3d', tau=1.0, period=0.01)
    u = iface.nominal_input(np.zeros(6), (0.0, 0.0, 1.0), yaw=1.0)
    np.testing.assert_allclose(u, [0.0, 0.0, 1.0], atol=1e-12)


@pytest.mark.parametrize('model', VELOCITY_MODELS)
@given(cmd=st.lists(finite, min_size=3, max_size=3), yaw=st.floats(-4.0, 4.0),
       offset=st.lists(finite, min_size=3, max_size=3))
def test_unconstrained_step_returns_the_command_when_tau_is_the_period(model, cmd, yaw, offset):
    """With tau = T, feeding u_nom back gives exactly the command (transparency)."""
    iface = VelocityCommandInterface(model, tau=0.02, period=0.02)
    state = STATES[model].copy()
    state[iface._slice] += offset[:iface.velocity_dim]
    cmd = np.array(cmd[:iface.velocity_dim])
    u = iface.nominal_input(state, cmd, yaw)
    np.testing.assert_allclose(iface.safe_command(state, u, yaw), cmd, atol=1e-9)
    # A state given as a tuple of floats (as the node keeps it) reads the same.
    as_tuple = tuple(state.tolist())
    np.testing.assert_array_equal(iface.nominal_input(as_tuple, cmd, yaw), u)
    np.testing.assert_array_equal(iface.safe_command(as_tuple, u, yaw),
                                  iface.safe_command(state, u, yaw))


def test_longer_tau_is_a_first_order_lag():
    """A tau of 10 T moves the velocity a tenth of the way per step."""
    iface = VelocityCommandInterface('unicycle', tau=0.1, period=0.01)
    state = np.zeros(5)
    v = iface.safe_command(state, iface.nominal_input(state, (1.0, 0.0)))
    np.testing.assert_allclose(v, [0.1, 0.0])


def test_refuses_other_models_and_bad_times():
    """Models without a velocity interface and bad tau/T are refused."""
    with pytest.raises(ValueError, match='quadrotor'):
        VelocityCommandInterface('quadrotor', 0.01, 0.01)
    for tau, period in ((0.0, 0.01), (0.01, -1.0), (math.nan, 0.01), (0.01, math.inf)):
        with pytest.raises(ValueError):
            VelocityCommandInterface('unicycle', tau, period)
