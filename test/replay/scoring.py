"""Score a filter's output against a recorded world, like Nav2's collision-monitor bag test.

Nav2 replays a small bag through the collision monitor and measures time to
stop, how long the stop holds and false stops.  Here the recorded world is the
bag's odometry and obstacle markers, and the output is what a live
``safety_filter`` answered to the bag's inputs (``bag_replay --lockstep``):

- ``braking_clearance``: from every recorded state, hold the output for one
  control period, then brake at the filter's own acceleration limits to a
  stop; the robot's footprint must keep a positive gap to every obstacle
  polygon known at that time (a command that leaves no room to stop fails);
- ``resimulate``: drive the simulator's plant from the first recorded state
  with the outputs, period by period, and measure the footprint's gap along
  the whole path (a filter that passes the nominal command through fails);
- ``appearances`` / ``first_below``: when an obstacle first shows up in the
  marker stream, and when the output speed first drops below a level.

The plant is the simulator's quadruped (``sim_bridge.world``: velocity
command tracked at up to ``QUADRUPED_MAX_ACCEL``, midpoint integration per
physics step).  The footprint is the standing A1's, not the filter's disc:
the link AABBs of the A1 in ``SimWorld`` span x -0.354..0.232 m and
y -0.153..0.153 m around the base, rounded up here.  Obstacles are read from
the markers the bridge sends (LINE_STRIP outlines relative to an unrotated
marker pose), independently of the node's conversion code.
"""
import dataclasses
import math

import numpy as np

from polyc2bf_ros.core.geometry.polygons import decompose_convex
from sim_bridge.bag_reader import BagReader
from sim_bridge.plants import (
    QUADRUPED_MAX_ACCEL,
    QUADRUPED_MAX_ANGULAR_ACCEL,
    QUADRUPED_MAX_SPEED,
    QUADRUPED_MAX_TURN_RATE,
)

FOOTPRINT = np.array([[-0.36, -0.16], [0.24, -0.16], [0.24, 0.16], [-0.36, 0.16]])
FOOTPRINT_REACH = float(np.linalg.norm(FOOTPRINT, axis=1).max())
EXACT_WITHIN = 0.5  # m: gaps up to this are computed exactly, larger ones bounded below
DELETE, DELETEALL = 2, 3  # visualization_msgs/Marker actions


def _ns(stamp):
    return stamp.sec * 1_000_000_000 + stamp.nanosec


@dataclasses.dataclass
class Recording:
    """One robot's recorded inputs and outputs, keyed by header stamp [ns]."""

    odometry: dict      # stamp -> [x, y, yaw, v, omega]
    nominal: dict       # stamp -> [v, omega]
    safe: dict          # stamp -> [v, omega]
    snapshots: list     # [(log ns, {ns/id: [convex parts (k, 2)]})] after each marker message

    @property
    def stamps(self):
        """Return the sorted stamps that have odometry, nominal and recorded safe command."""
        return sorted(set(self.odometry) & set(self.nominal) & set(self.safe))

    def obstacles_at(self, t_ns):
        """Return ``{key: parts}`` as known at log time ``t_ns`` (empty before any marker)."""
        known = {}
        for log_ns, obstacles in self.snapshots:
            if log_ns > t_ns:
                break
            known = obstacles
        return known

    def appearances(self):
        """Return ``{key: first log time [ns]}`` of every obstacle in the marker stream."""
        first = {}
        for log_ns, obstacles in self.snapshots:
            for key in obstacles:
                first.setdefault(key, log_ns)
        return first


def read_recording(bag, robot):
    """Read ``/robot/{odom, obstacles, cmd_vel_in, cmd_vel_out}`` of a bag."""
    topics = [f'/{robot}/{name}' for name in ('odom', 'obstacles', 'cmd_vel_in', 'cmd_vel_out')]
    rec = Recording({}, {}, {}, [])
    current = {}
    for topic, _, log_ns, msg in BagReader(bag).messages(topics):
        if topic == topics[0]:
            pose, twist = msg.pose.pose, msg.twist.twist
            yaw = 2.0 * math.atan2(pose.orientation.z, pose.orientation.w)
            rec.odometry[_ns(msg.header.stamp)] = np.array(
                [pose.position.x, pose.position.y, yaw, twist.linear.x, twist.angular.z])
        elif topic == topics[1]:
            current = dict(current)
            for marker in msg.markers:
                key = f'{marker.ns}/{marker.id}'
                if marker.action == DELETEALL:
                    current = {}
                elif marker.action == DELETE:
                    current.pop(key, None)
                else:
                    q = marker.pose.orientation
                    assert (q.x, q.y, q.z) == (0.0, 0.0, 0.0), 'rotated marker'
                    ring = np.array([(p.x, p.y) for p in marker.points])
                    ring = ring[:-1] if np.allclose(ring[0], ring[-1]) else ring
                    offset = (marker.pose.position.x, marker.pose.position.y)
                    current[key] = decompose_convex(ring + offset)
            rec.snapshots.append((log_ns, current))
        else:
            table = rec.nominal if topic == topics[2] else rec.safe
            table[_ns(msg.header.stamp)] = np.array([msg.twist.linear.x, msg.twist.angular.z])
    return rec


