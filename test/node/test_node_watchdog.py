"""Watchdogs over real DDS: stale odometry, command or obstacles -> stop; recovery after."""
import math
import time

import pytest
from geometry_msgs.msg import Twist, WrenchStamped
from nav_msgs.msg import Odometry
from visualization_msgs.msg import MarkerArray

from node_harness import Harness, LATCHED, markers, node_log, odometry, running_filter, twist
from polyc2bf_ros.core.models import crazyflie

RATE = 50.0
# Long enough that a starved harness (both cores busy) never leaves an input silent that
# long by accident: a stop caused by another input would break the lower bound below.
TIMEOUTS = {'odom_timeout': 1.0, 'cmd_timeout': 1.0, 'obstacles_timeout': 1.5}
# The stall guard's stop (a starved node) would look like a watchdog stop here.
STALL_TIMEOUT = 10.0
# A stop is due one control period after the timeout; GRACE is many times that, so it
# holds on a starved machine and only catches a stop that never comes (or far too late).
GRACE = 10.0
# Waits end as soon as the stop (or recovery) is seen; this only turns a hang into a failure.
WAIT = 30.0


class Feeds:
    """Publishes the three inputs each period, each switchable on and off."""

    def __init__(self, harness, command_type, command):
        """Create the publishers; ``command`` is the nominal message sent each period."""
        self.harness = harness
        self.odom = harness.publisher(Odometry, 'odom')
        self.command_topic = 'wrench_in' if command_type is WrenchStamped else 'cmd_vel_in'
        self.cmd = harness.publisher(command_type, self.command_topic)
        self.obstacles = harness.publisher(MarkerArray, 'obstacles', LATCHED)
        self.command = command
        self.on = {'odom': True, 'cmd': True, 'obstacles': True}
        self.last_sent = {'odom': -math.inf, 'cmd': -math.inf, 'obstacles': -math.inf}

    def __call__(self):
        """Publish every input that is switched on (obstacles at 5 Hz).

        ``last_sent`` is read just before each publish, so no receipt can precede it.
        """
        if self.on['odom']:
            self.last_sent['odom'] = time.monotonic()
            self.odom.publish(odometry(v=0.5, stamp=self.harness.now()))
        if self.on['cmd']:
            self.last_sent['cmd'] = time.monotonic()
            self.cmd.publish(self.command)
        now = time.monotonic()
        if self.on['obstacles'] and now - self.last_sent['obstacles'] > 0.2:
            self.last_sent['obstacles'] = now
            self.obstacles.publish(markers())


def _stop_after(h, feeds, out, name, is_stop):
    """Switch ``name`` off; return seconds from its last message to the first stop received.

    Ordering, not speed: the node can only receive the last message after it was sent, and
    stops ``timeout`` after receiving it (steady clock, CLOCK_MONOTONIC like the test's);
    this process receives the stop later still.  So the result is >= timeout however
    slow the machine is; the upper bound, GRACE, is a hang detector, not a latency bound.
    """
    feeds.on[name] = False
    count = len(out)
    ok = h.spin_until(lambda: any(is_stop(m) for _, m in out[count:]),
                      TIMEOUTS[f'{name}_timeout'] + 2 * GRACE, feeds, 1.0 / RATE)
    first = next((t for t, m in out[count:] if is_stop(m)), math.inf)
    feeds.on[name] = True
    assert ok, f'no stop after {name} went silent'
    return first - feeds.last_sent[name]


@pytest.mark.slow
def test_stale_inputs_stop_the_unicycle_and_it_recovers():
    """Each silent input gives a zero twist, never before its timeout, then recovers."""
    params = {'model': 'unicycle', 'rate': RATE, 'stall_timeout': STALL_TIMEOUT, **TIMEOUTS}
    with running_filter(params=params) as proc, Harness() as h:
        out = h.collect(Twist, 'cmd_vel_out')
        feeds = Feeds(h, Twist, twist(0.5))
        assert h.wait_for_subscribers(feeds.odom, feeds.cmd, feeds.obstacles), node_log(proc)

        def moving():
            return bool(out) and out[-1][1].linear.x > 0.4

        def is_stop(msg):
            return msg.linear.x == 0.0 and msg.angular.z == 0.0

        assert h.spin_until(moving, WAIT, feeds, 1.0 / RATE), node_log(proc)
        for name in ('odom', 'cmd', 'obstacles'):
            delay = _stop_after(h, feeds, out, name, is_stop)
            timeout = TIMEOUTS[f'{name}_timeout']
            assert timeout <= delay <= timeout + GRACE, (name, delay)
            assert h.spin_until(moving, WAIT, feeds, 1.0 / RATE), f'no recovery after {name}'


@pytest.mark.slow
def test_quadrotor_stops_with_a_hover_wrench_in_command_trigger_mode():
    """Quadrotor, one step per command: stale odometry or command -> braking (hover) wrench."""
    params = {'model': 'quadrotor', 'trigger': 'command', 'rate': RATE,
              'stall_timeout': STALL_TIMEOUT, **TIMEOUTS}
    nominal = WrenchStamped()
    nominal.header.frame_id = 'cf1'
    nominal.wrench.force.z = 0.2
    hover = crazyflie.MASS * crazyflie.GRAVITY
    with running_filter(params=params) as proc, Harness() as h:
        out = h.collect(WrenchStamped, 'wrench_out')
        feeds = Feeds(h, WrenchStamped, nominal)
        assert h.wait_for_subscribers(feeds.odom, feeds.cmd, feeds.obstacles), node_log(proc)

        def filtered():
            return bool(out) and abs(out[-1][1].wrench.force.z - 0.2) < 1e-6

        def is_stop(msg):
            return abs(msg.wrench.force.z - hover) < 1e-6 and msg.header.frame_id == 'cf1'

        assert h.spin_until(filtered, WAIT, feeds, 1.0 / RATE), node_log(proc)
        for name in ('odom', 'cmd'):
            delay = _stop_after(h, feeds, out, name, is_stop)
            timeout = TIMEOUTS[f'{name}_timeout']
            assert timeout <= delay <= timeout + GRACE, (name, delay)
            assert h.spin_until(filtered, WAIT, feeds, 1.0 / RATE), f'no recovery after {name}'
