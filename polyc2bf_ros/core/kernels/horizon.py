"""Kernels of ``barrier.horizon_cone``, whose docstring has the math.

The math in compiled form; every kernel lives in ``core/kernels`` (``jit.kernel_sources``).
"""
import math

import numpy as np

from polyc2bf_ros.core.kernels.barrier import barrier_column, plane_motion, store_input_column
from polyc2bf_ros.core.kernels.braking import (
    box_gap,
    group_box,
    group_size,
    path_groups,
    product_range,
)
from polyc2bf_ros.core.kernels.cones import (
    hinted_seen_edge,
    hinted_silhouette,
    midpoint_cone,
    nearest_edge,
    nearest_seen_edge,
    PLANE_ROWS,
    silhouette,
)
from polyc2bf_ros.core.kernels.jit import B1, F1, F2, F3, I1, I2, kernel, signature
from polyc2bf_ros.core.kernels.views import viewpoint

_TINY = 1e-12


@kernel
def _boundary_distance(x, y, edge_x, edge_y, inv_sq, count, n, qx, qy, a, b, seen, hints):
    """Return (d, grad_x d): the distance from q to polygon n and its gradient in x.

    A, B, seen: q's ``silhouette`` of the polygon (``hinted_seen_edge`` where seen).
    """
    if seen:
        square, ox, oy = hinted_seen_edge(x, y, edge_x, edge_y, inv_sq, count, n, qx, qy, a,
                                          b, hints)
    else:
        square, _, ox, oy, _ = nearest_edge(x, y, edge_x, edge_y, inv_sq, count, n, qx, qy)
    distance = math.sqrt(square)
    if distance == 0.0:
        return 0.0, 0.0, 0.0
    return distance, -ox / distance, -oy / distance



@kernel
def _bisector_frame(x, y, count, n, qx, qy, ax, ay, bx, by):
    """Return (L, g_hat, u, c, |m|, M) of the bisector cone of rays a, b (module docstring)."""
    gx = gy = 0.0
    for k in range(count):
        gx += x[n, k]
        gy += y[n, k]
    gx, gy = gx / count - qx, gy / count - qy
    length = max(math.sqrt(gx * gx + gy * gy), _TINY)
    a_norm = max(math.sqrt(ax * ax + ay * ay), _TINY)
    b_norm = max(math.sqrt(bx * bx + by * by), _TINY)
    ahx, ahy, bhx, bhy = ax / a_norm, ay / a_norm, bx / b_norm, by / b_norm
    mx, my = ahx + bhx, ahy + bhy
    m_norm = max(math.sqrt(mx * mx + my * my), _TINY)
    m00 = (1.0 - ahx * ahx) / a_norm + (1.0 - bhx * bhx) / b_norm
    m01 = -ahx * ahy / a_norm - bhx * bhy / b_norm
    m11 = (1.0 - ahy * ahy) / a_norm + (1.0 - bhy * bhy) / b_norm
    return (length, gx / length, gy / length, mx / m_norm, my / m_norm, 0.5 * m_norm, m_norm,
            m00, m01, m11)



@kernel
def _bisector_cone(x, y, count, n, qx, qy, a, b):
    """Return (px, py, kx, ky, s, ds_dx, ds_dy, frame): the bisector cone of vertices a, b."""
    ax, ay, bx, by = x[n, a] - qx, y[n, a] - qy, x[n, b] - qx, y[n, b] - qy
    frame = _bisector_frame(x, y, count, n, qx, qy, ax, ay, bx, by)
    length, gx, gy, ux, uy, c, _, m00, m01, m11 = frame
    mux, muy = m00 * ux + m01 * uy, m01 * ux + m11 * uy
    if ax * ax + ay * ay > bx * bx + by * by:
        ax, ay = bx, by
    return (length * ux, length * uy, ax, ay, length * c, c * gx + 0.5 * length * mux,
            c * gy + 0.5 * length * muy, frame)



