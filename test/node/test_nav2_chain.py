"""The Nav2 chain over real DDS: controller -> cmd_vel_nav -> safety_filter -> cmd_vel.

The filter runs as a child process with the shipped ``config/nav2_safety_filter.yaml`` and
the remappings of ``launch/nav2_safety_filter.launch.py`` (read from the file: the launch
packages are not in the venv).  The test process stands in for the rest of the stack: a
controller publishing a steady forward ``cmd_vel_nav``, a diff-drive base whose odometry
follows ``cmd_vel`` and a laser on ``scan``.  No MarkerArray is ever published: the
shipped parameters take obstacles from the scan only (``use_markers: false``), and the node
does not subscribe ``obstacles``.
"""
import ast
import contextlib
import math
import time

import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import Twist
from nav_msgs.msg import Odometry
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import LaserScan

from node_harness import (
    Harness,
    LATCHED,
    latest_status,
    node_log,
    odometry,
    REPO,
    running_filter,
    twist,
)
from polyc2bf_ros.filter_parameters import load_parameters

LAUNCH_FILE = REPO / 'launch' / 'nav2_safety_filter.launch.py'
PARAMS_FILE = REPO / 'config' / 'nav2_safety_filter.yaml'
WAIT = 60.0  # wall-clock bound on each wait: a starved 2-core machine is slow, not wrong
SPEED = 0.4  # m/s, the controller's nominal
PERIOD = 0.02  # s between the stand-ins' messages, and the base's largest integration step
BEAMS = 181
WALL_AHEAD = 0.8  # m from the base when the wall appears
ROBOT_RADIUS = load_parameters([PARAMS_FILE], (), '')['filter.robot_radius']


def launch_remappings():
    """Return ``{node topic: Nav2 topic}``: the launch file's remappings at their defaults."""
    calls = [node for node in ast.walk(ast.parse(LAUNCH_FILE.read_text()))
             if isinstance(node, ast.Call)]
    defaults = {c.args[0].value: k.value.value for c in calls
                if getattr(c.func, 'id', '') == 'DeclareLaunchArgument'
                for k in c.keywords if k.arg == 'default_value'
                and isinstance(k.value, ast.Constant)}
    node = next(c for c in calls if getattr(c.func, 'id', '') == 'Node')
    remappings = next(k.value for k in node.keywords if k.arg == 'remappings')
    return {pair.elts[0].value: defaults[pair.elts[1].args[0].value]
            for pair in remappings.elts}


def scan(wall_distance=None):
    """Return a half-turn scan from the base: a wall ``wall_distance`` ahead, or no returns."""
    msg = LaserScan()
    msg.header.frame_id = 'base_link'
    msg.angle_min, msg.angle_increment = -0.5 * math.pi, math.pi / (BEAMS - 1)
    msg.angle_max = msg.angle_min + (BEAMS - 1) * msg.angle_increment
    msg.range_min, msg.range_max = 0.05, 10.0
    ranges = []
    for i in range(BEAMS):
        cos = math.cos(msg.angle_min + i * msg.angle_increment)
        hit = wall_distance is not None and cos > 0.2
        ranges.append(wall_distance / cos if hit else math.inf)
    msg.ranges = ranges
    return msg


