"""ROS messages <-> numpy for the safety filter node: odometry, commands, obstacle markers.

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
RViz does).  Non-finite input is refused (``None`` / NaN), never normalised away.

Commands.  ``core.command_filter`` works on command vectors; a Twist or Wrench
carries them in its six numbers ``(linear|force xyz, angular|torque xyz)``::

    unicycle       [v, omega]       = linear.x, angular.z
    point_mass_2d  [vx, vy]         = linear.x, linear.y        (angular.z passed through)
    point_mass_3d  [vx, vy, vz]     = linear.x, .y, .z          (angular.z passed through)
    quadrotor      [T, tx, ty, tz]  = force.z, torque.x, .y, .z

On the node's hot path odometry and commands stay serialized (CDR): see
``read_odometry`` and ``SerializedCommand`` below.  Obstacle MarkerArrays do too
(``cdr_reader.read_marker_array``): the marker functions take a typed ``Marker``
or a ``cdr_reader.MarkerView`` alike.

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

The pose is split (``marker_placement``): a rotation about z only (``q.x = q.y
= 0``) becomes the ``Placement`` (yaw, then ``p``) of a ``Shape`` computed in the
marker's own frame (``marker_shape``), which the pose moves rigidly; any other
rotation is applied to the points inside the shape.  ``apply_markers`` reuses
the key's last ``Shape`` while its ``_source`` (type, scale, points, tilt, the
two settings) is unchanged, so a marker that only moved costs no outline
cleaning or hull.
"""
import math
import struct
from typing import NamedTuple

import numpy as np
from visualization_msgs.msg import Marker

from polyc2bf_ros.cdr_reader import aligned, layout_of, read_header, read_string
from polyc2bf_ros.core.geometry import convex_hull
from polyc2bf_ros.core.obstacle_tracker import (
    outline_polygon,
    Placement,
    POINT_TOLERANCE,
    Shape,
)
from polyc2bf_ros.core.polygon_limits import MAX_PARTS, MAX_VERTICES

# (max_vertices, max_parts) of marker outlines (``marker_shape``).
OUTLINE_LIMITS = (MAX_VERTICES, MAX_PARTS)

MARKER_TYPE_NAMES = {getattr(Marker, n): n for n in (
    'ARROW', 'CUBE', 'SPHERE', 'CYLINDER', 'LINE_STRIP', 'LINE_LIST', 'CUBE_LIST',
    'SPHERE_LIST', 'POINTS', 'TEXT_VIEW_FACING', 'MESH_RESOURCE', 'TRIANGLE_LIST',
    'ARROW_STRIP')}


class NonFiniteError(ValueError):
    """A message field holds NaN or Inf."""


def stamp_seconds(stamp):
    """``builtin_interfaces/Time`` -> float seconds."""
    return stamp.sec + 1e-9 * stamp.nanosec


# -- odometry -> state ------------------------------------------------------------------------

def rotation(qx, qy, qz, qw):
    """Row-major rotation matrix ``(r00, r01, ..., r22)`` of a quaternion, normalised.

    An all-zero quaternion reads as identity.  Plain floats: this runs per
    odometry message, where numpy's per-call overhead would dominate.
    """
    norm_sq = qx * qx + qy * qy + qz * qz + qw * qw
    if norm_sq == 0.0:
        return 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0
    s = 2.0 / norm_sq
    return (1.0 - s * (qy * qy + qz * qz), s * (qx * qy - qz * qw), s * (qx * qz + qy * qw),
            s * (qx * qy + qz * qw), 1.0 - s * (qx * qx + qz * qz), s * (qy * qz - qx * qw),
            s * (qx * qz - qy * qw), s * (qy * qz + qx * qw), 1.0 - s * (qx * qx + qy * qy))