@kernel
def _bisector_terms(frame, distance, ddx, ddy, inv_horizon, projections, velocities,
                    position_rate, drift, input_matrix, eps_sq, out, first, n):
    """Write h_tau, Lf h_tau, Lg h_tau of the bisector cone (module docstring)."""
    length, gx, gy, ux, uy, c, m_norm, m00, m01, m11 = frame
    vx, vy, ax, ay = plane_motion(projections, velocities, position_rate, drift, n)
    speed = math.sqrt(vx * vx + vy * vy + eps_sq)
    along = ux * vx + uy * vy
    value = along + speed * c + inv_horizon * distance * (1.0 - c)
    wx, wy = vx - along * ux, vy - along * uy  # (I - u u^T) v
    mux, muy = m00 * ux + m01 * uy, m01 * ux + m11 * uy
    mwx, mwy = m00 * wx + m01 * wy, m01 * wx + m11 * wy
    grad_x = mwx / m_norm + 0.5 * speed * mux + inv_horizon * (
        (1.0 - c) * ddx - 0.5 * distance * mux)
    grad_y = mwy / m_norm + 0.5 * speed * muy + inv_horizon * (
        (1.0 - c) * ddy - 0.5 * distance * muy)
    dh_dx, dh_dy = gx * value + length * grad_x, gy * value + length * grad_y
    dh_dvx, dh_dvy = length * (ux + c * vx / speed), length * (uy + c * vy / speed)
    out[first, n] = length * value
    out[first + 1, n] = dh_dx * vx + dh_dy * vy + dh_dvx * ax + dh_dvy * ay
    store_input_column(projections, input_matrix, dh_dvx, dh_dvy, out, first + 2, n)



@kernel
def _store_midpoint(out, first, n, ax, ay, bx, by):
    """Write the ``midpoint_cone`` of rays a, b (no extension) into rows ``first``..."""
    px, py, kx, ky, s, ds_dpx, ds_dpy = midpoint_cone(ax, ay, bx, by, 0.0)
    out[first, n], out[first + 1, n], out[first + 2, n], out[first + 3, n] = px, py, kx, ky
    out[first + 4, n], out[first + 5, n], out[first + 6, n] = s, ds_dpx, ds_dpy



@kernel
def _add_horizon_term(block, column, distance, ddx, ddy, inv_horizon, vx, vy):
    """Add (d / tau)(|p| - s) to h and its rate to Lf h of a midpoint cone (rows 2-8, 9-10)."""
    px, py, s = block[2, column], block[3, column], block[6, column]
    p_norm = max(math.sqrt(px * px + py * py), _TINY)
    gap = p_norm - s
    grad_x = gap * ddx + distance * (px / p_norm - block[7, column])
    grad_y = gap * ddy + distance * (py / p_norm - block[8, column])
    block[PLANE_ROWS, column] += inv_horizon * distance * gap
    block[PLANE_ROWS + 1, column] += inv_horizon * (grad_x * vx + grad_y * vy)



@kernel(signature('void', F2, F2, F2, F2, F2, I1, F2, 'b1', F2, B1))
def _horizon_cones(x, y, edge_x, edge_y, inv_sq, counts, viewpoints, bisector, out, valid):
    """Write the cone (midpoint or bisector axis) of every polygon seen from ``viewpoints``."""
    shared = viewpoints.shape[1] == 1
    for n in range(counts.shape[0]):
        j = 0 if shared else n
        qx, qy = viewpoints[0, j], viewpoints[1, j]
        a, b, seen = silhouette(x, y, counts[n], n, qx, qy)
        if bisector:
            cone = _bisector_cone(x, y, counts[n], n, qx, qy, a, b)
            out[0, n], out[1, n], out[2, n], out[3, n] = cone[0], cone[1], cone[2], cone[3]
            out[4, n], out[5, n], out[6, n] = cone[4], cone[5], cone[6]
            valid[n] = seen and cone[7][6] > _TINY
        else:
            _store_midpoint(out, 0, n, x[n, a] - qx, y[n, a] - qy, x[n, b] - qx, y[n, b] - qy)
            valid[n] = seen



