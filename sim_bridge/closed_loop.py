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
filtered robot, converted as the node converts its ``scan_topics`` (``_ScanView``):
no ground-truth polygon reaches the filter then.  With ``marker_pipeline`` (markers
only) the markers the bridge would publish go through the node's own obstacle pipeline
(``_MarkerView``), so the filter gets the node's velocity estimates, not the true ones.

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
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point
from rclpy.serialization import serialize_message
from visualization_msgs.msg import Marker, MarkerArray

from polyc2bf_ros import marker_obstacles
from polyc2bf_ros.core.decision import ControlDecision, ObstacleSnapshot
from polyc2bf_ros.core.models import crazyflie
from polyc2bf_ros.core.obstacles.obstacle_set import Obstacle, ObstacleSet
from polyc2bf_ros.filter_parameters import build_filter, load_parameters, NODE_PARAMETERS
from polyc2bf_ros.obstacle_pipeline import ObstacleJob, ObstaclePipeline
from sim_bridge.actuation import Actuation, CommandPipe, Odometry
from sim_bridge.launcher import (
    body_parameters,
    control_rate,
    FILTER_CHOICES,
    OBSTACLE_SOURCES,
    params_file,
    scan_parameters,
)
from sim_bridge.lidar import laser_scan, LidarSettings, RobotLidars, SCAN_TOPIC
from sim_bridge.metrics import RunMetrics
from sim_bridge.nominal import ReferencePath, UnicyclePathController
from sim_bridge.robots import ROBOT_TYPES
from sim_bridge.scenario import load_scenario
from sim_bridge.world import SimWorld

NOMINALS = ('goal', 'path')
MARKER_FRAME = 'world'       # the bridge's default frame_id
BRIDGE_LINE_WIDTH = 0.02     # m: scale.x of the bridge's outline markers (bridge_node.LINE_WIDTH)


def _cylinder_polygon(radius):
    """Return the polygon (k, 2) the node's defaults make of a robot CYLINDER marker, at 0."""
    marker = Marker(type=Marker.CYLINDER)
    marker.scale.x = marker.scale.y = 2.0 * radius
    marker.scale.z = 1.0
    marker.pose.orientation.w = 1.0
    polygons, *_ = marker_obstacles.marker_geometry(
        marker, NODE_PARAMETERS['wall_thickness'][0], NODE_PARAMETERS['cylinder_sides'][0])
    return polygons[0]


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
        self.controller, self.target = robot.goal_controller(), spec.goal
        if nominal == 'path':
            if not robot.unicycle or spec.path is None:
                raise ValueError(f'robot {spec.name!r}: the path nominal needs a unicycle '
                                 f'robot with a path, not a {spec.type} with path {spec.path}')
            self.controller, self.target = UnicyclePathController(), ReferencePath(spec.path)
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
        self.robot_radius = self.reference.safety_filter.config.robot_radius
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


@dataclasses.dataclass
class _Layout:
    """A robot's obstacle set as built at one obstacle version, and how to move it.

    ``index`` (N,): per part, its footprint's row in ``_ObstacleView._rows``;
    ``anchors`` (N, 3): that row's (x, y) of the first vertex and z_min at build time;
    ``current`` the set translated to physics step ``step`` (one object per step, so the
    filter's per-set cache holds within a step).
    """

    version: int
    base: ObstacleSet
    moves: bool
    index: np.ndarray
    anchors: np.ndarray
    step: int = -1
    current: ObstacleSet = None