def state_from_odometry(model_name, pose, twist):
    """``(state tuple, yaw)`` of ``model_name`` from Odometry numbers; ``None`` if non-finite.

    ``pose`` = (x, y, z, qx, qy, qz, qw) in the odometry frame, ``twist`` =
    (vx, vy, vz, wx, wy, wz) in the body frame (the layout of the messages).
    The yaw (of the body x axis in the odometry frame) rotates body-frame
    velocity commands into the odometry frame.  Every input number is checked,
    so a non-finite quaternion cannot hide behind the normalisation.
    """
    if not all(map(math.isfinite, pose)) or not all(map(math.isfinite, twist)):
        return None
    x, y, z, qx, qy, qz, qw = pose
    vx, vy, vz, wx, wy, wz = twist
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = rotation(qx, qy, qz, qw)
    yaw = math.atan2(r10, r00)
    if model_name == 'unicycle':
        return (x, y, yaw, vx, wz), yaw
    world_vx = r00 * vx + r01 * vy + r02 * vz
    world_vy = r10 * vx + r11 * vy + r12 * vz
    if model_name == 'point_mass_2d':
        return (x, y, world_vx, world_vy), yaw
    world_vz = r20 * vx + r21 * vy + r22 * vz
    if model_name == 'point_mass_3d':
        return (x, y, z, world_vx, world_vy, world_vz), yaw
    roll = math.atan2(r21, r22)
    pitch = math.asin(max(-1.0, min(1.0, -r20)))
    return (x, y, z, world_vx, world_vy, world_vz, roll, pitch, yaw, wx, wy, wz), yaw


def _vector(v):
    return v.x, v.y, v.z


def odometry_to_state(msg, model_name, out):
    """Fill ``out`` with the state of ``model_name`` from ``nav_msgs/Odometry``; return the yaw.

    Non-finite input fills ``out`` with NaN and returns NaN, for the caller to refuse.
    """
    pose, twist = msg.pose.pose, msg.twist.twist
    q = pose.orientation
    result = state_from_odometry(model_name, (*_vector(pose.position), q.x, q.y, q.z, q.w),
                                 (*_vector(twist.linear), *_vector(twist.angular)))
    if result is None:
        out[:] = math.nan
        return math.nan
    out[:] = result[0]
    return result[1]


# -- commands: the six numbers of a Twist or Wrench <-> the CommandFilter's vector -----------

# Positions in (linear|force x, y, z, angular|torque x, y, z) of the command vector of each
# model (core.command_filter), and of the numbers passed through from the nominal command:
# point masses have no heading, so their nominal yaw rate passes unchanged (a holonomic base
# turning in place does not move its centre).  Every other number of a safe command is 0.
COMMAND_FIELDS = {
    'unicycle': (0, 5),
    'point_mass_2d': (0, 1),
    'point_mass_3d': (0, 1, 2),
    'quadrotor': (2, 3, 4, 5),
}
KEPT_FIELDS = {'point_mass_2d': (5,), 'point_mass_3d': (5,)}


def command_from_values(values, model_name):
    """Pick the command vector of ``model_name`` out of the six numbers of a Twist or Wrench."""
    return tuple(values[i] for i in COMMAND_FIELDS[model_name])


def six_values(msg):
    """Return the six numbers of a Twist / TwistStamped or Wrench / WrenchStamped message."""
    body = getattr(msg, 'twist', None) or getattr(msg, 'wrench', None) or msg
    first, second = ((body.linear, body.angular) if hasattr(body, 'linear')
                     else (body.force, body.torque))
    return first.x, first.y, first.z, second.x, second.y, second.z


def twist_to_command(msg, model_name):
    """Command vector of ``model_name`` from a (stamped) Twist, or Wrench for the quadrotor."""
    return command_from_values(six_values(msg), model_name)


def values_from_command(command, model_name, nominal=None):
    """Six numbers of the Twist/Wrench carrying ``command``; kept ones copied from ``nominal``."""
    values = [0.0] * 6
    if nominal is not None:
        for i in KEPT_FIELDS.get(model_name, ()):
            values[i] = nominal[i]
    if isinstance(command, np.ndarray):
        command = command.tolist()  # floats at once, not one numpy scalar each
    for i, value in zip(COMMAND_FIELDS[model_name], command):
        values[i] = float(value)
    return values


