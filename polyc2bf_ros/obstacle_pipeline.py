"""Obstacle messages -> one ``ObstacleSnapshot``: the pure pipeline, no process, no ROS node.

Per pass (``ObstaclePipeline.run`` of one ``ObstacleJob``), steps 1-4 of
``obstacle_intake``'s docstring: markers read, conflated and tracked; scans read
(``read_scan``), placed at the odometry pose of their stamp, converted and tracked; one
``ObstacleSet`` built and its views prepared by the filter's ``ObstacleGeometry``.  The
node runs it in the worker process (``obstacle_intake``), offline replay and the
evaluation in process.
"""
import dataclasses
import math
from typing import NamedTuple

import numpy as np

from polyc2bf_ros import cdr_reader, marker_obstacles
from polyc2bf_ros.core.barrier.obstacle_geometry import ObstacleGeometry
from polyc2bf_ros.core.decision import ObstacleSnapshot
from polyc2bf_ros.core.obstacles.marker_tracker import ObstacleTracker
from polyc2bf_ros.core.obstacles.obstacle_set import ObstacleSet
from polyc2bf_ros.core.obstacles.scan_conversion import pose_at, scan_to_obstacles, ScanSettings
from polyc2bf_ros.core.obstacles.scan_memory import ScanMemory, ScanView
from polyc2bf_ros.core.obstacles.scan_tracker import (
    ScanTracker,
    TrackerSettings,
    unseen_obstacles,
    with_velocities,
)
from polyc2bf_ros.obstacle_settings import IntakeSettings
from polyc2bf_ros.static_transforms import IDENTITY, StaticTransforms


class ScanObstacles(NamedTuple):
    """One scan's obstacles: the scan's stamp [s], ``Obstacle`` list, cluster per obstacle.

    ``view``: where it looked from (``ScanView``: the sensor's pose in the odometry frame
    when the scan was taken) and over which bearings; ``settings``: its ``ScanSettings``.

    ``owner[i]`` indexes ``clusters``, the endpoints (n, 2) of each cluster in the odometry
    frame (``scan_to_obstacles(..., with_clusters=True)``).
    """

    stamp: float
    obstacles: list
    owner: np.ndarray
    clusters: list
    view: ScanView
    settings: ScanSettings


class ScanStatus(NamedTuple):
    """One scan topic: receipt times of its last accepted and last scan, rejections."""

    accepted: object = None
    received: object = None
    rejected: int = 0
    reason: str = ''


class ObstacleJob(NamedTuple):
    """One pass: messages [(data, received)], odometry frame, settings, geometry, stamp [s].

    ``data`` is a serialized MarkerArray, or a MarkerArray message (offline replay).
    ``scans``: the newest scan per topic, ``(topic, data, received, odometry samples
    ((stamp [s], x, y, yaw), ...), odometry child frame)``; ``transforms``: serialized
    ``/tf_static`` messages, oldest first.
    """

    messages: list
    frame: object
    settings: IntakeSettings
    geometry: ObstacleGeometry
    now: float
    scans: tuple = ()
    transforms: tuple = ()


