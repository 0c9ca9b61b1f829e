"""``sim_bridge``: the PyBullet world of a scenario as ROS topics, recorded into one MCAP bag.

Per robot namespace ``<ns>`` (the scenario's robot names), in frame ``frame_id``
(default ``world``) and stamped with sim time:

- publishes ``<ns>/odom`` (nav_msgs/Odometry: pose of the base, twist in the
  body frame ``<ns>/base_link``) and ``<ns>/obstacles``
  (visualization_msgs/MarkerArray, reliable + transient local): static prisms
  as ``LINE_STRIP`` footprints at z_min with ``scale.z`` = height (``ns``
  ``obstacles``), moving prisms as the same outline around a moving marker pose,
  every other robot as a ``CYLINDER`` (``ns`` ``robots``), so the filter
  estimates their velocities from successive poses.  Each control period sends
  the moving markers (if any); at the start, when an obstacle pops up, and
  every ``obstacles_refresh`` s of sim time, the full set (static obstacles
  included; empty if there is nothing).  In lockstep full sets are also at
  least ``obstacles_refresh_wall`` s of wall time apart: faster than real
  time, a sim-time refresh would only repeat unchanged static obstacles, which
  every consumer re-reads (with 50 obstacles the filter spent 3.1 ms of CPU
  per period with a full set every 0.2 s, 0.6 ms with one every 5 s).
  A filter's ``obstacles_timeout`` (wall) must exceed ``obstacles_refresh`` /
  real-time factor and, in lockstep, ``obstacles_refresh_wall``, or be 0;
- with ``lidar.enabled``, per robot that carries one (``lidar.robots``; empty: all)
  publishes ``<ns>/scan`` (sensor_msgs/LaserScan, frame ``<ns>/laser``): the
  simulated 2-D lidar of ``sim_bridge.lidar`` (``lidar.beams``, ``field_of_view``,
  ``range_min``, ``range_max``, ``noise_std``, ``height``, ``mount`` [x, y, yaw] in
  the base frame), a scan every ``physics_rate / lidar.rate`` physics steps (a
  whole number, else refused like a control rate), stamped with the step's sim
  time and sent with the next period's topics, after the odometry; and once, at
  the start, the base -> laser transforms on ``/tf_static`` (reliable +
  transient local; published when ``tf2_msgs`` is importable, recorded either
  way).  With ``obstacle_markers`` off the obstacle topics carry empty
  MarkerArrays only (the filter's obstacle watchdog still needs them), so a
  filter knows the world only from its scans;
- publishes ``/clock`` (rosgraph_msgs/Clock) once per control period;
- ``/tf`` (world -> ``<ns>/base_link``): published when ``tf2_msgs`` is
  importable; the PyPI ROS wheels lack it, so here ``/tf`` is only recorded,
  serialized by ``sim_bridge.cdr``;
- subscribes to the safe command: ``<ns>/cmd_vel_out`` (TwistStamped,
  quadruped, diff drive: ``linear.x`` = v, ``angular.z`` = omega, tracked by the plant) or
  ``<ns>/wrench_out`` (WrenchStamped, Crazyflie: ``force.z`` = collective thrust,
  ``torque`` = body torques, mixed into rotor thrusts).  Commands are held
  (zero-order hold); a robot whose last command is older than
  ``command_timeout`` s of sim time, or that never got one, brakes (quadruped, diff drive:
  zero velocity, ramped at the plant's acceleration limit; Crazyflie: the
  quadrotor model's hover brake).

Lockstep (``lockstep: true``, default): each control period the bridge publishes
odom, obstacles, clock and tf for sim time t, then waits until every robot that
takes part has sent a command whose header stamp equals t (the nominal
controller copies the odometry stamp, the filter the command's header; commands
with other stamps, e.g. the filter's watchdog stops, are recorded but not
applied), and only then steps physics to t + T.  Runs are deterministic and as
fast as the processes allow; bitwise so when every consumer pairs the
command with the same-stamp odometry, which ``safety_filter`` does with
``trigger: command`` and ``match_stamps: true`` (without it, it steps with the
newest odometry it holds, under load possibly t - T).  At
start the t = 0 topics are re-sent every 0.25 s (wall) until every robot has
answered or ``startup_timeout`` passes (subscribers that are still being
discovered miss the first ones).  The bag holds them once, like every other
period: the re-sends are published, not recorded, and only a robot's first
command stamped t is applied, so neither depends on how long discovery took
(answers to re-sends are recorded as received).  A robot takes part once it
has answered, and one that does not answer within ``lockstep_timeout`` (wall) is
dropped from the wait with a warning (it brakes after ``command_timeout`` and
rejoins with its next matching command).  A robot that never gets a command
simply brakes, without slowing the run.

Real time (``lockstep: false``): periods are paced at ``real_time_factor`` times
wall time; the latest command is applied whenever it arrives.

The control period is ``n = physics_rate / control_rate`` physics steps
(``Scenario.substeps``; 240 / 120 Hz -> 2 steps): equal periods for the
filter's sample-and-hold margin.  Rates that do not make a whole number of
steps (240 / 100 Hz) are refused, not rounded: the error names both rates and
valid control rates nearby, and the node exits with status 1, like any bad
parameter.

With ``record: true`` every topic published or received goes into one bag
(``bag_path``, default ``runs/<timestamp>/run``; ``sim_bridge.recorder``): the
above, the nominal commands ``cmd_vel_in`` / ``wrench_in`` (subscribed for
recording only), the filter's ``<ns>/safety_filter/markers`` (unless
``record_filter_markers`` is off: a filter renders its markers only while
someone subscribes, ~10 Hz of work per filter that large or fast runs may
not want) and ``/diagnostics``.
Log time is sim time.  Published messages are serialized once (odometry
and tf by ``sim_bridge.cdr``) and the same bytes are published and
recorded; received ones are taken raw.  Messages are waited for on one rcl
wait set of the bridge's subscriptions (``sim_bridge.inbox``), the executor turns every
0.1 s (wall) for the parameter services.  SIGINT/SIGTERM
close the bag cleanly (``close_on_signals``; rclpy's own handlers are off, the
bag path being a parameter).  At the end of the scenario (exit 0, summary on
stdout) or on shutdown the run metrics (``sim_bridge.metrics``) are written
to ``metrics_path`` (default: ``metrics.json`` beside the bag directory).

The markers are built by ``sim_bridge.bridge_markers``.  The rest is one module of over
500 lines (100 of them this docstring) on purpose: ``BridgeNode``'s parameters, per-robot
topics, publishing and recording of a period, lockstep waits and run loop all act on the
node's one recorder, current stamp and robot list, which a cut would have to pass around.
"""
import dataclasses
import gc
import json
import math
import signal
import sys
import time
from datetime import datetime
from pathlib import Path

