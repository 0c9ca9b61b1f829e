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
from builtin_interfaces.msg import Time
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


def scan(wall_distance=None, box=None):
    """Return a half-turn scan from the base: a wall ``wall_distance`` ahead, or no returns.

    ``box``: (x_min, y_min, x_max, y_max) in the base frame, an axis-aligned box the beams
    hit instead (slab test of each beam against it).
    """
    msg = LaserScan()
    msg.header.frame_id = 'base_link'
    msg.angle_min, msg.angle_increment = -0.5 * math.pi, math.pi / (BEAMS - 1)
    msg.angle_max = msg.angle_min + (BEAMS - 1) * msg.angle_increment
    msg.range_min, msg.range_max = 0.05, 10.0
    ranges = []
    for i in range(BEAMS):
        angle = msg.angle_min + i * msg.angle_increment
        cos = math.cos(angle)
        if box is not None:
            ranges.append(_box_range(cos, math.sin(angle), box))
            continue
        hit = wall_distance is not None and cos > 0.2
        ranges.append(wall_distance / cos if hit else math.inf)
    msg.ranges = ranges
    return msg


def _box_range(dx, dy, box):
    """Return the range along the unit ray (dx, dy) from the origin to ``box`` (inf: a miss)."""
    near, far = 0.0, math.inf
    for d, low, high in ((dx, box[0], box[2]), (dy, box[1], box[3])):
        if abs(d) < 1e-12:
            if not low <= 0.0 <= high:
                return math.inf
            continue
        t0, t1 = sorted((low / d, high / d))
        near, far = max(near, t0), min(far, t1)
    return near if near <= far else math.inf


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
        self.box = None  # a crossing box: f(t) -> (x_min, y_min, x_max, y_max), odom frame
        self.nominal = SPEED
        self.scanning = True
        self.trace = []  # (t, x, speed, box) per feed, while a box crosses
        self._last = self._start = None

    def speed(self):
        """Return the last ``cmd_vel`` forward speed (None before the first)."""
        return self.out[-1][1].linear.x if self.out else None

    def _feed(self):
        """Move the base at the last safe speed; publish odometry, nominal and scan.

        The base's clock advances by the wall time since the last feed, at most ``PERIOD``
        (a starved test pauses the base and the box); odometry and scans carry it as stamps.
        """
        now, speed = time.monotonic(), self.speed() or 0.0
        if self._last is None:
            self._start, self._clock = now, 0.0
        else:
            step = min(now - self._last, PERIOD)
            self._clock += step
            self.x += speed * step
        self._last = now
        stamp = Time(sec=1000 + int(self._clock), nanosec=int(1e9 * (self._clock % 1.0)))
        self._odom.publish(odometry(x=self.x, v=speed, stamp=stamp))
        self._cmd.publish(twist(self.nominal))
        if not self.scanning:
            return
        if self.box is not None:
            box = self.box(self._clock)
            self.trace.append((self._clock, self.x, speed, box))
            message = scan(box=(box[0] - self.x, box[1], box[2] - self.x, box[3]))
        else:
            message = scan(None if self.wall_x is None else self.wall_x - self.x)
        message.header.stamp = stamp
        self._scan.publish(message)

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


def _contacts(trace):
    """Return [(t, gap, closing speed)] of the fed states where the disc touches the box.

    The gap is the distance from the base to the box less ``ROBOT_RADIUS``; the closing
    speed is the base's velocity (along x) towards the box's centre.
    """
    contacts = []
    for t, x, speed, (x0, y0, x1, y1) in trace:
        dx, dy = max(x0 - x, 0.0, x - x1), max(y0, 0.0, -y1)
        gap = math.hypot(dx, dy) - ROBOT_RADIUS
        if gap <= 0.0:
            cx, cy = 0.5 * (x0 + x1) - x, 0.5 * (y0 + y1)
            contacts.append((t, gap, speed * cx / max(math.hypot(cx, cy), 1e-9)))
    return contacts


@pytest.mark.slow
def test_a_box_crossing_the_path_is_given_way_from_the_scan_alone():
    """A 1 m box crosses the base's lane at 0.6 m/s, timed to meet it at 1 m/s.

    The shipped Nav2 file tracks its scan: the base brakes for the box and is never the one
    that closes on it (no contact with the base moving towards the box at over 0.05 m/s).
    Without the filter the base would reach the lane at x = 3 m just as the box fills it.
    """
    lane_x, side, speed = 3.0, 1.0, 0.6
    with nav2_chain() as chain:
        chain.nominal = 1.0
        chain.run(lambda: chain.speed() is not None and chain.speed() > 0.9)
        start_x, start = chain.x, chain._clock
        # The base reaches the lane in (lane_x - start_x) s; the box's far face is then at 0.
        arrive = start + lane_x - start_x
        chain.box = lambda t: (lane_x - 0.5 * side, speed * (t - arrive) - side,
                               lane_x + 0.5 * side, speed * (t - arrive))
        chain.run(lambda: chain.trace and chain.box(chain._clock)[1] > 1.0)
        contacts = _contacts(chain.trace)
        at_fault = [c for c in contacts if c[2] > 0.05]
        assert not at_fault, (at_fault, node_log(chain.proc))
        slowest = min(s for _, _, s, _ in chain.trace)
        assert slowest < 0.5, (slowest, node_log(chain.proc))