class ObstaclePipeline:
    """One pass per ``ObstacleJob``, with the trackers it keeps between passes."""

    def __init__(self):
        """Start with no obstacles and no filter to prepare for."""
        self._tracker = ObstacleTracker()
        self._unreadable = ''
        self._received = None
        self._scans = {}  # topic: (stamp [s], its obstacles)
        self._scan_tracker = self._tracking = None  # made on the first tracked scan
        self._memories = {}  # topic: ScanMemory
        self._views = {}  # topic: the newest accepted scan's ScanView
        self._static = StaticTransforms()
        self.scan_status = {}  # topic: ScanStatus

    def run(self, job):
        """Process one ``ObstacleJob``; return the ``ObstacleSnapshot``."""
        markers = []
        for data, received in job.messages:
            try:
                markers += (cdr_reader.read_marker_array(data) if isinstance(data, bytes)
                            else data).markers
            except ValueError as exc:
                self._unreadable = f'malformed obstacle message: {exc}'
                continue
            self._unreadable, self._received = '', received
        settings, tracker = job.settings, self._tracker
        dim = job.geometry.dim
        for data in job.transforms:
            self._static.update(data)
        for scan in job.scans:
            self._take_scan(*scan, settings, job.geometry.own_radius)
        marker_obstacles.apply_markers(
            tracker, cdr_reader.MarkerArrayView(tuple(marker_obstacles.conflate_markers(markers))),
            job.now, settings.wall_thickness, settings.cylinder_sides,
            (settings.max_vertices, settings.max_parts))
        obstacles, t_ref, wrong_frame, error = ObstacleSet.empty(), math.nan, {}, ''
        if job.frame is not None:
            try:
                if self._scans:
                    obstacles, t_ref, wrong_frame = self._combined(job.frame, dim, settings)
                else:
                    obstacles, t_ref, wrong_frame = tracker.obstacle_set(
                        job.frame, dim, settings.max_parts, settings.max_obstacles)
                job.geometry.prepare(obstacles)
            except ValueError as exc:
                obstacles, error = ObstacleSet.empty(), f'obstacle set could not be built: {exc}'
        return ObstacleSnapshot(
            obstacles=obstacles, t_ref=t_ref, received=self._received,
            rejected=tracker.rejected, wrong_frame=wrong_frame, invalid=tracker.has_invalid,
            unreadable=self._unreadable, error=error, tracked=len(tracker),
            simplified=tracker.simplified, hulled=obstacles.capped,
            views=tuple(self._views.values()))

    def _combined(self, frame, dim, settings):
        """Return (markers and scans as one ``ObstacleSet``, t_ref, wrong_frame).

        ``t_ref`` is the newest stamp among the markers and the scans; every obstacle is
        moved along its velocity from its own stamp to it.
        """
        markers, marker_ref, wrong_frame = self._tracker.snapshot(frame, dim)
        stamps = [stamp for stamp, _ in self._scans.values()]
        t_ref = max(stamps + ([marker_ref] if markers else []))
        obstacles = [_moved(o, t_ref - marker_ref) for o in markers]
        obstacles += [_moved(o, t_ref - stamp)
                      for stamp, scan in self._scans.values() for o in scan]
        result = ObstacleSet.from_obstacles(obstacles, settings.max_parts)
        if len(result) > settings.max_obstacles:
            raise ValueError(f'{len(result)} obstacle parts exceed max_obstacles '
                             f'({settings.max_obstacles})')
        return result, t_ref, wrong_frame

    def _take_scan(self, topic, data, received, odometry, base_frame, settings, radius):
        """Convert one serialized LaserScan of ``topic``; a bad one is counted, not used."""
        status = self.scan_status.get(topic, ScanStatus())
        try:
            scan = read_scan(data, odometry, base_frame, settings, radius, self._static)
        except ValueError as exc:
            self.scan_status[topic] = status._replace(
                received=received, rejected=status.rejected + 1, reason=str(exc))
            return
        obstacles, unseen, estimates = scan.obstacles, [], None
        if settings.scan_tracking:
            # Unstamped scans and odometry: the tracker times them by their receipt.
            clock = scan.stamp if scan.stamp > 0.0 else received
            link = float(settings.scan_cluster_tolerance)
            tracking = (link, float(settings.odom_position_std),
                        float(settings.odom_heading_std))
            if tracking != self._tracking:  # clusters link at the scan's own tolerance
                self._scan_tracker = ScanTracker(TrackerSettings(
                    pose_std=tracking[1], heading_std=tracking[2]), link=link)
                self._tracking = tracking
            estimates = self._scan_tracker.update(clock, scan.clusters, scan.view)
            hidden = float(settings.scan_hidden_speed)
            obstacles = with_velocities(scan.obstacles, scan.owner, estimates,
                                        float(settings.scan_unknown_speed), hidden)
            unseen = unseen_obstacles(self._scan_tracker, f'{topic}:', hidden)
        self._scans[topic] = (scan.stamp, [
            dataclasses.replace(o, key=f'{topic}:{o.key}') for o in obstacles] + unseen
            + self._remembered(topic, scan, estimates, settings))
        self._views[topic] = scan.view
        self.scan_status[topic] = status._replace(accepted=received, received=received)


    def _remembered(self, topic, scan, estimates, settings):
        """Return the obstacles ``topic``'s laser saw before and cannot see now (``ScanMemory``).

        ``estimates``: the tracker's per cluster (None untracked); the clusters that no
        moving or untrusted track holds join the memory.
        """
        keep_time, reach = float(settings.scan_memory_time), float(settings.scan_memory_range)
        memory = self._memories.get(topic)
        if keep_time <= 0.0 or not scan.view.blind():  # a full turn sees all it keeps
            self._memories.pop(topic, None)
            return []
        if memory is None or (memory.keep_time, memory.reach) != (keep_time, reach):
            memory = self._memories[topic] = ScanMemory(keep_time, reach)
        unknown = float(settings.scan_unknown_speed)
        standing = scan.clusters if estimates is None else [
            cluster for cluster, estimate in zip(scan.clusters, estimates)
            if not (estimate.moving and estimate.confirmed)
            and (estimate.trusted or unknown == 0.0)]
        points = np.concatenate(standing) if standing else np.zeros((0, 2))
        return [dataclasses.replace(o, key=f'{topic}:memory/{index}') for index, o in
                enumerate(memory.update(scan.stamp, scan.view, points, scan.settings))]


