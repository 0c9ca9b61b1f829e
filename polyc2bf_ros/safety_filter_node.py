"""``safety_filter``: PolyC2BF safety filter between a planner and a robot.

Subscribes ``odom`` (nav_msgs/Odometry, best effort), ``obstacles``
(visualization_msgs/MarkerArray, reliable + transient local; not with ``use_markers:=false``,
which takes obstacles from ``scan_topics`` only) and the nominal
command: ``cmd_vel_in`` (Twist, or TwistStamped with ``stamped:=true``) for the
velocity-interface models, ``wrench_in`` (WrenchStamped) for ``quadrotor``.
Publishes the safe command on ``cmd_vel_out`` / ``wrench_out`` (same type,
header copied from the input), ``/diagnostics`` at 1 Hz and ``~/markers`` at
10 Hz while someone subscribes.  ``~/enable`` (std_srvs/SetBool) switches
filtering off (pass-through, reported as WARN) and on.

Each step (every ``1/rate`` s with ``trigger:=timer``, or per nominal command
with ``trigger:=command``)::

    stale odom / command / obstacles (steady clock)  -> stop
    NaN/Inf in odometry, command or obstacles        -> stop (brake)
    rejected obstacles, block_if_invalid, timeout 0  -> stop
    otherwise  safe command = CommandFilter.filter(state, yaw, nominal command, obstacles, age)

``core.decision.ControlDecision`` takes that decision, the same for bag replay
and the evaluation; the node only turns messages into its inputs and its answer
into a message.  ``CommandFilter`` (``core.command_filter``): velocity models
``u_nom = (Rz(yaw) v_cmd - v) / tau``, ``v_safe = Rz(yaw)^T (v + u_safe T)`` with
``T = 1/rate``; the quadrotor mixes the wrench into rotor thrusts and back.  A
stop is a zero twist, or the model's braking (hover) wrench.  Nothing is
published before the first nominal command; after it, every step publishes.

Obstacles: MarkerArrays are queued serialized and processed in a worker process
(``obstacle_intake``: conflated, capped by ``max_vertices`` / ``max_parts`` /
``max_obstacles``, prepared for the filter, handed over as one snapshot), so no
obstacle message delays a control step.  An unreadable message brakes until a
readable one arrives.  With ``block_if_invalid`` (default, as Nav2's collision
monitor) rejected obstacles (wrong frame, unusable) are not fresh data: the
obstacles go stale after ``obstacles_timeout`` and the node stops (at once with
timeout 0).
LaserScans on ``scan_topics`` take the same worker (``obstacle_intake``): each is placed at
the pose of the odometry stamped nearest its ``header.stamp``, among the last
``ODOMETRY_HISTORY`` (200) odometry messages, kept only with scan topics (no interpolation);
their obstacles join the markers', each topic with its own ``scan_timeout`` watchdog.  With
``use_markers:=false`` there is no ``obstacles`` input nor watchdog, and ``scan_topics`` must
name a topic.  With scan topics the node also takes ``/tf_static``
(tf2_msgs/TFMessage, reliable + transient local, depth 100; no tf2 buffer): a scan whose
frame a chain of static transforms links to the odometry child frame is placed by them (in
the plane, ``static_transforms``), any other at ``sensor_pose``; a non-finite transform
refuses the scan.  Without the tf2_msgs Python package (the PyPI ROS wheels) a warning says
that ``/tf_static`` is not read.

Stall guard: if no control step or tick has run for ``stall_timeout`` (steady
clock), a separate thread publishes the stop and the node's status at level
ERROR on ``/diagnostics`` (``stall_guard``).

Deadlock: when the filter has held the robot in place against its nominal command for
``deadlock_time`` (within ``deadlock_radius``; ``core.liveness.deadlock``), or it was asked to
move for ``stuck_time`` but stayed within ``stuck_radius``, ``~/deadlock``
(std_msgs/Bool, reliable + transient local, published on every change) turns true and
``/diagnostics`` says so at WARN, for a planner or behaviour tree to act on (replan,
back up).  The node itself keeps filtering: a report changes no command.

State: ``~/state`` (diagnostic_msgs/DiagnosticStatus, reliable + transient local) says
what the last step did (``filter_state``: pass, limit, stop, fallback, deadlock,
disabled), at 10 Hz and at once when that changes; the closest-obstacle distance it
carries is computed only then, not per step.

``SafetyFilterMixin`` holds all of this; ``SafetyFilterNode`` (this executable) sets it up
and starts it at once, the managed ``safety_filter_lifecycle`` from its lifecycle
transitions.

Hot path: odometry and commands are taken serialized and only the fields used
are read (``conversions``, CDR section); the answer is a copy of the command's
bytes with its six numbers replaced, so its header is the input's.
Diagnostics and markers are built on their own slow timers.
"""
import collections
import functools
import math
import sys
import time

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import Twist, TwistStamped, WrenchStamped
from nav_msgs.msg import Odometry
from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
from rclpy.clock import Clock, ClockType
from rclpy.exceptions import InvalidHandle, ParameterUninitializedException
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import LaserScan
from std_msgs.msg import Bool
from std_srvs.srv import SetBool
from visualization_msgs.msg import MarkerArray