import rclpy
from builtin_interfaces.msg import Time
from nav_msgs.msg import Odometry
from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
)
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import serialize_message
from rclpy.signals import SignalHandlerOptions
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import LaserScan
from visualization_msgs.msg import MarkerArray

from polyc2bf_ros.conversions import SerializedCommand
from polyc2bf_ros.core.models import make_model
from polyc2bf_ros.loop_log import LoopLogger
from polyc2bf_ros.node_main import CONFIGURATION_ERRORS, log_configuration_error
from sim_bridge.bag_reader import message_class
from sim_bridge.bridge_markers import ObstacleMarkers
from sim_bridge.cdr import OdometryCdr, tf_message_cdr, TF_MESSAGE_TYPE
from sim_bridge.inbox import Inbox
from sim_bridge.lidar import (
    laser_scan,
    lidar_settings,
    LidarSettings,
    MAX_BEAMS,
    mount_transform,
    PARAMETER_FIELDS,
    RobotLidars,
    SCAN_TOPIC,
)
from sim_bridge.metrics import RunMetrics
from sim_bridge.recorder import BagRecorder, close_on_signals
from sim_bridge.robots import ROBOT_TYPES
from sim_bridge.scenario import load_scenario
from sim_bridge.world import SimWorld

try:
    from tf2_msgs.msg import TFMessage
