"""``safety_filter``: PolyC2BF safety filter between a planner and a robot.

Subscribes ``odom`` (nav_msgs/Odometry, best effort), ``obstacles``
(visualization_msgs/MarkerArray, reliable + transient local) and the nominal
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
    otherwise  safe command = CommandFilter.filter(state, yaw, nominal command, obstacles, age)

``core.command_filter`` is the one decision path (shared with bag replay and
the evaluation): velocity models ``u_nom = (Rz(yaw) v_cmd - v) / tau``,
``v_safe = Rz(yaw)^T (v + u_safe T)`` with ``T = 1/rate``; the quadrotor mixes
the wrench into rotor thrusts and back.  A stop is a zero twist, or the
model's braking (hover) wrench.  Nothing is published before the first
nominal command; after it, every step publishes.

Obstacles: MarkerArrays are queued serialized and processed in a worker process
(``obstacle_intake``: conflated, capped by ``max_vertices`` / ``max_parts`` /
``max_obstacles``, prepared for the filter, handed over as one snapshot), so no
obstacle message delays a control step.  An unreadable message brakes until a
readable one arrives.  With ``block_if_invalid`` (default, as Nav2's collision
monitor) rejected obstacles (wrong frame, unusable) are not fresh data: the
obstacles go stale after ``obstacles_timeout`` and the node stops (at once with
timeout 0).

Stall guard: if no control step or tick has run for ``stall_timeout`` (steady
clock), a separate thread publishes the stop and an ERROR on ``/diagnostics``
(``stall_guard``).

Hot path: odometry and commands are taken serialized and only the fields used
are read (``conversions``, CDR section); the answer is a copy of the command's
bytes with its six numbers replaced, so its header is the input's.
Diagnostics and markers are built on their own slow timers.
"""
import dataclasses
import inspect
import math
import sys
import time

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
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_srvs.srv import SetBool
from visualization_msgs.msg import MarkerArray

from polyc2bf_ros import conversions
from polyc2bf_ros.core.command_filter import CommandFilter
from polyc2bf_ros.core.command_interface import VELOCITY_MODELS
from polyc2bf_ros.core.models import make_model, MODEL_NAMES, MODELS
from polyc2bf_ros.core.obstacle_tracker import extrapolation_age
from polyc2bf_ros.core.safety_filter import FilterConfig, FilterStatus
from polyc2bf_ros.core.stats import LatencyRing, RateMeter
from polyc2bf_ros.core.watchdog import Watchdog
from polyc2bf_ros.node_main import run_node
from polyc2bf_ros.obstacle_intake import IntakeSettings, ObstacleIntake
from polyc2bf_ros.stall_guard import StallGuard

# name: (default, (min, max) or None, description, read-only)
NODE_PARAMETERS = {
    'model': ('unicycle', None, f'robot model, one of {", ".join(MODEL_NAMES)}', True),
    'stamped': (False, None, 'cmd_vel_in / cmd_vel_out are TwistStamped instead of Twist', True),
    'trigger': ('timer', None, "'timer': step every 1/rate s; 'command': one step per "
                'nominal command', True),
    'match_stamps': (False, None, "with trigger 'command': answer a stamped command only once "
                     'odometry stamped no earlier than it has arrived (lockstep simulation, '
                     'repeatable runs); leave off when commands and odometry use different '
                     'clocks', True),
    'rate': (100.0, (1.0, 2000.0), 'control rate [Hz]: timer rate, and T = 1/rate in '
             'v_safe = v + u_safe T', False),
    'velocity_tau': (0.0, (0.0, 10.0), 'tau [s] in u_nom = (v_cmd - v) / tau; 0 = one '
                     'control period (transparent when nothing constrains)', False),
    'odom_timeout': (0.25, (0.002, 10.0), 'odometry older than this [s] -> stop', False),
    'cmd_timeout': (0.5, (0.002, 10.0), 'nominal command older than this [s] -> stop', False),
    'obstacles_timeout': (1.0, (0.0, 3600.0), 'obstacles older than this [s] -> stop; 0 = '
                          'never stale once received (latched static map)', False),
    'max_extrapolation': (0.5, (0.0, 5.0), 'obstacles are moved by velocity * age, age = '
                          'odometry stamp - obstacle stamp clipped to [0, this] [s]', False),
    'wall_thickness': (0.05, (0.001, 10.0), 'width [m] of walls from 2-point / collinear '
                       'outlines whose marker has no line width (scale.x)', False),
    'cylinder_sides': (12, (3, 64), 'sides of the polygon circumscribing CYLINDER / SPHERE '
                       'markers', False),
    'block_if_invalid': (True, None, 'rejected obstacles (wrong frame, unusable) are not fresh '
                         'data: stop once they have lasted obstacles_timeout (at once if 0)',
                         False),
    'max_vertices': (256, (3, 100000), 'outline points per polygon; more become an enclosing '
                     'convex polygon of this many vertices', False),
    'max_parts': (64, (1, 10000), 'convex parts per non-convex obstacle; more: its convex hull',
                  False),
    'max_obstacles': (1000, (1, 100000), 'convex obstacle parts in use; more: the obstacle '
                      'input is unusable (stop)', False),
    'stall_timeout': (0.25, (0.01, 10.0), 'no control step for this long [s] (steady clock): '
                      'a separate thread publishes the stop', False),
}