@kernel(signature('void', F2, F2, F2, F2, F2, I1, I2, 'f8', 'b1', F3, F1, F2, F2, 'f8', F1, F1,
                  F2, 'f8', F2, B1))
def _horizon_plane(x, y, edge_x, edge_y, inv_sq, counts, hints, inv_horizon, bisector,
                   projections, position, velocities, offsets, age, position_rate, drift,
                   input_matrix, velocity_epsilon, block, valid):
    """Per polygon: viewpoint, cone, distance and h_tau terms (``ConeModel.fill_plane``).

    ``hints``: each polygon's nearest edge and silhouette last time (``hinted_seen_edge``,
    ``hinted_silhouette``), updated.
    """
    eps_sq = velocity_epsilon * velocity_epsilon
    for n in range(counts.shape[0]):
        qx, qy = viewpoint(projections, position, velocities, offsets, age, n)
        block[0, n], block[1, n] = qx, qy
        a, b, seen = hinted_silhouette(x, y, counts[n], n, qx, qy, hints)
        distance, ddx, ddy = _boundary_distance(x, y, edge_x, edge_y, inv_sq, counts[n], n,
                                                qx, qy, a, b, seen, hints)
        if bisector:
            cone = _bisector_cone(x, y, counts[n], n, qx, qy, a, b)
            block[2, n], block[3, n], block[4, n], block[5, n] = cone[0], cone[1], cone[2], cone[3]
            block[6, n], block[7, n], block[8, n] = cone[4], cone[5], cone[6]
            valid[n] = seen and cone[7][6] > _TINY
            _bisector_terms(cone[7], distance, ddx, ddy, inv_horizon, projections, velocities,
                            position_rate, drift, input_matrix, eps_sq, block, PLANE_ROWS, n)
        else:
            _store_midpoint(block, 2, n, x[n, a] - qx, y[n, a] - qy, x[n, b] - qx,
                            y[n, b] - qy)
            valid[n] = seen
            vx, vy = barrier_column(block[2, n], block[3, n], block[6, n], block[7, n],
                                    block[8, n], projections, velocities, position_rate, drift,
                                    input_matrix, eps_sq, block, PLANE_ROWS, n)
            _add_horizon_term(block, n, distance, ddx, ddy, inv_horizon, vx, vy)



@kernel
def _misses_box(box, qx, qy, dx, dy):
    """Return True when the ray from q along d meets no point of ``box`` (as ``box_gap``).

    So when the box lies strictly on one side of the line through q along d (cross(d,
    c - q) of one strict sign at every corner c), or none of it ahead of q (<d, c - q> <= 0
    at every corner; always when d = 0): the box is convex, so what holds at its corners
    holds at every point of it.  Both are linear in c, so the signs of dx, dy pick the
    corner where each is smallest or largest, and three corners decide.
    """
    low_x, high_x, low_y, high_y = box
    right_x, right_y = (high_x if dy > 0.0 else low_x), (low_y if dx > 0.0 else high_y)
    left_x, left_y = (low_x if dy > 0.0 else high_x), (high_y if dx > 0.0 else low_y)
    front_x, front_y = (high_x if dx > 0.0 else low_x), (high_y if dy > 0.0 else low_y)
    return (dx * (right_y - qy) - dy * (right_x - qx) > 0.0
            or dx * (left_y - qy) - dy * (left_x - qx) < 0.0
            or dx * (front_x - qx) + dy * (front_y - qy) <= 0.0)



