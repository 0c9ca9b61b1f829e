"""ROS messages <-> numpy for the safety filter node.

Odometry -> model state.  ``nav_msgs/Odometry`` gives the pose in
``header.frame_id`` (the world/odometry frame) and the twist in
``child_frame_id`` (the body frame).  With ``R`` the body-to-world rotation of
the pose quaternion and ``(roll, pitch, yaw)`` its ZYX Euler angles
(``R = Rz(yaw) Ry(pitch) Rx(roll)``)::

    unicycle       [x, y, yaw, v, omega]        v = twist.linear.x, omega = twist.angular.z
    point_mass_2d  [x, y, vx, vy]               [vx, vy, .] = R twist.linear
    point_mass_3d  [x, y, z, vx, vy, vz]        [vx, vy, vz] = R twist.linear
    quadrotor      [x, y, z, R twist.linear, roll, pitch, yaw, twist.angular]

A non-unit quaternion is normalised; an all-zero one is read as identity (as
RViz does).  Non-finite values are passed through so the caller can refuse them.

Markers -> obstacles (``apply_markers``).  Each marker becomes one or more
polygons in its header frame plus a z range, after applying the marker pose
``(p, R)``: a local point ``q`` lands at ``p + R (s * q)``:

- ``LINE_STRIP``: the points outline one polygon (closing point optional).
- ``LINE_LIST``: every point pair is a wall segment.
- ``TRIANGLE_LIST``: every triple is a triangle; ``s`` = marker scale.
- ``CUBE``: the box ``scale`` centred on the pose; ``CYLINDER`` / ``SPHERE``: the
  ``cylinder_sides``-gon circumscribing the ellipse of diameters
  ``scale.x, scale.y`` (vertex radius ``r / cos(pi / n)``), height ``scale.z``.
  Tilted solids are replaced by the convex hull of their corners' footprint.
- ``TEXT_VIEW_FACING`` markers are labels and are skipped; other types are
  rejected.

Degenerate outlines (one point, a segment, collinear points) become thin
rectangles of width ``scale.x`` (the line width) or ``wall_thickness`` when the
marker has none; see ``outline_polygon``.  The z range is the points' z extent;
a flat LINE_STRIP / LINE_LIST outline with ``scale.z > 0`` is a prism from the
points' z up by ``scale.z`` (how ``sim_bridge`` publishes obstacles; RViz ignores
scale.z on lines), and otherwise an infinite extrusion (a wall).  The velocity reference
position is the pose, or the points' centroid when the pose is the identity.
"""
import math

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import Point, Vector3
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from polyc2bf_ros.core import crazyflie
from polyc2bf_ros.core.geometry import convex_hull
from polyc2bf_ros.core.obstacle_tracker import outline_polygon, POINT_TOLERANCE

MARKER_TYPE_NAMES = {getattr(Marker, n): n for n in (
    'ARROW', 'CUBE', 'SPHERE', 'CYLINDER', 'LINE_STRIP', 'LINE_LIST', 'CUBE_LIST',
    'SPHERE_LIST', 'POINTS', 'TEXT_VIEW_FACING', 'MESH_RESOURCE', 'TRIANGLE_LIST',
    'ARROW_STRIP')}


class NonFiniteError(ValueError):
    """A message field holds NaN or Inf."""


def stamp_seconds(stamp):
    """``builtin_interfaces/Time`` -> float seconds."""
    return stamp.sec + 1e-9 * stamp.nanosec


def quaternion_matrix(q):
    """Rotation matrix (3, 3) of Quaternion ``q``, normalised; all-zero reads as identity."""
    x, y, z, w = q.x, q.y, q.z, q.w
    norm_sq = x * x + y * y + z * z + w * w
    if norm_sq == 0.0:
        return np.eye(3)
    s = 2.0 / norm_sq
    return np.array([
        [1.0 - s * (y * y + z * z), s * (x * y - z * w), s * (x * z + y * w)],
        [s * (x * y + z * w), 1.0 - s * (x * x + z * z), s * (y * z - x * w)],
        [s * (x * z - y * w), s * (y * z + x * w), 1.0 - s * (x * x + y * y)],
    ])


