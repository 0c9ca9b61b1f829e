"""Offline check: re-run the node's decision on a bag and compare with its safe commands.

No DDS::

    bag_replay BAG --offline [--robot NS] --params-file config/quadruped.yaml
               [-p NAME:=VALUE ...] [--json REPORT] [--tolerance TOL] [--worst N]

feeds the bag's ``/NS/odom``, ``/NS/obstacles`` and nominal commands
(``/NS/cmd_vel_in``, or ``/NS/wrench_in`` for the quadrotor model) straight
into the node's decision, ``core.decision.ControlDecision``, configured from the same
parameter file(s) the node takes (rcl's YAML: the sections whose node name
pattern matches ``/NS/safety_filter``, e.g. ``/**/safety_filter``) plus ``-p``
overrides, with the node's defaults for the rest.  Obstacles go through the
node's own pipeline (``obstacle_pipeline.ObstaclePipeline``, in process), and the log
times stand in for the node's steady clock.

Each recorded safe command (``/NS/cmd_vel_out`` / ``/NS/wrench_out``, stamped
with the stamp of the nominal command it answers) is paired with the odometry
and nominal command of the same stamp; in lockstep with ``match_stamps`` that
is exactly what the node used, so the outputs must agree to rounding.  Outputs
with no same-stamp inputs (the watchdog's stops, stamped with the node's clock)
are counted as unpaired.  The report gives max and mean |difference| per
command component (``[v, omega]``, ``[vx, vy(, vz)]`` or the wrench
``[T, tau_x, tau_y, tau_z]``, absolute, in command units), the offline
filter's status counts and the worst steps; ``--json`` writes it.  It passes
when something was paired and every difference is within ``--tolerance``.
"""
import dataclasses
import math
from collections import Counter

import numpy as np

from polyc2bf_ros import conversions
from polyc2bf_ros.core.decision import ControlDecision
from polyc2bf_ros.filter_parameters import build_filter
from polyc2bf_ros.obstacle_pipeline import ObstacleJob, ObstaclePipeline
from sim_bridge.bag_player import log, ReplayError, stamp_ns
from sim_bridge.bag_reader import BagReader


def find_robot(topics):
    """Return the one namespace with odometry and a recorded safe command."""
    robots = sorted(name[:-len('/odom')] for name in topics if name.endswith('/odom') and (
        name[:-len('odom')] + 'cmd_vel_out' in topics
        or name[:-len('odom')] + 'wrench_out' in topics))
    if len(robots) != 1:
        raise ReplayError('pass --robot: the bag has ' + (
            f'several robots ({", ".join(r.strip("/") for r in robots)})' if robots
            else 'no <ns>/odom with a <ns>/cmd_vel_out or <ns>/wrench_out'))
    return robots[0].strip('/')


@dataclasses.dataclass
class OfflineStep:
    """One recorded safe command beside the offline filter's answer."""

    stamp_s: float
    status: str
    recorded: np.ndarray
    offline: np.ndarray
    nominal: np.ndarray
    state: np.ndarray

    @property
    def abs_diff(self):
        """Return |offline - recorded| per component."""
        return np.abs(self.offline - self.recorded)


