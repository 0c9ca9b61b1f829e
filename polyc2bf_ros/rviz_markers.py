"""The filter's obstacle parts and cones as a ``MarkerArray`` for RViz or Foxglove."""
import numpy as np
from geometry_msgs.msg import Point, Vector3
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray


def _color(r, g, b, a):
    return ColorRGBA(r=r, g=g, b=b, a=a)


_INACTIVE, _ACTIVE = _color(0.1, 0.8, 0.2, 0.8), _color(0.9, 0.1, 0.1, 1.0)
_BODY = _color(0.2, 0.4, 1.0, 1.0)
_CIRCLE_SIDES = 32


def body_outline(centre, yaw, footprint, radius):
    """Return the guarded body's outline (K, 2) in the odometry frame.

    ``footprint`` (the base-frame polygon of ``FilterConfig.footprint``, or None) turned by
    ``yaw`` and moved to ``centre``; without one the disc of ``radius`` about ``centre``.
    """
    if footprint is None:
        angles = np.linspace(0.0, 2.0 * np.pi, _CIRCLE_SIDES, endpoint=False)
        return np.asarray(centre[:2]) + radius * np.column_stack((np.cos(angles),
                                                                   np.sin(angles)))
    c, s = np.cos(yaw), np.sin(yaw)
    return np.asarray(centre[:2]) + footprint @ np.array([[c, s], [-s, c]])


def filter_markers(frame, stamp, footprints, active, apex=None, cones=None, body=None):
    """``MarkerArray`` for RViz/Foxglove: obstacle parts (red = active constraint) and cones.

    ``body``: the robot's outline (``body_outline``), drawn blue in namespace ``robot``.

    ``footprints`` is the filter's ``PolygonBatch`` (at the obstacles' stamp),
    ``active`` the indices of the active rows (indices past the footprints are parts the
    filter added itself, the ground of ``FilterConfig.ground_z``: not drawn).  Cones are
    drawn when
    ``cones`` (axis ``p`` and boundary ray ``k`` as (2, N) planar vectors) and the
    ``apex`` are given: the rays ``k`` and its mirror ``2 <k, p_hat> p_hat - k``.
    The first marker is a DELETEALL, so parts that disappeared vanish.
    """
    is_active = np.zeros(len(footprints), dtype=bool)
    active = np.asarray(active, dtype=int)
    is_active[active[active < len(footprints)]] = True
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
    if body is not None:
        markers.append(Marker(
            ns='robot', id=0, type=Marker.LINE_STRIP, action=Marker.ADD,
            scale=Vector3(x=0.02), color=_BODY,
            points=[Point(x=float(x), y=float(y)) for x, y in np.vstack([body, body[:1]])]))
    for marker in markers[1:]:
        marker.header.frame_id = frame
        marker.header.stamp = stamp
        marker.pose.orientation.w = 1.0
    return MarkerArray(markers=markers)