def _moved(obstacle, dt):
    """Return ``obstacle`` moved along its velocity for ``dt`` [s] (itself when it stands)."""
    velocity = np.asarray(obstacle.velocity, dtype=float)
    if dt == 0.0 or not velocity[:2].any():
        return obstacle
    return dataclasses.replace(obstacle, polygon=obstacle.polygon + velocity[:2] * dt)


def read_scan(data, odometry, base_frame, settings, robot_radius, transforms=None):
    """Return the ``ScanObstacles`` of a serialized LaserScan; ValueError says why it is unusable.

    Endpoints within ``robot_radius`` of the base (``ObstacleGeometry.own_radius``), or
    ``scan_footprint_radius`` when that is >= 0, are the robot's own.

    ``odometry``: samples ``(stamp [s], x, y, yaw)`` of the base in the odometry frame,
    oldest first (empty: no odometry yet); the scan is taken at their pose at its
    ``header.stamp`` (``pose_at``: interpolated between the samples around it).  A scan in
    another frame than ``base_frame`` (the odometry child frame) was taken where the
    ``StaticTransforms`` ``transforms`` put that frame, else at ``settings.sensor_pose``; a
    non-finite transform on the way refuses the scan.  Every range NaN is refused (no
    measurement at all).
    """
    # Imported on the first scan: a worker without scan input does not pay for them.
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import LaserScan
    if not odometry:
        raise ValueError('no odometry yet: the robot pose at the scan is unknown')
    try:
        scan = deserialize_message(data, LaserScan)
    except Exception as exc:  # noqa: BLE001 - any decoding failure is a malformed message
        raise ValueError(f'malformed LaserScan: {exc}') from None
    stamp = scan.header.stamp.sec + 1e-9 * scan.header.stamp.nanosec
    robot_pose = pose_at(odometry, stamp)
    ranges = scan.ranges
    if len(ranges) == 0:
        raise ValueError('LaserScan without ranges')
    if len(scan.intensities) not in (0, len(ranges)):
        raise ValueError(f'LaserScan with {len(ranges)} ranges but {len(scan.intensities)} '
                         'intensities')
    ranges = np.asarray(ranges, dtype=np.float64)
    if np.isnan(ranges).all():
        raise ValueError('LaserScan whose ranges are all NaN')
    sensor_pose = _sensor_pose(scan.header.frame_id.lstrip('/'), base_frame, settings,
                               transforms)
    radius = settings.scan_footprint_radius
    scan_settings = ScanSettings(cluster_tolerance=float(settings.scan_cluster_tolerance),
                                 footprint_radius=float(robot_radius if radius < 0 else radius),
                                 depth=float(settings.scan_obstacle_depth),
                                 split_tolerance=float(settings.scan_split_tolerance))
    obstacles, owner, clusters = scan_to_obstacles(
        ranges, scan.angle_min, scan.angle_increment, scan.range_min, scan.range_max,
        sensor_pose, robot_pose, scan_settings, with_clusters=True)
    # An unstamped scan is taken at the latest odometry sample (``pose_at``): its stamp too.
    view = ScanView.of_scan(robot_pose, sensor_pose, scan.angle_min, scan.angle_increment,
                            ranges, scan.range_min, scan.range_max)
    return ScanObstacles(stamp if stamp > 0.0 else float(odometry[-1][0]), obstacles, owner,
                         clusters, view, scan_settings)


def _sensor_pose(frame, base_frame, settings, transforms):
    """Return ``(x, y, yaw)`` of a scan's ``frame`` in the base frame (``read_scan``)."""
    if frame == base_frame:
        return IDENTITY
    pose = None if transforms is None else transforms.pose(base_frame, frame)
    return tuple(settings.sensor_pose) if pose is None else pose
