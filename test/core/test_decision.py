"""The node's decision without ROS: every rule of ``ControlDecision.step`` on given times."""
import math

import numpy as np
import pytest

from polyc2bf_ros.core.decision import ControlDecision, ObstacleSnapshot
from polyc2bf_ros.core.liveness.circulation import Circulation
from polyc2bf_ros.core.liveness.escape_route import RouteEscape
from polyc2bf_ros.core.obstacles.obstacle_set import Obstacle, ObstacleSet
from polyc2bf_ros.filter_parameters import build_filter

TIMEOUTS = {'odom': 0.25, 'cmd': 0.5, 'obstacles': 1.0}
WALL = ObstacleSet.from_obstacles([Obstacle(
    polygon=np.array([[2.0, -1.0], [2.2, -1.0], [2.2, 1.0], [2.0, 1.0]]), key='w')])
STATE = (0.0, 0.0, 0.0, 0.5, 0.0)


def _decision(block=True, timeouts=TIMEOUTS):
    """Return a unicycle decision with fresh odometry (0.5 m/s) and a 0.8 m/s command."""
    decision = ControlDecision(build_filter({}).command_filter, timeouts, block)
    decision.odometry(10.0, STATE, 0.0, 10.0)
    decision.command(10.0, (0.8, 0.0))
    return decision


def _snapshot(received=10.0, **fields):
    return ObstacleSnapshot(obstacles=WALL, t_ref=10.0, received=received, **fields)


def test_fresh_inputs_are_filtered_and_counted_by_status():
    """All fresh: the filter's answer (slower than 0.8 toward the wall), counted 'ok'."""
    decision = _decision()
    decision.obstacles(_snapshot())
    result = decision.step(10.01)
    assert result.action == 'filter' and result.info.status.value == 'ok'
    assert 0.0 <= result.command[0] < 0.8 and decision.counts['ok'] == 1


@pytest.mark.parametrize('silent, at', [('odom', 10.3), ('cmd', 10.6), ('obstacles', 11.1)])
def test_a_stale_input_stops(silent, at):
    """Each input past its own timeout gives the stop; the others are kept fresh."""
    decision = _decision()
    decision.obstacles(_snapshot())
    if silent != 'odom':
        decision.odometry(at, STATE, 0.0, at)
    if silent != 'cmd':
        decision.command(at, (0.8, 0.0))
    if silent != 'obstacles':
        decision.obstacles(_snapshot(received=at))
    result = decision.step(at)
    assert result.action == 'stop' and result.reason == 'stale_stop'
    np.testing.assert_array_equal(result.command, [0.0, 0.0])


def test_obstacles_never_received_are_stale():
    """No snapshot with a receipt time yet: stop."""
    assert _decision().step(10.0).reason == 'stale_stop'


@pytest.mark.parametrize('bad', ['odom', 'cmd', 'unreadable', 'invalid', 'error'])
def test_unusable_input_stops_at_once(bad):
    """Unusable odometry, command or obstacle input: the stop, counted 'invalid_input'."""
    decision = _decision()
    decision.obstacles(_snapshot())  # fresh obstacles first: the bad input is not staleness
    fields = {'unreadable': 'truncated'} if bad == 'unreadable' else {
        'invalid': True} if bad == 'invalid' else {'error': 'too many'} if bad == 'error' else {}
    decision.obstacles(_snapshot(received=10.0, **fields))
    if bad == 'odom':
        decision.odometry(10.0)
    if bad == 'cmd':
        decision.command(10.0)
    result = decision.step(10.0)
    assert result.action == 'stop' and result.reason == 'invalid_input'


def test_rejected_obstacles_are_not_fresh_under_block_if_invalid():
    """A wrong-frame marker: stale once obstacles_timeout passed; without blocking, fresh."""
    for block, expected in ((True, 'stop'), (False, 'filter')):
        decision = _decision(block)
        decision.obstacles(_snapshot())
        for t in np.arange(10.1, 11.3, 0.1):
            decision.odometry(t, STATE, 0.0, t)
            decision.command(t, (0.8, 0.0))
            decision.obstacles(_snapshot(received=t, wrong_frame={'m/1': 'frame map'}))
        assert decision.step(11.25).action == expected


def test_rejected_obstacles_with_a_latched_map_block_at_once():
    """obstacles_timeout 0: rejected input stops right away ('blocked_stop')."""
    decision = _decision(timeouts={**TIMEOUTS, 'obstacles': 0.0})
    decision.obstacles(_snapshot())
    decision.obstacles(_snapshot(rejected={'m/2': 'self-intersecting'}))
    result = decision.step(10.0)
    assert result.action == 'stop' and result.reason == 'blocked_stop'
    assert decision.counts['blocked_stop'] == 1


def test_without_an_obstacles_watchdog_snapshots_are_used_but_watch_nothing():
    """No 'obstacles' timeout (scans only): no watchdog to feed, no blocking on markers.

    A scan watchdog stops until fed; a snapshot never received is usable; a rejected marker
    (which a scan-only node cannot have) neither blocks nor raises.
    """
    decision = _decision(timeouts={'odom': 0.25, 'cmd': 0.5, 'scan_scan': 0.0})
    assert decision.watchdog.names == ('odom', 'cmd', 'scan_scan')
    decision.obstacles(_snapshot(received=None))
    assert decision.step(10.0).reason == 'stale_stop'
    decision.watchdog.feed('scan_scan', 10.0)
    assert decision.step(10.0).action == 'filter'
    decision.obstacles(_snapshot(rejected={'m/2': 'self-intersecting'}))
    assert decision.step(10.0).action == 'filter'
    assert decision.watchdog.names == ('odom', 'cmd', 'scan_scan')


