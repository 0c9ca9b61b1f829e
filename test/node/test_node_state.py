"""``~/state`` over real DDS: pass far from a wall, limit/stop near it, disabled when off."""
import math

import pytest
from diagnostic_msgs.msg import DiagnosticStatus
from std_srvs.srv import SetBool

from node_harness import (
    Harness,
    LATCHED,
    markers,
    node_log,
    odometry,
    RESEND,
    running_filter,
    twist,
    wall,
)

RATE = 50.0
WAIT = 60.0  # wall-clock bound on each wait: a starved 2-core machine is slow, not wrong
KEYS = {'action', 'closest_obstacle_m', 'active_constraints', 'status', 'deadlocked'}


def _values(status):
    return {kv.key: kv.value for kv in status.values}


@pytest.mark.slow
def test_state_follows_the_wall_coming_near_and_the_enable_switch():
    """A wall 20 m ahead: ``pass``; 1.5 m ahead: ``limit`` or ``stop``; disabled: ``disabled``.

    The robot drives at 0.5 m/s (odometry; it does not move) as its nominal asks; the wall
    marker array then adds a second wall close by.  A late subscriber gets the current state
    (transient local).
    """
    params = {'model': 'unicycle', 'rate': RATE, 'obstacles_timeout': 0.0,
              'odom_timeout': 10.0, 'cmd_timeout': 10.0, 'stall_timeout': 10.0,
              'deadlock_time': 600.0, 'stuck_time': 0.0}
    with running_filter(params=params) as proc, Harness() as h:
        io = h.filter_io(proc)
        states = h.collect(DiagnosticStatus, '/safety_filter/state', LATCHED)
        wall_x = [20.0]

        def feed():
            io.odom.publish(odometry(v=0.5))
            io.cmd.publish(twist(0.5))

        def show_wall(marker_id):
            # A new key each time: a moved marker would get a velocity estimate.
            io.obstacles.publish(markers(wall([(wall_x[0], -2.0), (wall_x[0], 2.0)],
                                              marker_id=marker_id)))

        def latest_action():
            return _values(states[-1][1])['action'] if states else None

        show_wall(0)
        assert h.spin_until(lambda: latest_action() == 'pass', WAIT, feed, 1.0 / RATE), \
            ([s.message for _, s in states[-3:]], node_log(proc))
        status = states[-1][1]
        values = _values(status)
        assert set(values) == KEYS
        assert status.name == '/safety_filter: state' and status.message == 'pass'
        assert status.level == DiagnosticStatus.OK
        assert values['deadlocked'] == 'false'
        # The reference point (offset_l ahead of the axle) to the wall's face, 20 - 0.05 m away.
        closest = float(values['closest_obstacle_m'])
        assert math.isfinite(closest) and 19.0 < closest < 20.0, values

        wall_x[0] = 1.5
        show_wall(1)
        assert h.spin_until(lambda: latest_action() in ('limit', 'stop'), WAIT, feed,
                            1.0 / RATE), (_values(states[-1][1]), node_log(proc))
        values = _values(states[-1][1])
        assert float(values['closest_obstacle_m']) < 1.5, values
        assert values['status'] in ('ok', 'recovering', 'brake', 'backup'), values
        assert out_changed(io.out)

        with Harness() as late:
            late_states = late.collect(DiagnosticStatus, '/safety_filter/state', LATCHED)
            assert late.spin_until(lambda: late_states, WAIT), node_log(proc)
            assert _values(late_states[-1][1])['action'] in ('limit', 'stop')

        response = h.call(SetBool, 'safety_filter/enable', SetBool.Request(data=False),
                          resend_after=RESEND)
        assert response is not None and response.success
        assert h.spin_until(lambda: latest_action() == 'disabled', WAIT, feed, 1.0 / RATE), \
            ([s.message for _, s in states[-3:]], node_log(proc))
        status = states[-1][1]
        assert status.level == DiagnosticStatus.WARN
        assert _values(status)['status'] == 'disabled'


def out_changed(out):
    """Return True when the newest safe command is slower than the nominal 0.5 m/s."""
    return bool(out) and out[-1][1].linear.x < 0.5 - 1e-6
