"""In-process lockstep closed loop: SimWorld + nominal controller + CommandFilter, no DDS.

The evaluation's runner.  Each control period ``T`` (the bridge's: ``n =
physics_rate / control_rate`` physics steps, ``Scenario.substeps``; rates that
do not divide are refused, not rounded), for every robot at once::

    state    = world.robot_state(robot)                      (the odometry's state)
    command  = nominal law of ``nominal_controller``: [v, omega] or wrench
    safe     = ControlDecision.step(t)  on that state, command and obstacles (the node's)
    world.set_command(robot, safe); n x world.step()        (zero-order hold)

Nominal laws (``NOMINALS``): ``goal``, the go-to-goal controller of the robot's
type (``sim_bridge.robots``); ``path``, pure pursuit along the robot's scenario
``path`` (``UnicyclePathController``, unicycle types only).  The filter is
configured from the same parameter file the node gets (the type's
``params_file``), read and built as the node does
(``polyc2bf_ros.filter_parameters``), with the lockstep run's ``rate`` = 1/T,
the chosen ``filter.barrier`` and what the body implies
(``launcher.body_parameters``); with ``barrier='none'`` the nominal command goes
straight to the robot.  Metrics come from the bridge's own ``RunMetrics``
(sampled once per period).  ``until``, if given, is asked after every period
whether the run is over (the BARN protocol ends runs early); the traces then
end there.

``obstacle_source`` says where a filter's obstacles come from: ``markers``
(default), what the bridge publishes as markers, or ``scan``, a simulated lidar
(``lidar``, a ``sim_bridge.lidar.LidarSettings``; default its defaults) on every
filtered robot, converted as the node converts its ``scan_topics``
(``obstacle_views.ScanView``): no ground-truth polygon reaches the filter then.  With
``marker_pipeline`` (markers only) the markers the bridge would publish go through the
node's own obstacle pipeline (``obstacle_views.MarkerView``), so the filter gets the
node's velocity estimates, not the true ones.

Marker obstacles (without ``marker_pipeline``) are what the bridge publishes, built as
the node builds them: static and moving prisms from their footprint polygons and z
ranges; other robots as the node's polygon for the bridge's CYLINDER marker
(``marker_obstacles.marker_geometry``: ``cylinder_sides`` = 12, circumscribing the
robot's footprint radius).  Differences from the DDS path, all on the side of
the exact information:

- obstacle and robot velocities are the true ones (without ``marker_pipeline``); the
  node estimates them from successive marker poses (``ObstacleTracker``), so it sees a
  moving obstacle's velocity only a few periods after it appears;
- the state is the plant's, not the odometry message's (equal up to the
  quaternion round trip of the Crazyflie's attitude);
- obstacles are never stale; markers are stamped with the period's time (age 0), and a
  scan's obstacles are moved along their tracked velocities from the scan's stamp to the
  period's, as the node does (``max_extrapolation``);
- in scan mode a scan always serves the period it is delivered to; over DDS the
  node may answer that period's command before the scan has arrived, one period
  late (1.4 mm apart over 6 s of ``long_wall``).

Recorded per robot and period: time, state, nominal and safe commands, the
model input ``u`` and ``u_nom`` (accelerations, or rotor thrusts), the filter
status, the wall time of the decision step (the step latency) and the verdict of the
node's deadlock report (``core.liveness.deadlock``, on simulated time, with the parameter file's
``deadlock_time`` / ``deadlock_radius``).  The decision is the node's ``ControlDecision``
with every input fresh (timeouts 0) and the obstacles stamped with the period's time;
``parameters`` (e.g. ``{'deadlock_resolution': 'circulate'}``) override the parameter
file's values for every robot.
"""
import dataclasses
import time
from pathlib import Path

import numpy as np

