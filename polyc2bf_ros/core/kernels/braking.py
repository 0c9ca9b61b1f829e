"""Kernels of ``barrier.braking_check``, whose docstring has the math.

The math in compiled form; every kernel lives in ``core/kernels`` (``jit.kernel_sources``).
"""
import math

import numpy as np

from polyc2bf_ros.core.kernels.cones import nearest_edge
from polyc2bf_ros.core.kernels.footprint import configuration_polygon, nearest_boundary
from polyc2bf_ros.core.kernels.jit import F1, F2, I1, kernel, signature


@kernel
def _signed_distance(x, y, edge_x, edge_y, inv_sq, count, n, px, py):
    """Return (signed distance, negative inside, of (px, py) to polygon n; its offset d).

    d = q - the nearest boundary point (``cones.nearest_edge``).
    """
    square, _, dx, dy, inside = nearest_edge(x, y, edge_x, edge_y, inv_sq, count, n, px, py)
    return (-math.sqrt(square) if inside else math.sqrt(square)), dx, dy



SLACK = 1e-9
"""m a group's bound must clear by: the rounding of a computed distance, within 10 km of the
origin, is below 1e-11 m."""


@kernel
def _footprint_bound(x, y, edge_x, edge_y, inv_sq, count, n, qx, qy, footprint, cos, sin):
    """Return a lower bound on the distance of a footprint at axle q, heading theta, to part n.

    With p the part's point nearest q and u = (p - q) / |p - q|, the part lies beyond the
    line through p normal to u and the footprint within its support s(u) = max_j <R f_j, u>
    of q along u, so the bodies are at least |p - q| - s(u) apart: a handful of products
    against the merge of ``configuration_polygon``.  -inf when q lies in the part.
    """
    square, _, dx, dy, inside = nearest_edge(x, y, edge_x, edge_y, inv_sq, count, n, qx, qy)
    if inside or not square > 0.0:
        return -math.inf
    distance = math.sqrt(square)
    ux, uy = -dx / distance, -dy / distance
    support = -math.inf
    for j in range(footprint.shape[1]):
        fx, fy = footprint[0, j], footprint[1, j]
        support = max(support, (cos * fx - sin * fy) * ux + (sin * fx + cos * fy) * uy)
    return distance - support



@kernel
def group_size(rows):
    """Return how many consecutive rows of a path of ``rows`` the check bounds together.

    About sqrt(rows): a part costs a test per group plus a test per row of the groups near
    it, rows / G + G of them along a stretch of path near it, least at G = sqrt(rows) (77
    rows: 9, 793: 29).
    """
    return max(1, int(math.sqrt(rows)))



