"""The robot's footprint: a polygon in the base frame, about the odometry origin.

Nav2's format (``nav2_costmap_2d`` ``footprint``, the collision monitor's
``footprint_topic``): the string ``"[[x, y], [x, y], ...]"``, at least three points, in
metres, in the frame the odometry's pose is of (``base_link``), in either winding, with or
without the first point repeated.  ``"[]"`` means none: the body is the disc of
``robot_radius``.

Until the barrier guards the polygon itself, the filter guards the smallest disc about the
origin that covers it (``covering_radius``), as it guards a disc robot: a footprint is
refused here exactly when it cannot describe a body, so the same string stays valid when
the polygon is guarded.
"""
import numpy as np
import yaml

from polyc2bf_ros.core.geometry.polygons import clean_polygon, InvalidPolygonError

NO_FOOTPRINT = '[]'


class FootprintError(ValueError):
    """A footprint that does not describe a body; the message says why, in one line."""


def parse_footprint(footprint):
    """Return the footprint as a CCW ``(n, 2)`` float64 polygon, or None for ``"[]"``.

    ``footprint``: Nav2's string, or the same as a sequence of ``(x, y)`` pairs.  Raises
    ``FootprintError`` when the string does not parse as a list of pairs, or the polygon has
    fewer than 3 distinct points, a NaN or infinite coordinate, no area, or edges that
    cross (``polygons.clean_polygon``).  Non-convex footprints are accepted.
    """
    points = footprint
    if isinstance(footprint, str):
        try:
            points = yaml.safe_load(footprint) if footprint.strip() else []
        except yaml.YAMLError:
            raise FootprintError(f'footprint {footprint!r} does not parse: expected '
                                 '"[[x, y], [x, y], [x, y], ...]" in metres') from None
    if points is None or (isinstance(points, (list, tuple)) and len(points) == 0):
        return None
    if isinstance(points, (list, tuple)):  # YAML reads nan and inf unquoted as strings
        points = [[_non_finite(value) for value in point] if isinstance(point, (list, tuple))
                  else point for point in points]
    if not (isinstance(points, (list, tuple, np.ndarray))
            and all(isinstance(point, (list, tuple, np.ndarray)) and len(point) == 2
                    and all(_is_number(value) for value in point) for point in points)):
        raise FootprintError(f'footprint {footprint!r} is not a list of [x, y] pairs of '
                             'numbers: expected "[[x, y], [x, y], [x, y], ...]" in metres')
    coordinates = np.array(points, dtype=np.float64)
    if not np.isfinite(coordinates).all():
        row = int(np.flatnonzero(~np.isfinite(coordinates).all(axis=1))[0])
        raise FootprintError(f'footprint point {row} is {points[row]!r}: every coordinate '
                             'must be a finite number')
    try:
        return clean_polygon(coordinates)
    except InvalidPolygonError as exc:
        raise FootprintError(f'footprint {format_footprint(coordinates)}: {exc}') from None


def _non_finite(value):
    """Return a string spelling NaN or infinity (``nan``, ``-inf``) as that float, else value."""
    if isinstance(value, str) and value.strip().lstrip('+-').lower() in ('nan', 'inf',
                                                                         'infinity'):
        return float(value)
    return value


def _is_number(value):
    """Return True for an int or float (not a bool, string or None)."""
    return isinstance(value, (int, float, np.floating, np.integer)) and not isinstance(value,
                                                                                       bool)


def format_footprint(points):
    """Return Nav2's string of a polygon's ``points`` (``parse_footprint`` reads it back)."""
    return '[' + ', '.join(f'[{float(x)!r}, {float(y)!r}]' for x, y in points) + ']'


def covering_radius(points):
    """Return the radius of the smallest disc about the origin that covers the polygon."""
    return float(np.max(np.hypot(points[:, 0], points[:, 1])))
