"""Helpers for the node tests: start ``safety_filter`` processes, drive them over real DDS.

``running_filter`` starts the node as a child process with ``--ros-args`` (it
inherits the per-worker ``ROS_DOMAIN_ID`` from test/conftest.py) and always
stops it.  ``Harness`` is the test's own ROS node in a private context with
publishers, collecting subscriptions and spin helpers.  Message builders keep
the tests short.
"""
import contextlib
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from types import SimpleNamespace

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Point, Twist, WrenchStamped
from nav_msgs.msg import Odometry
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from visualization_msgs.msg import Marker, MarkerArray

from sim_bridge.launcher import stop_processes

REPO = Path(__file__).resolve().parents[2]
RELIABLE = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
RESEND = 5.0  # s without a reply before an idempotent request is sent again (Harness.call)


@contextlib.contextmanager
def running_filter(*ros_args, params=None, module='polyc2bf_ros.safety_filter_node', env=None):
    """Run ``safety_filter`` with ``--ros-args ros_args`` and ``-p name:=value`` per param.

    ``module``: the executable's module (``polyc2bf_ros.safety_filter_lifecycle`` for the
    managed node); ``env``: variables to add to the environment.  Yields the ``Popen``; its
    combined output is in ``proc.log_path``.  The process gets SIGINT on exit, then SIGKILL
    if it lingers.
    """
    args = [sys.executable, '-m', module, '--ros-args', *ros_args]
    for name, value in (params or {}).items():
        args += ['-p', f'{name}:={_ros_value(value)}']
    log_dir = tempfile.mkdtemp(prefix='safety_filter_')
    log_path = Path(log_dir) / 'node.log'
    env = dict(os.environ, ROS_LOG_DIR=log_dir, PYTHONUNBUFFERED='1', **(env or {}))
    with open(log_path, 'w') as log:
        proc = subprocess.Popen(args, cwd=REPO, env=env, stdout=log, stderr=subprocess.STDOUT)
    proc.log_path = log_path
    try:
        yield proc
    finally:
        stop_processes([proc], timeout=5.0)


def _ros_value(value):
    if isinstance(value, bool):
        return str(value).lower()
    return str(value)


def node_log(proc):
    """Return what the filter process printed so far (for assertion messages)."""
    return proc.log_path.read_text()


class Harness:
    """The test's ROS node in its own context; use as a context manager."""

    def __init__(self, namespace=''):
        """Create the context, the node ``harness`` in ``namespace`` and an executor."""
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node('harness', namespace=namespace, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._clients = {}

    def __enter__(self):
        """Return self."""
        return self

    def __exit__(self, *exc):
        """Destroy the node and shut the context down."""
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)

    def publisher(self, msg_type, topic, qos=RELIABLE):
        """Create a publisher."""
        return self.node.create_publisher(msg_type, topic, qos)

    def collect(self, msg_type, topic, qos=RELIABLE):
        """Subscribe and return a list that fills with ``(monotonic receipt time, msg)``."""
        received = []
        self.node.create_subscription(
            msg_type, topic, lambda msg: received.append((time.monotonic(), msg)), qos)
        return received

    def spin_for(self, seconds):
        """Process callbacks for ``seconds``."""
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=min(0.01, max(end - time.monotonic(), 0.0)))

    def spin_until(self, predicate, timeout, every=None, period=0.02):
        """Spin until ``predicate()`` is true (return True) or ``timeout`` s pass (False).

        ``every()``, if given, is called each ``period`` s (e.g. to keep publishing).
        """
        end = time.monotonic() + timeout
        next_call = time.monotonic()
        while time.monotonic() < end:
            if every is not None and time.monotonic() >= next_call:
                every()
                next_call += period
            if predicate():
                return True
            self.executor.spin_once(timeout_sec=0.005)
        return predicate()

    def filter_io(self, proc, command_type=Twist, command_topic=None, odom_qos=RELIABLE,
                  obstacles=True):
        """Wire the filter's usual inputs and outputs; wait until ``proc`` subscribed.

        Returns a namespace with the publishers ``odom``, ``cmd`` and
        ``obstacles`` (latched; None with ``obstacles`` false: a node with
        ``use_markers:=false``) and the collected lists ``out`` (safe commands)
        and ``diagnostics``.  ``command_topic`` defaults to ``cmd_vel_in`` or
        ``wrench_in`` by ``command_type``.
        """
        wrench = command_type is WrenchStamped
        io = SimpleNamespace(
            out=self.collect(command_type, 'wrench_out' if wrench else 'cmd_vel_out'),
            diagnostics=self.collect(DiagnosticArray, '/diagnostics'),
            odom=self.publisher(Odometry, 'odom', odom_qos),
            cmd=self.publisher(command_type, command_topic or (
                'wrench_in' if wrench else 'cmd_vel_in')),
            obstacles=self.publisher(MarkerArray, 'obstacles', LATCHED) if obstacles else None)
        inputs = (io.odom, io.cmd, io.obstacles) if obstacles else (io.odom, io.cmd)
        assert self.wait_for_subscribers(*inputs), node_log(proc)
        return io

    def wait_for_subscribers(self, *publishers, timeout=15.0):
        """Wait until every publisher has a matched subscription."""
        return self.spin_until(
            lambda: all(p.get_subscription_count() > 0 for p in publishers), timeout)

    def call(self, srv_type, name, request, timeout=10.0, resend_after=None):
        """Call a service and return its response (``None`` on timeout).

        ``wait_for_service`` only sees the request path matched; a server that
        answers before its reply writer has matched this client drops the response
        ("failed to send response (timeout)").  For an idempotent request pass
        ``resend_after`` (s): the request is sent again at that period until any
        copy is answered.  Clients are kept per service, so once a reply path is
        matched it stays matched.
        """
        client = self._clients.get(name)
        if client is None:
            client = self._clients[name] = self.node.create_client(srv_type, name)
        end = time.monotonic() + timeout
        if not client.wait_for_service(timeout_sec=timeout):
            return None
        futures = []
        while time.monotonic() < end:
            futures.append(client.call_async(request))
            left = end - time.monotonic()
            wait = left if resend_after is None else min(resend_after, left)
            if self.spin_until(lambda: any(f.done() for f in futures), wait):
                return next(f.result() for f in futures if f.done())
        return None

    def now(self):
        """Return the current ROS time as a ``builtin_interfaces/Time``."""
        return self.node.get_clock().now().to_msg()


