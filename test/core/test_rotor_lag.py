"""Rotors lagging their thrust commands (``core.actuation.rotor_lag``, ``CommandFilter``)."""
import math

import numpy as np
import pytest
from hypothesis import given, strategies as st

from polyc2bf_ros.core.actuation.rotor_lag import RotorLag
from polyc2bf_ros.core.command_filter import CommandFilter
from polyc2bf_ros.core.models import crazyflie, make_model
from polyc2bf_ros.core.obstacles.obstacle_set import ObstacleSet
from polyc2bf_ros.core.safety_filter import FilterConfig

PERIOD = 0.002
UPPER = 0.15


def _rotor(thrust, command, duration, tau, steps=400):
    """Return the thrust a first-order rotor reaches from ``thrust`` under ``command``."""
    for _ in range(steps):
        thrust = thrust + (command - thrust) * (duration / steps) / tau
    return thrust


@given(tau=st.floats(0.005, 0.2), seed=st.integers(0, 2 ** 31))
def test_the_command_brings_the_rotors_to_the_filters_thrusts(tau, seed):
    """Each command brings the rotors to the filter's thrusts by the period's end.

    Commands published each period move the estimate as the rotors move; a command that
    must be clipped to the rotor's range is exempt.
    """
    rng = np.random.default_rng(seed)
    lag = RotorLag(tau, PERIOD, np.zeros(4), np.full(4, UPPER))
    thrusts = np.full(4, 0.066)  # hover
    lag.published(0.0, thrusts)
    for k in range(1, 30):
        wanted = np.clip(0.066 + rng.normal(0.0, 0.002, 4), 0.0, UPPER)
        command = lag.command(wanted)
        assert np.all((command >= 0.0) & (command <= UPPER))
        reached = _rotor(thrusts, command, PERIOD, tau)
        free = (command > 0.0) & (command < UPPER)
        np.testing.assert_allclose(reached[free], wanted[free], atol=2e-5)
        lag.published(k * PERIOD, command)
        thrusts = reached


def test_a_slow_rotor_gets_a_larger_step_and_bad_values_are_refused():
    """The gain is 1 / (1 - exp(-T / tau)); tau <= 0 or not finite is refused."""
    lag = RotorLag(0.03, PERIOD, np.zeros(4), np.full(4, UPPER))
    lag.published(0.0, np.full(4, 0.06))
    step = lag.command(np.full(4, 0.061)) - 0.06
    assert step == pytest.approx(np.full(4, 0.001 / -math.expm1(-PERIOD / 0.03)))
    for tau in (0.0, -0.1, math.nan, math.inf):
        with pytest.raises(ValueError, match='actuator_tau'):
            RotorLag(tau, PERIOD, np.zeros(4), np.full(4, UPPER))


def test_the_quadrotor_takes_actuator_tau_but_not_a_latency():
    """``CommandFilter``: a Crazyflie's wrench is scaled for its rotors; a latency refused."""
    model = make_model('quadrotor')
    config = FilterConfig(control_period=PERIOD)
    plain = CommandFilter(model, config)
    lagging = CommandFilter(model, config, actuator_tau=0.03)
    assert plain.rotors is None and lagging.rotors is not None
    hover = crazyflie.wrench_from_thrusts(np.full(4, 0.066))
    lagging.published(0.0, hover)
    state = np.zeros(model.state_dim)
    nominal = crazyflie.wrench_from_thrusts(np.full(4, 0.067))
    a, _ = plain.filter(state, 0.0, nominal, ObstacleSet.empty())
    b, _ = lagging.filter(state, 0.0, nominal, ObstacleSet.empty())
    assert b[0] - hover[0] > 5.0 * (a[0] - hover[0]) > 0.0  # a larger thrust step
    with pytest.raises(ValueError, match='command_latency applies to velocity models'):
        CommandFilter(model, config, command_latency=0.03)
