"""The safety filter node's reports: ``/diagnostics``, ``~/state``, ``~/markers``, ``~/deadlock``.

``Reporter`` turns the steps' decisions (``core.decision.Decision``) and their counts into
messages.  Per step it only keeps numbers (``stepped``: the latency, min h, the
``filter_state`` classification, a few comparisons); messages are built on the node's slow
timers, or when what they say changes:

- ``/diagnostics`` (1 Hz): one status with rate, latency, input ages, step counts, min h,
  invalid messages, obstacle and scan rejections, stalls and deadlocks
  (doc/safety_filter.md, "Diagnostics"); a stall of the control loop at once, at ERROR
  (``report_stall``, from the stall guard's thread).
- ``~/state`` (reliable, transient local): what the last step did (``filter_state``: pass,
  limit, stop, fallback, deadlock, disabled), at 10 Hz and at once when that changes; the
  closest-obstacle distance it carries is computed only then.
- ``~/deadlock`` (std_msgs/Bool, reliable, transient local): the deadlock detector's verdict
  (``core.liveness.deadlock``), published on every change, for a planner or behaviour tree
  to act on; a report changes no command.
- ``~/markers`` (10 Hz, only while someone subscribes): obstacle parts, active constraints
  and cones (``rviz_markers``).
"""
import math
import time

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Bool
from visualization_msgs.msg import MarkerArray

from polyc2bf_ros import diagnostics, filter_state, rviz_markers
from polyc2bf_ros.core.stats import LatencyRing

_FALLBACKS = ('slack', 'brake', 'escape', 'backup', 'evade')
_INFEASIBLE = ('slack', 'brake')
_LATCHED_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                          durability=DurabilityPolicy.TRANSIENT_LOCAL)