@kernel
def path_groups(path, size, velocities):
    """Return the bounds of each ``size`` consecutive rows of ``path`` ([x, y, vx, vy]).

    Row g: [low x, high x, low y, high y] of rows g size ... (g + 1) size - 1 (the last
    group may be shorter); with ``velocities`` also [low vx, high vx, low vy, high vy, the
    largest vx^2 + vy^2].
    """
    rows = path.shape[0]
    groups = np.empty(((rows + size - 1) // size, 9 if velocities else 4))
    for g in range(groups.shape[0]):
        first, end = g * size, min((g + 1) * size, rows)
        low_x = high_x = path[first, 0]
        low_y = high_y = path[first, 1]
        for k in range(first + 1, end):
            low_x, high_x = min(low_x, path[k, 0]), max(high_x, path[k, 0])
            low_y, high_y = min(low_y, path[k, 1]), max(high_y, path[k, 1])
        groups[g, 0], groups[g, 1], groups[g, 2], groups[g, 3] = low_x, high_x, low_y, high_y
        if velocities:
            low_x = high_x = path[first, 2]
            low_y = high_y = path[first, 3]
            square = 0.0
            for k in range(first, end):
                low_x, high_x = min(low_x, path[k, 2]), max(high_x, path[k, 2])
                low_y, high_y = min(low_y, path[k, 3]), max(high_y, path[k, 3])
                square = max(square, path[k, 2] * path[k, 2] + path[k, 3] * path[k, 3])
            groups[g, 4], groups[g, 5], groups[g, 6], groups[g, 7] = (low_x, high_x, low_y,
                                                                      high_y)
            groups[g, 8] = square
    return groups



@kernel
def box_gap(low_x, high_x, low_y, high_y, box):
    """Return the distance between the box [low, high] and ``box``.

    Both as [low x, high x, low y, high y] (``cones.PlanarPolygons.boxes``).  Each
    operation rounds monotonically, so a box holding another gives a gap at most the
    other's, in floating point too.
    """
    gap_x = max(0.0, box[0] - high_x, low_x - box[1])
    gap_y = max(0.0, box[2] - high_y, low_y - box[3])
    return math.sqrt(gap_x * gap_x + gap_y * gap_y)



@kernel
def sorted_pair(a, b):
    """Return (min(a, b), max(a, b))."""
    return (a, b) if a <= b else (b, a)



@kernel
def product_range(low_a, high_a, low_b, high_b):
    """Return (min, max) of the rounded a b over a in [low_a, high_a], b in [low_b, high_b].

    a b is bilinear, so both lie at corners, and rounding is monotone: so are they rounded.
    """
    first, second = sorted_pair(low_a * low_b, low_a * high_b)
    third, fourth = sorted_pair(high_a * low_b, high_a * high_b)
    return min(first, third), max(second, fourth)



@kernel
def group_box(group, first_time, last_time, vx, vy, ox, oy):
    """Return (low x, high x, low y, high y) of a group's points relative to a moving part.

    Row k of ``group`` (``path_groups``) at time t_k, first_time <= t_k <= last_time, is at
    q_k = p_k - t_k c_dot - o relative to a part moved by o and moving at c_dot = (vx,
    vy), computed as ``p - t * v - o``; every operation rounds monotonically and
    t_k v lies between its values at the two ends, so the box holds every q_k as computed.
    """
    shift_low_x, shift_high_x = sorted_pair(first_time * vx, last_time * vx)
    shift_low_y, shift_high_y = sorted_pair(first_time * vy, last_time * vy)
    return (group[0] - shift_high_x - ox, group[1] - shift_low_x - ox,
            group[2] - shift_high_y - oy, group[3] - shift_low_y - oy)



@kernel(signature('UniTuple(f8, 2)', F2, F2, F2, F2, F2, I1, F2, F2, F2, F2, 'f8', F2, 'f8',
                  'f8', 'f8', F1, 'b1', F2, 'f8', F1))
def path_clearance(x, y, edge_x, edge_y, inv_sq, counts, boxes, velocities, offsets,
                   accelerations, age, path, period, cutoff, accel, velocity_errors,
                   closing_only, footprint, cover, per_part):
    """Return min(cutoff, the smallest signed distance of a ``path`` row's x, y to a polygon).

    Or, with a ``footprint`` (2, m > 0; ``barrier.footprint_cone``), of the footprint turned
    to the row's heading (rows [x, y, vx, vy, theta] of its origin): the signed distance of
    the row's x, y to the configuration polygon C(theta) (``footprint.configuration_polygon``),
    the bodies' distance apart; ``cover`` is its covering radius, which the pruning below
    subtracts from every gap (a footprint reaches no farther than that from its origin).

    Two values: over the static polygons, and over the moving ones.  Negative inside.
    Polygon n (CCW, rows of ``x``, ``y``, ``boxes`` as ``cones.PlanarPolygons``) has moved
    by ``offsets[n]`` and moves at ``velocities[n]``, speeding up at ``accelerations[n]``
    (x, y): by t it has moved by v t + a t^2 / 2 more (zeros: at constant velocity); path
    row k ([x, y, vx, vy]) is at age + (k + 1) period.  A moving polygon, or one with
    ``velocity_errors[n]`` > 0, counts less ``velocity_errors[n]`` t + ``accel`` t^2 / 2,
    t = age + (k + 1) period: as far as it may stray from its stated motion by then; with
    ``closing_only`` (the braking check) only at the rows where the path's velocity closes
    on it (points towards its nearest point) or that lie inside it (module docstring),
    else at every row (an evasion's look ahead, ``SafetyFilter``).

    ``per_part`` (N,), or empty: when it has a row per polygon, each moving polygon's own
    value (the smallest over its rows, as counted above; cutoff where none counts, and for
    static polygons) is written there, and each moving polygon is pruned against its own
    running value instead of all polygons' (the braking check compares them part by part).

    Pruning, exact: a polygon whose bounding box stays farther than ``cutoff`` from the
    path's is not measured.  Nor is a group of consecutive rows (``path_groups``) whose
    box, relative to the polygon over the group's times (``group_box``), lies a gap g > 0
    from the polygon's box: each of its points is outside the box, so at least g from
    the polygon, and counts at least g - max(e t + a t^2 / 2) over the group's two end
    times (the bound is convex in t); when that is ``SLACK`` above the running minimum,
    no row of the group can lower it, and the result is the one every row gives.  Nor is
    a footprint's row whose ``_footprint_bound``, so counted, is ``SLACK`` above it.
    """
    rows = path.shape[0]
    parts = per_part.shape[0] == counts.shape[0]
    if parts:
        per_part[:] = cutoff
    if rows == 0:
        return cutoff, cutoff
    size = group_size(rows)
    groups = path_groups(path, size, False)
    bounds = path_box(groups)
    width = x.shape[1] + footprint.shape[1]
    cx, cy = np.empty((1, width)), np.empty((1, width))
    feet = np.empty(width, dtype=np.int64)
    best, best_moving = cutoff, cutoff
    for n in range(counts.shape[0]):
        moving, far = part_prospect(boxes, velocities, offsets, accelerations,
                                    velocity_errors, n, accel, age, age + rows * period,
                                    cutoff + cover, bounds)
        if far:
            continue
        vx, vy, ox, oy = velocities[n, 0], velocities[n, 1], offsets[n, 0], offsets[n, 1]
        hx, hy = 0.5 * accelerations[n, 0], 0.5 * accelerations[n, 1]
        for g in range(groups.shape[0]):
            first, end = g * size, min((g + 1) * size, rows)
            running = (per_part[n] if parts else best_moving) if moving else best
            if group_skipped(groups[g], boxes, velocities, offsets, accelerations,
                             velocity_errors, n, moving, accel, age + (first + 1) * period,
                             age + end * period, cover, running):
                continue
            for k in range(first, end):
                t = age + (k + 1) * period
                qx = path[k, 0] - t * vx - hx * t * t - ox
                qy = path[k, 1] - t * vy - hy * t * t - oy
                if footprint.shape[1]:
                    bound = _footprint_bound(x, y, edge_x, edge_y, inv_sq, counts[n], n, qx,
                                             qy, footprint, math.cos(path[k, 4]),
                                             math.sin(path[k, 4]))
                    if moving:
                        bound -= t * (velocity_errors[n] + 0.5 * accel * t)
                    running = (per_part[n] if parts else best_moving) if moving else best
                    if bound >= running + SLACK:
                        continue
                distance, dx, dy = _body_distance(x, y, edge_x, edge_y, inv_sq, counts[n], n,
                                                  qx, qy, path[k, 4] if footprint.shape[1]
                                                  else 0.0, footprint, cx, cy, feet)
                if not moving:
                    best = min(best, distance)
                elif (not closing_only or distance <= 0.0
                      or path[k, 2] * dx + path[k, 3] * dy < 0.0):
                    value = distance - t * (velocity_errors[n] + 0.5 * accel * t)
                    best_moving = min(best_moving, value)
                    if parts:
                        per_part[n] = min(per_part[n], value)
    return best, best_moving



@kernel
def _body_distance(x, y, edge_x, edge_y, inv_sq, count, n, qx, qy, theta, footprint, cx, cy,
                   feet):
    """Return (signed distance, its offset d) of a body at q to polygon n.

    A point (``footprint`` (2, 0)): ``_signed_distance``.  A footprint turned to ``theta``:
    of q to the configuration polygon C(theta) (``footprint.configuration_polygon``, built
    in the scratch ``cx``, ``cy``, ``feet``), the bodies' distance apart.  d = q - the
    nearest boundary point; the distance is negative inside.
    """
    if not footprint.shape[1]:
        return _signed_distance(x, y, edge_x, edge_y, inv_sq, count, n, qx, qy)
    size = configuration_polygon(x, y, count, n, footprint, math.cos(theta), math.sin(theta),
                                 cx, cy, feet)
    _, _, wx, wy, inside = nearest_boundary(cx, cy, size, qx, qy)
    distance = math.hypot(wx, wy)
    return (-distance if inside else distance), -wx, -wy



@kernel
def path_box(groups):
    """Return [low x, high x, low y, high y] of every row of a path's ``path_groups``."""
    low_x, high_x = groups[0, 0], groups[0, 1]
    low_y, high_y = groups[0, 2], groups[0, 3]
    for g in range(1, groups.shape[0]):
        low_x, high_x = min(low_x, groups[g, 0]), max(high_x, groups[g, 1])
        low_y, high_y = min(low_y, groups[g, 2]), max(high_y, groups[g, 3])
    return low_x, high_x, low_y, high_y



@kernel
def part_prospect(boxes, velocities, offsets, accelerations, velocity_errors, n, accel, age,
                  last, reach, bounds):
    """Return (moving, far) of part n for a path ``path_box`` ``bounds`` over [age, last].

    Moving: it moves, speeds up or may stray (``velocity_errors[n]`` > 0); far: its box,
    grown by how far it moves (|v| t + |a| t^2 / 2) and strays by then, stays farther than
    ``reach`` from the path's box.
    """
    vx, vy = velocities[n, 0], velocities[n, 1]
    speeding = math.hypot(accelerations[n, 0], accelerations[n, 1])
    moving = vx != 0.0 or vy != 0.0 or speeding != 0.0 or velocity_errors[n] > 0.0
    horizon = max(abs(age), abs(last))
    reach += horizon * (math.sqrt(vx * vx + vy * vy) + 0.5 * horizon * speeding)
    if moving:
        reach += horizon * (velocity_errors[n] + 0.5 * accel * horizon)
    low_x, high_x, low_y, high_y = bounds
    ox, oy = offsets[n, 0], offsets[n, 1]
    return moving, (low_x - ox - reach > boxes[n, 1] or high_x - ox + reach < boxes[n, 0]
                    or low_y - oy - reach > boxes[n, 3] or high_y - oy + reach < boxes[n, 2])



@kernel
def group_skipped(group, boxes, velocities, offsets, accelerations, velocity_errors, n,
                  moving, accel, first_time, last_time, cover, best):
    """Return True when no row of a group can bring part n's distance below ``best``.

    The group's box relative to the part over its times (``group_box``, widened on each
    side by the part's largest a t^2 / 2 over them) lies a gap g > 0 from the part's box
    less ``cover`` (a body within that of each row), and g less the part's straying at the
    group's end times (convex in t) is ``SLACK`` above ``best``.
    """
    vx, vy = velocities[n, 0], velocities[n, 1]
    low_qx, high_qx, low_qy, high_qy = group_box(group, first_time, last_time, vx, vy,
                                                 offsets[n, 0], offsets[n, 1])
    square = max(first_time * first_time, last_time * last_time)
    spread_x = 0.5 * abs(accelerations[n, 0]) * square
    spread_y = 0.5 * abs(accelerations[n, 1]) * square
    gap = box_gap(low_qx - spread_x, high_qx + spread_x, low_qy - spread_y, high_qy + spread_y,
                  boxes[n]) - cover
    bound = gap
    if moving:
        error = velocity_errors[n]
        bound -= max(first_time * (error + 0.5 * accel * first_time),
                     last_time * (error + 0.5 * accel * last_time))
    return gap > 0.0 and bound - SLACK >= best



@kernel(signature('void', F2, 'f8', 'f8', 'f8', F2))
def grow_bands(bands, reach, speed, turn, out):
    """Write into ``out`` a stop's ``bands`` (``RobotModel.stop_bands``) widened.

    Each position box by ``reach`` [m] on every side, each velocity box by ``speed`` [m/s],
    the bound on |omega| (column 9) by ``turn`` [rad/s]; column 8 bounds |v|^2 over the
    widened velocity box (and stays at least the given bound).  Every row the given bands
    hold, the widened ones hold too.
    """
    for b in range(bands.shape[0]):
        out[b, 0], out[b, 1] = bands[b, 0] - reach, bands[b, 1] + reach
        out[b, 2], out[b, 3] = bands[b, 2] - reach, bands[b, 3] + reach
        out[b, 4], out[b, 5] = bands[b, 4] - speed, bands[b, 5] + speed
        out[b, 6], out[b, 7] = bands[b, 6] - speed, bands[b, 7] + speed
        out[b, 8] = max(bands[b, 8], max(out[b, 4] * out[b, 4], out[b, 5] * out[b, 5])
                        + max(out[b, 6] * out[b, 6], out[b, 7] * out[b, 7]))
        out[b, 9] = bands[b, 9] + turn



@kernel(signature('b1', F2, 'f8', 'f8', F2, 'f8', 'f8'))
def bands_within(bands, first_time, last_time, held, held_first, held_last):
    """Return True when every row ``bands`` hold over [first, last], ``held`` holds too.

    Band by band (the same count): each position and velocity box inside the held one's,
    the bounds of |v|^2 and |omega| at most the held ones', and the times inside
    [held_first, held_last].
    """
    if bands.shape[0] != held.shape[0] or first_time < held_first or last_time > held_last:
        return False
    for b in range(bands.shape[0]):
        for low in range(0, 8, 2):
            if bands[b, low] < held[b, low] or bands[b, low + 1] > held[b, low + 1]:
                return False
        if bands[b, 8] > held[b, 8] or bands[b, 9] > held[b, 9]:
            return False
    return True



@kernel(signature('b1', F2, 'f8', 'f8', F2, F2, F2, F2, F1, 'f8', 'f8', 'f8', 'b1'))
def stop_clear(bands, first_time, last_time, boxes, velocities, offsets, accelerations,
               velocity_errors, accel, cutoff, cover, moving_only):
    """Return True when no row of a stop can come within ``cutoff`` of a part.

    ``bands`` (``RobotModel.stop_bands``): rows at times in [first_time, last_time] that
    lie in ``bands[0]``'s position box, which holds ``path_box`` of them and the box of
    each of their groups.  A part is passed when ``part_prospect`` finds it farther than
    ``cutoff`` + ``cover`` (grown by what it may move by the larger time), or when
    ``group_skipped`` passes the whole box as one group against ``cutoff`` (its motion
    over the times as a shift): both are monotone in the box and the times, so they
    pass each group ``path_clearance`` forms, and with a ``cutoff`` at most its own it
    returns (cutoff, cutoff), or (for a look ahead with a larger one) values at least
    this ``cutoff``.  ``moving_only``: the standing parts are not asked.
    """
    bounds = bands[0, 0], bands[0, 1], bands[0, 2], bands[0, 3]
    for n in range(boxes.shape[0]):
        moving, far = part_prospect(boxes, velocities, offsets, accelerations,
                                    velocity_errors, n, accel, first_time, last_time,
                                    cutoff + cover, bounds)
        if far or (moving_only and not moving):
            continue
        if not group_skipped(bands[0], boxes, velocities, offsets, accelerations,
                             velocity_errors, n, moving, accel, first_time, last_time, cover,
                             cutoff):
            return False
    return True



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