@kernel
def _value(x, y, edge_x, edge_y, inv_sq, count, n, qx, qy, vx, vy, inv_horizon, bisector,
           eps_sq):
    """Return h_tau of polygon n seen from q with relative velocity v; inf where no cone."""
    a, b, seen = silhouette(x, y, count, n, qx, qy)
    if not seen:
        return math.inf
    distance = math.sqrt(nearest_seen_edge(x, y, edge_x, edge_y, inv_sq, count, n, qx, qy, a,
                                           b)[0])
    ax, ay, bx, by = x[n, a] - qx, y[n, a] - qy, x[n, b] - qx, y[n, b] - qy
    speed = math.sqrt(vx * vx + vy * vy + eps_sq)
    if bisector:
        length, _, _, ux, uy, c, m_norm, _, _, _ = _bisector_frame(x, y, count, n, qx, qy,
                                                                   ax, ay, bx, by)
        if not m_norm > _TINY:
            return math.inf
        return length * (ux * vx + uy * vy + speed * c + inv_horizon * distance * (1.0 - c))
    px, py, _, _, shape, _, _ = midpoint_cone(ax, ay, bx, by, 0.0)
    gap = max(math.sqrt(px * px + py * py), _TINY) - shape
    return px * vx + py * vy + speed * shape + inv_horizon * distance * gap



@kernel
def _group_heads_past(group, box, first_time, last_time, ovx, ovy, ox, oy, inv_horizon):
    """Return True when ``min_h_along``'s point tests skip every row of a group.

    The group's rows (``path_groups``) at times in [first_time, last_time], relative to a
    part moved by o and moving at (ovx, ovy).  Each bound below is the row tests' own
    arithmetic on the group's extremes (``group_box``; ``ovx - pvx`` is monotone in pvx),
    and rounding is monotone, so it bounds every row's value as the row test computes it.
    Far: inv_tau gap(group box) >= |w| at the largest |w_x|, |w_y| of the group.  Heads
    past (``_misses_box`` along d = -w): where the signs of d_x, d_y are the same at every
    row, the three corners are, and one of the three tests holds for all rows: its two
    products' ranges (``product_range``) do not overlap (a rounded difference or sum of
    two floats has the sign of the exact one).
    """
    low_qx, high_qx, low_qy, high_qy = group_box(group, first_time, last_time, ovx, ovy,
                                                 ox, oy)
    low_wx, high_wx = ovx - group[5], ovx - group[4]
    low_wy, high_wy = ovy - group[7], ovy - group[6]
    wx, wy = max(abs(low_wx), abs(high_wx)), max(abs(low_wy), abs(high_wy))
    if inv_horizon * box_gap(low_qx, high_qx, low_qy, high_qy, box) >= math.sqrt(
            wx * wx + wy * wy):
        return True
    low_dx, high_dx, low_dy, high_dy = -high_wx, -low_wx, -high_wy, -low_wy
    if (low_dx > 0.0) != (high_dx > 0.0) or (low_dy > 0.0) != (high_dy > 0.0):
        return False
    low_x, high_x, low_y, high_y = box
    right_x, right_y = (high_x if low_dy > 0.0 else low_x), (low_y if low_dx > 0.0 else high_y)
    left_x, left_y = (low_x if low_dy > 0.0 else high_x), (high_y if low_dx > 0.0 else low_y)
    front_x, front_y = (high_x if low_dx > 0.0 else low_x), (high_y if low_dy > 0.0 else low_y)
    cross_y = product_range(low_dx, high_dx, right_y - high_qy, right_y - low_qy)
    cross_x = product_range(low_dy, high_dy, right_x - high_qx, right_x - low_qx)
    if cross_y[0] > cross_x[1]:
        return True
    cross_y = product_range(low_dx, high_dx, left_y - high_qy, left_y - low_qy)
    cross_x = product_range(low_dy, high_dy, left_x - high_qx, left_x - low_qx)
    if cross_y[1] < cross_x[0]:
        return True
    ahead_x = product_range(low_dx, high_dx, front_x - high_qx, front_x - low_qx)
    ahead_y = product_range(low_dy, high_dy, front_y - high_qy, front_y - low_qy)
    return ahead_x[1] + ahead_y[1] <= 0.0