except ImportError:
    TFMessage = None

LIDAR = LidarSettings()
# name: (default, (min, max) or None, description).  Negative numbers mean "from the scenario".
PARAMETERS = {
    'scenario': ('', None, 'scenario name (config/scenarios/<name>.yaml) or YAML path; required'),
    'physics_rate': (-1.0, (-1.0, 10000.0), "physics rate [Hz]; -1 = the scenario's (240)"),
    'control_rate': (-1.0, (-1.0, 10000.0), "control rate [Hz], dividing physics_rate; -1 = the "
                     "scenario's (120)"),
    'duration': (-1.0, (-1.0, 1e6), "sim time [s] after which the run ends; -1 = scenario's"),
    'seed': (-1, (-1, 2 ** 31 - 1), "random obstacle seed; -1 = the scenario's"),
    'lockstep': (True, None, "wait for every robot's command of period t before stepping"),
    'real_time_factor': (1.0, (0.01, 1000.0), 'pace (sim s per wall s) when lockstep is off'),
    'lockstep_timeout': (2.0, (0.01, 60.0), 'wall [s] a lockstep period waits for a robot'),
    'startup_timeout': (10.0, (0.0, 600.0), "wall [s] to wait for every robot's first command"),
    'command_timeout': (0.5, (0.001, 60.0), 'sim [s]: an older command -> the robot brakes'),
    'obstacles_refresh': (0.2, (0.001, 60.0), 'sim [s] between full obstacle marker sets'),
    'obstacles_refresh_wall': (0.5, (0.0, 60.0), 'lockstep: wall [s] at least between full '
                               "obstacle marker sets (below the filters' obstacles_timeout)"),
    'frame_id': ('world', None, 'frame of odometry, obstacles and tf'),
    'record': (False, None, 'record every topic into one MCAP bag'),
    'record_filter_markers': (True, None, "subscribe to (and record) each robot's "
                              'safety_filter/markers; off spares every filter rendering them'),
    'bag_path': ('', None, 'bag directory; empty = runs/<timestamp>/run'),
    'metrics_path': ('', None, 'metrics JSON; empty = metrics.json beside the bag (if any)'),
    'obstacle_markers': (True, None, 'publish the obstacles as markers; false: empty marker '
                         'arrays only (the filters then sense them, e.g. by lidar)'),
    'lidar.enabled': (False, None, 'simulate a 2-D lidar: <ns>/scan and /tf_static'),
    'lidar.robots': ('', None, 'comma-separated robots that carry a lidar; empty: every robot'),
    'lidar.beams': (LIDAR.beams, (1, MAX_BEAMS), 'beams per scan'),
    'lidar.field_of_view': (LIDAR.field_of_view, (0.0, LIDAR.field_of_view),
                            'field of view [rad], centred on the sensor x axis'),
    'lidar.range_min': (LIDAR.range_min, (0.0, 1000.0), 'shortest range [m] reported valid'),
    'lidar.range_max': (LIDAR.range_max, (0.0, 1000.0), 'longest range [m]; beyond: +inf'),
    'lidar.rate': (LIDAR.rate, (0.0, 10000.0), 'scans per sim second, dividing physics_rate'),
    'lidar.noise_std': (LIDAR.noise_std, (0.0, 10.0), 'Gaussian range noise [m] (seeded)'),
    'lidar.height': (LIDAR.height, (-10.0, 10.0), 'scan plane above the base [m]'),
    'lidar.mount': (list(LIDAR.mount), None, '[x, y, yaw] of the sensor in the base frame'),
}
PUBLISHED_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
LATCHED_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
# What the safety filter and nominal controller offer (doc/safety_filter.md), for the bag.
COMMAND_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE)
DIAGNOSTICS_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
RECEIVE_DEPTH = 100  # reader history of the bridge's subscriptions (recorded as offered above)
STARTUP_RESEND = 0.25  # wall s between re-sends of the t = 0 topics while waiting
SERVICE_PERIOD = 0.1  # wall s between turns of the executor for services; longest wait