@dataclasses.dataclass
class OfflineReport:
    """The offline comparison of a bag's safe commands."""

    bag: str
    robot: str
    model: str
    topics: dict        # role (odom, obstacles, nominal, safe) -> bag topic
    components: tuple
    steps: list
    unpaired: int
    tolerance: float
    parameters: dict

    @property
    def max_abs_diff(self):
        """Return the max |difference| per component (NaN without steps)."""
        if not self.steps:
            return np.full(len(self.components), np.nan)
        return np.max([s.abs_diff for s in self.steps], axis=0)

    @property
    def mean_abs_diff(self):
        """Return the mean |difference| per component (NaN without steps)."""
        if not self.steps:
            return np.full(len(self.components), np.nan)
        return np.mean([s.abs_diff for s in self.steps], axis=0)

    @property
    def status_counts(self):
        """Return ``{status: steps}`` of the offline filter."""
        return dict(Counter(s.status for s in self.steps))

    @property
    def passed(self):
        """Whether something was paired and every difference is within the tolerance."""
        return bool(self.steps) and float(np.max(self.max_abs_diff)) <= self.tolerance

    def worst(self, count):
        """Return the ``count`` steps with the largest difference, largest first."""
        return sorted(self.steps, key=lambda s: -float(s.abs_diff.max()))[:count]

    def to_json(self, worst=5):
        """Return the report as plain JSON data."""
        def step(s):
            return {'stamp_s': s.stamp_s, 'status': s.status, 'recorded': s.recorded.tolist(),
                    'offline': s.offline.tolist(), 'nominal': s.nominal.tolist(),
                    'max_abs_diff': float(s.abs_diff.max())}

        return {
            'bag': self.bag, 'robot': self.robot, 'model': self.model, 'topics': self.topics,
            'components': list(self.components), 'paired': len(self.steps),
            'unpaired': self.unpaired,
            'max_abs_diff': dict(zip(self.components, self.max_abs_diff.tolist())),
            'mean_abs_diff': dict(zip(self.components, self.mean_abs_diff.tolist())),
            'tolerance': self.tolerance, 'passed': self.passed,
            'status_counts': self.status_counts, 'worst': [step(s) for s in self.worst(worst)],
            'parameters': {k: v for k, v in sorted(self.parameters.items())},
        }

    def summary(self, worst=5):
        """Return the report as text."""
        params = self.parameters
        lines = [f'offline check of /{self.robot} in {self.bag}: {len(self.steps)} safe commands '
                 f'paired by stamp, {self.unpaired} unpaired (no same-stamp odometry and '
                 'command, e.g. watchdog stops)',
                 f'model {self.model}, barrier {params["filter.barrier"]}, rate '
                 f'{params["rate"]:g} Hz, trigger {params["trigger"]}, match_stamps '
                 f'{str(params["match_stamps"]).lower()}']
        if not (params['trigger'] == 'command' and params['match_stamps']):
            lines.append('note: without trigger command and match_stamps the node may have '
                         'used other odometry than the same-stamp one; expect differences')
        lines.append(f'{"component":<10} {"max |diff|":>12} {"mean |diff|":>12}')
        for name, high, mean in zip(self.components, self.max_abs_diff, self.mean_abs_diff):
            lines.append(f'{name:<10} {high:12.3e} {mean:12.3e}')
        lines.append('offline statuses: ' + ', '.join(
            f'{k} {v}' for k, v in sorted(self.status_counts.items())))
        if self.steps:
            lines.append('worst steps:')
            for s in self.worst(worst):
                lines.append(f'  t = {s.stamp_s:.4f} s {s.status}: recorded '
                             f'{np.round(s.recorded, 6).tolist()}, offline '
                             f'{np.round(s.offline, 6).tolist()}, nominal '
                             f'{np.round(s.nominal, 6).tolist()}')
        verdict = 'PASS' if self.passed else 'FAIL'
        high = float(np.max(self.max_abs_diff)) if self.steps else math.nan
        lines.append(f'{verdict}: max |difference| {high:.3e} (tolerance {self.tolerance:g})')
        return '\n'.join(lines)


def _command_vector(msg, velocity, model_name):
    """Command vector of a TwistStamped (velocity models) or WrenchStamped."""
    if velocity:
        return np.array(conversions.twist_to_command(msg.twist, model_name), dtype=float)
    w = msg.wrench
    return np.array([w.force.z, w.torque.x, w.torque.y, w.torque.z], dtype=float)


