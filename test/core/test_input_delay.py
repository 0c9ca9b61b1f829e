"""Commands in flight and a lagging base (``core.actuation.input_delay``, ``CommandFilter``)."""
import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from polyc2bf_ros.core.actuation.input_delay import braking_plan, InputDelay
from polyc2bf_ros.core.command_filter import CommandFilter
from polyc2bf_ros.core.models import make_model
from polyc2bf_ros.core.obstacles.obstacle_set import ObstacleSet
from polyc2bf_ros.core.safety_filter import FilterConfig
from strategies import examples

PERIOD = 0.01
FINE = 1e-4  # s: the reference base's integration step


class Base:
    """A unicycle base as the arena's plant: commands act ``latency`` late, first-order lag."""

    def __init__(self, state, latency, tau, limits=(2.0, 4.0)):
        """Start at ``state`` [x, y, theta, v, omega], holding its velocity."""
        self.state, self.latency, self.tau = np.array(state, float), latency, tau
        self.limits = limits
        self.queue = []  # (arrival, command)
        self.command = np.array(state[3:5], float)  # holds its velocity until one arrives

    def send(self, now, command):
        """Publish ``command`` at ``now``: it arrives ``latency`` later."""
        self.queue.append((now + self.latency, np.array(command, float)))

    def run(self, now, duration):
        """Advance from ``now`` by ``duration`` in fine steps; return the state."""
        for k in range(round(duration / FINE)):
            t = now + k * FINE
            while self.queue and self.queue[0][0] <= t + 1e-9:
                self.command = self.queue.pop(0)[1]
            x, y, theta, v, omega = self.state
            lag = max(self.tau, FINE)
            a = np.clip((self.command[0] - v) / lag, -self.limits[0], self.limits[0])
            alpha = np.clip((self.command[1] - omega) / lag, -self.limits[1], self.limits[1])
            v2, omega2 = v + a * FINE, omega + alpha * FINE
            heading = theta + 0.5 * (omega + omega2) * 0.5 * FINE
            self.state = np.array([x + 0.5 * (v + v2) * FINE * math.cos(heading),
                                   y + 0.5 * (v + v2) * FINE * math.sin(heading),
                                   theta + 0.5 * (omega + omega2) * FINE, v2, omega2])
        return self.state


@settings(max_examples=examples(30), deadline=None)
@given(latency=st.sampled_from([0.02, 0.03, 0.05]), tau=st.sampled_from([0.0, 0.05, 0.1]),
       seed=st.integers(0, 2 ** 32 - 1))
def test_the_predictor_finds_where_the_base_is_when_the_command_acts(latency, tau, seed):
    """With random commands published every period, x(t + L) is predicted within 5 mm.

    The reference base integrates in 0.1 ms steps; the predictor in steps of at most a
    period, with the model's acceleration bounds (2 m/s^2, 4 rad/s^2, as the base's).
    """
    rng = np.random.default_rng(seed)
    model = make_model('unicycle', offset_l=0.01, max_accel=2.0, max_angular_accel=4.0)
    delay = InputDelay(model, latency, tau, PERIOD)
    base = Base([0.0, 0.0, 0.3, 0.5, 0.0], latency, tau)
    now = 0.0
    for k in range(60):
        command = [rng.uniform(-0.5, 1.5), rng.uniform(-1.0, 1.0)]
        if k >= 10:  # after a few sends the predictor knows everything in flight
            predicted = delay.predict(base.state, 0.0, now)
            future = Base(base.state, latency, tau)
            future.queue, future.command = list(base.queue), base.command.copy()
            actual = future.run(now, latency)
            np.testing.assert_allclose(predicted[:3], actual[:3], atol=5e-3)
            np.testing.assert_allclose(predicted[3:], actual[3:], atol=2e-2)
        base.send(now, command)
        delay.published(now, command)
        base.run(now, PERIOD)
        now += PERIOD


@pytest.mark.parametrize('tau', [0.0, 0.05, 0.1, 0.2])
def test_the_published_command_makes_a_lagging_base_realise_the_acceleration(tau):
    """Over one period from rest the base gains u T of speed, as the filter's model says."""
    model = make_model('unicycle', offset_l=0.01, max_accel=2.0, max_angular_accel=4.0)
    config = FilterConfig(barrier='polyc2bf_horizon', robot_radius=0.2, control_period=PERIOD)
    command_filter = CommandFilter(model, config, actuator_tau=tau)
    state = np.array([0.0, 0.0, 0.0, 0.5, 0.0])
    nominal = [0.6, 0.05]  # within the bounds of one period: u = (0.1, 0.05) / T ... clipped
    safe, _ = command_filter.filter(state, 0.0, nominal, ObstacleSet.empty())
    u = np.clip((np.array(nominal) - state[3:5]) / PERIOD, -np.array([2.0, 4.0]), [2.0, 4.0])
    base = Base(state, 0.0, tau, limits=(1e9, 1e9))  # the gain is about the lag, not limits
    base.send(0.0, safe)
    after = base.run(0.0, PERIOD)
    np.testing.assert_allclose(after[3:5] - state[3:5], u * PERIOD, rtol=2e-3, atol=1e-6)


