"""Watchdogs over real DDS: stale odometry, command or obstacles -> stop; recovery after."""
import math
import time

import pytest
from geometry_msgs.msg import Twist, WrenchStamped
from nav_msgs.msg import Odometry
from visualization_msgs.msg import MarkerArray

from node_harness import Harness, LATCHED, markers, node_log, odometry, running_filter, twist
from polyc2bf_ros.core import crazyflie

RATE = 50.0
TIMEOUTS = {'odom_timeout': 0.3, 'cmd_timeout': 0.3, 'obstacles_timeout': 0.6}
# Scheduling slack on a loaded 2-core machine; the behaviour, not the latency, is under test.
SLACK = 0.6


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
        self._last_obstacles = 0.0

    def __call__(self):
        """Publish every input that is switched on (obstacles at 5 Hz)."""
        if self.on['odom']:
            self.odom.publish(odometry(v=0.5, stamp=self.harness.now()))
        if self.on['cmd']:
            self.cmd.publish(self.command)
        if self.on['obstacles'] and time.monotonic() - self._last_obstacles > 0.2:
            self.obstacles.publish(markers())
            self._last_obstacles = time.monotonic()


def _stop_after(h, feeds, out, name, is_stop, timeout):
    """Switch ``name`` off; return seconds until the first stop output; switch it back on."""
    feeds.on[name] = False
    off = time.monotonic()
    count = len(out)
    ok = h.spin_until(lambda: any(is_stop(m) for _, m in out[count:]), timeout + SLACK + 1.0,
                      feeds, 1.0 / RATE)
    first = next((t for t, m in out[count:] if is_stop(m)), math.inf)
    feeds.on[name] = True
    assert ok, f'no stop after {name} went silent'
    return first - off


@pytest.mark.slow
def test_stale_inputs_stop_the_unicycle_and_it_recovers():
    """Each silent input gives a zero twist within its timeout plus a period, then recovers."""
    with running_filter(params={'model': 'unicycle', 'rate': RATE, **TIMEOUTS}) as proc, \
            Harness() as h:
        out = h.collect(Twist, 'cmd_vel_out')
        feeds = Feeds(h, Twist, twist(0.5))
        assert h.wait_for_subscribers(feeds.odom, feeds.cmd, feeds.obstacles), node_log(proc)

        def moving():
            return bool(out) and out[-1][1].linear.x > 0.4

        def is_stop(msg):
            return msg.linear.x == 0.0 and msg.angular.z == 0.0

        assert h.spin_until(moving, 15.0, feeds, 1.0 / RATE), node_log(proc)
        for name in ('odom', 'cmd', 'obstacles'):
            delay = _stop_after(h, feeds, out, name, is_stop, TIMEOUTS[f'{name}_timeout'])
            timeout = TIMEOUTS[f'{name}_timeout']
            # The last message may have left up to one feed period (0.2 s) before the switch.
            assert timeout - 0.25 <= delay <= timeout + 1.0 / RATE + SLACK, (name, delay)
            assert h.spin_until(moving, 5.0, feeds, 1.0 / RATE), f'no recovery after {name}'


@pytest.mark.slow
def test_quadrotor_stops_with_a_hover_wrench_in_command_trigger_mode():
    """Quadrotor, one step per command: stale odometry or command -> braking (hover) wrench."""
    params = {'model': 'quadrotor', 'trigger': 'command', 'rate': RATE, **TIMEOUTS}
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

        assert h.spin_until(filtered, 15.0, feeds, 1.0 / RATE), node_log(proc)
        for name in ('odom', 'cmd'):
            delay = _stop_after(h, feeds, out, name, is_stop, TIMEOUTS[f'{name}_timeout'])
            assert delay <= TIMEOUTS[f'{name}_timeout'] + 0.02 + SLACK, (name, delay)
            assert h.spin_until(filtered, 5.0, feeds, 1.0 / RATE), f'no recovery after {name}'