from polyc2bf_ros import conversions, diagnostics, filter_state, rviz_markers
from polyc2bf_ros.core.actuation.command_interface import VELOCITY_MODELS
from polyc2bf_ros.core.decision import ControlDecision
from polyc2bf_ros.core.models import MODEL_NAMES, MODELS
from polyc2bf_ros.core.safety_filter import FilterConfig, FilterStatus
from polyc2bf_ros.core.stats import LatencyRing, RateMeter
from polyc2bf_ros.filter_parameters import (
    build_settings,
    FILTER_FIELDS,
    FILTER_PARAMETERS,
    model_parameters,
    NODE_PARAMETERS,
    scan_watchdog,
)
from polyc2bf_ros.loop_log import LoopLogger
from polyc2bf_ros.node_main import run_node
from polyc2bf_ros.obstacle_intake import ObstacleIntake, ODOMETRY_HISTORY
from polyc2bf_ros.stall_guard import StallGuard

try:
    from tf2_msgs.msg import TFMessage
except ImportError:  # the PyPI ROS wheels have no tf2_msgs: scans use sensor_pose only
    TFMessage = None

_STEADY = ClockType.STEADY_TIME
_DIAGNOSTICS_PERIOD = 1.0
_MARKERS_PERIOD = 0.1
_STATE_PERIOD = 0.1
_STALL_CHECKS_PER_TIMEOUT = 4
_FALLBACKS = ('slack', 'brake', 'escape', 'backup', 'evade')
_INFEASIBLE = ('slack', 'brake')
_REFUSED = FilterStatus.INVALID_INPUT
# As tf2's static listener: every static transform ever sent, from every broadcaster.
_STATIC_TF_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE,
                            durability=DurabilityPolicy.TRANSIENT_LOCAL)