def odometry(x=0.0, y=0.0, yaw=0.0, v=0.0, omega=0.0, stamp=None, frame='odom'):
    """Planar odometry: pose (x, y, yaw), body twist (v, 0, 0) and yaw rate omega."""
    msg = Odometry()
    msg.header.frame_id = frame
    msg.child_frame_id = 'base_link'
    if stamp is not None:
        msg.header.stamp = stamp
    msg.pose.pose.position.x, msg.pose.pose.position.y = float(x), float(y)
    msg.pose.pose.orientation.z = math.sin(0.5 * yaw)
    msg.pose.pose.orientation.w = math.cos(0.5 * yaw)
    msg.twist.twist.linear.x = float(v)
    msg.twist.twist.angular.z = float(omega)
    return msg


def twist(v=0.0, omega=0.0, vy=0.0):
    """Twist with linear.x = v, linear.y = vy, angular.z = omega."""
    msg = Twist()
    msg.linear.x, msg.linear.y, msg.angular.z = float(v), float(vy), float(omega)
    return msg


def wall(points, ns='walls', marker_id=0, stamp=None, frame='odom', width=0.1, z=0.0):
    """LINE_STRIP marker through ``points`` (a 2-point strip is a wall of ``width``)."""
    marker = Marker(ns=ns, id=marker_id, type=Marker.LINE_STRIP, action=Marker.ADD)
    marker.header.frame_id = frame
    if stamp is not None:
        marker.header.stamp = stamp
    marker.pose.orientation.w = 1.0
    marker.scale.x = float(width)
    marker.points = [Point(x=float(px), y=float(py), z=float(z)) for px, py in points]
    return marker


def markers(*items):
    """MarkerArray of ``items``."""
    return MarkerArray(markers=list(items))


# ~/state statuses of a step the filter computed (a watchdog's stop has the stale input's).
FILTERED_STATUSES = ('ok', 'recovering', 'brake', 'backup', 'evade')


def status_values(status):
    """``{key: value}`` of a ``DiagnosticStatus``."""
    return {kv.key: kv.value for kv in status.values}


def braked_by_filter(out, states, nominal):
    """Return True when the newest safe command is slower than ``nominal`` by the filter.

    ``out``: collected Twists; ``states``: collected ``~/state``, whose newest must be a
    filtered step's ``limit`` or ``stop``, not a stop for a stale or invalid input.
    """
    if not (out and states) or out[-1][1].linear.x >= nominal - 0.005:
        return False
    values = status_values(states[-1][1])
    return values['action'] in ('limit', 'stop') and values['status'] in FILTERED_STATUSES


def diagnostic_values(msg, name_part='safety filter'):
    """``(status, {key: value})`` of the first status whose name contains ``name_part``."""
    for status in msg.status:
        if name_part in status.name:
            return status, {kv.key: kv.value for kv in status.values}
    return None, {}


def latest_status(diagnostics, name_part='safety filter'):
    """``(status, values)`` of the newest matching entry in a collected DiagnosticArray list."""
    for _, msg in reversed(diagnostics):
        status, values = diagnostic_values(msg, name_part)
        if status is not None:
            return status, values
    return None, {}