def fill_twist(out, model_name, command, yaw_rate=0.0):
    """Write ``command`` into Twist ``out``; point masses get ``yaw_rate`` on angular.z."""
    values = values_from_command(command, model_name, (0.0,) * 5 + (float(yaw_rate),))
    out.linear.x, out.linear.y, out.linear.z, out.angular.x, out.angular.y, out.angular.z = values


# -- serialized odometry and commands on the node's hot path ----------------------------------
#
# rclpy turns every received message into Python objects field by field; for an Odometry
# (two 36-double covariances) that costs more than the safety filter step.  The node takes
# odometry and commands serialized and reads only the numbers it uses, and answers a command
# by replacing the six numbers in a copy of its bytes, which copies the header for free.
# The CDR layout is in ``cdr_reader``.

class OdometryView(NamedTuple):
    """The numbers of a serialized Odometry that are read (see ``read_odometry``)."""

    sec: int
    nanosec: int
    frame: bytes
    child_frame: bytes
    pose: tuple
    twist: tuple

    @property
    def stamp(self):
        """Header stamp [s]."""
        return self.sec + 1e-9 * self.nanosec


def read_odometry(data):
    """``OdometryView`` (stamp, frame ids, pose (7,), twist (6,)) of a serialized Odometry.

    The covariances are skipped, not read.  Raises ``ValueError`` for a malformed message.
    """
    layout = layout_of(data)
    try:
        sec, nanosec, frame, end = read_header(data, layout)
        child_frame, end = read_string(data, layout, end)
        pose_at = aligned(end, 8)
        pose = layout.pose.unpack_from(data, pose_at)
        twist = layout.six.unpack_from(data, pose_at + 8 * (7 + 36))
    except struct.error as exc:
        raise ValueError(f'truncated Odometry: {exc}') from None
    return OdometryView(sec, nanosec, frame, child_frame, pose, twist)


class SerializedCommand:
    """A received serialized Twist, TwistStamped or WrenchStamped and its six numbers.

    ``stamp`` [s] and ``stamp_ns`` (exact, for matching stamps) are 0 without a header.
    """

    __slots__ = ('data', 'layout', 'at', 'values', 'stamp', 'stamp_ns', 'finite')

    def __init__(self, data, stamped):
        """Parse ``data``; ``stamped``: it starts with a Header.  ``ValueError`` if malformed."""
        self.data = data
        self.layout = layout_of(data)
        self.stamp, self.stamp_ns, self.at = 0.0, 0, 4
        try:
            if stamped:
                sec, nanosec, _, end = read_header(data, self.layout)
                self.stamp, self.stamp_ns = sec + 1e-9 * nanosec, sec * 1_000_000_000 + nanosec
                self.at = aligned(end, 8)
            self.values = self.layout.six.unpack_from(data, self.at)
        except struct.error as exc:
            raise ValueError(f'truncated command: {exc}') from None
        self.finite = all(map(math.isfinite, self.values))

    def replaced(self, values, stamp=None):
        """Return a copy of the bytes with the six numbers (and the stamp (sec, nanosec)) set."""
        at, layout = self.at, self.layout
        head = self.data[:at] if stamp is None else (
            self.data[:4] + layout.stamp.pack(*stamp) + self.data[12:at])
        return head + layout.six.pack(*values) + self.data[at + 48:]


# -- markers -> obstacles ---------------------------------------------------------------------

_SOLIDS = (Marker.CUBE, Marker.CYLINDER, Marker.SPHERE)


def _points(points):
    """(N, 3) array of a marker's points: a message's Point list, or a view's array."""
    if isinstance(points, np.ndarray):
        return points
    return np.array([(p.x, p.y, p.z) for p in points], dtype=float).reshape(-1, 3)


