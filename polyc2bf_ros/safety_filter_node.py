"""``safety_filter``: PolyC2BF safety filter between a planner and a robot.

Topics, QoS, parameters and diagnostics: doc/safety_filter.md.  In short: ``odom``,
``obstacles`` (markers; not with ``use_markers:=false``), ``scan_topics``,
``footprint_topic`` and the nominal ``cmd_vel_in`` (Twist, TwistStamped with
``stamped:=true``) or ``wrench_in`` (quadrotor) in;
the safe command on ``cmd_vel_out`` / ``wrench_out`` (the input's type and header),
``/diagnostics``, ``~/markers``, ``~/state`` and ``~/deadlock`` out; ``~/enable`` switches
filtering off (pass-through, WARN) and on.

Each step (every ``1/rate`` s with ``trigger:=timer``, or per nominal command
with ``trigger:=command``)::

    stale odom / command / obstacles (steady clock)  -> stop
    NaN/Inf in odometry, command or obstacles        -> stop (brake)
    rejected obstacles, block_if_invalid, timeout 0  -> stop
    otherwise  safe command = CommandFilter.filter(state, yaw, nominal command, obstacles, age)

``core.decision.ControlDecision`` takes that decision, the same for bag replay and the
evaluation; the node only turns messages into its inputs and its answer into a message.  A
stop is a zero twist, or the model's braking (hover) wrench.  Nothing is published before
the first nominal command; after it, every step publishes.  Obstacles are processed in a
worker process (``obstacle_intake``), so no obstacle message delays a step.  If no step or
tick has run for ``stall_timeout`` (steady clock), a separate thread publishes the stop and
an ERROR status (``stall_guard``).

``SafetyFilterMixin`` is the composition root: ``_configure`` creates and wires the parts,
``_step`` runs a step.  The parts: ``node_parameters``, ``ports`` (one input port per
source: ``odometry_port``, ``command_port``, ``marker_port``, ``scan_port``,
``transform_port``, ``footprint_port``; ``obstacle_feed``), ``lockstep_gate``
(``match_stamps``) and ``reporter``.  ``SafetyFilterNode`` (this executable) sets it up and
starts it at once, the managed ``safety_filter_lifecycle`` from its lifecycle transitions.
Hot path: inputs are taken serialized and only the fields used are read (``conversions``);
the answer is a copy of the command's bytes with its six numbers replaced.
"""
import sys
import time

from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from std_srvs.srv import SetBool

from polyc2bf_ros import conversions
from polyc2bf_ros.core.actuation.command_interface import VELOCITY_MODELS
from polyc2bf_ros.core.decision import ControlDecision
from polyc2bf_ros.core.safety_filter import FilterStatus
from polyc2bf_ros.core.stats import RateMeter
from polyc2bf_ros.lockstep_gate import LockstepGate
from polyc2bf_ros.loop_log import LoopLogger
from polyc2bf_ros.node_entities import NodeEntitiesMixin
from polyc2bf_ros.node_main import run_node
from polyc2bf_ros.node_parameters import NodeParameters
from polyc2bf_ros.obstacle_intake import ObstacleIntake
from polyc2bf_ros.ports.command_port import COMMAND_QOS, command_topics, CommandPort
from polyc2bf_ros.ports.footprint_port import FootprintPort
from polyc2bf_ros.ports.invalid_messages import InvalidMessages
from polyc2bf_ros.ports.marker_port import MarkerPort
from polyc2bf_ros.ports.obstacle_feed import ObstacleFeed
from polyc2bf_ros.ports.odometry_port import OdometryPort
from polyc2bf_ros.ports.scan_port import ScanPort
from polyc2bf_ros.ports.transform_port import subscribe_static_transforms
from polyc2bf_ros.reporter import Reporter
from polyc2bf_ros.stall_guard import StallGuard

_STEADY = ClockType.STEADY_TIME
_DIAGNOSTICS_PERIOD = 1.0
_MARKERS_PERIOD = 0.1
_STATE_PERIOD = 0.1
_STALL_CHECKS_PER_TIMEOUT = 4
_REFUSED = FilterStatus.INVALID_INPUT