class Reporter:
    """The node's reports (module docstring); their publishers are created on the node."""

    def __init__(self, node, decision, log, invalid, commands, odometry, intake, scan_topics,
                 rate_meter):
        """Create the outputs on ``node``; report on ``decision`` and the inputs.

        ``log``: the control path's ``LoopLogger``; ``invalid``: the inputs'
        ``InvalidMessages``; ``commands``, ``odometry``: the ``CommandPort`` and
        ``OdometryPort``; ``intake`` counts the rejections of ``scan_topics``;
        ``rate_meter`` is ticked per published command.
        """
        self._node, self._decision, self._log, self._invalid = node, decision, log, invalid
        self._commands, self._odometry = commands, odometry
        self._intake, self._scan_topics, self._rate_meter = intake, scan_topics, rate_meter
        command_filter = decision.filter  # a parameter change keeps the model
        self._model, self._velocity = command_filter.model, command_filter.velocity
        self._model_name = self._model.name
        self._diagnostics_pub = node._create_output(DiagnosticArray, '/diagnostics', 10)
        self._markers_pub = node._create_output(MarkerArray, '~/markers', 1)
        self._deadlock_pub = node._create_output(Bool, '~/deadlock', _LATCHED_QOS)
        self._state_pub = node._create_output(DiagnosticStatus, '~/state', _LATCHED_QOS)
        name = node.get_fully_qualified_name()
        self._status_name, self._state_name = f'{name}: safety filter', f'{name}: state'
        self._status_values = {'model': self._model_name}  # of the last status published
        self._reported = dict(decision.counts)  # the counts as of the last status
        self._reported_stalls = 0
        self._latency = LatencyRing()
        self._min_h = math.inf
        self.last_info = None  # the filter's FilterInfo of the last filtered step
        self._deadlocked = None  # last state published on ~/deadlock
        self._state = None  # (action, status, active constraints) of the last step
        self._state_published = None  # the action last published on ~/state

    # -- per step ----------------------------------------------------------------------------

    def stepped(self, decision, start):
        """Keep what a step did, once its answer is out; publish what changed.

        ``~/deadlock`` and ``~/state`` are published when they change; ``start``:
        ``time.perf_counter()`` when the step began.
        """
        self.report_deadlock(decision.deadlocked)
        info = decision.info
        if info is not None:  # the filter ran
            self.last_info = info
            self._min_h = min(self._min_h, info.min_h)
            self._latency.add(time.perf_counter() - start)
        self._state = filter_state.classify(self._decision.enabled, decision,
                                            self._decision.command_vector, self._velocity)
        if self._state[0] != self._state_published:
            self.publish_state()

    def report_deadlock(self, deadlocked):
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

    def reset_deadlock(self):
        """Publish ``~/deadlock`` false even if it was (activation)."""
        self._deadlocked = None
        self.report_deadlock(False)

    # -- ~/state and ~/markers ---------------------------------------------------------------

    def publish_state(self):
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

    def publish_state_once(self, state):
        """Publish ``state`` on ``~/state``; the timer repeats nothing until the next step."""
        self._state = state
        self.publish_state()
        self._state = None

    def publish_markers(self):
        """Publish obstacle parts and cones, only while ``~/markers`` has subscribers."""
        frame = self._odometry.frame
        if frame is None or self._markers_pub.get_subscription_count() == 0:
            return
        info = self.last_info
        active = info.active if info is not None else ()
        apex = cones = body = None
        decision = self._decision
        state = decision.state
        if state is not None:
            state = np.asarray(state)
            geometry = decision.filter.safety_filter.geometry
            body = rviz_markers.body_outline(self._model.body_centre(state), decision.yaw,
                                             geometry.footprint, geometry.robot_radius)
        if info is not None and state is not None and self._model.position_dim == 2:
            apex = self._model.reference(state).position
            cones = info.cones
        self._markers_pub.publish(rviz_markers.filter_markers(
            frame, self._node.get_clock().now().to_msg(),
            decision.snapshot.obstacles.footprints, active, apex, cones, body))

    # -- /diagnostics ------------------------------------------------------------------------

    def publish_diagnostics(self, obstacles, stalls):
        """Publish one status: rate, latency, staleness, step counts, min h, rejections.

        ``obstacles``: the obstacle snapshot in use; ``stalls``: the stall guard's count.
        """
        now = time.monotonic()
        decision = self._decision
        watchdog, counts = decision.watchdog, decision.counts
        config = decision.filter.safety_filter.config
        p50, p99 = self._latency.percentiles()
        self._latency.clear()
        stale = watchdog.stale(now)
        window = {k: v - self._reported[k] for k, v in counts.items()}
        self._reported = dict(counts)
        rejected = {**obstacles.rejected, **obstacles.wrong_frame}
        commanded = self._commands.last is not None
        values = {
            'enabled': str(decision.enabled).lower(),
            'model': self._model_name,
            'barrier': config.barrier,
            'rate_target_hz': f'{1.0 / config.control_period:g}',
            'rate_achieved_hz': f'{self._rate_meter.rate(now):.1f}',
            'latency_p50_ms': f'{1e3 * p50:.3f}',
            'latency_p99_ms': f'{1e3 * p99:.3f}',
            'stale_inputs': ','.join(stale) or 'none',
            **{f'age_{name}_s': f'{watchdog.age(name, now):.3f}'
               for name in watchdog.names},
            **{f'steps_{name}': count for name, count in counts.items()},
            'steps_infeasible': sum(counts[name] for name in _INFEASIBLE),
            'steps_fallback': sum(counts[name] for name in _FALLBACKS),
            'invalid_messages': self._invalid.count,
            'last_invalid_message': self._invalid.last,
            'min_h': f'{self._min_h:.4g}',
            'obstacles_in_use': len(obstacles.obstacles),
            'obstacles_tracked': obstacles.tracked,
            'obstacles_rejected': len(rejected),
            'obstacles_simplified': obstacles.simplified,
            'obstacles_hulled': len(obstacles.hulled),
            'block_if_invalid': str(decision.block_if_invalid).lower(),
            'stalls': stalls,
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
        if stalls > self._reported_stalls:
            errors.append(f'control loop stalled ({stalls} times): stop '
                          'published by the stall guard')
        self._reported_stalls = stalls
        if obstacles.simplified or obstacles.hulled:
            warnings.append(f'{obstacles.simplified} obstacle outlines simplified '
                            f'(max_vertices / max_parts), {len(obstacles.hulled)} replaced by '
                            'their hull (max_parts)')
        if not decision.enabled:
            warnings.append('DISABLED: pass-through, not filtering')
            self._log.warning('safety filter is DISABLED: nominal commands pass through '
                              'unfiltered', throttle_s=5.0)
        if stale and commanded:
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
            'ok' if commanded else 'waiting for the first nominal command')
        self._status_values = values
        self._publish_status(level, message, values)

    def _scan_values(self):
        """Diagnostics of the scan topics: rejections and the last reason, per topic."""
        values = {}
        for topic in self._scan_topics:
            status = self._intake.scan_status.get(topic)
            values[f'scans_rejected {topic}'] = 0 if status is None else status.rejected
            if status is not None and status.reason:
                values[f'last_scan_rejection {topic}'] = status.reason
        return values

    def report_stall(self, silence, guard):
        """Stall guard's thread: log the stall and publish the last status at ERROR.

        ``silence``: how long the loop has been silent [s]; ``guard``: the ``StallGuard``.
        """
        message = (f'control loop stalled for {silence:.3f} s (stall_timeout '
                   f'{guard.timeout:g} s): stop published by the stall guard')
        self._log.error(message, throttle_s=1.0)
        self._publish_status(DiagnosticStatus.ERROR, message, {
            **self._status_values, 'stalls': guard.stalls, 'stall_s': f'{silence:.3f}'})

    def _publish_status(self, level, message, values):
        self._diagnostics_pub.publish(diagnostics.diagnostic_array(
            self._node.get_clock().now().to_msg(), self._status_name, self._model_name, level,
            message, values))