class _ObstacleView:
    """Per robot, the ObstacleSet the node would hold: built once, then translated.

    Per obstacle version (pop-ups) and robot the set is built from the
    footprints (``ObstacleSet.from_obstacles``).  While something moves, each
    period translates it by each footprint's displacement since (of its first
    vertex and z_min) and gives it the current velocities, as the node's
    ``ObstacleTracker`` does for pose-only marker updates; the filter then
    moves the geometry it prepared for the built set.
    """

    def __init__(self, world):
        """Prepare the robot-marker polygons of every robot."""
        self.world = world
        self._robot_polygons = {name: _cylinder_polygon(world.robot_spec(name).radius)
                                for name in world.robot_names}
        self._layouts = {}
        self._rows_key = None
        self._rows = None

    def _now(self):
        """Return every footprint (obstacles, then all robots) and their rows, once per step.

        Row: first vertex x, y, z_min, velocity (3).
        """
        key = (self.world.obstacle_version, self.world.steps)
        if key != self._rows_key:
            footprints = self.world.obstacle_footprints()
            self._rows_key = key
            self._rows = footprints, np.array(
                [(*f.polygon[0].tolist(), f.z_min, *f.velocity.tolist()) for f in footprints],
                dtype=float).reshape(-1, 6)
        return self._rows

    def _layout(self, robot):
        """Build ``robot``'s set at the current obstacle version (every footprint but its own)."""
        footprints, rows = self._now()
        select = [i for i, f in enumerate(footprints) if not (f.robot and f.name == robot)]
        items = []
        for i in select:
            f = footprints[i]
            polygon = f.polygon
            if f.robot:
                polygon = self._robot_polygons[f.name] + np.mean(f.polygon, axis=0)
            items.append(Obstacle(polygon=polygon, velocity=np.asarray(f.velocity, dtype=float),
                                  z_min=f.z_min, z_max=f.z_max, key=f.name))
        base = ObstacleSet.from_obstacles(items)
        index = np.asarray(select, dtype=np.intp)[base.owner]
        moves = any(footprints[i].robot or np.any(footprints[i].velocity) for i in select)
        return _Layout(self.world.obstacle_version, base, moves, index, rows[index, :3])

    def snapshot(self, robot, state, yaw, now):
        """Return ``robot``'s obstacles as a snapshot received and stamped at ``now``."""
        return ObstacleSnapshot(obstacles=self.obstacles(robot), t_ref=now, received=now)

    def obstacles(self, robot):
        """Return ``robot``'s ObstacleSet at the world's current time."""
        layout = self._layouts.get(robot)
        if layout is None or layout.version != self.world.obstacle_version:
            layout = self._layouts[robot] = self._layout(robot)
        if not layout.moves:
            return layout.base
        step = self.world.steps
        if layout.step != step:
            rows = self._now()[1][layout.index]
            layout.step = step
            layout.current = layout.base.translated(rows[:, :3] - layout.anchors, rows[:, 3:])
        return layout.current


class _ScanView:
    """Per filtered robot, the obstacles the node makes of its lidar's scans.

    ``RobotLidars`` scans the world's ray scene every physics_rate / rate physics steps
    (``sense``, after each step and once at the start).  A scan is serialized as the
    bridge publishes it and, at the start of the next control period, goes with the
    pose (x, y, yaw) of that period's odometry as the only odometry sample (the node takes
    the odometry stamped nearest the scan: in lockstep, that one) to the node's own
    obstacle pipeline (``obstacle_pipeline.ObstaclePipeline``:
    ``scan_obstacles``, then the ``ObstacleSet``, prepared for the filter), which has had
    the empty marker set the bridge sends in scan mode.  The snapshot holds until the next
    scan; its obstacles have velocity 0.
    """

    def __init__(self, world, robots, settings):
        """Mount a lidar on every filtered robot and take the scans of step 0."""
        self.world = world
        self._robots = {name: robot for name, robot in robots.items() if robot.filter is not None}
        self.lidars = RobotLidars(world, settings, list(self._robots), world.scenario.seed)
        self._pipelines = {name: ObstaclePipeline() for name in self._robots}
        self._snapshots = {name: self._run(name, [(MarkerArray(), 0.0)], ())
                           for name in self._robots}
        self._pending = {}  # robot: (serialized LaserScan, sim time taken)
        self.sense()

    def _run(self, name, messages, scans):
        """Run one pass of ``name``'s pipeline; return its ObstacleSnapshot."""
        robot = self._robots[name]
        return self._pipelines[name].run(ObstacleJob(messages, 'world', robot.intake,
                                                     robot.geometry, self.world.time, scans))

    def sense(self):
        """Keep the scans due at the world's current physics step for the next period."""
        for name, scan in self.lidars.scans():
            sec, nanosec = divmod(round(self.world.time * 1e9), 1_000_000_000)
            message = laser_scan(scan, Time(sec=sec, nanosec=nanosec))
            self._pending[name] = (serialize_message(message), self.world.time)

    def snapshot(self, robot, state, yaw, now):
        """Return ``robot``'s snapshot, after converting its pending scan with pose ``state``."""
        pending = self._pending.pop(robot, None)
        if pending is not None:
            data, taken = pending
            odometry = ((taken, float(state[0]), float(state[1]), float(yaw)),)
            self._snapshots[robot] = self._run(robot, [], (
                (SCAN_TOPIC, data, taken, odometry, f'{robot}/base_link'),))
        return self._snapshots[robot]