from polyc2bf_ros.core.decision import ControlDecision
from polyc2bf_ros.core.models import crazyflie
from polyc2bf_ros.filter_parameters import build_filter, load_parameters
from sim_bridge.actuation import Actuation, CommandPipe, Odometry
from sim_bridge.launcher import (
    body_parameters,
    control_rate,
    FILTER_CHOICES,
    OBSTACLE_SOURCES,
    params_file,
    scan_parameters,
)
from sim_bridge.lidar import LidarSettings
from sim_bridge.metrics import RunMetrics
from sim_bridge.nominal import ReferencePath, UnicyclePathController
from sim_bridge.obstacle_views import MarkerView, ObstacleView, ScanView
from sim_bridge.robots import ROBOT_TYPES
from sim_bridge.scenario import load_scenario
from sim_bridge.world import SimWorld

NOMINALS = ('goal', 'path')


@dataclasses.dataclass
class RobotTrace:
    """Per-period record of one robot; ``states`` has one row more (the final state).

    ``input_box`` is (lower, upper) of the model input ``u`` (the node's parameters).
    """

    name: str
    type: str
    goal: np.ndarray
    input_box: tuple
    times: np.ndarray
    states: np.ndarray
    nominal: np.ndarray
    commands: np.ndarray
    u_nom: np.ndarray
    u: np.ndarray
    statuses: list
    latency_s: np.ndarray
    deadlocked: np.ndarray
    min_h: np.ndarray

    def speeds(self):
        """Return the speed [m/s] at every recorded state (|v| or |velocity|)."""
        if ROBOT_TYPES[self.type].unicycle:
            return np.abs(self.states[:, 3])
        return np.linalg.norm(self.states[:, 3:6], axis=1)

    def positions(self):
        """Return the positions (K + 1, 2 or 3): [x, y] or [x, y, z]."""
        return self.states[:, :2] if ROBOT_TYPES[self.type].unicycle else self.states[:, :3]


@dataclasses.dataclass
class ClosedLoopRun:
    """Result of ``run_in_process``: the scenario run, per-robot traces and bridge metrics.

    ``ended`` is what ``until`` answered when it ended the run early (None: it ran the
    scenario's duration).
    """

    scenario: object
    barrier: str
    period: float
    robots: dict
    metrics: dict
    wall_time_s: float
    robot_radius: float = None
    nominal: str = 'goal'
    ended: object = None
    obstacle_source: str = 'markers'
    lidar: LidarSettings = None
    marker_pipeline: bool = False
    actuation: Actuation = Actuation()