class Chain:
    """The stand-ins around the filter: controller, base, laser; ``run`` drives them."""

    def __init__(self, harness, proc):
        """Create the publishers and collectors; wait until the filter has subscribed."""
        topics = launch_remappings()
        self.harness, self.proc = harness, proc
        self.out = harness.collect(Twist, topics['cmd_vel_out'])
        self.state = harness.collect(DiagnosticStatus, 'safety_filter/state', LATCHED)
        self.diagnostics = harness.collect(DiagnosticArray, '/diagnostics')
        self._odom = harness.publisher(Odometry, 'odom')
        self._cmd = harness.publisher(Twist, topics['cmd_vel_in'])
        self._scan = harness.publisher(LaserScan, 'scan', qos_profile_sensor_data)
        assert harness.wait_for_subscribers(self._odom, self._cmd, self._scan,
                                            timeout=WAIT), node_log(proc)
        assert harness.node.count_subscribers('/obstacles') == 0, node_log(proc)
        self.x = 0.0  # the base's position along its heading (odometry frame x)
        self.wall_x = None  # where the wall stands; None: nothing in range
        self.scanning = True
        self._last = None

    def speed(self):
        """Return the last ``cmd_vel`` forward speed (None before the first)."""
        return self.out[-1][1].linear.x if self.out else None

    def _feed(self):
        """Move the base at the last safe speed; publish odometry, nominal and scan."""
        now, speed = time.monotonic(), self.speed() or 0.0
        if self._last is not None:
            self.x += speed * min(now - self._last, PERIOD)  # a starved test pauses the base
        self._last = now
        self._odom.publish(odometry(x=self.x, v=speed))
        self._cmd.publish(twist(SPEED))
        if self.scanning:
            self._scan.publish(scan(None if self.wall_x is None else self.wall_x - self.x))

    def run(self, predicate):
        """Drive the chain until ``predicate()`` holds; fail with the node's log if never."""
        assert self.harness.spin_until(predicate, WAIT, self._feed, PERIOD), (
            self.speed(), self.x, node_log(self.proc))

    def status(self):
        """Return the newest ``/diagnostics`` values of the filter."""
        return latest_status(self.diagnostics)[1]

    def action(self):
        """Return the newest ``~/state`` ``(action, status)``."""
        if not self.state:
            return None
        values = {kv.key: kv.value for kv in self.state[-1][1].values}
        return values['action'], values['status']


@contextlib.contextmanager
def nav2_chain():
    """Start the filter as the launch file does and yield the ``Chain`` around it."""
    ros_args = ['--params-file', str(PARAMS_FILE), '-p', 'use_sim_time:=false']
    for topic, nav2_topic in launch_remappings().items():
        ros_args += ['-r', f'{topic}:={nav2_topic}']
    with running_filter(*ros_args) as proc, Harness() as h:
        yield Chain(h, proc)


def passing(chain):
    """Return whether ``cmd_vel`` is the nominal and ``~/state`` says the filter passed it."""
    speed = chain.speed()
    return speed is not None and abs(speed - SPEED) < 0.01 and chain.action() == ('pass', 'ok')


def test_the_test_uses_the_launch_files_nav2_topics():
    """The launch file remaps the node's command topics onto Nav2's defaults."""
    assert launch_remappings() == {'cmd_vel_in': 'cmd_vel_nav', 'cmd_vel_out': 'cmd_vel'}


@pytest.mark.slow
def test_an_empty_scan_passes_the_nominal_and_a_wall_in_the_scan_brakes():
    """No return: the nominal passes; a wall appears ahead: the base brakes short of it."""
    with nav2_chain() as chain:
        chain.run(lambda: passing(chain))
        chain.wall_x = chain.x + WALL_AHEAD

        def braked():
            # Stopped well past where the wall appeared, by the filter, not by a watchdog.
            return (chain.speed() < 0.02 and chain.wall_x - chain.x < 0.5 * WALL_AHEAD
                    and chain.action() is not None and chain.action()[1] != 'stale_stop')

        chain.run(braked)
        chain.run(lambda: int(chain.status().get('obstacles_in_use', 0)) > 0)
        gap = chain.wall_x - chain.x
        assert gap > ROBOT_RADIUS, (gap, node_log(chain.proc))


@pytest.mark.slow
def test_a_silent_scan_source_stops_the_base_until_scans_return():
    """Scans stop: after scan_timeout the output is a stop (stale scan_scan); then resumes."""
    with nav2_chain() as chain:
        chain.run(lambda: passing(chain))
        chain.scanning = False

        def stopped_by_the_scan_watchdog():
            return (chain.speed() == 0.0 and chain.action() == ('stop', 'stale_stop')
                    and 'scan_scan' in chain.status().get('stale_inputs', ''))

        chain.run(stopped_by_the_scan_watchdog)
        assert chain.proc.poll() is None, node_log(chain.proc)
        chain.scanning = True
        chain.run(lambda: passing(chain))