def _unicycle_state(pose, twist, rot):
    return (pose.position.x, pose.position.y, math.atan2(rot[1, 0], rot[0, 0]),
            twist.linear.x, twist.angular.z)


def _world_velocity(twist, rot):
    v = twist.linear
    return rot @ (v.x, v.y, v.z)


def _point_mass_2d_state(pose, twist, rot):
    vx, vy, _ = _world_velocity(twist, rot)
    return pose.position.x, pose.position.y, vx, vy


def _point_mass_3d_state(pose, twist, rot):
    p = pose.position
    return (p.x, p.y, p.z, *_world_velocity(twist, rot))


def _quadrotor_state(pose, twist, rot):
    p, w = pose.position, twist.angular
    roll = math.atan2(rot[2, 1], rot[2, 2])
    pitch = math.asin(max(-1.0, min(1.0, -rot[2, 0])))
    yaw = math.atan2(rot[1, 0], rot[0, 0])
    return (p.x, p.y, p.z, *_world_velocity(twist, rot), roll, pitch, yaw, w.x, w.y, w.z)


_STATE_FROM_ODOMETRY = {
    'unicycle': _unicycle_state,
    'point_mass_2d': _point_mass_2d_state,
    'point_mass_3d': _point_mass_3d_state,
    'quadrotor': _quadrotor_state,
}


def odometry_to_state(msg, model_name, out):
    """Fill ``out`` with the state of ``model_name`` from ``nav_msgs/Odometry``; return the yaw.

    The yaw (of the body x axis in the odometry frame) rotates body-frame
    velocity commands into the odometry frame.
    """
    pose, twist = msg.pose.pose, msg.twist.twist
    rot = quaternion_matrix(pose.orientation)
    out[:] = _STATE_FROM_ODOMETRY[model_name](pose, twist, rot)
    return math.atan2(rot[1, 0], rot[0, 0])


def twist_values(twist):
    """All six numbers of a ``geometry_msgs/Twist`` (for finiteness checks)."""
    lin, ang = twist.linear, twist.angular
    return lin.x, lin.y, lin.z, ang.x, ang.y, ang.z


def twist_to_command(twist, model_name):
    """Velocity command vector of ``model_name`` (see ``core.command_interface``)."""
    if model_name == 'unicycle':
        return twist.linear.x, twist.angular.z
    if model_name == 'point_mass_2d':
        return twist.linear.x, twist.linear.y
    return twist.linear.x, twist.linear.y, twist.linear.z


def fill_twist(out, model_name, command, yaw_rate):
    """Write ``command`` into Twist ``out``; point masses get ``yaw_rate`` on angular.z.

    The point-mass models have no heading, so the nominal yaw rate passes
    through unchanged (a holonomic base turning in place does not move its
    centre).  Every other field is zero.
    """
    out.linear.x = float(command[0])
    if model_name == 'unicycle':
        out.linear.y = out.linear.z = 0.0
        out.angular.z = float(command[1])
    else:
        out.linear.y = float(command[1])
        out.linear.z = float(command[2]) if len(command) > 2 else 0.0
        out.angular.z = float(yaw_rate)
    out.angular.x = out.angular.y = 0.0


def zero_twist(out):
    """Set every field of Twist ``out`` to zero (the stop command)."""
    fill_twist(out, 'unicycle', (0.0, 0.0), 0.0)


def wrench_values(wrench):
    """All six numbers of a ``geometry_msgs/Wrench``."""
    f, t = wrench.force, wrench.torque
    return f.x, f.y, f.z, t.x, t.y, t.z


def wrench_to_thrusts(wrench):
    """Rotor thrusts (4,) from collective thrust ``force.z`` and body ``torque``: f = M^-1 w."""
    t = wrench.torque
    return crazyflie.thrusts_from_wrench((wrench.force.z, t.x, t.y, t.z))


def fill_wrench(out, thrusts):
    """Write the wrench ``[T, tau] = M f`` of rotor thrusts ``f`` into Wrench ``out``."""
    thrust, tx, ty, tz = (float(v) for v in crazyflie.wrench_from_thrusts(thrusts))
    out.force.x = out.force.y = 0.0
    out.force.z = thrust
    out.torque.x, out.torque.y, out.torque.z = tx, ty, tz


