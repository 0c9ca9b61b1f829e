"""``/diagnostics`` and ``~/markers``: the promised fields are there and follow what happens."""
import math

import pytest
from diagnostic_msgs.msg import DiagnosticStatus
from visualization_msgs.msg import Marker, MarkerArray

from node_harness import (
    Harness,
    latest_status,
    markers,
    node_log,
    odometry,
    running_filter,
    twist,
    wall,
)

RATE = 50.0
# Waits end as soon as the report is seen; this only turns a hang into a failure.
WAIT = 30.0
FIELDS = ('enabled', 'model', 'barrier', 'rate_target_hz', 'rate_achieved_hz', 'latency_p50_ms',
          'latency_p99_ms', 'stale_inputs', 'age_odom_s', 'age_cmd_s', 'age_obstacles_s',
          'steps_ok', 'steps_slack', 'steps_brake', 'steps_escape', 'steps_invalid_input',
          'steps_stale_stop', 'steps_infeasible', 'steps_fallback', 'invalid_messages',
          'last_invalid_message', 'min_h', 'obstacles_in_use', 'obstacles_tracked',
          'obstacles_rejected')


@pytest.mark.slow
def test_diagnostics_fields_follow_the_inputs_and_markers_show_the_cones():
    """Fields track healthy running, a marker in a foreign frame and silent odometry.

    Healthy: level OK, achieved rate positive and not above the target (how far
    below depends on the machine), finite min h, markers for a subscriber.  A
    marker in frame 'map': ERROR naming it, until it is deleted.
    Odometry silent: WARN, stale_inputs 'odom', stale stops counted.
    """
    # A starved node's stall-guard stop would turn the healthy report into an ERROR; on a
    # busy machine a late odometry message (a stale stop) or the stuck rule (the odometry
    # does not move; 8 s by default) would turn it into a WARN.
    params = {'model': 'unicycle', 'rate': RATE, 'stall_timeout': 10.0, 'odom_timeout': 1.0,
              'cmd_timeout': 1.0, 'stuck_time': 0.0}
    with running_filter(params=params) as proc, Harness() as h:
        drawn = h.collect(MarkerArray, 'safety_filter/markers')
        io = h.filter_io(proc)
        diagnostics = io.diagnostics
        inputs = {'odom': True, 'obstacles': [wall([(2.0, -1.0), (2.0, 1.0)])]}

        def feed():
            if inputs['odom']:
                io.odom.publish(odometry(v=0.3))
            io.cmd.publish(twist(0.3))
            io.obstacles.publish(markers(*inputs['obstacles']))

        def report(predicate):
            count = len(diagnostics)
            ok = h.spin_until(lambda: len(diagnostics) > count and predicate(
                latest_status(diagnostics)[1]), WAIT, feed, 1.0 / RATE)
            assert ok, (latest_status(diagnostics), node_log(proc))
            return latest_status(diagnostics)

        # Two seconds of steps: the latest one-second window is fully in steady state.
        status, values = report(lambda v: int(v['steps_ok']) > 2 * RATE)
        assert set(FIELDS) <= set(values)
        assert status.level == DiagnosticStatus.OK, status.message
        assert status.hardware_id == 'unicycle'
        assert values['stale_inputs'] == 'none' and values['enabled'] == 'true'
        assert values['obstacles_in_use'] == '1' and math.isfinite(float(values['min_h']))
        # A steady timer fires at most once per period (rcl skips missed ones), so only
        # a rate above the target is wrong; the +50 % covers a report window cut short.
        assert values['rate_target_hz'] == f'{RATE:g}'
        assert 0.0 < float(values['rate_achieved_hz']) < 1.5 * RATE
        assert 0.0 < float(values['latency_p50_ms']) <= float(values['latency_p99_ms'])

        assert h.spin_until(lambda: any(len(m.markers) > 1 for _, m in drawn), WAIT, feed,
                            1.0 / RATE), 'no markers for a subscriber'
        _, latest = drawn[-1]
        namespaces = {m.ns for m in latest.markers if m.action == Marker.ADD}
        assert namespaces == {'obstacles', 'cones', 'robot'}
        body = next(m for m in latest.markers if m.ns == 'robot')  # the 0.3 m disc at the origin
        assert all(math.hypot(p.x, p.y) == pytest.approx(0.3) for p in body.points)
        assert all(m.header.frame_id == 'odom' for m in latest.markers[1:])

        inputs['obstacles'].append(wall([(0.0, 3.0), (1.0, 3.0)], marker_id=9, frame='map'))
        status, values = report(lambda v: v['obstacles_rejected'] == '1')
        assert status.level == DiagnosticStatus.ERROR
        assert "'map'" in values['rejected walls/9'] and values['obstacles_in_use'] == '1'
        inputs['obstacles'][-1] = Marker(ns='walls', id=9, action=Marker.DELETE)
        status, values = report(lambda v: v['obstacles_rejected'] == '0')
        assert status.level == DiagnosticStatus.OK, status.message

        stops_before = int(values['steps_stale_stop'])
        inputs['odom'] = False
        status, values = report(lambda v: v['stale_inputs'] == 'odom')
        assert status.level == DiagnosticStatus.WARN and 'stale' in status.message
        assert int(values['steps_stale_stop']) > stops_before
        assert float(values['age_odom_s']) > 0.25