class _Robot:
    """One robot's controller, filter and trace buffers."""

    def __init__(self, spec, barrier, nominal, period, steps, world, overrides=None):
        """Build the nominal law and (unless ``barrier`` is 'none') the node's CommandFilter.

        ``intake`` and ``geometry`` are what the node's obstacle worker gets.
        """
        robot = ROBOT_TYPES[spec.type]
        self.kind, self.yaw_index = robot.command_kind, robot.yaw_index
        self.spec = spec
        self.controller, self.target = robot.goal_controller(**spec.nominal_gains), spec.goal
        if nominal == 'path':
            if not robot.unicycle or spec.path is None:
                raise ValueError(f'robot {spec.name!r}: the path nominal needs a unicycle '
                                 f'robot with a path, not a {spec.type} with path {spec.path}')
            self.controller = UnicyclePathController(**spec.nominal_gains)
            self.target = ReferencePath(spec.path)
        parameters = {**load_parameters([params_file(spec.type)], (), spec.name),
                      'rate': 1.0 / period, **body_parameters(spec), **(overrides or {})}
        self.filter = self.decision = self.intake = self.geometry = None
        # The model gives u and u_nom for the intervention metric even without a filter.
        self.reference = build_filter(parameters).command_filter
        if barrier != 'none':
            settings = build_filter({**parameters, 'filter.barrier': barrier})
            self.filter = settings.command_filter
            self.intake = settings.intake
            self.geometry = self.filter.safety_filter.geometry
            self.decision = ControlDecision(self.filter, dict.fromkeys(settings.timeouts, 0.0),
                                            settings.block_if_invalid, settings.max_extrapolation,
                                            settings.deadlock, settings.resolution,
                                            settings.route)
        self.robot_radius = self.reference.safety_filter.geometry.robot_radius
        state = world.robot_state(spec.name)
        dim = 2 if robot.unicycle else 4
        inputs = self.reference.model.input_dim
        self.times = np.arange(steps) * period
        self.states = np.zeros((steps + 1, state.size))
        self.states[0] = state
        self.nominal = np.zeros((steps, dim))
        self.commands = np.zeros((steps, dim))
        self.inputs = inputs
        self.statuses = []
        self.latency = np.full(steps, np.nan)
        self.deadlocked = np.zeros(steps, dtype=bool)
        self.min_h = np.full(steps, np.inf)  # the step's smallest barrier (inf: none)

    def command(self, k, state, snapshot):
        """Return the safe command of period ``k`` (obstacles: ``snapshot``) and record it."""
        if self.kind == 'velocity':
            nominal = self.controller.velocity_command(state, self.target)
        else:
            nominal = self.controller.wrench(state, self.target)
        command, status = nominal, 'none'
        if self.decision is not None:
            now, decision = self.times[k], self.decision
            start = time.perf_counter()
            decision.odometry(now, state, float(state[self.yaw_index]), now)
            decision.command(now, nominal)
            decision.obstacles(snapshot)
            result = decision.step(now)
            self.latency[k] = time.perf_counter() - start
            command = result.command
            status = result.info.status.value if result.info is not None else result.reason
            self.deadlocked[k] = result.deadlocked
            if result.info is not None:
                self.min_h[k] = result.info.min_h
        self.nominal[k] = nominal
        self.commands[k] = command
        self.statuses.append(status)
        return command

    def truncate(self, steps):
        """Keep the first ``steps`` periods (the run ended there)."""
        self.times, self.states = self.times[:steps], self.states[:steps + 1]
        self.nominal, self.commands = self.nominal[:steps], self.commands[:steps]
        self.statuses, self.latency = self.statuses[:steps], self.latency[:steps]
        self.deadlocked, self.min_h = self.deadlocked[:steps], self.min_h[:steps]

    def _model_inputs(self):
        """Return (u_nom, u) per period, in the model's inputs, from the recorded commands.

        Velocity commands: u_nom = (v_cmd - v) / tau as the filter sees it, u from
        v_safe = v + u T with v = [v, omega] of the unicycle state; wrenches: the
        rotor thrusts M^-1 w.  Computed after the run, outside the timed loop.
        """
        steps = len(self.times)
        u_nom, u = np.zeros((steps, self.inputs)), np.zeros((steps, self.inputs))
        interface = self.reference.interface
        for k in range(steps):
            state = self.states[k]
            if interface is not None:
                u_nom[k] = interface.nominal_input(state, self.nominal[k])
                u[k] = (self.commands[k] - state[3:5]) / interface.period
            else:
                u_nom[k] = crazyflie.thrusts_from_wrench(self.nominal[k])
                u[k] = crazyflie.thrusts_from_wrench(self.commands[k])
        return u_nom, u

    def trace(self):
        """Return the recorded RobotTrace."""
        model = self.reference.model
        return RobotTrace(self.spec.name, self.spec.type, self.spec.goal,
                          (model.input_lower, model.input_upper), self.times, self.states,
                          self.nominal, self.commands, *self._model_inputs(), self.statuses,
                          self.latency, self.deadlocked, self.min_h)


def obstacle_free(scenario):
    """Return ``scenario`` without its obstacles (listed and random): the nominal reference."""
    return dataclasses.replace(scenario, obstacles=(), random_obstacles=None)


