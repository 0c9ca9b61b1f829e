"""CommandFilter: the node's per-step decision in command units (velocity or wrench)."""
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from polyc2bf_ros.core.command_filter import CommandFilter
from polyc2bf_ros.core.models import crazyflie, make_model
from polyc2bf_ros.core.obstacles.obstacle_set import Obstacle, ObstacleSet
from polyc2bf_ros.core.safety_filter import FilterConfig, FilterStatus
from strategies import examples

PERIOD = 0.01
WALL = ObstacleSet.from_obstacles([Obstacle(
    polygon=np.array([[1.0, -5.0], [1.3, -5.0], [1.3, 5.0], [1.0, 5.0]]), z_min=0.0, z_max=2.0)])


def _filter(model_name, **config):
    return CommandFilter(make_model(model_name),
                         FilterConfig(control_period=PERIOD, **config))


@settings(max_examples=examples(50), deadline=None)
@given(v=st.floats(-0.5, 0.5), omega=st.floats(-0.5, 0.5),
       dv=st.floats(-0.015, 0.015), domega=st.floats(-0.03, 0.03))
def test_unicycle_is_transparent_without_obstacles(v, omega, dv, domega):
    """With tau = T a command reachable within the acceleration bounds comes back unchanged."""
    state = np.array([0.0, 0.0, 0.3, v, omega])
    command = np.array([v + dv, omega + domega])
    safe, info = _filter('unicycle').filter(state, 0.3, command, ObstacleSet.empty())
    assert info.status == FilterStatus.OK
    np.testing.assert_allclose(safe, command, atol=1e-12)


def test_unicycle_acceleration_bound_limits_the_velocity_step():
    """From rest, a 1 m/s command becomes v = a_max T after one period."""
    model = make_model('unicycle')
    safe, _ = _filter('unicycle').filter(np.zeros(5), 0.0, [1.0, 0.0], ObstacleSet.empty())
    np.testing.assert_allclose(safe, [model.input_upper[0] * PERIOD, 0.0])


@pytest.mark.parametrize('model_name', ['point_mass_2d', 'point_mass_3d'])
def test_point_mass_commands_are_in_the_heading_frame(model_name):
    """A body-frame command at yaw 90 deg moves the point mass along world +y."""
    model = make_model(model_name)
    filt = _filter(model_name)
    state = np.zeros(model.state_dim)
    command = np.zeros(filt.command_dim)
    command[0] = 0.01
    safe, info = filt.filter(state, np.pi / 2, command, ObstacleSet.empty())
    assert info.status == FilterStatus.OK
    np.testing.assert_allclose(safe, command, atol=1e-12)
    u_nom = filt.interface.nominal_input(state, command, np.pi / 2)
    np.testing.assert_allclose(u_nom[:2] * filt.interface.tau, [0.0, 0.01], atol=1e-12)


def test_wall_ahead_holds_the_unicycle_back():
    """At rest facing a wall 1 m ahead, a 1.5 m/s command: eq. 7 holds the unicycle back.

    Without the wall the same command gives v = a_max T > 0 (previous test).  Eq. 7 forbids
    any velocity into the wall's cone; the horizon-aware default lets it creep forward, by
    less than the full acceleration (contact would be more than tau away).
    """
    paper = _filter('unicycle', barrier='polyc2bf_inflated')
    safe, info = paper.filter(np.zeros(5), 0.0, [1.5, 0.0], WALL)
    assert info.status == FilterStatus.OK
    assert safe[0] <= 0.0
    # The node hands over its state as a tuple of floats: the same decision.
    from_tuple, _ = paper.filter((0.0,) * 5, 0.0, (1.5, 0.0), WALL)
    np.testing.assert_array_equal(from_tuple, safe)
    creep, _ = _filter('unicycle').filter(np.zeros(5), 0.0, [1.5, 0.0], WALL)
    assert 0.0 < creep[0] < 0.5 * make_model('unicycle').input_upper[0] * PERIOD


def test_quadrotor_wrench_round_trip_without_obstacles():
    """A hover wrench within the rotor limits passes through the mixer unchanged."""
    state = np.zeros(12)
    state[2] = 1.0
    hover = np.array([crazyflie.MASS * crazyflie.GRAVITY, 1e-5, -2e-5, 1e-6])
    safe, info = _filter('quadrotor').filter(state, 0.0, hover, ObstacleSet.empty())
    assert info.status == FilterStatus.OK
    np.testing.assert_allclose(safe, hover, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize('model_name', ['unicycle', 'point_mass_2d', 'quadrotor'])
@pytest.mark.parametrize('where', ['command', 'state', 'yaw'])
def test_non_finite_input_gives_a_finite_stop(model_name, where):
    """NaN anywhere: invalid_input and the stop command, never NaN."""
    model = make_model(model_name)
    filt = _filter(model_name)
    state = np.zeros(model.state_dim)
    command = np.zeros(filt.command_dim)
    yaw = 0.0
    if where == 'command':
        command[0] = np.nan
    elif where == 'state':
        state[0] = np.inf
    else:
        yaw = np.nan
    safe, info = filt.filter(state, yaw, command, WALL)
    assert info.status == FilterStatus.INVALID_INPUT
    assert np.isfinite(safe).all()
    np.testing.assert_allclose(safe, filt.stop(state))


def test_stop_commands():
    """Velocity models stop at zero; the quadrotor's stop is its hover brake as a wrench."""
    assert _filter('unicycle').stop(np.ones(5)).tolist() == [0.0, 0.0]
    quad = _filter('quadrotor')
    state = np.zeros(12)
    wrench = quad.stop(state)
    np.testing.assert_allclose(wrench, crazyflie.wrench_from_thrusts(
        quad.model.braking_input(state)))
    assert wrench[0] == pytest.approx(crazyflie.MASS * crazyflie.GRAVITY)
