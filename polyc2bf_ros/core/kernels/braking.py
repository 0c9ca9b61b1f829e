"""Kernels of ``barrier.braking_check``, whose docstring has the math.

The math in compiled form; every kernel lives in ``core/kernels`` (``jit.kernel_sources``).
"""
import math

from polyc2bf_ros.core.kernels.cones import nearest_edge
from polyc2bf_ros.core.kernels.jit import F1, F2, I1, kernel, signature


@kernel
def _signed_distance(x, y, edge_x, edge_y, inv_sq, count, n, px, py):
    """Return (signed distance, negative inside, of (px, py) to polygon n; its offset d).

    d = q - the nearest boundary point (``cones.nearest_edge``).
    """
    square, _, dx, dy, inside = nearest_edge(x, y, edge_x, edge_y, inv_sq, count, n, px, py)
    return (-math.sqrt(square) if inside else math.sqrt(square)), dx, dy



@kernel(signature('UniTuple(f8, 2)', F2, F2, F2, F2, F2, I1, F2, F2, F2, 'f8', F2, 'f8',
                  'f8', 'f8', F1, 'b1'))
def path_clearance(x, y, edge_x, edge_y, inv_sq, counts, boxes, velocities, offsets, age,
                   path, period, cutoff, accel, velocity_errors, closing_only):
    """Return min(cutoff, the smallest signed distance of a ``path`` row's x, y to a polygon).

    Two values: over the static polygons, and over the moving ones.  Negative inside.
    Polygon n (CCW, rows of ``x``, ``y``, ``boxes`` as ``cones.PlanarPolygons``) has moved
    by ``offsets[n]`` and moves at ``velocities[n]``; path row k ([x, y, vx, vy]) is at
    age + (k + 1) period.  A moving polygon, or one with ``velocity_errors[n]`` > 0,
    counts less ``velocity_errors[n]`` t + ``accel`` t^2 / 2, t = age + (k + 1) period: as
    far as it may stray from its stated velocity by then; with ``closing_only`` (the braking check) only at the rows where the path's
    velocity closes on it (points towards its nearest point) or that lie inside it (module
    docstring), else at every row (an evasion's look ahead, ``SafetyFilter``).  A polygon
    whose bounding box stays farther than ``cutoff`` from the path's is not measured.
    """
    rows = path.shape[0]
    if rows == 0:
        return cutoff, cutoff
    low_x = high_x = path[0, 0]
    low_y = high_y = path[0, 1]
    for k in range(rows):
        low_x, high_x = min(low_x, path[k, 0]), max(high_x, path[k, 0])
        low_y, high_y = min(low_y, path[k, 1]), max(high_y, path[k, 1])
    last = age + rows * period
    best, best_moving = cutoff, cutoff
    for n in range(counts.shape[0]):
        vx, vy = velocities[n, 0], velocities[n, 1]
        velocity_error = velocity_errors[n]
        moving = vx != 0.0 or vy != 0.0 or velocity_error > 0.0
        horizon = max(abs(age), abs(last))
        reach = cutoff + horizon * math.sqrt(vx * vx + vy * vy)
        if moving:
            reach += horizon * (velocity_error + 0.5 * accel * horizon)
        ox, oy = offsets[n, 0], offsets[n, 1]
        if (low_x - ox - reach > boxes[n, 1] or high_x - ox + reach < boxes[n, 0]
                or low_y - oy - reach > boxes[n, 3] or high_y - oy + reach < boxes[n, 2]):
            continue
        for k in range(rows):
            t = age + (k + 1) * period
            distance, dx, dy = _signed_distance(x, y, edge_x, edge_y, inv_sq, counts[n], n,
                                                path[k, 0] - t * vx - ox,
                                                path[k, 1] - t * vy - oy)
            if not moving:
                best = min(best, distance)
            elif (not closing_only or distance <= 0.0
                  or path[k, 2] * dx + path[k, 3] * dy < 0.0):
                best_moving = min(best_moving,
                                  distance - t * (velocity_error + 0.5 * accel * t))
    return best, best_moving



@kernel(signature('b1', F2, F2, F2, F1, 'f8', 'f8', 'f8', 'f8', 'f8', 'b1'))
def clear_around(boxes, velocities, offsets, velocity_errors, accel, elapsed, cx, cy, reach,
                 moving_only):
    """Return True when no polygon's bounding box comes within ``reach`` of (cx, cy).

    With ``moving_only``, no moving polygon's (an evasion's trigger, ``SafetyFilter``).

    Polygon n (bounding box ``boxes[n]``, as ``cones.PlanarPolygons``) has moved by
    ``offsets[n]`` and moves at ``velocities[n]`` for up to ``elapsed`` s more, straying by
    up to ``velocity_errors[n]`` t + ``accel`` t^2 / 2 if it moves (as ``path_clearance``
    counts it).  The square
    of half-side ``reach`` around (cx, cy) holds the bounding box of any path within that
    distance of it, so ``path_clearance`` of such a path, with ``cutoff`` <= reach - rho,
    returns ``cutoff``: the check skips computing the path (``SafetyFilter``).
    """
    for n in range(boxes.shape[0]):
        vx, vy = velocities[n, 0], velocities[n, 1]
        if moving_only and vx == 0.0 and vy == 0.0:
            continue
        grown = reach + elapsed * math.sqrt(vx * vx + vy * vy)
        if vx != 0.0 or vy != 0.0 or velocity_errors[n] > 0.0:
            grown += elapsed * (velocity_errors[n] + 0.5 * accel * elapsed)
        low_x, high_x, low_y, high_y = boxes[n, 0], boxes[n, 1], boxes[n, 2], boxes[n, 3]
        px, py = cx - offsets[n, 0], cy - offsets[n, 1]
        if not (px - grown > high_x or px + grown < low_x
                or py - grown > high_y or py + grown < low_y):
            return False
    return True