class SafetyFilterMixin:
    """The safety filter on a node: its parameters, topics, timers, service and worker.

    Shared by ``SafetyFilterNode`` (set up and stepping from the start) and the managed
    ``safety_filter_lifecycle`` node, which calls the same four stages from its transitions:
    ``_configure`` (parameters, subscriptions, outputs, timers, the obstacle worker),
    ``_activate`` (steps and the stall guard run), ``_deactivate`` (they stop; inputs are
    still taken) and ``_release`` (everything ``_configure`` created is destroyed).
    """

    _active = False  # steps publish only while active
    _undo = ()  # what ``_release`` calls, newest first, to undo ``_configure``

    def _configure(self):
        """Read and check the parameters, then create everything the filter uses.

        An invalid configuration raises one of ``node_main.CONFIGURATION_ERRORS`` before
        anything is created.
        """
        settings = self._read_parameters()
        self._undo = []
        self._model = settings.command_filter.model
        self._stamped = self.get_parameter('stamped').value
        self._per_command = settings.per_command
        self._match_stamps = self._per_command and self.get_parameter('match_stamps').value
        self._cmd_stamp = 0.0
        self._waiting = False  # a matched command waits for its odometry and obstacles
        self._obstacles_needed = 0  # obstacle intake generation a waiting command needs
        velocity = self._model_name in VELOCITY_MODELS
        # Command messages with a header: TwistStamped (stamped:=true) and WrenchStamped.
        self._has_header = self._stamped or not velocity

        self._decision = ControlDecision(settings.command_filter, self._timeouts(settings),
                                         settings.block_if_invalid, settings.max_extrapolation,
                                         settings.deadlock, settings.resolution, settings.route)
        self._deadlocked = None  # last state published on ~/deadlock
        self._state = None  # (action, status, active constraints) of the last step
        self._state_published = None  # the action last published on ~/state
        self._obstacles_ready = self._keep(self.destroy_guard_condition,
                                           self.create_guard_condition(self._answer_if_ready))
        self._intake = ObstacleIntake(settings.command_filter.safety_filter.geometry,
                                      lambda: self.get_clock().now().nanoseconds * 1e-9,
                                      settings.intake, self._obstacles_processed)
        self._log = LoopLogger(self.get_logger())  # for the control path (loop_log)
        self._stall_guard = self._new_stall_guard(settings.stall_timeout)
        self._apply(settings)
        self._odom_frame = None
        self._odom_frame_raw = None
        self._child_frame_raw = None
        self._child_frame = ''
        self._scan_fed = {}  # topic: receipt time last fed to its watchdog
        # (stamp, x, y, yaw) of recent odometry for placing scans: filled with scan topics only.
        self._odometry = collections.deque(maxlen=ODOMETRY_HISTORY)
        self._scan_rejected = {}  # topic: rejections reported so far
        self._cmd = None  # the last readable nominal command (its bytes carry the answer)
        self._last_info = None
        self._reported = dict(self._decision.counts)
        self._invalid_messages = 0
        self._reported_stalls = 0
        self._last_invalid = 'none'
        self._min_h = math.inf
        self._status_name = f'{self.get_fully_qualified_name()}: safety filter'
        self._status_values = {'model': self._model_name}  # of the last status published
        self._latency = LatencyRing()
        self._rate_meter = RateMeter(time.monotonic())
        self._velocity = velocity
        self._create_topics()
        self._create_timers(settings)
        self._keep(self.destroy_service, self.create_service(SetBool, '~/enable', self._on_enable))
        self.add_on_set_parameters_callback(self._validate_parameters)
        self._keep(self.remove_on_set_parameters_callback, self._validate_parameters)
        self.add_post_set_parameters_callback(self._parameters_changed)
        self._keep(self.remove_post_set_parameters_callback, self._parameters_changed)
        self._intake.start()
        self._undo.append(self._intake.stop)
        self._undo.append(self._deactivate)  # undone first: no step or stall stop after it
        self.get_logger().info(
            f'model {self._model_name}, barrier {self._barrier}, trigger '
            f'{"command" if self._per_command else "timer"} at {1.0 / settings.period:g} Hz, '
            f'listening on {self._command_in}')

    def _create_topics(self):
        """Create the outputs, then the subscriptions (relative names: namespaces, remapping)."""
        sensor_qos = QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT)
        command_qos = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE)
        latched_qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                                 durability=DurabilityPolicy.TRANSIENT_LOCAL)
        if self._velocity:
            self._command_type = TwistStamped if self._stamped else Twist
            self._command_in, command_out = 'cmd_vel_in', 'cmd_vel_out'
        else:
            self._command_type = WrenchStamped
            self._command_in, command_out = 'wrench_in', 'wrench_out'
        self._publisher = self._create_output(self._command_type, command_out, command_qos)
        self._diagnostics_pub = self._create_output(DiagnosticArray, '/diagnostics', 10)
        self._markers_pub = self._create_output(MarkerArray, '~/markers', 1)
        self._deadlock_pub = self._create_output(
            Bool, '~/deadlock', QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                                           durability=DurabilityPolicy.TRANSIENT_LOCAL))
        self._state_pub = self._create_output(
            DiagnosticStatus, '~/state',
            QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.TRANSIENT_LOCAL))
        self._state_name = f'{self.get_fully_qualified_name()}: state'
        # Obstacles, then odometry, then commands: an executor serving them in one wake-up
        # (in creation order) answers on the newest inputs.  All are taken serialized
        # (raw): obstacle bytes go to the worker as they came; see the module docstring.
        if self._use_markers:
            self._subscribe(MarkerArray, 'obstacles', self._on_obstacles, latched_qos)
        if self._scan_watchdogs:
            self._subscribe_static_transforms()
        self._subscribe(Odometry, 'odom',
                        self._on_odom_for_scans if self._scan_watchdogs else self._on_odom,
                        sensor_qos)
        scan_qos = QoSProfile(depth=5, reliability=ReliabilityPolicy.BEST_EFFORT)
        for topic in self._scan_watchdogs:
            self._subscribe(LaserScan, topic,
                            lambda data, topic=topic: self._on_scan(topic, data), scan_qos)
        self._subscribe(self._command_type, self._command_in, self._on_command, command_qos)

    def _subscribe_static_transforms(self):
        """Take ``/tf_static`` for the scans' frames; without tf2_msgs say that it is not read."""
        if TFMessage is None:
            self.get_logger().warning(
                'tf2_msgs is not installed: /tf_static is not read, scans in a frame other '
                'than the odometry child frame are taken at sensor_pose')
            return
        self._subscribe(TFMessage, '/tf_static', self._on_static_transforms, _STATIC_TF_QOS)

    def _create_timers(self, settings):
        """Create the control (or stale-command) timer and the slow observability timers."""
        steady = Clock(clock_type=_STEADY)
        callback = self._on_watchdog if self._per_command else self._on_timer
        self._timer = self._keep(self.destroy_timer,
                                 self.create_timer(settings.tick, callback, clock=steady))
        for period, callback in ((_DIAGNOSTICS_PERIOD, self._publish_diagnostics),
                                 (_MARKERS_PERIOD, self._publish_markers),
                                 (_STATE_PERIOD, self._publish_state)):
            self._keep(self.destroy_timer, self.create_timer(period, callback, clock=steady))

    def _keep(self, undo, entity):
        """Remember ``undo(entity)`` for ``_release``; return ``entity``."""
        self._undo.append(functools.partial(undo, entity))
        return entity

    def _subscribe(self, msg_type, topic, callback, qos):
        """Create a serialized (raw) subscription that ``_release`` destroys."""
        return self._keep(self.destroy_subscription, self.create_subscription(
            msg_type, topic, callback, qos, raw=True))

    def _create_output(self, msg_type, topic, qos):
        """Create a publisher of one of the filter's outputs that ``_release`` destroys."""
        return self._keep(self.destroy_publisher, self.create_publisher(msg_type, topic, qos))

    def _new_stall_guard(self, timeout):
        """Return a stall guard (not started) that acts after ``timeout`` s of silence."""
        return StallGuard(timeout, self._on_stall, timeout / _STALL_CHECKS_PER_TIMEOUT)

    def _activate(self):
        """Step and publish; a new stall guard watches the loop from its first beat on."""
        previous = self._stall_guard
        self._stall_guard = self._new_stall_guard(previous.timeout)
        self._stall_guard.stalls = previous.stalls
        self._stall_guard.start()
        self._active = True
        self._deadlocked = None
        self._report_deadlock(False)

    def _deactivate(self):
        """Stop stepping and the stall guard; inputs are still taken."""
        self._active = False
        self._stall_guard.stop()

    def _release(self):
        """Undo ``_configure``, newest first: steps and stall guard, worker, topics, timers."""
        while self._undo:
            self._undo.pop()()

    def destroy_node(self):
        """Stop the obstacle worker and the stall guard, then destroy the node."""
        self._release()
        return super().destroy_node()

    # -- parameters ------------------------------------------------------------------------

    def _read_parameters(self):
        """Declare the parameters not declared yet, read them; return the ``NodeSettings``."""
        self._declared = []
        for name, (default, bounds, text, read_only) in NODE_PARAMETERS.items():
            self._declare(name, default, bounds, text, read_only)
        self._model_name = self.get_parameter('model').value
        if self._model_name not in MODELS:
            raise ValueError(f"parameter 'model' must be one of {MODEL_NAMES}, "
                             f'got {self._model_name!r}')
        self._declare_model_and_filter_parameters()
        self._declare_scan_topics()
        settings = build_settings(self._parameter_values())
        self._use_markers = settings.use_markers
        self._scan_watchdogs = {topic: scan_watchdog(topic) for topic in settings.scan_topics}
        return settings

    def _declare_model_and_filter_parameters(self):
        """Declare ``model_params.*`` (read-only, the model's constructor) and ``filter.*``."""
        for name, default in model_parameters(self._model_name).items():
            self._declare(f'model_params.{name}', default, None,
                          f'{self._model_name} model parameter {name!r}', True)
        defaults = FilterConfig()
        for name in FILTER_FIELDS:
            bounds, text = FILTER_PARAMETERS[name]
            self._declare(f'filter.{name}', getattr(defaults, name), bounds, text, False)

    def _declare_scan_topics(self):
        """Declare ``scan_topics`` (read-only, a string array with no default)."""
        if not self.has_parameter('scan_topics'):
            self.declare_parameter('scan_topics', Parameter.Type.STRING_ARRAY, ParameterDescriptor(
                name='scan_topics', read_only=True, description='sensor_msgs/LaserScan topics '
                'to take obstacles from (empty: none); each has its own scan_timeout watchdog; '
                'scans are placed by /tf_static from the odometry child frame, else at '
                'sensor_pose'))

    def _timeouts(self, settings):
        """Return the watchdog timeouts: odometry, command, obstacles (markers), one per scan."""
        return {**settings.timeouts,
                **dict.fromkeys(self._scan_watchdogs.values(), settings.scan_timeout)}

    def _declare(self, name, default, bounds, description, read_only):
        """Declare one parameter with its description and range, unless it already is.

        A managed node configured again keeps the parameters (and values) it has.
        """
        self._declared.append(name)
        if self.has_parameter(name):
            return
        descriptor = ParameterDescriptor(name=name, description=description, read_only=read_only)
        if bounds is not None and isinstance(default, int):
            descriptor.integer_range = [IntegerRange(from_value=bounds[0], to_value=bounds[1])]
        elif bounds is not None:
            descriptor.floating_point_range = [
                FloatingPointRange(from_value=float(bounds[0]), to_value=float(bounds[1]))]
        self.declare_parameter(name, default, descriptor)

    def _parameter_values(self, changes=()):
        """Return ``{name: value}`` of every parameter, overlaid with ``changes``."""
        values = {p.name: p.value for p in self.get_parameters(self._declared)}
        try:
            values['scan_topics'] = list(self.get_parameter('scan_topics').value)
        except ParameterUninitializedException:  # declared without a value: no scans
            values['scan_topics'] = []
        values.update({p.name: p.value for p in changes})
        return values


    def _apply(self, settings):
        """Swap in validated settings (decision, obstacle worker, stall guard)."""
        self._filter = settings.command_filter
        self._barrier = self._filter.safety_filter.config.barrier
        self._period = settings.period
        self._decision.configure(settings.command_filter, self._timeouts(settings),
                                 settings.block_if_invalid, settings.max_extrapolation,
                                 settings.deadlock, settings.resolution, settings.route)
        self._intake.configure(settings.intake, settings.command_filter.safety_filter.geometry)
        self._stall_guard.timeout = settings.stall_timeout
        self._stall_guard.period = settings.stall_timeout / _STALL_CHECKS_PER_TIMEOUT

    def _validate_parameters(self, params):
        """Refuse a change that makes the configuration invalid, with the reason."""
        try:
            build_settings(self._parameter_values(params), self._model)
        except (ValueError, TypeError) as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    def _parameters_changed(self, params):
        """Apply accepted parameters (filter rebuilt, timer period updated)."""
        settings = build_settings(self._parameter_values(), self._model)
        self._apply(settings)
        self._timer.timer_period_ns = int(1e9 * settings.tick)

    # -- inputs ------------------------------------------------------------------------------

    def _on_odom(self, data):
        """Read serialized odometry into the decision's state; keep the last finite one."""
        now = time.monotonic()
        try:
            odom = conversions.read_odometry(data)
        except ValueError as exc:
            self._decision.odometry(now)
            self._bad_message(f'odometry ({exc})')
            return
        result = conversions.state_from_odometry(self._model_name, odom.pose, odom.twist)
        if result is None:
            self._decision.odometry(now)
            self._bad_message('odometry (NaN/Inf)')
            return
        stamp = odom.stamp
        # The state is a tuple of floats: the core converts it once.
        self._decision.odometry(now, result[0], result[1], stamp)
        frame = odom.frame
        if frame != self._odom_frame_raw:
            self._odom_frame_raw = frame
            self._odom_frame = frame.decode(errors='replace').lstrip('/')
            self._intake.set_frame(self._odom_frame)
        if odom.child_frame != self._child_frame_raw:
            self._child_frame_raw = odom.child_frame
            self._child_frame = odom.child_frame.decode(errors='replace').lstrip('/')
        if self._waiting:
            # The answer uses this odometry: and the obstacles as of it (a new frame).
            self._obstacles_needed = self._intake.generation
            self._answer_if_ready()

    def _on_odom_for_scans(self, data):
        """``_on_odom``, then keep a usable odometry's stamp and pose for placing scans."""
        self._on_odom(data)
        decision = self._decision
        if decision.odom_valid:
            state = decision.state
            self._odometry.append((decision.odom_stamp, state[0], state[1], decision.yaw))

    def _on_command(self, data):
        """Store the nominal command; with ``trigger:=command`` answer it right away."""
        now = time.monotonic()
        try:
            cmd = conversions.SerializedCommand(data, self._has_header)
        except ValueError as exc:
            cmd = None  # malformed: the previous command's bytes carry the stop
            self._bad_message(f'nominal command ({exc})')
        if cmd is None or not cmd.finite:
            self._decision.command(now)
        else:
            self._decision.command(now, conversions.command_from_values(cmd.values,
                                                                        self._model_name))
        if cmd is not None:
            self._cmd = cmd
            if not cmd.finite:
                self._bad_message('nominal command (NaN/Inf)')
            if self._match_stamps and self._has_header:
                self._cmd_stamp = cmd.stamp
                self._obstacles_needed = self._intake.generation
                self._waiting = True
                self._answer_if_ready()
                return
        if self._per_command:
            self._step(now)

    def _answer_if_ready(self):
        """``match_stamps``: answer the waiting command once its inputs are in.

        Its odometry (stamped no earlier than the command) and every obstacle input
        received before it or before that odometry (messages, a new odometry frame),
        processed by the worker: a lockstep simulation then gets the same answers however
        long the worker takes.
        """
        if (self._waiting and self._decision.odom_stamp >= self._cmd_stamp
                and self._intake.covers(self._obstacles_needed)):
            self._waiting = False
            self._step(time.monotonic())

    def _on_obstacles(self, data):
        """Queue a serialized MarkerArray for the obstacle worker (``obstacle_intake``)."""
        self._intake.submit(data, time.monotonic())

    def _on_static_transforms(self, data):
        """Queue a serialized ``/tf_static`` message for the scan frames (``obstacle_intake``)."""
        self._intake.submit_transforms(data)

    def _on_scan(self, topic, data):
        """Queue a serialized LaserScan with the recent odometry (``obstacle_intake``)."""
        self._intake.submit_scan(topic, data, time.monotonic(), tuple(self._odometry),
                                 self._child_frame)

    def _take_scans(self):
        """Feed each scan topic's watchdog with its accepted scans; log rejected ones.

        Under ``block_if_invalid`` only accepted scans are fresh data, as for markers.
        """
        block = self._decision.block_if_invalid
        for topic, status in self._intake.scan_status.items():
            fresh = status.accepted if block else status.received
            if fresh is not None and fresh != self._scan_fed.get(topic):
                self._scan_fed[topic] = fresh
                self._decision.watchdog.feed(self._scan_watchdogs[topic], fresh)
            if status.rejected != self._scan_rejected.get(topic, 0):
                self._scan_rejected[topic] = status.rejected
                self._log.error(f'rejected LaserScan on {topic!r}: {status.reason} (its last '
                                'obstacles kept; stop once it is stale)', throttle_s=1.0)

    def _obstacles_processed(self):
        """Feeder thread, after each pass: wake a command that waits for its obstacles.

        On a loaded machine a pass can end after ``destroy_node`` gave up waiting for it
        (Ctrl-C while the worker was busy): the guard condition is gone then, and nothing
        waits for it.
        """
        try:
            self._obstacles_ready.trigger()
        except InvalidHandle:
            pass

    def _take_obstacles(self):
        """Hand the worker's newest snapshot to the decision; log what is wrong with it."""
        snapshot, previous = self._intake.snapshot, self._decision.snapshot
        if snapshot is previous:
            return snapshot
        self._decision.obstacles(snapshot)
        if self._scan_watchdogs:
            self._take_scans()
        if snapshot.received != previous.received or snapshot.unreadable != previous.unreadable:
            if snapshot.unreadable:
                self._bad_message(f'obstacles ({snapshot.unreadable})')
            elif snapshot.invalid:
                self._bad_message('obstacles (NaN/Inf)')
            if snapshot.error:
                self._log.error(snapshot.error, throttle_s=1.0)
        return snapshot

    def _bad_message(self, what):
        self._invalid_messages += 1
        self._last_invalid = what
        self._log.error(f'invalid {what}: braking', throttle_s=1.0)

    def _on_enable(self, request, response):
        """``~/enable``: true filters, false passes nominal commands through."""
        self._decision.enabled = bool(request.data)
        response.success = True
        if self._decision.enabled:
            response.message = 'safety filter enabled'
            self.get_logger().info(response.message)
        else:
            response.message = 'safety filter DISABLED: nominal commands pass through unfiltered'
            self.get_logger().warning(response.message)
        return response

    # -- steps -------------------------------------------------------------------------------

    def _on_timer(self):
        self._step(time.monotonic())

    def _on_watchdog(self):
        """With ``trigger:=command``, keep publishing stops while the command is stale."""
        now = time.monotonic()
        self._stall_guard.beat(now)
        self._take_obstacles()
        if self._decision.watchdog.is_stale('cmd', now):
            self._step(now)

    def _on_stall(self, silence):
        """Stall guard (its own thread): the control loop is silent; publish the stop."""
        cmd = self._cmd
        message = (f'control loop stalled for {silence:.3f} s (stall_timeout '
                   f'{self._stall_guard.timeout:g} s): stop published by the stall guard')
        self._log.error(message, throttle_s=1.0)
        if cmd is not None:
            self._publish_stop(cmd, self._decision.stop())
        values = {**self._status_values, 'stalls': self._stall_guard.stalls,
                  'stall_s': f'{silence:.3f}'}
        self._diagnostics_pub.publish(diagnostics.diagnostic_array(
            self.get_clock().now().to_msg(), self._status_name, self._model_name,
            DiagnosticStatus.ERROR, message, values))

    def _step(self, now):
        """Publish one safe command (or a stop, or the nominal when disabled)."""
        self._stall_guard.beat(now)
        cmd = self._cmd
        if cmd is None or not self._active:
            return
        start = time.perf_counter()
        self._take_obstacles()
        decision = self._decision.step(now)
        action = decision.action
        if action == 'stop':
            self._publish_stop(cmd, decision.command)
            self._report_deadlock(False)
            self._note_state(decision)
            return
        if action == 'pass':
            self._publish(cmd.data)
            self._report_deadlock(False)
            self._note_state(decision)
            return
        info = decision.info
        # A refused step returns the stop: nothing of the nominal command is kept then.
        kept = cmd.values if info.status != _REFUSED else None
        self._publish(cmd.replaced(conversions.values_from_command(
            decision.command, self._model_name, kept)))
        # Bookkeeping after the answer is out.
        self._report_deadlock(decision.deadlocked)
        self._last_info = info
        self._min_h = min(self._min_h, info.min_h)
        self._latency.add(time.perf_counter() - start)
        self._note_state(decision)

    def _note_state(self, decision):
        """Keep the step's ``~/state`` (``filter_state``); publish it now if the action changed."""
        self._state = filter_state.classify(self._decision.enabled, decision,
                                            self._decision.command_vector, self._velocity)
        if self._state[0] != self._state_published:
            self._publish_state()

    def _report_deadlock(self, deadlocked):
        """Publish ``~/deadlock`` (latched) when the detector's verdict changes."""
        if deadlocked == self._deadlocked:
            return
        self._deadlocked = deadlocked
        self._deadlock_pub.publish(Bool(data=deadlocked))
        if deadlocked:
            detector = self._decision.deadlock
            self._log.warning(f'deadlock: the filter has held the robot within '
                              f'{detector.radius_m:g} m for {detector.time_s:g} s against its '
                              'nominal command')

    def _publish(self, data):
        """Publish a serialized command and count it for the achieved rate."""
        self._publisher.publish(data)
        self._rate_meter.tick()

    def _publish_stop(self, cmd, stop):
        """Publish the ``stop`` command vector in ``cmd``'s message.

        Stamped stops carry the current time and the last command's frame.
        """
        values = conversions.values_from_command(stop, self._model_name)
        stamp = self.get_clock().now().seconds_nanoseconds() if self._has_header else None
        self._publish(cmd.replaced(values, stamp))

    # -- observability ------------------------------------------------------------------------

    def _publish_diagnostics(self):
        """Publish one status: rate, latency, staleness, step counts, min h, rejections."""
        now = time.monotonic()
        obstacles = self._take_obstacles()
        decision = self._decision
        watchdog, counts = decision.watchdog, decision.counts
        p50, p99 = self._latency.percentiles()
        self._latency.clear()
        stale = watchdog.stale(now)
        window = {k: v - self._reported[k] for k, v in counts.items()}
        self._reported = dict(counts)
        rejected = {**obstacles.rejected, **obstacles.wrong_frame}
        values = {
            'enabled': str(decision.enabled).lower(),
            'model': self._model_name,
            'barrier': self._barrier,
            'rate_target_hz': f'{1.0 / self._period:g}',
            'rate_achieved_hz': f'{self._rate_meter.rate(now):.1f}',
            'latency_p50_ms': f'{1e3 * p50:.3f}',
            'latency_p99_ms': f'{1e3 * p99:.3f}',
            'stale_inputs': ','.join(stale) or 'none',
            **{f'age_{name}_s': f'{watchdog.age(name, now):.3f}'
               for name in watchdog.names},
            **{f'steps_{name}': count for name, count in counts.items()},
            'steps_infeasible': sum(counts[name] for name in _INFEASIBLE),
            'steps_fallback': sum(counts[name] for name in _FALLBACKS),
            'invalid_messages': self._invalid_messages,
            'last_invalid_message': self._last_invalid,
            'min_h': f'{self._min_h:.4g}',
            'obstacles_in_use': len(obstacles.obstacles),
            'obstacles_tracked': obstacles.tracked,
            'obstacles_rejected': len(rejected),
            'obstacles_simplified': obstacles.simplified,
            'obstacles_hulled': len(obstacles.hulled),
            'block_if_invalid': str(decision.block_if_invalid).lower(),
            'stalls': self._stall_guard.stalls,
            'deadlocked': str(bool(self._deadlocked)).lower(),
            'deadlocks': decision.deadlock.onsets,
            'stuck_reports': decision.deadlock.stuck_onsets,
            'repeat_reports': decision.deadlock.repeat_onsets,
            'deadlock_held_s': f'{decision.deadlock.held_s(now):.2f}',
            'resolving': decision.resolving,
            'resolutions': decision.resolutions,
            **self._scan_values(),
            **{f'rejected {key}': reason for key, reason in sorted(rejected.items())},
        }
        self._min_h = math.inf
        errors, warnings = [], []
        if rejected:
            blocking = (' (block_if_invalid: stopping once stale)' if decision.block_if_invalid
                        else '')
            errors.append(f'{len(rejected)} obstacles rejected{blocking}')
        errors += [e for e in (obstacles.error, obstacles.unreadable) if e]
        if window['invalid_input']:
            errors.append('invalid input: braking')
        if self._stall_guard.stalls > self._reported_stalls:
            errors.append(f'control loop stalled ({self._stall_guard.stalls} times): stop '
                          'published by the stall guard')
        self._reported_stalls = self._stall_guard.stalls
        if obstacles.simplified or obstacles.hulled:
            warnings.append(f'{obstacles.simplified} obstacle outlines simplified '
                            f'(max_vertices / max_parts), {len(obstacles.hulled)} replaced by '
                            'their hull (max_parts)')
        if not decision.enabled:
            warnings.append('DISABLED: pass-through, not filtering')
            self._log.warning('safety filter is DISABLED: nominal commands pass through '
                              'unfiltered', throttle_s=5.0)
        if stale and self._cmd is not None:
            warnings.append(f'stale {", ".join(stale)}: stopping')
        if self._deadlocked and decision.deadlock.held:
            warnings.append(f'deadlock: held in place by the filter for '
                            f'{decision.deadlock.held_s(now):.1f} s')
        elif self._deadlocked and decision.deadlock.stuck:
            warnings.append('deadlock: asked to move, but stayed within stuck_radius for '
                            'stuck_time')
        elif self._deadlocked:
            warnings.append('deadlock: deadlock_repeat_count reports within '
                            'deadlock_repeat_window')
        fallbacks = [f'{name} x{window[name]}' for name in _FALLBACKS if window[name]]
        if fallbacks:
            warnings.append('fallback ' + ', '.join(fallbacks))
        if window['recovering']:
            warnings.append(f'outside the safe set (h < 0) x{window["recovering"]}')
        level = (DiagnosticStatus.ERROR if errors else DiagnosticStatus.WARN if warnings
                 else DiagnosticStatus.OK)
        message = '; '.join(errors + warnings) or (
            'ok' if self._cmd is not None else 'waiting for the first nominal command')
        self._status_values = values
        self._diagnostics_pub.publish(diagnostics.diagnostic_array(
            self.get_clock().now().to_msg(), self._status_name, self._model_name, level,
            message, values))

    def _publish_state(self):
        """Publish ``~/state`` (latched) for the last step; nothing before the first step."""
        state = self._state
        if state is None:
            return
        action, status, active = state
        position = None
        if self._decision.state is not None:
            position = self._model.reference(np.asarray(self._decision.state)).position
        closest = filter_state.closest_obstacle(position, self._decision.snapshot.obstacles)
        self._state_published = action
        self._state_pub.publish(filter_state.state_status(
            self._state_name, self._model_name, action, status, active, closest,
            self._deadlocked))

    def _scan_values(self):
        """Diagnostics of the scan topics: rejections and the last reason, per topic."""
        values = {}
        for topic in self._scan_watchdogs:
            status = self._intake.scan_status.get(topic)
            values[f'scans_rejected {topic}'] = 0 if status is None else status.rejected
            if status is not None and status.reason:
                values[f'last_scan_rejection {topic}'] = status.reason
        return values

    def _publish_markers(self):
        """Publish obstacle parts and cones, only while ``~/markers`` has subscribers."""
        if self._odom_frame is None or self._markers_pub.get_subscription_count() == 0:
            return
        info = self._last_info
        active = info.active if info is not None else ()
        apex = cones = None
        if info is not None and self._model.position_dim == 2:
            apex = self._model.reference(np.asarray(self._decision.state)).position
            cones = info.cones
        self._markers_pub.publish(rviz_markers.filter_markers(
            self._odom_frame, self.get_clock().now().to_msg(),
            self._decision.snapshot.obstacles.footprints,
            active, apex, cones))


class SafetyFilterNode(SafetyFilterMixin, Node):
    """The safety filter as a plain node: configured and active from the start."""

    def __init__(self, **kwargs):
        """Declare the parameters, create the topics, timers and worker, start stepping."""
        super().__init__('safety_filter', **kwargs)
        self._configure()
        self._activate()


def main(args=None):
    """Run the safety filter node until shutdown; exit status 1 on a configuration error."""
    return run_node(SafetyFilterNode, 'safety_filter', args)


if __name__ == '__main__':
    sys.exit(main())