def _points(points):
    return np.array([(p.x, p.y, p.z) for p in points], dtype=float).reshape(-1, 3)


def _solid_corners(marker, sides):
    """Local corners (k, 3) of a CUBE or of the prism circumscribing a CYLINDER/SPHERE."""
    sx, sy, sz = marker.scale.x, marker.scale.y, marker.scale.z
    if marker.type == Marker.CUBE:
        xy = 0.5 * np.array([[-sx, -sy], [sx, -sy], [sx, sy], [-sx, sy]])
    else:
        angles = 2.0 * np.pi * (np.arange(sides) + 0.5) / sides
        radius = 0.5 / math.cos(math.pi / sides)
        xy = radius * np.column_stack([sx * np.cos(angles), sy * np.sin(angles)])
    return np.vstack([np.column_stack([xy, np.full(len(xy), z)]) for z in (-0.5 * sz, 0.5 * sz)])


def _is_identity(pose):
    p, q = pose.position, pose.orientation
    return p.x == p.y == p.z == 0.0 and q.x == q.y == q.z == 0.0 and q.w in (0.0, 1.0)


def marker_geometry(marker, wall_thickness, cylinder_sides):
    """``(polygons, z_min, z_max, position (3,))`` of one marker; ``ValueError`` with a reason."""
    pose, scale = marker.pose, marker.scale
    numbers = (pose.position.x, pose.position.y, pose.position.z, pose.orientation.x,
               pose.orientation.y, pose.orientation.z, pose.orientation.w,
               scale.x, scale.y, scale.z)
    rot = quaternion_matrix(pose.orientation)
    origin = np.array(numbers[:3])
    kind = marker.type
    if kind in (Marker.CUBE, Marker.CYLINDER, Marker.SPHERE):
        if not np.isfinite(numbers).all():
            raise NonFiniteError('non-finite pose or scale')
        if not (scale.x > 0.0 and scale.y > 0.0 and scale.z >= 0.0):
            raise ValueError(f'{MARKER_TYPE_NAMES[kind]} needs scale x, y > 0 and z >= 0')
        world = origin + _solid_corners(marker, cylinder_sides) @ rot.T
        polygons = [outline_polygon(convex_hull(world[:, :2]), wall_thickness)]
        return polygons, world[:, 2].min(), world[:, 2].max(), origin
    local = _points(marker.points)
    if not (np.isfinite(numbers).all() and np.isfinite(local).all()):
        raise NonFiniteError('non-finite pose, scale or points')
    thickness = scale.x if scale.x > 0.0 else wall_thickness
    if kind == Marker.TRIANGLE_LIST:
        local = local * (scale.x, scale.y, scale.z)
    world = origin + local @ rot.T
    if kind == Marker.LINE_STRIP:
        groups = [world]
    elif kind in (Marker.LINE_LIST, Marker.TRIANGLE_LIST):
        size = 2 if kind == Marker.LINE_LIST else 3
        if len(world) == 0 or len(world) % size:
            raise ValueError(f'{MARKER_TYPE_NAMES[kind]} needs a positive multiple of '
                             f'{size} points, got {len(world)}')
        groups = np.split(world, len(world) // size)
    else:
        raise ValueError(f'unsupported marker type {MARKER_TYPE_NAMES.get(kind, kind)}')
    if len(world) == 0:
        raise ValueError('no points')
    polygons = [outline_polygon(g[:, :2], thickness) for g in groups]
    z_min, z_max = world[:, 2].min(), world[:, 2].max()
    if z_max - z_min < POINT_TOLERANCE:
        # A flat outline is a prism of height scale.z above it, or an infinite extrusion.
        z_max = z_min + scale.z if kind != Marker.TRIANGLE_LIST and scale.z > 0.0 else math.inf
        z_min = z_min if math.isfinite(z_max) else -math.inf
    position = origin if not _is_identity(pose) else world.mean(axis=0)
    return polygons, z_min, z_max, position


def apply_markers(tracker, msg, now_stamp, wall_thickness, cylinder_sides):
    """Apply a ``visualization_msgs/MarkerArray`` to an ``ObstacleTracker``, marker by marker.

    Markers stamped zero use ``now_stamp`` [s].  A marker that cannot be used is
    rejected with its reason (non-finite numbers mark the tracker invalid);
    markers without a frame are rejected too.
    """
    for marker in msg.markers:
        key = f'{marker.ns}/{marker.id}'
        if marker.action == Marker.DELETEALL:
            tracker.delete_all()
            continue
        if marker.action == Marker.DELETE:
            tracker.delete(key)
            continue
        if marker.type == Marker.TEXT_VIEW_FACING:
            continue
        frame = marker.header.frame_id.lstrip('/')
        stamp = stamp_seconds(marker.header.stamp) or now_stamp
        try:
            if not frame:
                raise ValueError('empty header.frame_id')
            polygons, z_min, z_max, position = marker_geometry(
                marker, wall_thickness, cylinder_sides)
        except ValueError as exc:
            tracker.reject(key, str(exc), invalid=isinstance(exc, NonFiniteError))
            continue
        tracker.update(key, frame, stamp, position, polygons, z_min, z_max)


def _color(r, g, b, a):
    return ColorRGBA(r=r, g=g, b=b, a=a)


_INACTIVE, _ACTIVE = _color(0.1, 0.8, 0.2, 0.8), _color(0.9, 0.1, 0.1, 1.0)


def filter_markers(frame, stamp, footprints, active, apex=None, cones=None):
    """``MarkerArray`` for RViz/Foxglove: obstacle parts (red = active constraint) and cones.

    ``footprints`` is the filter's ``PolygonBatch`` (at the obstacles' stamp),
    ``active`` the indices of the active rows.  Cones are drawn when
    ``cones`` (axis ``p`` and boundary ray ``k`` as (2, N) planar vectors) and the
    ``apex`` are given: the rays ``k`` and its mirror ``2 <k, p_hat> p_hat - k``.
    The first marker is a DELETEALL, so parts that disappeared vanish.
    """
    is_active = np.zeros(len(footprints), dtype=bool)
    is_active[np.asarray(active, dtype=int)] = True
    markers = [Marker(action=Marker.DELETEALL)]
    for i in range(len(footprints)):
        ring = footprints.vertices[i, :footprints.counts[i]]
        markers.append(Marker(
            ns='obstacles', id=i, type=Marker.LINE_STRIP, action=Marker.ADD,
            scale=Vector3(x=0.03), color=_ACTIVE if is_active[i] else _INACTIVE,
            points=[Point(x=float(x), y=float(y)) for x, y in np.vstack([ring, ring[:1]])]))
    if cones is not None and apex is not None and cones.k.shape[1] == len(footprints):
        axis, ray = cones.p.T, cones.k.T
        p_hat = axis / np.maximum(np.linalg.norm(axis, axis=1, keepdims=True), 1e-12)
        mirror = 2.0 * np.sum(ray * p_hat, axis=1, keepdims=True) * p_hat - ray
        apex_point = Point(x=float(apex[0]), y=float(apex[1]))
        for i, (k, m) in enumerate(zip(ray, mirror)):
            markers.append(Marker(
                ns='cones', id=i, type=Marker.LINE_LIST, action=Marker.ADD,
                scale=Vector3(x=0.01), color=_ACTIVE if is_active[i] else _INACTIVE,
                points=[apex_point, Point(x=float(apex[0] + k[0]), y=float(apex[1] + k[1])),
                        apex_point, Point(x=float(apex[0] + m[0]), y=float(apex[1] + m[1]))]))
    for marker in markers[1:]:
        marker.header.frame_id = frame
        marker.header.stamp = stamp
        marker.pose.orientation.w = 1.0
    return MarkerArray(markers=markers)


def diagnostic_array(stamp, name, hardware_id, level, message, values):
    """``DiagnosticArray`` with one status; ``values`` is ``{key: value}`` (str() each)."""
    status = DiagnosticStatus(
        level=level, name=name, message=message, hardware_id=hardware_id,
        values=[KeyValue(key=str(k), value=str(v)) for k, v in values.items()])
    array = DiagnosticArray(status=[status])
    array.header.stamp = stamp
    return array