class _MarkerView:
    """Per filtered robot, the obstacles the node makes of the bridge's obstacle markers.

    Each control period the MarkerArray the bridge would publish to the robot
    (``bridge_node``: a static prism as its LINE_STRIP outline at z_min with ``scale.z`` its
    height; a moving one as the same outline about a pose at its vertex mean; every other
    robot as a CYLINDER of its radius; frame ``world``, stamped with the period's time) runs
    through the robot's own ``obstacle_pipeline.ObstaclePipeline``, as the node's obstacle
    worker runs it: conflation, the ``ObstacleTracker`` (shapes kept while only poses
    change, the set translated, not rebuilt) and the prepared ``ObstacleSet``.  It goes as
    the message, not serialized (the pipeline's offline-replay input; the marker functions
    read a message and the node's CDR view alike): rclpy's serialization alone cost about
    1 ms per period for 20 outlines, more than the rest of the pass.
    The full set goes out at the start and whenever an obstacle pops up; in between a
    period carries the moving markers only, and a period without any runs no pass (the
    snapshot holds).  The filter thus gets the tracker's velocity estimates from successive
    marker poses (``core.obstacles.marker_tracker``: zero at first sight), never the true ones.
    Over DDS the node may still hold the previous period's markers when it answers; here a
    period's markers always serve it.
    """

    def __init__(self, world, robots):
        """Prepare a pipeline per filtered robot; the full set goes out with the first period."""
        self.world = world
        self._robots = {name: robot for name, robot in robots.items() if robot.filter is not None}
        self._pipelines = {name: ObstaclePipeline() for name in self._robots}
        self._markers = {}  # (footprint.robot, footprint.index) -> (Marker, dynamic)
        self._version = None  # the obstacle version of the last full set
        self._step = None  # the physics step the pending messages were built at
        self._pending = {}  # robot: serialized MarkerArray not yet run through its pipeline
        self._snapshots = {name: ObstacleSnapshot() for name in self._robots}

    def _marker(self, footprint):
        """Return (Marker, dynamic) of a footprint as the bridge makes it, then reused."""
        key = (footprint.robot, footprint.index)
        entry = self._markers.get(key)
        if entry is not None:
            return entry
        marker = Marker(action=Marker.ADD)
        marker.header.frame_id = MARKER_FRAME
        marker.pose.orientation.w = 1.0
        marker.scale.z = footprint.z_max - footprint.z_min
        if footprint.robot:
            diameter = 2.0 * self.world.robot_spec(footprint.name).radius
            marker.ns, marker.id, marker.type = 'robots', footprint.index, Marker.CYLINDER
            marker.scale.x = marker.scale.y = diameter
            dynamic = True
        else:
            dynamic = bool(np.any(footprint.velocity))
            centre = footprint.polygon.mean(axis=0) if dynamic else np.zeros(2)
            ring = np.vstack([footprint.polygon, footprint.polygon[:1]]) - centre
            marker.ns, marker.id, marker.type = 'obstacles', footprint.index, Marker.LINE_STRIP
            marker.points = [Point(x=x, y=y) for x, y in ring.tolist()]
            marker.scale.x = BRIDGE_LINE_WIDTH
            marker.pose.position = Point(x=float(centre[0]), y=float(centre[1]),
                                         z=float(footprint.z_min))
        entry = self._markers[key] = (marker, dynamic)
        return entry

    def _publish(self):
        """Build this step's serialized MarkerArray per filtered robot (module docstring)."""
        world = self.world
        self._step = world.steps
        full = self._version != world.obstacle_version
        self._version = world.obstacle_version
        sec, nanosec = divmod(round(world.time * 1e9), 1_000_000_000)
        stamp = Time(sec=sec, nanosec=nanosec)
        markers = []
        for footprint in world.obstacle_footprints(moving_only=not full):
            marker, dynamic = self._marker(footprint)
            if dynamic:
                position = marker.pose.position
                position.x, position.y = footprint.polygon.mean(axis=0).tolist()
                if footprint.robot:
                    position.z = 0.5 * (footprint.z_min + footprint.z_max)
            marker.header.stamp = stamp
            markers.append((footprint.name if footprint.robot else None, marker))
        self._pending = {}
        for name in self._robots:
            own = [marker for owner, marker in markers if owner != name]
            if own or full:
                self._pending[name] = MarkerArray(markers=own)

    def snapshot(self, robot, state, yaw, now):
        """Return ``robot``'s snapshot after this period's markers ran through its pipeline."""
        if self._step != self.world.steps:
            self._publish()
        data = self._pending.pop(robot, None)
        if data is not None:
            spec = self._robots[robot]
            self._snapshots[robot] = self._pipelines[robot].run(ObstacleJob(
                [(data, self.world.time)], MARKER_FRAME, spec.intake, spec.geometry,
                self.world.time))
        return self._snapshots[robot]


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
    pipeline (``_MarkerView``: estimated velocities), not straight to the filter;
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
            view = _ScanView(world, robots, lidar)
        else:
            view = _MarkerView(world, robots) if marker_pipeline else _ObstacleView(world)
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