def footprints(poses):
    """Return the footprint corners (N, 4, 2) at ``poses`` (N, 3) = [x, y, yaw]."""
    poses = np.asarray(poses, dtype=float).reshape(-1, 3)
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    x = FOOTPRINT[:, 0] * c[:, None] - FOOTPRINT[:, 1] * s[:, None]
    y = FOOTPRINT[:, 0] * s[:, None] + FOOTPRINT[:, 1] * c[:, None]
    return np.stack([x + poses[:, :1], y + poses[:, 1:2]], axis=-1)


def _point_polygon_distance(points, polygon):
    """Return the distance (..., ) from ``points`` (..., 2) to the boundary of ``polygon``."""
    a = polygon
    b = np.roll(polygon, -1, axis=0)
    edge = b - a
    rel = points[..., None, :] - a
    t = np.clip(np.sum(rel * edge, axis=-1) / np.sum(edge * edge, axis=-1), 0.0, 1.0)
    return np.min(np.linalg.norm(rel - t[..., None] * edge, axis=-1), axis=-1)


def _overlap(shapes, polygon):
    """Return (N,) whether each convex quadrilateral of ``shapes`` meets convex ``polygon``.

    Separating-axis test over the edge normals of both shapes.
    """
    overlap = np.ones(len(shapes), dtype=bool)
    normals = [np.roll(polygon, -1, axis=0) - polygon]
    normals.append(np.roll(shapes, -1, axis=1) - shapes)
    for edges in normals:
        axes = np.stack([-edges[..., 1], edges[..., 0]], axis=-1)
        if axes.ndim == 2:
            axes = np.broadcast_to(axes, (len(shapes), *axes.shape))
        proj_shape = np.einsum('nvd,nkd->nkv', shapes, axes)
        proj_polygon = np.einsum('vd,nkd->nkv', polygon, axes)
        apart = ((proj_shape.max(-1) < proj_polygon.min(-1))
                 | (proj_polygon.max(-1) < proj_shape.min(-1)))
        overlap &= ~apart.any(axis=-1)
    return overlap


def gaps(poses, obstacles):
    """Return the footprint's gap [m] (N,) to the obstacle parts at ``poses``; 0 if touching.

    ``obstacles`` is ``{key: [convex parts]}``; no obstacles give +inf.  Gaps
    up to ``EXACT_WITHIN`` are exact; a pose whose base is farther from a part
    than that plus the footprint's reach gets the lower bound
    ``distance(base, part) - reach`` for it instead (cheap, and > EXACT_WITHIN).
    """
    poses = np.asarray(poses, dtype=float).reshape(-1, 3)
    gap = np.full(len(poses), np.inf)
    for parts in obstacles.values():
        for part in parts:
            bound = _signed_distance(poses[:, :2], part) - FOOTPRINT_REACH
            near = bound <= EXACT_WITHIN
            if np.any(near):
                shapes = footprints(poses[near])
                apart = np.minimum(_point_polygon_distance(shapes, part).min(axis=-1),
                                   _polygon_to_shapes(part, shapes))
                bound[near] = np.where(_overlap(shapes, part), 0.0, apart)
            gap = np.minimum(gap, bound)
    return gap


def _signed_distance(points, polygon):
    """Return the distance (N,) of ``points`` to convex ``polygon``, negative inside."""
    edge = np.roll(polygon, -1, axis=0) - polygon
    cross = edge[:, 0] * (points[:, None, 1] - polygon[:, 1]) - edge[:, 1] * (
        points[:, None, 0] - polygon[:, 0])
    inside = np.all(cross >= 0.0, axis=1) | np.all(cross <= 0.0, axis=1)
    distance = _point_polygon_distance(points, polygon)
    return np.where(inside, -distance, distance)


