"""The managed ``safety_filter_lifecycle`` over real DDS, driven by its lifecycle services.

Each state's outputs: unconfigured has no topics at all; inactive takes inputs but publishes
nothing; active filters (free space passes the nominal, a wall ahead brakes); deactivate
publishes one stop, then nothing; cleanup and a second configure work; invalid parameters
make configure fail until they are fixed.
"""
import pytest
from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import Twist
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState, GetState
from nav_msgs.msg import Odometry
from rcl_interfaces.msg import Parameter as ParameterMsg, ParameterType, ParameterValue
from rcl_interfaces.srv import SetParameters
from visualization_msgs.msg import MarkerArray

from node_harness import (
    braked_by_filter,
    Harness,
    LATCHED,
    markers,
    node_log,
    odometry,
    RESEND,
    running_filter,
    status_values,
    twist,
    wall,
)

MODULE = 'polyc2bf_ros.safety_filter_lifecycle'
NODE = 'safety_filter'
RATE = 50.0
WAIT = 60.0  # wall-clock bound on each wait: a starved 2-core machine is slow, not wrong
QUIET = 1.5  # seconds of feeding inputs in which a silent state must stay silent
SPEED = 0.5
PARAMS = {'model': 'unicycle', 'rate': RATE, 'obstacles_timeout': 0.0, 'odom_timeout': 10.0,
          'cmd_timeout': 10.0, 'stall_timeout': 10.0, 'deadlock_time': 600.0,
          'stuck_time': 0.0}  # the odometry does not move: no deadlock report


def _state(h, proc):
    """Return the node's lifecycle state label (``get_state``)."""
    response = h.call(GetState, f'{NODE}/get_state', GetState.Request(), timeout=WAIT,
                      resend_after=RESEND)
    assert response is not None, node_log(proc)
    return response.current_state.label


def _change(h, proc, transition):
    """Request a lifecycle transition; return whether it succeeded."""
    before = _state(h, proc)
    request = ChangeState.Request(transition=Transition(id=transition))
    response = h.call(ChangeState, f'{NODE}/change_state', request, timeout=WAIT)
    if response is not None:
        return response.success
    # The reply was lost (see Harness.call); a transition is not idempotent, so read
    # the state instead of asking again.
    return _state(h, proc) != before


class _Inputs:
    """The test's publishers and collected outputs, wired before the node subscribes."""

    def __init__(self, h):
        """Create the publishers (obstacles latched) and the collecting subscriptions."""
        self.h = h
        self.out = h.collect(Twist, 'cmd_vel_out')
        self.states = h.collect(DiagnosticStatus, f'{NODE}/state', LATCHED)
        self.odom = h.publisher(Odometry, 'odom')
        self.cmd = h.publisher(Twist, 'cmd_vel_in')
        self.obstacles = h.publisher(MarkerArray, 'obstacles', LATCHED)

    def feed(self):
        """Publish the robot driving at ``SPEED`` as its nominal command asks."""
        self.odom.publish(odometry(v=SPEED))
        self.cmd.publish(twist(SPEED))

    def speed(self):
        """Return the newest safe forward speed (None before any)."""
        return self.out[-1][1].linear.x if self.out else None

    def wait_for(self, predicate):
        """Feed inputs until ``predicate()`` holds; return whether it did within ``WAIT``."""
        return self.h.spin_until(predicate, WAIT, self.feed, 1.0 / RATE)

    def quiet(self):
        """Feed inputs for ``QUIET`` s; return how many commands came meanwhile."""
        before = len(self.out)
        self.h.spin_until(lambda: False, QUIET, self.feed, 1.0 / RATE)
        return len(self.out) - before


def _no_filter_topics(h):
    """Return True once the node has no command output and no input subscription."""
    node = h.node
    return (node.count_publishers('/cmd_vel_out') == 0
            and node.count_subscribers('/cmd_vel_in') == 0
            and node.count_subscribers('/odom') == 0)


def _filter_topics(h):
    """Return True once the node publishes commands and takes odometry and commands."""
    node = h.node
    return (node.count_publishers('/cmd_vel_out') > 0
            and node.count_subscribers('/cmd_vel_in') > 0
            and node.count_subscribers('/odom') > 0)


