"""``~/deadlock`` over real DDS: a robot held at a wall is reported, and the report clears."""
import pytest
from std_msgs.msg import Bool

from node_harness import (
    Harness,
    LATCHED,
    latest_status,
    markers,
    node_log,
    odometry,
    running_filter,
    twist,
    wall,
)

ANSWER_TIMEOUT = 60.0  # wall-clock bound on each wait: a starved 2-core machine is slow


@pytest.mark.slow
def test_a_robot_held_at_a_wall_is_reported_on_the_latched_deadlock_topic():
    """Held at a wall: ``~/deadlock`` true and WARN in ``/diagnostics``; let go: false.

    At rest just before a wall, told to drive at it, the filter holds it; told to stand
    still, it no longer does.  A late subscriber gets the current state (transient local).
    """
    params = {'model': 'unicycle', 'rate': 50.0, 'obstacles_timeout': 0.0,
              'deadlock_time': 0.5, 'deadlock_radius': 0.05,
              'odom_timeout': 10.0, 'cmd_timeout': 10.0}
    with running_filter(params=params) as proc, Harness() as h:
        io = h.filter_io(proc)
        states = h.collect(Bool, '/safety_filter/deadlock', LATCHED)
        io.obstacles.publish(markers(wall([(1.5, -1.5), (1.5, 1.5)])))
        speed = [1.0]

        def drive():
            io.odom.publish(odometry(1.0, 0.0))
            io.cmd.publish(twist(speed[0]))

        assert h.spin_until(lambda: states and states[-1][1].data, ANSWER_TIMEOUT,
                            every=drive), node_log(proc)
        assert states[0][1].data is False  # the state before: published at start

        def reported():
            return latest_status(io.diagnostics)[1].get('deadlocked') == 'true'

        assert h.spin_until(reported, ANSWER_TIMEOUT, every=drive), node_log(proc)
        status, values = latest_status(io.diagnostics)
        assert 'deadlock' in status.message and int(values['deadlocks']) >= 1

        with Harness() as late:
            late_states = late.collect(Bool, '/safety_filter/deadlock', LATCHED)
            assert late.spin_until(lambda: late_states, ANSWER_TIMEOUT), node_log(proc)
            assert late_states[-1][1].data is True

        speed[0] = 0.0
        assert h.spin_until(lambda: not states[-1][1].data, ANSWER_TIMEOUT, every=drive), \
            node_log(proc)


@pytest.mark.slow
def test_with_the_route_resolution_a_held_robot_is_steered_and_diagnostics_say_so():
    """deadlock_resolution route: once reported, the command turns off the nominal's line.

    The robot stands still (its odometry never moves), so every route is blocked in turn;
    ``/diagnostics`` reports ``resolving: route`` and counts the resolutions.  The route
    backs away from the wall, so the safe command turns (by at most the 2 rad/s^2 bound
    times one period from the odometry's rest) where the nominal drives straight.
    """
    params = {'model': 'unicycle', 'rate': 50.0, 'obstacles_timeout': 0.0,
              'deadlock_time': 0.5, 'deadlock_radius': 0.05, 'stuck_time': 0.0,
              'deadlock_resolution': 'route', 'odom_timeout': 10.0, 'cmd_timeout': 10.0}
    with running_filter(params=params) as proc, Harness() as h:
        io = h.filter_io(proc)
        io.obstacles.publish(markers(wall([(1.5, -1.5), (1.5, 1.5)])))

        def drive():
            io.odom.publish(odometry(0.7, 0.0))   # guarded point 0.6 m from the wall
            io.cmd.publish(twist(1.0))

        def routing():
            return latest_status(io.diagnostics)[1].get('resolving') == 'route'

        assert h.spin_until(routing, ANSWER_TIMEOUT, every=drive), node_log(proc)
        assert int(latest_status(io.diagnostics)[1]['resolutions']) >= 1
        assert h.spin_until(lambda: io.out and abs(io.out[-1][1].angular.z) > 0.02,
                            ANSWER_TIMEOUT, every=drive), node_log(proc)