def stamp(ns):
    """Return builtin_interfaces/Time of ``ns`` nanoseconds."""
    sec, nanosec = divmod(ns, 1_000_000_000)
    return Time(sec=sec, nanosec=nanosec)


@dataclasses.dataclass
class _Robot:
    """Per-robot ROS plumbing and lockstep bookkeeping."""

    name: str
    type: str
    kind: str
    odom_topic: str
    obstacles_topic: str
    command_topic: str
    odom_pub: object
    obstacles_pub: object
    child_frame: str
    odom_cdr: OdometryCdr
    scan_pub: object = None
    command: tuple = None
    command_time: float = -math.inf
    answered_ns: int = -1
    waited: bool = False
    commands: int = 0
    stray: int = 0
    timeouts: int = 0


class BridgeNode(Node):
    """Step a SimWorld, publish its state, apply the robots' commands, record everything."""

    def __init__(self, **kwargs):
        """Load the scenario, build the world, publishers, subscriptions and the recorder."""
        super().__init__('sim_bridge', **kwargs)
        self._log = LoopLogger(self.get_logger())  # for the loop (loop_log)
        params = {name: self._declare(name, *spec) for name, spec in PARAMETERS.items()}
        if not params['scenario']:
            raise ValueError("parameter 'scenario' is required (a shipped name such as "
                             "long_wall, or a YAML path)")
        scenario = load_scenario(params['scenario'])
        if params['seed'] >= 0:
            scenario = scenario.with_seed(params['seed'])
        overrides = {name: params[name] for name in ('physics_rate', 'control_rate', 'duration')
                     if params[name] > 0}
        # A Scenario checks its rates when made: ScenarioError (a ValueError) unless
        # physics_rate / control_rate is a whole number of steps.
        scenario = dataclasses.replace(scenario, **overrides)
        self.scenario = scenario
        self.params = params
        self.lockstep = params['lockstep']
        self.world = SimWorld(scenario)
        self.lidars = None
        if params['lidar.enabled']:
            carriers = [n.strip() for n in params['lidar.robots'].split(',') if n.strip()]
            settings = lidar_settings(**{f: params[f'lidar.{f}'] for f in PARAMETER_FIELDS})
            self.lidars = RobotLidars(self.world, settings, carriers or None, scenario.seed)
        self._scans = []  # (robot, serialized LaserScan) to send with the next period
        self.metrics = RunMetrics(self.world)
        self.steps_per_period = scenario.substeps
        self.period = self.steps_per_period * self.world.dt
        self.frame = params['frame_id']
        self.recorder = None
        self.bag_path = None
        if params['record']:
            default = Path('runs') / datetime.now().strftime('%Y%m%d_%H%M%S') / 'run'
            self.bag_path = Path(params['bag_path'] or default)
            self.recorder = BagRecorder(self.bag_path)
        metrics_path = params['metrics_path']
        if not metrics_path and self.bag_path is not None:
            metrics_path = self.bag_path.parent / 'metrics.json'
        self.metrics_path = Path(metrics_path) if metrics_path else None
        self._now_ns = 0
        self._unrecorded = []  # (topic, CDR) published this period, recorded after publishing
        self._wall_start = None
        self._metrics_written = False
        self._brake_model = make_model('quadrotor')
        self._tf_pub = None
        self._clock_pub = self._publisher(Clock, '/clock', PUBLISHED_QOS)
        if TFMessage is not None:
            self._tf_pub = self._publisher(TFMessage, '/tf', PUBLISHED_QOS)
        elif self.recorder is not None:
            self.recorder.add_topic('/tf', TF_MESSAGE_TYPE, PUBLISHED_QOS)
        self.robots = [self._add_robot(name) for name in self.world.robot_names]
        self._by_name = {robot.name: robot for robot in self.robots}
        self._tf_static_pub = self._tf_static = None
        if self.lidars is not None:
            self._tf_static = tf_message_cdr([
                mount_transform(lidar.settings, self._by_name[name].child_frame)
                for name, lidar in self.lidars.lidars.items()])
            if TFMessage is not None:
                self._tf_static_pub = self._publisher(TFMessage, '/tf_static', LATCHED_QOS)
            elif self.recorder is not None:
                self.recorder.add_topic('/tf_static', TF_MESSAGE_TYPE, LATCHED_QOS)
        self._markers = ObstacleMarkers(self.world, self.frame)
        self._obstacle_version = self.world.obstacle_version
        self._record_only(DIAGNOSTICS_QOS, 'diagnostic_msgs/msg/DiagnosticArray', '/diagnostics')
        self._inbox = Inbox(self)
        self._executor = SingleThreadedExecutor(context=self.context)
        self._executor.add_node(self)
        self._next_service = 0.0
        self.get_logger().info(
            f'scenario {scenario.name} (seed {scenario.seed}), {len(self.robots)} robot(s), '
            f'physics {scenario.physics_rate:g} Hz, control every {self.steps_per_period} steps '
            f'({1.0 / self.period:g} Hz), {"lockstep" if self.lockstep else "real time"}, '
            f'duration {scenario.duration:g} s'
            + (f', lidar on {", ".join(self.lidars.lidars)} every {self.lidars.steps} steps'
               if self.lidars else '')
            + ('' if params['obstacle_markers'] else ', no obstacle markers')
            + (f', recording to {self.bag_path}' if self.recorder else ''))

    # -- setup --------------------------------------------------------------------------------

    def _declare(self, name, default, bounds, description):
        """Declare a read-only parameter with its range and return its value."""
        descriptor = ParameterDescriptor(description=description, read_only=True)
        if bounds is not None and isinstance(default, int) and not isinstance(default, bool):
            descriptor.integer_range = [IntegerRange(from_value=bounds[0], to_value=bounds[1])]
        elif bounds is not None:
            descriptor.floating_point_range = [FloatingPointRange(
                from_value=float(bounds[0]), to_value=float(bounds[1]))]
        return self.declare_parameter(name, default, descriptor).value

    def _publisher(self, msg_type, topic, qos):
        """Create a publisher and register its topic with the recorder."""
        publisher = self.create_publisher(msg_type, topic, qos)
        if self.recorder is not None:
            self.recorder.add_topic(publisher.topic_name, msg_type, qos)
        return publisher

    def _record_only(self, qos, type_name, topic, callback=None):
        """Subscribe raw to ``topic``: record every message, then pass it to ``callback``.

        Without a recorder, a topic that is only recorded is not subscribed to.
        """
        if callback is None and self.recorder is None:
            return None
        msg_type = message_class(type_name)
        # Keep every sample until taken: a depth-1 reader drops a nominal command that is
        # overtaken by the next period's before the bridge takes it (the bag lost it).
        receive = QoSProfile(depth=RECEIVE_DEPTH, reliability=qos.reliability,
                             durability=qos.durability)
        subscription = self.create_subscription(
            msg_type, topic, lambda data: self._on_raw(subscription.topic_name, data, callback),
            receive, raw=True)
        if self.recorder is not None:
            self.recorder.add_topic(subscription.topic_name, msg_type, qos)
        return subscription

    def _add_robot(self, name):
        """Create one robot's publishers and subscriptions."""
        spec = self.world.robot_spec(name)
        robot_type = ROBOT_TYPES[spec.type]
        safe, nominal = robot_type.safe_topic, robot_type.nominal_topic
        child_frame = f'{name}/base_link'
        odom_pub = self._publisher(Odometry, f'{name}/odom', PUBLISHED_QOS)
        obstacles_pub = self._publisher(MarkerArray, f'{name}/obstacles', LATCHED_QOS)
        scan_pub = None
        if self.lidars is not None and name in self.lidars.lidars:
            scan_pub = self._publisher(LaserScan, f'{name}/{SCAN_TOPIC}', PUBLISHED_QOS)
        robot = _Robot(name=name, type=spec.type, kind=robot_type.command_kind,
                       odom_topic=odom_pub.topic_name, obstacles_topic=obstacles_pub.topic_name,
                       command_topic=f'{name}/{safe}', odom_pub=odom_pub,
                       obstacles_pub=obstacles_pub, child_frame=child_frame,
                       odom_cdr=OdometryCdr(self.frame, child_frame), scan_pub=scan_pub)
        type_name = robot_type.command_type
        self._record_only(COMMAND_QOS, type_name, f'{name}/{safe}',
                          lambda data: self._on_command(robot, data))
        self._record_only(COMMAND_QOS, type_name, f'{name}/{nominal}')
        if self.params['record_filter_markers']:
            self._record_only(COMMAND_QOS, 'visualization_msgs/msg/MarkerArray',
                              f'{name}/safety_filter/markers')
        return robot

    # -- messages -----------------------------------------------------------------------------

    def _send(self, publisher, topic, data, record):
        """Publish CDR ``data``; if ``record``, queue the same bytes for ``_record_sent``."""
        if publisher is not None:
            publisher.publish(data)
        if record and self.recorder is not None:
            self._unrecorded.append((topic, data))

    def _record_sent(self):
        """Record the queued published messages at the current sim time."""
        for topic, data in self._unrecorded:
            self.recorder.write_serialized(topic, data, self._now_ns)
        self._unrecorded.clear()

    def _on_raw(self, topic, data, callback):
        """Record a received message, then handle it."""
        if self.recorder is not None:
            self.recorder.write_serialized(topic, data, self._now_ns)
        if callback is not None:
            callback(data)

    def _on_command(self, robot, data):
        """Take a safe command: in lockstep only the first one stamped with the current period.

        Later ones with that stamp (answers to the startup re-sends of t = 0) are
        recorded but not applied, so the applied command does not depend on timing.
        TwistStamped: [linear.x, angular.z]; WrenchStamped: [force.z, torque].
        """
        try:
            command = SerializedCommand(data, stamped=True)
        except ValueError as exc:
            robot.stray += 1
            self._log.error(f'{robot.command_topic}: {exc}', throttle_s=1.0)
            return
        stamp_ns, (x, _, z, rx, ry, rz) = command.stamp_ns, command.values
        values = (x, rz) if robot.kind == 'velocity' else (z, rx, ry, rz)
        if self.lockstep and (stamp_ns != self._now_ns or robot.answered_ns == stamp_ns):
            robot.stray += 1
            return
        if not all(map(math.isfinite, values)):
            robot.stray += 1
            return
        robot.command = values
        robot.command_time = self.world.time
        robot.answered_ns = stamp_ns
        robot.waited = True
        robot.commands += 1

    def _publish_period(self, full, record=True):
        """Publish obstacles (moving only unless ``full``), odometry, clock and tf at sim time.

        What the controllers wait for goes out first; recording follows
        (``record=False``: not at all, for the startup re-sends of t = 0), in one section
        that holds SIGINT/SIGTERM back, so the bag has every message that went out.  A
        full set also goes out whenever an obstacle has popped up since the last one.
        """
        if self.recorder is None:
            self._publish_and_record(full, record)
        else:
            with self.recorder.holding_signals():
                self._publish_and_record(full, record)

    def _publish_and_record(self, full, record):
        """Publish the period's topics, then record what went out (see ``_publish_period``)."""
        time_msg = stamp(self._now_ns)
        if self.world.obstacle_version != self._obstacle_version:
            self._obstacle_version = self.world.obstacle_version
            full = True
        markers = self._markers.current(time_msg, full) if self.params['obstacle_markers'] else []
        transforms = []
        for robot in self.robots:
            position, quaternion = self.world.robot_pose(robot.name)
            transforms.append((time_msg.sec, time_msg.nanosec, self.frame,
                               robot.child_frame, position.tolist(), quaternion.tolist()))
            own = [m for name, m in markers if name != robot.name]
            if own or full:  # an empty full set still says "nothing around" (watchdogs)
                self._send(robot.obstacles_pub, robot.obstacles_topic,
                           serialize_message(MarkerArray(markers=own)), record)
            self._send_odometry(robot, time_msg, position, quaternion, record)
        for robot, data in self._scans:  # after the odometry the node pairs them with
            self._send(robot.scan_pub, robot.scan_pub.topic_name, data, record)
        self._send(self._clock_pub, '/clock', serialize_message(Clock(clock=time_msg)), record)
        if self._tf_pub is not None or self.recorder is not None:
            self._send(self._tf_pub, '/tf', tf_message_cdr(transforms), record)
        if self._unrecorded:
            self._record_sent()

    def _send_odometry(self, robot, time_msg, position, quaternion, record):
        """Send ``<ns>/odom``: world pose, body-frame twist (hand-written CDR)."""
        data = robot.odom_cdr.pack(time_msg.sec, time_msg.nanosec,
                                   (*position.tolist(), *quaternion.tolist()),
                                   self.world.body_twist(robot.name))
        self._send(robot.odom_pub, robot.odom_topic, data, record)

    def _take_scans(self):
        """Queue the scans due at the current physics step, serialized, for the next period."""
        for name, scan in self.lidars.scans():
            message = laser_scan(scan, stamp(round(self.world.time * 1e9)))
            self._scans.append((self._by_name[name], serialize_message(message)))

    # -- loop ---------------------------------------------------------------------------------

    def _apply_commands(self):
        """Hold each robot's command, or brake when it has none fresh enough."""
        timeout = self.params['command_timeout']
        for robot in self.robots:
            if robot.command is not None and self.world.time - robot.command_time <= timeout:
                self.world.set_command(robot.name, robot.command, robot.kind)
            elif robot.kind == 'velocity':
                self.world.set_command(robot.name, (0.0, 0.0), 'velocity')
            else:
                state = self.world.robot_state(robot.name)
                self.world.set_command(robot.name, self._brake_model.braking_input(state),
                                       'thrusts')

    def _spin_until(self, done, deadline):
        """Handle messages until ``done()`` or the monotonic ``deadline``; return done().

        Every SERVICE_PERIOD (wall) the executor also serves the node's services
        (parameters); each wait is at most that long, so signals are handled soon.
        """
        while not done():
            now = time.monotonic()
            if now >= self._next_service:
                self._next_service = now + SERVICE_PERIOD
                self._executor.spin_once(timeout_sec=0.0)
                continue
            remaining = deadline - now
            if remaining <= 0.0:
                return done()
            self._inbox.wait(min(remaining, SERVICE_PERIOD))
        return True

    def _pending(self):
        """Robots taking part in lockstep that have not answered the current period."""
        return [r for r in self.robots if r.waited and r.answered_ns != self._now_ns]

    def _wait_startup(self):
        """Re-send the t = 0 topics until every robot has answered or the startup timeout."""
        deadline = time.monotonic() + self.params['startup_timeout']
        unanswered = [r for r in self.robots if r.answered_ns != self._now_ns]
        while unanswered and time.monotonic() < deadline:
            self._spin_until(lambda: all(r.answered_ns == self._now_ns for r in self.robots),
                             min(deadline, time.monotonic() + STARTUP_RESEND))
            unanswered = [r for r in self.robots if r.answered_ns != self._now_ns]
            if unanswered:
                self._publish_period(full=True, record=False)
        for robot in unanswered:
            self.get_logger().warning(f'{robot.name}: no command on {robot.command_topic} '
                                      'after startup_timeout; it brakes until one arrives')

    def _wait_commands(self):
        """Lockstep: wait for the current period's commands; drop robots that time out."""
        deadline = time.monotonic() + self.params['lockstep_timeout']
        if self._spin_until(lambda: not self._pending(), deadline):
            self._inbox.wait(0.0)
            return
        for robot in self._pending():
            robot.waited = False
            robot.timeouts += 1
            self._log.warning(
                f'{robot.name}: no command for t = {self._now_ns * 1e-9:.3f} s within '
                f'lockstep_timeout; stepping without it', throttle_s=1.0)

    def run(self):
        """Run the scenario to its duration; return True when it was reached."""
        world = self.world
        duration = self.scenario.duration
        refresh_every = max(1, round(self.params['obstacles_refresh'] / self.period))
        pace = self.period / self.params['real_time_factor']
        self._wall_start = time.monotonic()
        period = last_full = 0
        if self.lidars is not None:
            self._send(self._tf_static_pub, '/tf_static', self._tf_static, True)
            self._take_scans()
        self._publish_period(full=True)
        if self.lockstep:
            self._wait_startup()
            self._wall_start = time.monotonic()
        last_full_wall = self._wall_start
        while world.time < duration - 0.5 * world.dt:
            if self.lockstep:
                self._wait_commands()
            else:
                deadline = self._wall_start + (period + 1) * pace
                self._spin_until(lambda: False, deadline)
                self._inbox.wait(0.0)
            self._apply_commands()
            self._scans.clear()
            for _ in range(self.steps_per_period):
                world.step()
                if self.lidars is not None:
                    self._take_scans()
            period += 1
            self._now_ns = round(world.time * 1e9)
            full = period - last_full >= refresh_every
            if full and self.lockstep:
                full = time.monotonic() - last_full_wall >= self.params['obstacles_refresh_wall']
            if full:
                last_full, last_full_wall = period, time.monotonic()
            self._publish_period(full)
            self.metrics.update()  # after publishing: overlaps with the controllers' work
        return True

    # -- end ----------------------------------------------------------------------------------

    def summary(self, completed):
        """Return the run summary (also the metrics JSON)."""
        wall = time.monotonic() - self._wall_start if self._wall_start is not None else 0.0
        sim = self.world.time
        return {
            'scenario': self.scenario.name, 'seed': self.scenario.seed,
            'completed': completed, 'lockstep': self.lockstep,
            'duration_s': self.scenario.duration, 'sim_time_s': round(sim, 6),
            'wall_time_s': round(wall, 3),
            'real_time_factor': round(sim / wall, 3) if wall > 0 else None,
            'physics_rate': self.scenario.physics_rate, 'control_rate': 1.0 / self.period,
            'bag': str(self.bag_path) if self.bag_path else None,
            'lockstep_timeouts': {r.name: r.timeouts for r in self.robots},
            'commands': {r.name: r.commands for r in self.robots},
            'robots': self.metrics.to_json(),
        }

    def finish(self, completed):
        """Close the bag, write the metrics JSON once and print a short summary."""
        if self.recorder is not None:
            self.recorder.close()
        if self._metrics_written:
            return
        self._metrics_written = True
        summary = self.summary(completed)
        if self.metrics_path is not None:
            self.metrics_path.parent.mkdir(parents=True, exist_ok=True)
            self.metrics_path.write_text(json.dumps(summary, indent=1) + '\n')
        print(f"sim_bridge: {summary['scenario']} {'completed' if completed else 'stopped'} at "
              f"t = {summary['sim_time_s']:.2f} s in {summary['wall_time_s']:.2f} s wall "
              f"(x{summary['real_time_factor'] or 0:.1f})", flush=True)
        for name, robot in summary['robots'].items():
            print(f'  {name}: goal {robot["goal_reached"]} at {robot["time_to_goal_s"]} s, '
                  f'collision {robot["collision"]}, min clearance {robot["min_clearance_m"]} m, '
                  f'path {robot["path_length_m"]} m', flush=True)
        self.world.close()


def main(args=None):
    """Run the bridge until the scenario ends (0) or a signal; 1 on a configuration error."""
    # The bag path is a parameter, so the recorder exists only after init: rclpy's signal
    # handlers stay off and close_on_signals closes the bag, then raises KeyboardInterrupt
    # (SIGINT) or SystemExit (SIGTERM) here.
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    try:
        node = BridgeNode()
    except (*CONFIGURATION_ERRORS, OSError) as exc:
        log_configuration_error('sim_bridge', exc)
        rclpy.try_shutdown()
        return 1
    gc.freeze()  # start-up objects leave the collector: shorter full collections in the loop
    if node.recorder is not None:
        close_on_signals(node.recorder)
    else:
        signal.signal(signal.SIGTERM, lambda signum, frame: sys.exit(128 + signum))
    completed = False
    try:
        completed = node.run()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.finish(completed)
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