@kernel(signature('b1', F2, 'f8', 'f8', F2, F2, F2, 'f8'))
def stop_heads_past(bands, first_time, last_time, boxes, velocities, offsets, inv_horizon):
    """Return True when ``min_h_along`` (bisector axis) skips every row a stop's bands hold.

    ``bands`` (``RobotModel.stop_bands``): every row, the start too, at a time in
    [first_time, last_time], has its position in the bands' box and its velocity in one
    band's; each band passes ``_group_heads_past`` for every part, whole or split where
    d = p_dot - o_dot changes sign (``_split_heads_past``).  Then every row's point tests
    hold and the minimum is +inf.
    """
    part = np.empty(9)
    square = bands[0, 8]
    for b in range(1, bands.shape[0]):
        square = max(square, bands[b, 8])
    fastest = math.sqrt(square)
    moved = max(abs(first_time), abs(last_time))
    for n in range(boxes.shape[0]):
        ovx, ovy, ox, oy = velocities[n, 0], velocities[n, 1], offsets[n, 0], offsets[n, 1]
        box = boxes[n, 0], boxes[n, 1], boxes[n, 2], boxes[n, 3]
        obstacle_speed = math.sqrt(ovx * ovx + ovy * ovy)
        reach = moved * obstacle_speed
        if inv_horizon * box_gap(bands[0, 0] - ox - reach, bands[0, 1] - ox + reach,
                                 bands[0, 2] - oy - reach, bands[0, 3] - oy + reach,
                                 box) >= fastest + obstacle_speed:
            continue  # min_h_along's own test on the whole path
        for b in range(bands.shape[0]):
            if not (_group_heads_past(bands[b], box, first_time, last_time, ovx, ovy, ox, oy,
                                      inv_horizon)
                    or _split_heads_past(bands[b], part, box, first_time, last_time, ovx,
                                         ovy, ox, oy, inv_horizon)):
                return False
    return True



@kernel
def _split_heads_past(band, part, box, first_time, last_time, ovx, ovy, ox, oy, inv_horizon):
    """Return True when ``_group_heads_past`` holds on each sign class of a band's d.

    d_x = p_dot_x - o_dot_x > 0 exactly where p_dot_x > o_dot_x (a rounded difference has
    the exact one's sign): [low, o_dot_x] and [next float above o_dot_x, high] split a
    range that holds o_dot_x; the same in y.  ``part`` (9,) is scratch.
    """
    part[0], part[1], part[2], part[3] = band[0], band[1], band[2], band[3]
    x_split = band[4] <= ovx < band[5]
    y_split = band[6] <= ovy < band[7]
    if not (x_split or y_split):
        return False
    for side_x in range(2 if x_split else 1):
        part[4] = np.nextafter(ovx, math.inf) if x_split and side_x else band[4]
        part[5] = ovx if x_split and not side_x else band[5]
        for side_y in range(2 if y_split else 1):
            part[6] = np.nextafter(ovy, math.inf) if y_split and side_y else band[6]
            part[7] = ovy if y_split and not side_y else band[7]
            if not _group_heads_past(part, box, first_time, last_time, ovx, ovy, ox, oy,
                                     inv_horizon):
                return False
    return True



@kernel(signature('f8', F2, F2, F2, F2, F2, I1, F2, 'f8', 'b1', F2, F2, 'f8', F1, F2, 'f8',
                  'f8'))