def run_in_process(scenario, barrier='polyc2bf_inflated', duration=None, seed=None,
                   progress=None, nominal='goal', until=None, parameters=None,
                   obstacle_source='markers', lidar=None, marker_pipeline=False,
                   actuation=None):
    """Run ``scenario`` (Scenario or name) in lockstep in this process; return ClosedLoopRun.

    ``progress(sim_time, duration)`` is called about once per simulated second;
    ``until(sim_time, world, metrics)`` after every period: anything true ends the run;
    ``parameters``: node parameters that override the parameter file's;
    ``obstacle_source``: 'markers' or 'scan' (by ``lidar``, default ``LidarSettings()``);
    ``marker_pipeline`` (markers only): the markers go through the node's obstacle
    pipeline (``MarkerView``: estimated velocities), not straight to the filter;
    ``actuation`` (``sim_bridge.actuation.Actuation``, default exact): command latency,
    the plants' first-order response and odometry noise.
    """
    if barrier not in FILTER_CHOICES:
        raise ValueError(f'filter must be one of {", ".join(FILTER_CHOICES)}, got {barrier!r}')
    if nominal not in NOMINALS:
        raise ValueError(f'nominal must be one of {", ".join(NOMINALS)}, got {nominal!r}')
    if obstacle_source not in OBSTACLE_SOURCES:
        raise ValueError(f'obstacle source must be one of {", ".join(OBSTACLE_SOURCES)}, '
                         f'got {obstacle_source!r}')
    scanning = obstacle_source == 'scan'
    if scanning and marker_pipeline:
        raise ValueError('marker_pipeline needs obstacle_source markers, not scan')
    lidar = (lidar or LidarSettings()).validate() if scanning else None
    actuation = (actuation or Actuation()).validate()
    if scanning:
        parameters = {**scan_parameters(lidar), **(parameters or {})}
    scenario = load_scenario(scenario) if isinstance(scenario, (str, Path)) else scenario
    if seed is not None:
        scenario = scenario.with_seed(seed)
    if duration is not None:
        scenario = dataclasses.replace(scenario, duration=float(duration))
    substeps = scenario.substeps
    period = 1.0 / control_rate(scenario)
    world = SimWorld(scenario)
    try:
        steps = int(round(scenario.duration / period))
        metrics = RunMetrics(world)
        robots = {spec.name: _Robot(spec, barrier, nominal, period, steps, world, parameters)
                  for spec in scenario.robots}
        pipes = {name: CommandPipe(actuation.latency, None) for name in robots}
        odometry = {name: Odometry(actuation.odom_noise, (actuation.seed, index),
                                   yaw_index=robot.yaw_index)
                    for index, (name, robot) in enumerate(robots.items())}
        for name in robots:
            world.set_actuator_tau(name, actuation.actuator_tau)
        applied = {}  # the command each plant holds
        if scanning:
            view = ScanView(world, robots, lidar)
        else:
            view = MarkerView(world, robots) if marker_pipeline else ObstacleView(world)
        report_every = max(1, round(1.0 / period))
        start, ended = time.perf_counter(), None
        for k in range(steps):
            commands = {}
            for name, robot in robots.items():
                # The state recorded after the last period's physics (nothing moved since),
                # as the robot's odometry reports it.
                state = odometry[name].read(robot.states[k])
                snapshot = (view.snapshot(name, state, state[robot.yaw_index], robot.times[k])
                            if robot.filter is not None else None)
                commands[name] = robot.command(k, state, snapshot)
            for name, command in commands.items():
                pipes[name].send(k * period, command)
            for substep in range(substeps):
                now = k * period + substep * world.dt
                for name, pipe in pipes.items():
                    command = pipe.at(now)
                    if command is not None and command is not applied.get(name):
                        world.set_command(name, command, robots[name].kind)
                        applied[name] = command
                world.step()
                if scanning:
                    view.sense()
            metrics.update()
            for name, robot in robots.items():
                robot.states[k + 1] = world.robot_state(name)
            if progress is not None and (k + 1) % report_every == 0:
                progress((k + 1) * period, scenario.duration)
            ended = until((k + 1) * period, world, metrics) if until is not None else None
            if ended:
                for robot in robots.values():
                    robot.truncate(k + 1)
                break
        wall = time.perf_counter() - start
        radius = next(iter(robots.values())).robot_radius
        return ClosedLoopRun(scenario=scenario, barrier=barrier, period=period,
                             robots={n: r.trace() for n, r in robots.items()},
                             metrics=metrics.to_json(), wall_time_s=wall, robot_radius=radius,
                             nominal=nominal, ended=ended or None,
                             obstacle_source=obstacle_source, lidar=lidar,
                             marker_pipeline=bool(marker_pipeline), actuation=actuation)
    finally:
        world.close()