def _solid_corners(kind, sx, sy, sz, sides):
    """Local corners (k, 3) of a CUBE or of the prism circumscribing a CYLINDER/SPHERE."""
    if kind == Marker.CUBE:
        xy = 0.5 * np.array([[-sx, -sy], [sx, -sy], [sx, sy], [-sx, sy]])
    else:
        angles = 2.0 * np.pi * (np.arange(sides) + 0.5) / sides
        radius = 0.5 / math.cos(math.pi / sides)
        xy = radius * np.column_stack([sx * np.cos(angles), sy * np.sin(angles)])
    return np.vstack([np.column_stack([xy, np.full(len(xy), z)]) for z in (-0.5 * sz, 0.5 * sz)])


def _is_identity(pose):
    p, q = pose.position, pose.orientation
    return p.x == p.y == p.z == 0.0 and q.x == q.y == q.z == 0.0 and q.w in (0.0, 1.0)


def marker_placement(marker):
    """``(Placement, tilt)`` of a marker pose; ``NonFiniteError`` for NaN/Inf in it.

    A rotation about z only (``q.x = q.y = 0``) is the placement's yaw and
    ``tilt`` is ``None``: the shape turns rigidly with the pose.  Any other
    rotation is ``tilt`` (3, 3), applied to the shape itself (its footprint
    changes), and the placement only translates.
    """
    p, q = marker.pose.position, marker.pose.orientation
    if not all(map(math.isfinite, (p.x, p.y, p.z, q.x, q.y, q.z, q.w))):
        raise NonFiniteError('non-finite pose or scale' if marker.type in _SOLIDS
                             else 'non-finite pose, scale or points')
    r = rotation(q.x, q.y, q.z, q.w)
    if q.x == 0.0 and q.y == 0.0:
        return Placement(p.x, p.y, p.z, r[0], r[3]), None
    return Placement(p.x, p.y, p.z), np.array(r).reshape(3, 3)


def _source(marker, tilt, wall_thickness, cylinder_sides, limits):
    """Everything a marker's ``Shape`` depends on besides the placement, as a comparable tuple."""
    scale, q = marker.scale, marker.pose.orientation
    source = (marker.type, scale.x, scale.y, scale.z, wall_thickness, cylinder_sides, limits,
              None if tilt is None else (q.x, q.y, q.z, q.w))
    if marker.type in _SOLIDS:
        return source
    return source + (_points(marker.points).tobytes(),)