# FilterConfig field: ((min, max) or None, description); control_period comes from rate.
FILTER_PARAMETERS = {
    'barrier': (None, "cone construction: 'polyc2bf_paper' (segment extended by w/2), "
                "'polyc2bf_inflated' (polygon inflated by the radius) or 'c3bf' (circles)"),
    'robot_radius': ((0.0, 10.0), 'robot radius w/2 [m]'),
    'gamma': ((0.0, 1000.0), 'class-K gain in h_dot + gamma h >= margin [1/s], > 0'),
    'margin_gain': ((0.0, 1000.0), 'sample-and-hold margin = margin_gain * T'),
    'solver': (None, "QP solver: 'daqp' or 'proxsuite'"),
    'velocity_epsilon': ((0.0, 10.0), 'smooth norm sqrt(|v_rel|^2 + eps^2) [m/s], > 0'),
    'slack_weight': ((0.0, 1e12), 'weight of the shared slack when the QP is infeasible, > 0'),
    'prune': (None, 'drop rows that no input in the box can violate (same solution)'),
    'escape_speed': ((0.0, 10.0), 'speed [m/s] of the escape from inside an obstacle'),
    'escape_gain': ((0.0, 1000.0), 'gain [1/s] of the escape velocity loop, > 0'),
    'inflation_segments': ((3, 256), 'segments of the robot disc for polyc2bf_inflated'),
}

_STEADY = ClockType.STEADY_TIME
_DIAGNOSTICS_PERIOD = 1.0
_MARKERS_PERIOD = 0.1
_COMMAND_WATCHDOG_PERIOD = 0.02
_STALL_CHECKS_PER_TIMEOUT = 4
_FALLBACKS = ('slack', 'brake', 'escape')
_INFEASIBLE = ('slack', 'brake')


@dataclasses.dataclass
class _Settings:
    """Everything derived from the mutable parameters (built and validated together)."""

    command_filter: CommandFilter
    timeouts: dict
    period: float
    intake: IntakeSettings
    stall_timeout: float