def _polygon_to_shapes(polygon, shapes):
    """Return (N,) the distance from the vertices of ``polygon`` to each shape's boundary."""
    a = shapes
    edge = np.roll(shapes, -1, axis=1) - a                        # (N, 4, 2)
    rel = polygon[None, :, None, :] - a[:, None, :, :]            # (N, k, 4, 2)
    t = np.clip(np.sum(rel * edge[:, None], axis=-1)
                / np.sum(edge * edge, axis=-1)[:, None], 0.0, 1.0)
    return np.linalg.norm(rel - t[..., None] * edge[:, None], axis=-1).min(axis=(1, 2))


def plant_step(state, command, dt, accel=QUADRUPED_MAX_ACCEL,
               angular_accel=QUADRUPED_MAX_ANGULAR_ACCEL):
    """Advance states (N, 5) = [x, y, yaw, v, omega] by ``dt`` toward ``command`` (N, 2).

    The simulator's velocity-command plant: the rates move toward the command
    at most ``accel`` / ``angular_accel``, speed and turn rate are capped, and
    the pose is integrated with the midpoint rates.
    """
    x, y, yaw, v, w = np.moveaxis(np.asarray(state, dtype=float), -1, 0)
    v_new = np.clip(v + np.clip(command[..., 0] - v, -accel * dt, accel * dt),
                    -QUADRUPED_MAX_SPEED, QUADRUPED_MAX_SPEED)
    w_new = np.clip(w + np.clip(command[..., 1] - w, -angular_accel * dt, angular_accel * dt),
                    -QUADRUPED_MAX_TURN_RATE, QUADRUPED_MAX_TURN_RATE)
    speed, turn = 0.5 * (v + v_new), 0.5 * (w + w_new)
    heading = yaw + 0.5 * turn * dt
    return np.stack([x + speed * np.cos(heading) * dt, y + speed * np.sin(heading) * dt,
                     yaw + turn * dt, v_new, w_new], axis=-1)


def braking_clearance(rec, outputs, period, dt, brake_accel, brake_angular_accel):
    """Return ``{stamp: smallest gap}`` over hold-one-period-then-brake from each state.

    ``outputs`` is ``{stamp: [v, omega]}``; the brake commands zero rates at
    ``brake_accel`` / ``brake_angular_accel`` (the filter's limits) until the
    robot stands still.
    """
    stamps = [s for s in rec.stamps if s in outputs]
    state = np.array([rec.odometry[s] for s in stamps])
    command = np.array([outputs[s] for s in stamps])
    poses = [state[:, :3]]
    for _ in range(round(period / dt)):
        state = plant_step(state, command, dt)
        poses.append(state[:, :3])
    stop = np.zeros_like(command)
    while np.any(np.abs(state[:, 3:]) > 1e-9):
        state = plant_step(state, stop, dt, brake_accel, brake_angular_accel)
        poses.append(state[:, :3])
    return dict(zip(stamps, _gaps_per_stamp(rec, stamps, np.stack(poses, axis=1))))


def _gaps_per_stamp(rec, stamps, poses):
    """Return the smallest gap of each stamp's poses (stamps, steps, 3) to its obstacles."""
    result = np.full(len(stamps), np.inf)
    groups = {}
    for i, stamp in enumerate(stamps):
        groups.setdefault(id(rec.obstacles_at(stamp)), []).append(i)
    for rows in groups.values():
        obstacles = rec.obstacles_at(stamps[rows[0]])
        if obstacles:
            flat = poses[rows].reshape(-1, 3)
            result[rows] = gaps(flat, obstacles).reshape(len(rows), -1).min(axis=1)
    return result.tolist()


def resimulate(rec, outputs, period, dt):
    """Drive the plant from the first recorded state with ``outputs``; return (stamps, gaps).

    Each output is held for one period from its stamp; the gap at each physics
    step is taken to the obstacles known at that time.  Also returns the
    re-simulated states at the stamps (for comparison with the odometry).
    """
    stamps = [s for s in rec.stamps if s in outputs]
    state = rec.odometry[stamps[0]].copy()
    substeps = round(period / dt)
    states, poses = [], []
    for stamp in stamps:
        states.append(state)
        path = [state[:3]]
        for _ in range(substeps):
            state = plant_step(state, np.asarray(outputs[stamp]), dt)
            path.append(state[:3])
        poses.append(path)
    gap = _gaps_per_stamp(rec, stamps, np.array(poses))
    return stamps, np.array(gap), np.array(states)


def first_below(outputs, stamps, level):
    """Return the first stamp whose output speed |v| <= ``level`` (None if never)."""
    for stamp in stamps:
        if abs(outputs[stamp][0]) <= level:
            return stamp
    return None