def min_h_along(x, y, edge_x, edge_y, inv_sq, counts, boxes, inv_horizon, bisector, velocities,
                offsets, age, start, path, period, eps_sq):
    """Return the smallest h_tau of any polygon at ``start`` and every ``path`` row.

    ``start`` and the rows are the reference point's [x, y, vx, vy], ``start`` at ``age``
    and row k at age + (k + 1) period; polygon n (bounding box ``boxes[n]``, as
    ``cones.PlanarPolygons``) has moved by ``offsets[n]`` and moves at ``velocities[n]``.
    Points inside a polygon (no cone) are left out, as the filter leaves such a part out
    of its rows.  Pruning (bisector axis) is exact, it skips only
    points with h_tau >= 0; w is the relative velocity and
    h_tau = L [<u, w> + |w|_e c + (d / tau)(1 - c)], c = cos(half-angle) >= 0,
    |w|_e >= |w|.  First, h_tau >= L (1 - c)(d / tau - |w|): a point whose distance to the
    polygon's bounding box is at least tau |w| is not evaluated, nor is a polygon for which
    that holds along the whole path.  Second, the robot's velocity relative to the polygon,
    -w: where the ray from q along -w misses the bounding box (``_misses_box``), -w lies
    outside the cone of the polygon's silhouette rays (that cone is spanned by points of
    the polygon, inside the box), so its angle to the axis u exceeds the half-angle:
    <u, -w> < |w| c, and h_tau > 0 (or w = 0, and h_tau >= 0).  The midpoint axis's s can
    be negative close to a polygon, so there every point is evaluated.  +inf when nothing
    is evaluated; so the value is exact where it is negative, and otherwise only >= 0.
    The rows are taken a group at a time (``path_groups``): a group whose every row these
    two tests skip (``_group_heads_past``, on the group's bounds) is skipped whole, so the
    value is the one the tests taken row by row give, bit for bit.
    """
    rows = path.shape[0]
    low_x = high_x = start[0]
    low_y = high_y = start[1]
    square = start[2] * start[2] + start[3] * start[3]
    size = group_size(rows)
    groups = path_groups(path, size, True)
    for g in range(groups.shape[0]):
        low_x, high_x = min(low_x, groups[g, 0]), max(high_x, groups[g, 1])
        low_y, high_y = min(low_y, groups[g, 2]), max(high_y, groups[g, 3])
        square = max(square, groups[g, 8])
    fastest = math.sqrt(square)  # the largest |v| of the rows: sqrt is monotone
    moved = max(abs(age), abs(age + rows * period))
    best = math.inf
    for n in range(counts.shape[0]):
        ovx, ovy = velocities[n, 0], velocities[n, 1]
        obstacle_speed = math.sqrt(ovx * ovx + ovy * ovy)
        reach = moved * obstacle_speed
        ox, oy = offsets[n, 0], offsets[n, 1]
        box = boxes[n, 0], boxes[n, 1], boxes[n, 2], boxes[n, 3]
        gap = box_gap(low_x - ox - reach, high_x - ox + reach, low_y - oy - reach,
                      high_y - oy + reach, box)
        if bisector and inv_horizon * gap >= fastest + obstacle_speed:
            continue
        best = min(best, _point_h(x, y, edge_x, edge_y, inv_sq, counts[n], n, box, start[0],
                                  start[1], start[2], start[3], age, ovx, ovy, ox, oy,
                                  inv_horizon, bisector, eps_sq))
        for g in range(groups.shape[0]):
            first = g * size
            end = min(first + size, rows)
            if bisector and _group_heads_past(groups[g], box, age + (first + 1) * period,
                                              age + end * period, ovx, ovy, ox, oy,
                                              inv_horizon):
                continue
            for k in range(first, end):
                best = min(best, _point_h(x, y, edge_x, edge_y, inv_sq, counts[n], n, box,
                                          path[k, 0], path[k, 1], path[k, 2], path[k, 3],
                                          age + (k + 1) * period, ovx, ovy, ox, oy,
                                          inv_horizon, bisector, eps_sq))
    return best



@kernel
def _point_h(x, y, edge_x, edge_y, inv_sq, count, n, box, px, py, pvx, pvy, t, ovx, ovy, ox,
             oy, inv_horizon, bisector, eps_sq):
    """Return h_tau of polygon n at the point (px, py) moving at (pvx, pvy) at time t.

    inf where skipped.

    Skipped (bisector axis) where the point heads past the box or lies tau |w| from it
    (``min_h_along``).
    """
    qx, qy = px - t * ovx - ox, py - t * ovy - oy
    vx, vy = ovx - pvx, ovy - pvy
    if bisector and (_misses_box(box, qx, qy, -vx, -vy) or inv_horizon * box_gap(
            qx, qx, qy, qy, box) >= math.sqrt(vx * vx + vy * vy)):
        return math.inf
    return _value(x, y, edge_x, edge_y, inv_sq, count, n, qx, qy, vx, vy, inv_horizon,
                  bisector, eps_sq)