def test_disabled_passes_the_nominal_but_still_stops_on_a_stale_command():
    """Pass-through while disabled; a stale or unusable command still gives the stop."""
    decision = _decision()
    decision.enabled = False
    assert decision.step(10.1).action == 'pass'
    assert decision.step(10.6).reason == 'stale_stop'
    decision.command(11.0)
    assert decision.step(11.0).reason == 'invalid_input'


def test_the_stop_before_any_odometry_is_the_zero_command():
    """No state yet: the stop is built from zeros, never NaN."""
    decision = ControlDecision(build_filter({}).command_filter, TIMEOUTS)
    stop = decision.stop()
    assert np.all(np.isfinite(stop)) and not math.isnan(float(np.sum(stop)))


def test_a_robot_held_at_the_wall_is_reported_deadlocked_after_deadlock_time():
    """At rest 0.3 m from the wall, told to drive on: held, deadlocked after 3 s, not before.

    A stale input then stops the robot: that stop clears the verdict.
    """
    decision = ControlDecision(build_filter({}).command_filter, TIMEOUTS, deadlock=(3.0, 0.1))
    at_wall = (1.45, 0.0, 0.0, 0.0, 0.0)
    verdicts = []
    for k in range(400):
        now = 10.0 + 0.01 * k
        decision.odometry(now, at_wall, 0.0, now)
        decision.command(now, (0.8, 0.0))
        decision.obstacles(_snapshot(received=now))
        result = decision.step(now)
        assert result.action == 'filter' and result.command[0] < 0.8
        verdicts.append(result.deadlocked)
    first = verdicts.index(True)
    assert 299 <= first <= 301 and all(verdicts[first:])
    assert decision.deadlock.onsets == 1
    assert not decision.step(20.0).deadlocked and decision.deadlock.held_s(20.0) == 0.0


@pytest.mark.parametrize('state, command', [
    ((0.0, 0.0, math.pi, 0.0, 0.0), (0.5, 0.0)),   # driving away: nothing in the way
    ((1.45, 0.0, 0.0, 0.0, 0.0), (0.0, 0.0)),      # parked at the wall, told to stand
])
def test_a_robot_the_filter_does_not_hold_back_is_never_deadlocked(state, command):
    """Not held back: at rest for 2 s, four times deadlock_time, and never reported."""
    decision = ControlDecision(build_filter({}).command_filter, TIMEOUTS, deadlock=(0.5, 0.1))
    for k in range(200):
        now = 10.0 + 0.01 * k
        decision.odometry(now, state, state[2], now)
        decision.command(now, command)
        decision.obstacles(_snapshot(received=now))
        assert not decision.step(now).deadlocked
    assert decision.deadlock.onsets == 0


def test_a_robot_asked_to_move_that_stays_put_is_reported_stuck():
    """Nothing holds it, but it stays put while asked for 0.8 m/s: stuck from 8 s on.

    ``stuck_time`` is 8 s by default; not reported before.
    """
    decision = ControlDecision(build_filter({}).command_filter,
                               {'odom': 0.0, 'cmd': 0.0, 'obstacles': 0.0}, True)
    decision.obstacles(ObstacleSnapshot(obstacles=ObstacleSet.empty(), t_ref=0.0,
                                        received=0.0))
    verdicts = []
    for k in range(1000):
        now = 0.01 * k
        decision.odometry(now, STATE, 0.0, now)
        decision.command(now, (0.8, 0.0))
        verdicts.append(decision.step(now).deadlocked)
    assert verdicts.index(True) == 800 and all(verdicts[800:])
    assert decision.deadlock.stuck_onsets == 1 and decision.deadlock.onsets == 0


@pytest.mark.parametrize('model, resolution, expected', [
    ('unicycle', 'route', 'route'), ('point_mass_2d', 'route', 'holonomic route'),
    ('unicycle', 'circulate', 'circulation'), ('point_mass_2d', 'circulate', None),
    ('point_mass_3d', 'route', None), ('unicycle', 'none', None)])
def test_each_resolution_steers_only_the_models_it_knows(model, resolution, expected):
    """route: unicycle and point_mass_2d (holonomic); circulate: unicycle; else nothing."""
    settings = build_filter({'model': model})
    decision = ControlDecision(settings.command_filter, TIMEOUTS, resolution=resolution)
    resolver = decision.circulation
    assert decision.resolving == 'none' and decision.resolutions == 0   # nothing began yet
    if expected is None:
        assert resolver is None
    elif expected == 'circulation':
        assert isinstance(resolver, Circulation)
    else:
        assert isinstance(resolver, RouteEscape)
        assert resolver.holonomic is (expected == 'holonomic route')
        safety = settings.command_filter.safety_filter
        assert resolver.free_clearance == pytest.approx(
            safety.guard_radius + safety.config.braking_margin + 0.02)