def marker_shape(marker, wall_thickness, cylinder_sides, tilt=None, source=None,
                 limits=OUTLINE_LIMITS):
    """``Shape`` of one marker in its own frame (``tilt`` applied); ``ValueError`` with a reason.

    The pose is not read here (see ``marker_placement``); ``source`` is stored in the shape.
    ``limits``: an outline of more than ``max_vertices`` points, or a LINE_LIST /
    TRIANGLE_LIST of more than ``max_parts`` pieces, becomes the enclosing polygon of all
    its points (``core.polygon_limits``; the shape is marked ``simplified``).
    """
    scale, kind = marker.scale, marker.type
    sx, sy, sz = scale.x, scale.y, scale.z
    if kind in _SOLIDS:
        if not all(map(math.isfinite, (sx, sy, sz))):
            raise NonFiniteError('non-finite pose or scale')
        if not (sx > 0.0 and sy > 0.0 and sz >= 0.0):
            raise ValueError(f'{MARKER_TYPE_NAMES[kind]} needs scale x, y > 0 and z >= 0')
        corners = _solid_corners(kind, sx, sy, sz, cylinder_sides)
        if tilt is not None:
            corners = corners @ tilt.T
        polygon = outline_polygon(convex_hull(corners[:, :2]), wall_thickness)
        return Shape((polygon,), corners[:, 2].min(), corners[:, 2].max(), None, source)
    local = _points(marker.points)
    if not (all(map(math.isfinite, (sx, sy, sz))) and np.isfinite(local).all()):
        raise NonFiniteError('non-finite pose, scale or points')
    thickness = sx if sx > 0.0 else wall_thickness
    if kind == Marker.TRIANGLE_LIST:
        local = local * (sx, sy, sz)
    if tilt is not None:
        local = local @ tilt.T
    if kind == Marker.LINE_STRIP:
        groups = [local]
    elif kind in (Marker.LINE_LIST, Marker.TRIANGLE_LIST):
        size = 2 if kind == Marker.LINE_LIST else 3
        if len(local) == 0 or len(local) % size:
            raise ValueError(f'{MARKER_TYPE_NAMES[kind]} needs a positive multiple of '
                             f'{size} points, got {len(local)}')
        groups = np.split(local, len(local) // size)
    else:
        raise ValueError(f'unsupported marker type {MARKER_TYPE_NAMES.get(kind, kind)}')
    if len(local) == 0:
        raise ValueError('no points')
    max_vertices, max_parts = limits
    regrouped = len(groups) > max_parts
    if regrouped:
        groups = [local]
    simplified = regrouped or any(len(g) > max_vertices for g in groups)
    polygons = tuple(outline_polygon(g[:, :2], thickness, max_vertices) for g in groups)
    z_min, z_max = local[:, 2].min(), local[:, 2].max()
    if z_max - z_min < POINT_TOLERANCE:
        # A flat outline is a prism of height scale.z above it, or an infinite extrusion.
        z_max = z_min + sz if kind != Marker.TRIANGLE_LIST and sz > 0.0 else math.inf
        z_min = z_min if math.isfinite(z_max) else -math.inf
    return Shape(polygons, z_min, z_max, local.mean(axis=0), source, simplified)


def _reference(marker, shape, placement):
    """Velocity reference position: the pose, or the points' centroid when the pose is identity."""
    if shape.centroid is not None and _is_identity(marker.pose):
        return shape.centroid
    return placement[:3]


def marker_geometry(marker, wall_thickness, cylinder_sides):
    """``(polygons, z_min, z_max, position (3,))`` of one marker; ``ValueError`` with a reason."""
    placement, tilt = marker_placement(marker)
    shape = marker_shape(marker, wall_thickness, cylinder_sides, tilt)
    polygons = [placement.rotate(p) + placement[:2] for p in shape.polygons]
    return (polygons, shape.z_min + placement.z, shape.z_max + placement.z,
            np.array(_reference(marker, shape, placement), dtype=float))


def conflate_markers(markers):
    """Return markers with the same effect as ``markers`` applied in order, newest per key.

    Everything before the last DELETEALL is dropped (the DELETEALL is kept first); after
    it, each ``ns/id`` keeps only its last ADD/MODIFY or DELETE, in the order of those
    last occurrences.  The obstacles this leaves are those of applying every marker; a
    key updated several times gets its velocity from the first and last positions only.
    """
    markers = list(markers)
    start = 0
    for index, marker in enumerate(markers):
        if marker.action == Marker.DELETEALL:
            start = index
    newest = {}
    for marker in markers[start:]:
        if marker.action != Marker.DELETEALL:
            key = (marker.ns, marker.id)
            newest.pop(key, None)  # re-inserted last: order of last occurrence
            newest[key] = marker
    head = markers[start:start + 1] if markers and markers[start].action == Marker.DELETEALL \
        else []
    return head + list(newest.values())


def apply_markers(tracker, msg, now_stamp, wall_thickness, cylinder_sides,
                  limits=OUTLINE_LIMITS):
    """Apply a ``visualization_msgs/MarkerArray`` to an ``ObstacleTracker``, marker by marker.

    Markers stamped zero use ``now_stamp`` [s].  A marker that cannot be used is
    rejected with its reason (non-finite numbers mark the tracker invalid);
    markers without a frame are rejected too.  A marker whose shape (type,
    scale, points, tilt, the settings and ``limits``) equals the one last given for its
    key reuses that ``Shape``: only its pose is read (``Placement``).
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
            placement, tilt = marker_placement(marker)
            source = _source(marker, tilt, wall_thickness, cylinder_sides, limits)
            shape = tracker.shape(key)
            if shape is None or shape.source != source:
                shape = marker_shape(marker, wall_thickness, cylinder_sides, tilt, source,
                                     limits)
        except ValueError as exc:
            tracker.reject(key, str(exc), invalid=isinstance(exc, NonFiniteError))
            continue
        tracker.update(key, frame, stamp, _reference(marker, shape, placement), shape,
                       placement)