class SafetyFilterNode(Node):
    """ROS shell around ``core.CommandFilter``: messages, watchdogs, diagnostics, markers."""

    def __init__(self, **kwargs):
        """Declare parameters, build the model and filter, wire topics, timers and service."""
        super().__init__('safety_filter', **kwargs)
        self._declared = []
        for name, (default, bounds, text, read_only) in NODE_PARAMETERS.items():
            self._declare(name, default, bounds, text, read_only)
        self._model_name = self.get_parameter('model').value
        if self._model_name not in MODELS:
            raise ValueError(f"parameter 'model' must be one of {MODEL_NAMES}, "
                             f'got {self._model_name!r}')
        self._declare_model_and_filter_parameters()
        self._stamped = self.get_parameter('stamped').value
        trigger = self.get_parameter('trigger').value
        if trigger not in ('timer', 'command'):
            raise ValueError(f"parameter 'trigger' must be 'timer' or 'command', got {trigger!r}")
        self._per_command = trigger == 'command'
        self._match_stamps = self._per_command and self.get_parameter('match_stamps').value
        self._cmd_stamp = 0.0
        self._waiting_for_odom = False
        self._model = make_model(self._model_name, **{
            name: self.get_parameter(f'model_params.{name}').value
            for name in self._model_parameter_names})
        velocity = self._model_name in VELOCITY_MODELS
        # Command messages with a header: TwistStamped (stamped:=true) and WrenchStamped.
        self._has_header = self._stamped or not velocity

        settings = self._settings(self._parameter_values())
        self._watchdog = Watchdog(settings.timeouts)
        self._intake = ObstacleIntake(self._filter_spec(settings),
                                      lambda: self.get_clock().now().nanoseconds * 1e-9,
                                      settings.intake)
        self._apply(settings)
        self._obstacles = self._intake.snapshot
        self._stall_guard = StallGuard(settings.stall_timeout, self._on_stall,
                                       settings.stall_timeout / _STALL_CHECKS_PER_TIMEOUT)

        # State (the last finite odometry) and the latest nominal command.
        self._state = (0.0,) * self._model.state_dim
        self._yaw = 0.0
        self._odom_stamp = -math.inf  # no odometry yet: a matched command waits for it
        self._odom_frame = None
        self._odom_frame_raw = None
        self._odom_valid = False
        self._cmd = None
        self._cmd_valid = False
        self._enabled = True
        self._last_info = None
        self._counts = dict.fromkeys([s.value for s in FilterStatus] + ['stale_stop',
                                                                        'blocked_stop'], 0)
        self._status_names = {s: s.value for s in FilterStatus}
        self._reported = dict(self._counts)
        self._invalid_messages = 0
        self._reported_stalls = 0
        self._last_invalid = 'none'
        self._min_h = math.inf
        self._latency = LatencyRing()
        steady = Clock(clock_type=_STEADY)
        self._rate_meter = RateMeter(time.monotonic())

        # Topics (relative names), QoS per DESIGN.md section 5.
        sensor_qos = QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT)
        command_qos = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE)
        latched_qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                                 durability=DurabilityPolicy.TRANSIENT_LOCAL)
        if velocity:
            command_type = TwistStamped if self._stamped else Twist
            command_in, command_out = 'cmd_vel_in', 'cmd_vel_out'
        else:
            command_type = WrenchStamped
            command_in, command_out = 'wrench_in', 'wrench_out'
        self._publisher = self.create_publisher(command_type, command_out, command_qos)
        # Odometry before commands: an executor serving both in one wake-up steps on fresh
        # odometry.  Both are taken serialized (raw), see the module docstring.
        self.create_subscription(Odometry, 'odom', self._on_odom, sensor_qos, raw=True)
        self.create_subscription(command_type, command_in, self._on_command, command_qos,
                                 raw=True)
        self.create_subscription(MarkerArray, 'obstacles', self._on_obstacles, latched_qos,
                                 raw=True)
        self._diagnostics_pub = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self._markers_pub = self.create_publisher(MarkerArray, '~/markers', 1)
        self.create_service(SetBool, '~/enable', self._on_enable)

        callback = self._on_watchdog if self._per_command else self._on_timer
        self._timer = self.create_timer(self._timer_period(settings), callback, clock=steady)
        self.create_timer(_DIAGNOSTICS_PERIOD, self._publish_diagnostics, clock=steady)
        self.create_timer(_MARKERS_PERIOD, self._publish_markers, clock=steady)
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._parameters_changed)
        self._intake.start()
        self._stall_guard.start()
        self.get_logger().info(
            f'model {self._model_name}, barrier {self._barrier}, trigger {trigger} '
            f'at {1.0 / settings.period:g} Hz, listening on {command_in}')

    # -- parameters ------------------------------------------------------------------------

    def _declare_model_and_filter_parameters(self):
        """Declare ``model_params.*`` (read-only, from the model constructor) and ``filter.*``."""
        signature = inspect.signature(MODELS[self._model_name].__init__)
        self._model_parameter_names = []
        for name, p in signature.parameters.items():
            if isinstance(p.default, (float, int)) and not isinstance(p.default, bool):
                self._model_parameter_names.append(name)
                self._declare(f'model_params.{name}', float(p.default), None,
                              f'{self._model_name} model parameter {name!r}', True)
        self._filter_fields = [f for f in dataclasses.fields(FilterConfig)
                               if f.name != 'control_period']
        for field in self._filter_fields:
            bounds, text = FILTER_PARAMETERS.get(field.name, (None, f'FilterConfig.{field.name}'))
            self._declare(f'filter.{field.name}', field.default, bounds, text, False)

    def _declare(self, name, default, bounds, description, read_only):
        """Declare one parameter with its description and range."""
        descriptor = ParameterDescriptor(name=name, description=description, read_only=read_only)
        if bounds is not None and isinstance(default, int):
            descriptor.integer_range = [IntegerRange(from_value=bounds[0], to_value=bounds[1])]
        elif bounds is not None:
            descriptor.floating_point_range = [
                FloatingPointRange(from_value=float(bounds[0]), to_value=float(bounds[1]))]
        self.declare_parameter(name, default, descriptor)
        self._declared.append(name)

    def _parameter_values(self, changes=()):
        """Return ``{name: value}`` of every parameter, overlaid with ``changes``."""
        values = {p.name: p.value for p in self.get_parameters(self._declared)}
        values.update({p.name: p.value for p in changes})
        return values

    def _settings(self, values):
        """Build and validate everything derived from ``values``; ``ValueError`` says why not."""
        period = 1.0 / values['rate']
        config = FilterConfig(control_period=period, **{
            f.name: values[f'filter.{f.name}'] for f in self._filter_fields}).validate()
        timeouts = {name: values[f'{name}_timeout'] for name in ('odom', 'cmd', 'obstacles')}
        for name, timeout in timeouts.items():
            if 0.0 < timeout <= period:
                raise ValueError(f'{name}_timeout ({timeout:g} s) must exceed the control '
                                 f'period 1/rate ({period:g} s)')
        tick = max(period, _COMMAND_WATCHDOG_PERIOD) if self._per_command else period
        if not values['stall_timeout'] > 2.0 * tick:
            raise ValueError(f"stall_timeout ({values['stall_timeout']:g} s) must exceed two "
                             f'control ticks ({2.0 * tick:g} s)')
        command_filter = CommandFilter(self._model, config, values['velocity_tau'])
        intake = IntakeSettings(*(values[name] for name in IntakeSettings._fields))
        return _Settings(command_filter, timeouts, period, intake, values['stall_timeout'])

    def _apply(self, settings):
        """Swap in a validated configuration."""
        self._filter = settings.command_filter
        self._barrier = self._filter.safety_filter.config.barrier
        self._period = settings.period
        for name, timeout in settings.timeouts.items():
            self._watchdog.set_timeout(name, timeout)
        self._max_extrapolation = self.get_parameter('max_extrapolation').value
        self._block_if_invalid = self.get_parameter('block_if_invalid').value
        self._intake.configure(settings.intake, self._filter_spec(settings))

    def _filter_spec(self, settings):
        """Return what the obstacle worker prepares geometry for: (model name, config)."""
        return self._model_name, settings.command_filter.safety_filter.config

    def _validate_parameters(self, params):
        """Refuse a change that makes the configuration invalid, with the reason."""
        try:
            self._settings(self._parameter_values(params))
        except (ValueError, TypeError) as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    def _parameters_changed(self, params):
        """Apply accepted parameters (filter rebuilt, timer period updated)."""
        settings = self._settings(self._parameter_values())
        self._apply(settings)
        self._timer.timer_period_ns = int(1e9 * self._timer_period(settings))
        self._stall_guard.timeout = settings.stall_timeout
        self._stall_guard.period = settings.stall_timeout / _STALL_CHECKS_PER_TIMEOUT

    def _timer_period(self, settings):
        """Step period, or with ``trigger:=command`` the stop watchdog's (at most 50 Hz)."""
        if self._per_command:
            return max(settings.period, _COMMAND_WATCHDOG_PERIOD)
        return settings.period

    # -- inputs ------------------------------------------------------------------------------

    def _on_odom(self, data):
        """Read serialized odometry into the model state; keep the last finite one."""
        self._watchdog.feed('odom', time.monotonic())
        try:
            odom = conversions.read_odometry(data)
        except ValueError as exc:
            self._odom_valid = False
            self._bad_message(f'odometry ({exc})')
            return
        result = conversions.state_from_odometry(self._model_name, odom.pose, odom.twist)
        self._odom_valid = result is not None
        if result is None:
            self._bad_message('odometry (NaN/Inf)')
            return
        self._state, self._yaw = result  # a tuple of floats: the core converts it once
        self._odom_stamp = stamp = odom.stamp
        frame = odom.frame
        if frame != self._odom_frame_raw:
            self._odom_frame_raw = frame
            self._odom_frame = frame.decode(errors='replace').lstrip('/')
            self._intake.set_frame(self._odom_frame)
        if self._waiting_for_odom and stamp >= self._cmd_stamp:
            self._waiting_for_odom = False
            self._step(time.monotonic())

    def _on_command(self, data):
        """Store the nominal command; with ``trigger:=command`` answer it right away."""
        now = time.monotonic()
        self._watchdog.feed('cmd', now)
        try:
            cmd = conversions.SerializedCommand(data, self._has_header)
        except ValueError as exc:
            cmd = None  # malformed: the previous command's bytes carry the stop
            self._bad_message(f'nominal command ({exc})')
        self._cmd_valid = cmd is not None and cmd.finite
        if cmd is not None:
            self._cmd = cmd
            if not cmd.finite:
                self._bad_message('nominal command (NaN/Inf)')
            if self._match_stamps and self._has_header:
                self._cmd_stamp = cmd.stamp
                if cmd.stamp > self._odom_stamp:
                    self._waiting_for_odom = True  # answered by _on_odom with matching state
                    return
        if self._per_command:
            self._step(now)

    def _on_obstacles(self, data):
        """Queue a serialized MarkerArray for the obstacle worker (``obstacle_intake``)."""
        self._intake.submit(data, time.monotonic())

    def _take_obstacles(self):
        """Adopt the worker's newest snapshot; feed the watchdog if it is fresh data.

        Under ``block_if_invalid`` only a snapshot with nothing rejected is fresh.
        """
        snapshot = self._intake.snapshot
        if snapshot is self._obstacles:
            return snapshot
        previous, self._obstacles = self._obstacles, snapshot
        if snapshot.received is not None and (snapshot.clean or not self._block_if_invalid):
            self._watchdog.feed('obstacles', snapshot.received)
        if snapshot.received != previous.received or snapshot.unreadable != previous.unreadable:
            if snapshot.unreadable:
                self._bad_message(f'obstacles ({snapshot.unreadable})')
            elif snapshot.invalid:
                self._bad_message('obstacles (NaN/Inf)')
            if snapshot.error:
                self.get_logger().error(snapshot.error, throttle_duration_sec=1.0)
        return snapshot

    def _blocked(self, snapshot):
        """Return True when rejected obstacles stop the robot at once (timeout 0)."""
        return (self._block_if_invalid and not snapshot.clean
                and self._watchdog.timeout('obstacles') == 0.0)

    def _bad_message(self, what):
        self._invalid_messages += 1
        self._last_invalid = what
        self.get_logger().error(f'invalid {what}: braking', throttle_duration_sec=1.0)

    def _on_enable(self, request, response):
        """``~/enable``: true filters, false passes nominal commands through."""
        self._enabled = bool(request.data)
        response.success = True
        if self._enabled:
            response.message = 'safety filter enabled'
            self.get_logger().info(response.message)
        else:
            response.message = 'safety filter DISABLED: nominal commands pass through unfiltered'
            self.get_logger().warning(response.message)
        return response

    # -- steps -------------------------------------------------------------------------------

    def _on_timer(self):
        now = time.monotonic()
        self._stall_guard.beat(now)
        self._step(now)

    def _on_watchdog(self):
        """With ``trigger:=command``, keep publishing stops while the command is stale."""
        now = time.monotonic()
        self._stall_guard.beat(now)
        self._take_obstacles()
        if self._watchdog.is_stale('cmd', now):
            self._step(now)

    def _on_stall(self, silence):
        """Stall guard (its own thread): the control loop is silent; publish the stop."""
        cmd = self._cmd
        message = (f'control loop stalled for {silence:.3f} s (stall_timeout '
                   f'{self._stall_guard.timeout:g} s): stop published by the stall guard')
        self.get_logger().error(message, throttle_duration_sec=1.0)
        if cmd is not None:
            self._publish_stop(cmd)
        self._diagnostics_pub.publish(conversions.diagnostic_array(
            self.get_clock().now().to_msg(), f'{self.get_fully_qualified_name()}: stall guard',
            self._model_name, DiagnosticStatus.ERROR, message,
            {'stalls': self._stall_guard.stalls, 'stall_s': f'{silence:.3f}'}))

    def _step(self, now):
        """Publish one safe command (or a stop); see the module docstring."""
        cmd = self._cmd
        if cmd is None:
            return
        start = time.perf_counter()
        self._stall_guard.beat(now)
        obstacles = self._take_obstacles()
        if not self._enabled:
            self._pass_through(cmd, now)
            return
        if self._watchdog.any_stale(now):
            self._counts['stale_stop'] += 1
            self._publish_stop(cmd)
            return
        if not (self._odom_valid and self._cmd_valid and obstacles.usable):
            self._counts['invalid_input'] += 1
            self._publish_stop(cmd)
            return
        if self._blocked(obstacles):
            self._counts['blocked_stop'] += 1
            self._publish_stop(cmd)
            return
        age = extrapolation_age(self._odom_stamp, obstacles.t_ref, self._max_extrapolation)
        model_name = self._model_name
        safe, info = self._filter.filter(
            self._state, self._yaw, conversions.command_from_values(cmd.values, model_name),
            obstacles.obstacles, age)
        # A refused step returns the stop: nothing of the nominal command is kept then.
        kept = cmd.values if info.status != FilterStatus.INVALID_INPUT else None
        self._publish(cmd.replaced(conversions.values_from_command(safe, model_name, kept)))
        # Bookkeeping after the answer is out.
        self._counts[self._status_names[info.status]] += 1
        self._last_info = info
        self._min_h = min(self._min_h, info.min_h)
        self._latency.add(time.perf_counter() - start)

    def _publish(self, data):
        """Publish a serialized command and count it for the achieved rate."""
        self._publisher.publish(data)
        self._rate_meter.tick()

    def _pass_through(self, cmd, now):
        """Disabled: forward the nominal command as is; stop if it is stale or non-finite."""
        if self._watchdog.is_stale('cmd', now):
            self._counts['stale_stop'] += 1
            self._publish_stop(cmd)
        elif not self._cmd_valid:
            self._counts['invalid_input'] += 1
            self._publish_stop(cmd)
        else:
            self._publish(cmd.data)

    def _publish_stop(self, cmd):
        """Zero twist, or the quadrotor's braking (hover) wrench from the last finite state.

        Stamped stops carry the current time and the last command's frame.
        """
        values = conversions.values_from_command(self._filter.stop(self._state), self._model_name)
        stamp = self.get_clock().now().seconds_nanoseconds() if self._has_header else None
        self._publish(cmd.replaced(values, stamp))

    # -- observability ------------------------------------------------------------------------

    def _publish_diagnostics(self):
        """Publish one status: rate, latency, staleness, step counts, min h, rejections."""
        now = time.monotonic()
        obstacles = self._take_obstacles()
        p50, p99 = self._latency.percentiles()
        self._latency.clear()
        stale = self._watchdog.stale(now)
        window = {k: v - self._reported[k] for k, v in self._counts.items()}
        self._reported = dict(self._counts)
        rejected = {**obstacles.rejected, **obstacles.wrong_frame}
        values = {
            'enabled': str(self._enabled).lower(),
            'model': self._model_name,
            'barrier': self._barrier,
            'rate_target_hz': f'{1.0 / self._period:g}',
            'rate_achieved_hz': f'{self._rate_meter.rate(now):.1f}',
            'latency_p50_ms': f'{1e3 * p50:.3f}',
            'latency_p99_ms': f'{1e3 * p99:.3f}',
            'stale_inputs': ','.join(stale) or 'none',
            **{f'age_{name}_s': f'{self._watchdog.age(name, now):.3f}'
               for name in self._watchdog.names},
            **{f'steps_{name}': count for name, count in self._counts.items()},
            'steps_infeasible': sum(self._counts[name] for name in _INFEASIBLE),
            'steps_fallback': sum(self._counts[name] for name in _FALLBACKS),
            'invalid_messages': self._invalid_messages,
            'last_invalid_message': self._last_invalid,
            'min_h': f'{self._min_h:.4g}',
            'obstacles_in_use': len(obstacles.obstacles),
            'obstacles_tracked': obstacles.tracked,
            'obstacles_rejected': len(rejected),
            'obstacles_simplified': obstacles.simplified,
            'obstacles_hulled': len(obstacles.hulled),
            'block_if_invalid': str(self._block_if_invalid).lower(),
            'stalls': self._stall_guard.stalls,
            **{f'rejected {key}': reason for key, reason in sorted(rejected.items())},
        }
        self._min_h = math.inf
        errors, warnings = [], []
        if rejected:
            blocking = ' (block_if_invalid: stopping once stale)' if self._block_if_invalid else ''
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
        if not self._enabled:
            warnings.append('DISABLED: pass-through, not filtering')
            self.get_logger().warning('safety filter is DISABLED: nominal commands pass '
                                      'through unfiltered', throttle_duration_sec=5.0)
        if stale and self._cmd is not None:
            warnings.append(f'stale {", ".join(stale)}: stopping')
        fallbacks = [f'{name} x{window[name]}' for name in _FALLBACKS if window[name]]
        if fallbacks:
            warnings.append('fallback ' + ', '.join(fallbacks))
        level = (DiagnosticStatus.ERROR if errors else DiagnosticStatus.WARN if warnings
                 else DiagnosticStatus.OK)
        message = '; '.join(errors + warnings) or (
            'ok' if self._cmd is not None else 'waiting for the first nominal command')
        self._diagnostics_pub.publish(conversions.diagnostic_array(
            self.get_clock().now().to_msg(), f'{self.get_fully_qualified_name()}: safety filter',
            self._model_name, level, message, values))

    def destroy_node(self):
        """Stop the obstacle worker and the stall guard, then destroy the node."""
        self._stall_guard.stop()
        self._intake.stop()
        return super().destroy_node()

    def _publish_markers(self):
        """Publish obstacle parts and cones, only while ``~/markers`` has subscribers."""
        if self._odom_frame is None or self._markers_pub.get_subscription_count() == 0:
            return
        info = self._last_info
        active = info.active if info is not None else ()
        apex = cones = None
        if info is not None and self._model.position_dim == 2:
            apex = self._model.reference(self._state).position
            cones = info.cones
        self._markers_pub.publish(conversions.filter_markers(
            self._odom_frame, self.get_clock().now().to_msg(),
            self._obstacles.obstacles.footprints,
            active, apex, cones))


def main(args=None):
    """Run the safety filter node until shutdown; exit status 1 on a configuration error."""
    return run_node(SafetyFilterNode, 'safety_filter', args)


if __name__ == '__main__':
    sys.exit(main())
