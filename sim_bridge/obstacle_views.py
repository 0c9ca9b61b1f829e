"""The obstacles ``closed_loop.run_in_process`` gives a filtered robot, one view per source.

``ObstacleView``: the true footprints as the node builds them from the bridge's markers;
``ScanView``: the node's obstacles from a simulated lidar's scans; ``MarkerView``: the
bridge's markers through the node's obstacle pipeline.  Each answers
``snapshot(robot, state, yaw, now)`` with the robot's ``ObstacleSnapshot`` of the period.
"""
import dataclasses

import numpy as np
from builtin_interfaces.msg import Time
from rclpy.serialization import serialize_message
from visualization_msgs.msg import Marker, MarkerArray

from polyc2bf_ros import marker_obstacles
from polyc2bf_ros.core.decision import ObstacleSnapshot
from polyc2bf_ros.core.obstacles.obstacle_set import Obstacle, ObstacleSet
from polyc2bf_ros.filter_parameters import NODE_PARAMETERS
from polyc2bf_ros.obstacle_pipeline import ObstacleJob, ObstaclePipeline
from sim_bridge.bridge_markers import ObstacleMarkers
from sim_bridge.lidar import laser_scan, RobotLidars, SCAN_TOPIC

MARKER_FRAME = 'world'       # the bridge's default frame_id


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
class _Layout:
    """A robot's obstacle set as built at one obstacle version, and how to move it.

    ``index`` (N,): per part, its footprint's row in ``ObstacleView._rows``;
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


class ObstacleView:
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


class ScanView:
    """Per filtered robot, the obstacles the node makes of its lidar's scans.

    ``RobotLidars`` scans the world's ray scene every physics_rate / rate physics steps
    (``sense``, after each step and once at the start).  A scan is serialized as the
    bridge publishes it and, at the start of the next control period, goes with the
    odometry (x, y, yaw) of the last period and of that one (the node places it at the
    pose interpolated between them at its stamp, ``pose_at``) to the node's own
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
        self._odometry = {}  # robot: its last period's odometry sample (stamp, x, y, yaw)
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
        """Return ``robot``'s snapshot, after converting its pending scan with pose ``state``.

        The scan goes with the odometry of the last period and of this one (time ``now``), as
        the node keeps its recent odometry: it was taken between the two.
        """
        sample = (float(now), float(state[0]), float(state[1]), float(yaw))
        last, self._odometry[robot] = self._odometry.get(robot), sample
        pending = self._pending.pop(robot, None)
        if pending is not None:
            data, taken = pending
            odometry = (sample,) if last is None else (last, sample)
            self._snapshots[robot] = self._run(robot, [], (
                (SCAN_TOPIC, data, taken, odometry, f'{robot}/base_link'),))
        return self._snapshots[robot]


class MarkerView:
    """Per filtered robot, the obstacles the node makes of the bridge's obstacle markers.

    Each control period the MarkerArray the bridge would publish to the robot
    (``bridge_markers``: a static prism as its LINE_STRIP outline at z_min with ``scale.z`` its
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
        self._bridge = ObstacleMarkers(world, MARKER_FRAME)  # the bridge's own markers
        self._version = None  # the obstacle version of the last full set
        self._step = None  # the physics step the pending messages were built at
        self._pending = {}  # robot: serialized MarkerArray not yet run through its pipeline
        self._snapshots = {name: ObstacleSnapshot() for name in self._robots}

    def _publish(self):
        """Build this step's serialized MarkerArray per filtered robot (module docstring)."""
        world = self.world
        self._step = world.steps
        full = self._version != world.obstacle_version
        self._version = world.obstacle_version
        sec, nanosec = divmod(round(world.time * 1e9), 1_000_000_000)
        stamp = Time(sec=sec, nanosec=nanosec)
        markers = self._bridge.current(stamp, full)
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

