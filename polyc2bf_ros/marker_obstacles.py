"""Obstacle markers -> obstacles: each ``visualization_msgs/Marker`` into the tracker.

Each marker (``apply_markers``) becomes one or more
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

The functions take a typed ``Marker`` or a ``cdr_reader.MarkerView`` alike.
"""
import math

import numpy as np
from visualization_msgs.msg import Marker

from polyc2bf_ros.conversions import rotation
from polyc2bf_ros.core.geometry.polygon_limits import MAX_PARTS, MAX_VERTICES
from polyc2bf_ros.core.geometry.polygons import convex_hull
from polyc2bf_ros.core.obstacles.marker_tracker import (
    outline_polygon,
    Placement,
    POINT_TOLERANCE,
    Shape,
)

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
    its points (``core.geometry.polygon_limits``; the shape is marked ``simplified``).
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