class _OfflineNode:
    """The node's decision (``ControlDecision``) and obstacle pipeline, fed from a bag.

    Log times stand in for the node's steady clock (the bridge logs what it receives when
    it receives it), so the watchdogs see what the node saw.
    """

    def __init__(self, setup):
        self.setup = setup
        self.filter = setup.command_filter
        self.decision = ControlDecision(setup.command_filter, setup.timeouts,
                                        setup.block_if_invalid, setup.max_extrapolation,
                                        setup.deadlock, setup.resolution, setup.route)
        self.pipeline = ObstaclePipeline()
        self.geometry = setup.command_filter.safety_filter.geometry
        self.frame = None
        self.odometry = {}   # stamp ns -> (log time s, state, yaw)
        self.nominal = {}    # stamp ns -> (log time s, command vector)

    def _obstacles(self, messages, now):
        """Run the node's obstacle pipeline on ``messages`` and hand the result over."""
        self.decision.obstacles(self.pipeline.run(ObstacleJob(
            messages, self.frame, self.setup.intake, self.geometry, now)))

    def on_obstacles(self, msg, t_ns):
        """Process a MarkerArray (zero stamps read as the log time)."""
        self._obstacles([(msg, t_ns * 1e-9)], t_ns * 1e-9)

    def on_odometry(self, msg, t_ns):
        """Keep the state of each odometry stamp; a new frame rebuilds the obstacles."""
        state = np.zeros(self.filter.model.state_dim)
        yaw = conversions.odometry_to_state(msg, self.setup.model_name, state)
        self.odometry[stamp_ns(msg)] = (t_ns * 1e-9, state, yaw)
        frame = msg.header.frame_id.lstrip('/')
        if frame != self.frame:
            self.frame = frame
            self._obstacles([], t_ns * 1e-9)

    def on_nominal(self, msg, t_ns):
        """Keep the nominal command of each stamp."""
        self.nominal[stamp_ns(msg)] = (t_ns * 1e-9, _command_vector(
            msg, self.filter.velocity, self.setup.model_name))

    def answer(self, stamp):
        """Return ``(command, status, nominal, state)`` for the stamp, or None if unpaired."""
        if stamp not in self.odometry or stamp not in self.nominal:
            return None
        odom_time, state, yaw = self.odometry[stamp]
        cmd_time, command = self.nominal[stamp]
        decision = self.decision
        finite = bool(np.isfinite(state).all() and math.isfinite(yaw))
        decision.odometry(odom_time, *((state, yaw, stamp * 1e-9) if finite else ()))
        finite_command = bool(np.isfinite(command).all())
        decision.command(cmd_time, *((command,) if finite_command else ()))
        result = decision.step(max(odom_time, cmd_time))
        if result.action == 'filter':
            return result.command, result.info.status.value, command, state
        return result.command, result.reason, command, state


def offline_check(bag, robot=None, parameters=None, tolerance=1e-6):
    """Re-run the node's decision on a bag; return the ``OfflineReport``.

    See the module docstring; ``parameters`` is ``{name: value}`` (e.g. from
    ``load_parameters``).  A recorded safe command logged at ``t`` is answered
    once every message logged at ``t`` is in: the bridge logs what it receives
    during period ``t`` at ``t``, in arrival order, so the same-stamp nominal
    command may come after it.
    """
    reader = BagReader(bag)
    topics = reader.topics
    robot = (robot or find_robot(topics)).strip('/')
    setup = build_filter(parameters or {})
    if setup.ignored:
        log(f'ignoring parameters the node does not declare: {", ".join(setup.ignored)}')
    node = _OfflineNode(setup)
    velocity = setup.command_filter.velocity
    kind = ('cmd_vel_in', 'cmd_vel_out') if velocity else ('wrench_in', 'wrench_out')
    names = {'odom': f'/{robot}/odom', 'obstacles': f'/{robot}/obstacles',
             'nominal': f'/{robot}/{kind[0]}', 'safe': f'/{robot}/{kind[1]}'}
    for role, name in names.items():
        if name not in topics:
            raise ReplayError(f'the bag has no {name} ({role}); topics: '
                              f'{", ".join(sorted(topics))}')
    for role in ('nominal', 'safe'):
        type_name = topics[names[role]].type_name
        if not type_name.endswith('Stamped'):
            raise ReplayError(f'{names[role]} is {type_name}: pairing commands with odometry '
                              'needs stamped commands (TwistStamped / WrenchStamped)')
    components = (('v', 'omega') if setup.model_name == 'unicycle'
                  else ('vx', 'vy', 'vz')[:setup.command_filter.command_dim] if velocity
                  else ('thrust', 'tau_x', 'tau_y', 'tau_z'))
    steps, pending, unpaired = [], [], 0

    def flush():
        nonlocal unpaired
        for stamp, recorded in pending:
            answer = node.answer(stamp)
            if answer is None:
                unpaired += 1
                continue
            safe, status, command, state = answer
            steps.append(OfflineStep(stamp * 1e-9, status, recorded,
                                     np.asarray(safe, dtype=float), command, state))
        pending.clear()

    role_of = {name: role for role, name in names.items()}
    log_ns = None
    for topic, _, t_ns, msg in reader.messages(names.values()):
        if t_ns != log_ns:
            flush()
            log_ns = t_ns
        role = role_of[topic]
        if role == 'obstacles':
            node.on_obstacles(msg, t_ns)
        elif role == 'odom':
            node.on_odometry(msg, t_ns)
        elif role == 'nominal':
            node.on_nominal(msg, t_ns)
        else:
            pending.append((stamp_ns(msg), _command_vector(msg, velocity, setup.model_name)))
    flush()
    return OfflineReport(str(bag), robot, setup.model_name, names, components, steps,
                         unpaired, tolerance, setup.parameters)