class SafetyFilterMixin(NodeEntitiesMixin):
    """The safety filter on a node: its parameters, topics, timers, service and worker.

    Shared by ``SafetyFilterNode`` (set up and stepping from the start) and the managed
    ``safety_filter_lifecycle`` node, which calls the same four stages from its transitions:
    ``_configure`` (parameters, subscriptions, outputs, timers, the obstacle worker),
    ``_activate`` (steps and the stall guard run), ``_deactivate`` (they stop; inputs are
    still taken) and ``_release`` (``node_entities``: everything ``_configure`` created is
    destroyed, newest first).
    """

    _active = False  # steps publish only while active

    def _configure(self):
        """Read and check the parameters, then create everything the filter uses.

        An invalid configuration raises one of ``node_main.CONFIGURATION_ERRORS`` before
        anything is created.
        """
        parameters = NodeParameters(self)
        settings = parameters.settings
        self._undo = []
        self._model_name = settings.model_name
        self._per_command = settings.per_command
        stamped = self.get_parameter('stamped').value
        velocity = self._model_name in VELOCITY_MODELS
        # Command messages with a header: TwistStamped (stamped:=true) and WrenchStamped.
        self._has_header = stamped or not velocity
        self._command_type, command_in, command_out = command_topics(velocity, stamped)
        lockstep = (self._per_command and self.get_parameter('match_stamps').value
                    and self._has_header)
        self._decision = ControlDecision(settings.command_filter, settings.watchdog_timeouts,
                                         settings.block_if_invalid, settings.max_extrapolation,
                                         settings.deadlock, settings.resolution, settings.route)
        self._intake = ObstacleIntake(settings.command_filter.safety_filter.geometry,
                                      lambda: self.get_clock().now().nanoseconds * 1e-9,
                                      settings.intake,
                                      self._obstacles_processed if lockstep else None)
        self._log = LoopLogger(self.get_logger())  # for the control path (loop_log)
        self._invalid = InvalidMessages(self._log)
        self._stall_guard = self._new_stall_guard(settings.stall_timeout)
        self._apply(settings)
        self._gate = (LockstepGate(self, self._decision, self._intake, self._step) if lockstep
                      else None)
        self._create_inputs(settings, command_in)
        self._publisher = self._create_output(self._command_type, command_out, COMMAND_QOS)
        self._rate_meter = RateMeter(time.monotonic())
        self._reporter = Reporter(self, self._decision, self._log, self._invalid, self._commands,
                                  self._odometry, self._intake, settings.scan_topics,
                                  self._rate_meter)
        self._create_timers(settings)
        self._keep(self.destroy_service, self.create_service(SetBool, '~/enable', self._on_enable))
        parameters.watch(self._parameters_changed)
        self._intake.start()
        self._undo.append(self._intake.stop)
        self._undo.append(self._deactivate)  # undone first: no step or stall stop after it
        self.get_logger().info(
            f'model {self._model_name}, barrier {self._barrier}, trigger '
            f'{"command" if self._per_command else "timer"} at {1.0 / settings.period:g} Hz, '
            f'listening on {command_in}')

    def _create_inputs(self, settings, command_in):
        """Create the input ports (relative names: namespaces, remapping).

        Obstacles, then odometry, then commands: an executor serving them in one wake-up
        (in creation order) answers on the newest inputs.  All are taken serialized (raw):
        obstacle bytes go to the worker as they came; see the module docstring.
        """
        if settings.use_markers:
            self._on_obstacles = MarkerPort(self, self._intake).on_markers
        watchdogs = settings.scan_watchdogs
        if watchdogs:
            subscribe_static_transforms(self, self._intake)
        self._odometry = OdometryPort(self, self._decision, self._intake, self._invalid,
                                      self._gate, self._model_name, keep_history=bool(watchdogs))
        footprint_topic = self.get_parameter('footprint_topic').value
        if footprint_topic:
            FootprintPort(self, footprint_topic, self._odometry, self._log)
        scans = (ScanPort(self, self._decision, self._intake, self._log, self._odometry,
                          watchdogs) if watchdogs else None)
        self._commands = CommandPort(
            self, self._decision, self._invalid, self._gate,
            self._step if self._per_command else None, self._command_type, command_in,
            self._has_header, self._model_name)
        self._take_obstacles = ObstacleFeed(self._intake, self._decision, scans, self._invalid,
                                            self._log).take
        # The subscriptions' callbacks, for drivers that run the node in process (tests, bench/).
        self._on_odom, self._on_command = self._odometry.callback, self._commands.on_command

    def _create_timers(self, settings):
        """Create the control (or stale-command) timer and the slow observability timers."""
        steady = Clock(clock_type=_STEADY)
        callback = self._on_watchdog if self._per_command else self._on_timer
        self._timer = self._keep(self.destroy_timer,
                                 self.create_timer(settings.tick, callback, clock=steady))
        for period, callback in ((_DIAGNOSTICS_PERIOD, self._publish_diagnostics),
                                 (_MARKERS_PERIOD, self._reporter.publish_markers),
                                 (_STATE_PERIOD, self._reporter.publish_state)):
            self._keep(self.destroy_timer, self.create_timer(period, callback, clock=steady))

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
        self._reporter.reset_deadlock()

    def _deactivate(self):
        """Stop stepping and the stall guard; inputs are still taken."""
        self._active = False
        self._stall_guard.stop()

    def _apply(self, settings):
        """Swap in validated settings (decision, obstacle worker, stall guard)."""
        self._filter = settings.command_filter
        self._barrier = self._filter.safety_filter.config.barrier
        self._decision.configure(settings.command_filter, settings.watchdog_timeouts,
                                 settings.block_if_invalid, settings.max_extrapolation,
                                 settings.deadlock, settings.resolution, settings.route)
        self._intake.configure(settings.intake, settings.command_filter.safety_filter.geometry)
        self._stall_guard.timeout = settings.stall_timeout
        self._stall_guard.period = settings.stall_timeout / _STALL_CHECKS_PER_TIMEOUT

    def _parameters_changed(self, settings):
        """Apply accepted parameters (filter rebuilt, timer period updated)."""
        self._apply(settings)
        self._timer.timer_period_ns = int(1e9 * settings.tick)

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

    def _obstacles_processed(self):
        """Feeder thread, after each obstacle pass (``match_stamps``): wake the lockstep gate."""
        self._gate.obstacles_processed()

    def _step(self, now):
        """Publish one safe command (or a stop, or the nominal when disabled)."""
        self._stall_guard.beat(now)
        cmd = self._commands.last
        if cmd is None or not self._active:
            return
        start = time.perf_counter()
        self._take_obstacles()
        decision = self._decision.step(now)
        action = decision.action
        if action == 'stop':
            self._publish_stop(cmd, decision.command)
        elif action == 'pass':
            self._publish(cmd.data)
        else:
            # A refused step returns the stop: nothing of the nominal command is kept then.
            kept = cmd.values if decision.info.status != _REFUSED else None
            self._publish(cmd.replaced(conversions.values_from_command(
                decision.command, self._model_name, kept)))
        self._reporter.stepped(decision, start)  # bookkeeping after the answer is out

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

    def _on_stall(self, silence):
        """Stall guard (its own thread): the control loop is silent; publish the stop."""
        cmd = self._commands.last
        if cmd is not None:
            self._publish_stop(cmd, self._decision.stop())
        self._reporter.report_stall(silence, self._stall_guard)

    def _publish_diagnostics(self):
        """Publish ``/diagnostics`` (``reporter``) on the newest obstacles."""
        self._reporter.publish_diagnostics(self._take_obstacles(), self._stall_guard.stalls)

    @property
    def _last_info(self):
        # The filter's info of the last filtered step, as bench/bench_cold.py reads it.
        return self._reporter.last_info


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