def test_without_latency_or_lag_the_command_filter_is_unchanged():
    """L = 0 and tau = 0: the same command as a filter built without them, bit for bit."""
    model = make_model('unicycle', offset_l=0.01)
    config = FilterConfig(barrier='polyc2bf_horizon', robot_radius=0.2, control_period=PERIOD)
    plain, delayed = CommandFilter(model, config), CommandFilter(model, config, 0.0, 0.0, 0.0)
    state = np.array([1.0, 2.0, 0.4, 0.7, 0.1])
    delayed.published(0.0, [0.3, 0.0])
    a, _ = plain.filter(state, 0.4, [1.0, 0.2], ObstacleSet.empty())
    b, _ = delayed.filter(state, 0.4, [1.0, 0.2], ObstacleSet.empty(), now=0.01)
    np.testing.assert_array_equal(a, b)


def test_latency_and_lag_are_for_velocity_models_and_must_be_non_negative():
    """The quadrotor takes thrusts: refused by name; a negative latency too."""
    config = FilterConfig(control_period=PERIOD)
    with pytest.raises(ValueError, match='velocity models'):
        CommandFilter(make_model('quadrotor'), config, command_latency=0.03)
    with pytest.raises(ValueError, match='command_latency'):
        InputDelay(make_model('unicycle'), -0.01, 0.0, PERIOD)
    with pytest.raises(ValueError, match='actuator_tau'):
        InputDelay(make_model('unicycle'), 0.0, math.inf, PERIOD)


@settings(max_examples=examples(40), deadline=None)
@given(speed=st.floats(0.1, 2.0), told=st.sampled_from([0.0, 0.05, 0.07, 0.1]),
       tau_error=st.sampled_from([0.0, 0.01, 0.03, 0.05]),
       latency_error=st.sampled_from([0.0, 0.01, 0.02]))
def test_the_planned_stop_is_no_shorter_than_a_slower_later_base_makes(speed, told, tau_error,
                                                                       latency_error):
    """``braking_plan``: a base up to dtau slower and dL later than told still stops in time.

    The filter brakes with the model's brake, measured each period and scaled for the
    time constant it was told (``InputDelay.gain``); the base lags with tau + dtau and acts
    dL late.  Where it comes to rest lies no farther along than the braking check's
    planned path ends (``RobotModel.plan_braking``).
    """
    model = make_model('unicycle', offset_l=0.0, brake_time_constant=max(0.05,
                                                                         told + tau_error))
    model.plan_braking(*braking_plan(PERIOD, told, tau_error, latency_error))
    state = np.array([0.0, 0.0, 0.0, speed, 0.0])
    planned = model.braking_path(state, PERIOD)[-1, 0]
    gain = 1.0 / -math.expm1(-PERIOD / told) if told else 1.0
    # No limits on the base: a compensated command asks for about (1 + T / (2 tau)) of u
    # at the start of the period, which a base held to max_accel clips (not this bound).
    base = Base(state, latency_error, told + tau_error, limits=(1e9, 1e9))
    now = 0.0
    while base.state[3] > 1e-4 and now < 10.0:
        brake = model.braking_input(base.state)
        base.send(now, base.state[3:5] + brake * PERIOD * gain)
        base.run(now, PERIOD)
        now += PERIOD
    assert base.state[0] <= planned + 1e-3


def test_the_braking_plan_is_exact_without_mismatch_and_refuses_bad_bounds():
    """No error bound: the full limits and no coast; a negative or NaN bound: one clear line."""
    assert braking_plan(PERIOD, 0.07, 0.0, 0.0) == (1.0, 0.0)
    share, coast = braking_plan(PERIOD, 0.07, 0.03, 0.01)
    assert 0.6 < share < 0.7 and coast == pytest.approx(0.08)
    for bad in (-0.01, math.nan):
        with pytest.raises(ValueError, match='actuator_tau_error must be a finite number'):
            braking_plan(PERIOD, 0.07, bad, 0.0)
        with pytest.raises(ValueError, match='command_latency_error must be a finite number'):
            braking_plan(PERIOD, 0.07, 0.0, bad)
    with pytest.raises(ValueError, match='braking share'):
        make_model('unicycle').plan_braking(1.5)
