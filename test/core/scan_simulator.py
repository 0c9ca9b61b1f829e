"""A 2-D laser scanner for tests: the ranges of a LaserScan cast against polygons and circles.

Not collected (no ``test_`` prefix).  Beam i leaves the sensor at ``o = (x, y)`` along
``d_i = (cos phi_i, sin phi_i)``, ``phi_i = yaw + angle_min + i * angle_increment``, and
returns the smallest ``r > 0`` with ``o + r d_i`` on an edge or a circle:

- edge ``[a, b]``: ``o + r d = a + s (b - a)``, ``0 <= s <= 1``, solved with 2-D cross
  products ``r = (w x e) / (d x e)``, ``s = (w x d) / (d x e)``, ``w = a - o``, ``e = b - a``;
- circle (c, rho): ``r = t - sqrt(rho^2 - m^2)`` with ``t = (c - o) . d`` and ``m^2 =
  |c - o|^2 - t^2`` (the near intersection; a sensor inside a circle sees its far wall).

No hit, or one beyond ``range_max``, gives ``inf`` (REP 117: no return); Gaussian noise of
standard deviation ``noise`` is added to the hits only (and may push one past range_max,
as a real sensor's would).  Everything is vectorised over beams x edges and beams x circles.
"""
import math

import numpy as np


def box(centre, half_x, half_y, yaw=0.0):
    """Return the (4, 2) counter-clockwise corners of a rectangle turned by ``yaw``."""
    corners = np.array([[-half_x, -half_y], [half_x, -half_y], [half_x, half_y],
                        [-half_x, half_y]])
    cos_yaw, sin_yaw = math.cos(yaw), math.sin(yaw)
    rotation = np.array([[cos_yaw, -sin_yaw], [sin_yaw, cos_yaw]])
    return corners @ rotation.T + np.asarray(centre, dtype=float)


def sensor_pose_in_world(robot_pose, sensor_pose=(0.0, 0.0, 0.0)):
    """Return the sensor's world pose (x, y, yaw) on a base at ``robot_pose``."""
    x, y, yaw = robot_pose
    sx, sy, syaw = sensor_pose
    return (x + math.cos(yaw) * sx - math.sin(yaw) * sy,
            y + math.sin(yaw) * sx + math.cos(yaw) * sy, yaw + syaw)


def cast(origin, headings, polygons=(), circles=()):
    """Return the range along each heading to the nearest polygon edge or circle (inf: none).

    ``polygons``: (k, 2) arrays, closed (the last corner joins the first); ``circles``:
    ``((cx, cy), radius)`` pairs.
    """
    ox, oy = float(origin[0]), float(origin[1])
    dx, dy = np.cos(headings)[:, None], np.sin(headings)[:, None]
    ranges = np.full(len(headings), np.inf)
    with np.errstate(divide='ignore', invalid='ignore'):
        if len(polygons):
            starts = np.concatenate([np.asarray(p, dtype=float) for p in polygons])
            ends = np.concatenate([np.roll(np.asarray(p, dtype=float), -1, axis=0)
                                   for p in polygons])
            ex, ey = ends[:, 0] - starts[:, 0], ends[:, 1] - starts[:, 1]
            wx, wy = starts[:, 0] - ox, starts[:, 1] - oy
            denominator = dx * ey - dy * ex
            r = (wx * ey - wy * ex) / denominator
            s = (wx * dy - wy * dx) / denominator
            hit = (denominator != 0) & (r > 0) & (s >= 0) & (s <= 1)
            ranges = np.minimum(ranges, np.where(hit, r, np.inf).min(axis=1))
        if len(circles):
            centres = np.array([c for c, _ in circles], dtype=float)
            radii = np.array([rho for _, rho in circles], dtype=float)
            cx, cy = centres[:, 0] - ox, centres[:, 1] - oy
            along = cx * dx + cy * dy
            miss_sq = cx * cx + cy * cy - along * along
            near = along - np.sqrt(radii * radii - miss_sq)
            far = along + np.sqrt(radii * radii - miss_sq)
            r = np.where(near > 0, near, far)
            hit = (miss_sq <= radii * radii) & (r > 0)
            ranges = np.minimum(ranges, np.where(hit, r, np.inf).min(axis=1))
    return ranges


def simulate_ranges(sensor_pose, count, angle_min, angle_increment, range_max, polygons=(),
                    circles=(), noise=0.0, seed=None):
    """Return the ``count`` ranges a scanner at world pose ``sensor_pose`` measures.

    ``noise``: standard deviation [m] of Gaussian range noise on hits, drawn with ``seed``
    (a ``numpy.random.Generator`` is used as it is).  Misses and hits beyond ``range_max``
    are ``inf``.
    """
    x, y, yaw = sensor_pose
    headings = yaw + angle_min + angle_increment * np.arange(count)
    ranges = cast((x, y), headings, polygons, circles)
    if noise > 0:
        rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
        hits = np.isfinite(ranges)
        ranges[hits] += rng.normal(0.0, noise, int(hits.sum()))
    ranges[~(ranges <= range_max)] = np.inf
    return ranges