@pytest.mark.slow
def test_each_lifecycle_state_publishes_what_it_should():
    """Unconfigured and inactive: no command; active: filters; deactivate: one stop; again.

    The robot drives at 0.5 m/s (odometry; it does not move) as its nominal asks.  In free
    space the nominal passes; after cleanup and a second configure a latched wall 1.5 m ahead
    (taken while inactive) brakes it.  A late subscriber of ``~/state`` after deactivation
    reads action ``disabled``, status ``inactive``.
    """
    with running_filter(params=PARAMS, module=MODULE) as proc, Harness() as h:
        io = _Inputs(h)
        assert _state(h, proc) == 'unconfigured'
        assert h.spin_until(lambda: _no_filter_topics(h), WAIT)
        assert io.quiet() == 0, node_log(proc)

        io.obstacles.publish(markers())  # free space
        assert _change(h, proc, Transition.TRANSITION_CONFIGURE), node_log(proc)
        assert _state(h, proc) == 'inactive'
        assert h.spin_until(lambda: _filter_topics(h), WAIT), node_log(proc)
        assert io.quiet() == 0, node_log(proc)

        assert _change(h, proc, Transition.TRANSITION_ACTIVATE), node_log(proc)
        assert _state(h, proc) == 'active'
        assert io.wait_for(lambda: io.speed() == SPEED), (io.speed(), node_log(proc))

        assert _change(h, proc, Transition.TRANSITION_DEACTIVATE), node_log(proc)
        assert _state(h, proc) == 'inactive'
        # Reliable and in order: the stop comes after every filtered command, and is the last.
        assert io.wait_for(lambda: io.speed() == 0.0), node_log(proc)
        assert io.quiet() == 0, node_log(proc)
        assert io.speed() == 0.0 and io.out[-1][1].angular.z == 0.0
        with Harness() as late:
            late_states = late.collect(DiagnosticStatus, f'{NODE}/state', LATCHED)
            assert late.spin_until(lambda: late_states, WAIT), node_log(proc)
            values = status_values(late_states[-1][1])
            assert (values['action'], values['status']) == ('disabled', 'inactive'), values

        assert _change(h, proc, Transition.TRANSITION_CLEANUP), node_log(proc)
        assert _state(h, proc) == 'unconfigured'
        assert h.spin_until(lambda: _no_filter_topics(h), WAIT), node_log(proc)

        # A new key: a marker that moved would get a velocity estimate.
        io.obstacles.publish(markers(wall([(1.5, -2.0), (1.5, 2.0)], marker_id=1)))
        assert _change(h, proc, Transition.TRANSITION_CONFIGURE), node_log(proc)
        assert h.spin_until(lambda: _filter_topics(h), WAIT), node_log(proc)
        assert io.quiet() == 0, node_log(proc)
        assert _change(h, proc, Transition.TRANSITION_ACTIVATE), node_log(proc)
        assert io.wait_for(lambda: braked_by_filter(io.out, io.states, SPEED)), \
            (io.speed(), [s.message for _, s in io.states[-3:]], node_log(proc))
        assert proc.poll() is None, node_log(proc)


def _set_parameter(h, proc, name, value):
    """Set one double parameter through ``set_parameters``; return whether it was taken."""
    request = SetParameters.Request(parameters=[ParameterMsg(name=name, value=ParameterValue(
        type=ParameterType.PARAMETER_DOUBLE, double_value=float(value)))])
    response = h.call(SetParameters, f'{NODE}/set_parameters', request, timeout=WAIT,
                      resend_after=RESEND)
    assert response is not None, node_log(proc)
    return response.results[0].successful


@pytest.mark.slow
def test_invalid_parameters_and_transitions_are_refused():
    """odom_timeout at the control period: configure fails and says why; fixed, it works.

    A transition the state does not have (activate while unconfigured) is refused, and the
    node lives on.  Shut down from inactive, the node is finalized and has no topics left.
    """
    params = {**PARAMS, 'odom_timeout': 1.0 / RATE}
    with running_filter(params=params, module=MODULE) as proc, Harness() as h:
        assert not _change(h, proc, Transition.TRANSITION_ACTIVATE), node_log(proc)
        assert _state(h, proc) == 'unconfigured' and 'refused' in node_log(proc)
        assert not _change(h, proc, Transition.TRANSITION_CONFIGURE), node_log(proc)
        assert _state(h, proc) == 'unconfigured'
        assert 'invalid configuration' in node_log(proc) and 'odom_timeout' in node_log(proc)
        assert h.spin_until(lambda: _no_filter_topics(h), WAIT), node_log(proc)

        assert _set_parameter(h, proc, 'odom_timeout', 1.0), node_log(proc)
        assert _change(h, proc, Transition.TRANSITION_CONFIGURE), node_log(proc)
        assert _state(h, proc) == 'inactive'
        assert h.spin_until(lambda: _filter_topics(h), WAIT), node_log(proc)

        assert _change(h, proc, Transition.TRANSITION_INACTIVE_SHUTDOWN), node_log(proc)
        assert _state(h, proc) == 'finalized'
        assert h.spin_until(lambda: _no_filter_topics(h), WAIT), node_log(proc)
        assert proc.poll() is None, node_log(proc)


@pytest.mark.parametrize('scan_topics', [None, '[scan]'])
@pytest.mark.slow
def test_use_markers_false_takes_obstacles_from_scans_only(scan_topics):
    """Without scan topics configure fails: no obstacle source; with one, no ``obstacles``."""
    params = {**PARAMS, 'use_markers': False}
    if scan_topics is not None:
        params['scan_topics'] = scan_topics
    with running_filter(params=params, module=MODULE) as proc, Harness() as h:
        if scan_topics is None:
            assert not _change(h, proc, Transition.TRANSITION_CONFIGURE), node_log(proc)
            assert _state(h, proc) == 'unconfigured'
            assert 'no obstacle source' in node_log(proc)
            return
        assert _change(h, proc, Transition.TRANSITION_CONFIGURE), node_log(proc)
        assert h.spin_until(lambda: _filter_topics(h) and h.node.count_subscribers('/scan'),
                            WAIT), node_log(proc)
        assert h.node.count_subscribers('/obstacles') == 0, node_log(proc)
