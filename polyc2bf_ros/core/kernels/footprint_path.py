"""Kernels of ``barrier.footprint_cone`` along a braking path: ``min_h_along`` for a box.

``footprint_min_h_along`` is ``horizon.min_h_along`` for a turning footprint; its pruning
tests (``_far_from_box``, ``_sweeps_past`` and their group forms) hold only where h >= 0.
The math in compiled form; every kernel lives in ``core/kernels`` (``jit.kernel_sources``).
"""
import math

import numpy as np

from polyc2bf_ros.core.kernels.braking import (
    box_gap,
    group_box,
    group_size,
    path_groups,
    product_range,
)
from polyc2bf_ros.core.kernels.cones import PLANE_ROWS, silhouette
from polyc2bf_ros.core.kernels.footprint import (
    _footprint_column,
    configuration_polygon,
    nearest_boundary,
)
from polyc2bf_ros.core.kernels.jit import F1, F2, I1, kernel, signature


@kernel
def _value_at(x, y, count, n, footprint, cover, row, qx, qy, ovx, ovy, inv_horizon, eps_sq,
              cx, cy, feet, scratch):
    """Return h of part n at a path ``row`` [x, y, vx, vy, theta, omega]; inf: none.

    q: the row's axle relative to the part, which moves at (ovx, ovy);
    ``_footprint_column`` into the one-column ``scratch``.
    """
    cos, sin = math.cos(row[4]), math.sin(row[4])
    vertices = configuration_polygon(x, y, count, n, footprint, cos, sin, cx, cy, feet)
    ia, ib, seen = silhouette(cx, cy, vertices, 0, qx, qy)
    k, near_t, wx, wy, _ = nearest_boundary(cx, cy, vertices, qx, qy)
    if not _footprint_column(cx, cy, vertices, feet, footprint, ia, ib, seen, k, near_t, wx,
                             wy, qx, qy, cos, sin, row[2] * cos + row[3] * sin, row[5], ovx,
                             ovy, inv_horizon, eps_sq, 0.0, 0.0, 0.0, cover, scratch, 0):
        return math.inf
    return scratch[PLANE_ROWS, 0]



@kernel
def _far_from_box(box, cover, qx, qy, square, turn, obstacle_speed, inv_horizon):
    """Return True when h >= 0 at an axle q (relative to the part) surely: tau |v| <= distance.

    The footprint lies within ``cover`` of the axle, so its distance to the part is at
    least g - cover, g the axle's distance to the part's box; the touching points'
    relative speed |v| is at most |o_dot| + |c_dot| + |omega| cover (``square`` = |c_dot|^2,
    ``turn`` = |omega|); and h >= L (1 - cc) (d / tau - |v|) (``horizon_cone``'s bound with
    v the touching points').  Each operation rounds monotonically, so a box holding q, a
    larger ``square`` or ``turn`` give a test that holds only where this one does.
    """
    speed = obstacle_speed + math.sqrt(square) + turn * cover
    return inv_horizon * (box_gap(qx[0], qx[1], qy[0], qy[1], box) - cover) >= speed



@kernel
def _sweeps_past(box, cover, qx, qy, dx, dy, spread):
    """Return True when h > 0 at a row surely: the touching points head past the part.

    The robot's touching points move at d + e relative to the part, d = c_dot - o_dot and
    |e| <= ``spread`` = |omega| cover (``footprint_cone``: the turning share, s <= 1), and
    C(theta) lies in the part's box grown by ``cover`` on every side.  When every ray from
    q along any d + e misses that box, -v lies outside the silhouette cone of C(theta), so
    <u, v> + |v| c > 0 and h > 0 (``min_h_along``'s second test, here for a set of
    directions).  Sufficient, with r = corner - q at each of the four corners: cross(d, r)
    - spread |r| > 0 at all (the box lies left of every such ray), or cross(d, r) + spread
    |r| < 0 at all (right), or <d, r> + spread |r| < 0 at all (behind q).  The first two are
    concave in the corner and the last convex, so what holds at the corners holds over
    the box.
    """
    left = right = behind = True
    for corner in range(4):
        rx = (box[0] - cover if corner < 2 else box[1] + cover) - qx
        ry = (box[2] - cover if corner % 2 == 0 else box[3] + cover) - qy
        reach = spread * math.sqrt(rx * rx + ry * ry)
        cross = dx * ry - dy * rx
        left = left and cross - reach > 0.0
        right = right and cross + reach < 0.0
        behind = behind and dx * rx + dy * ry + reach < 0.0
    return left or right or behind



@kernel
def _group_sweeps_past(box, cover, qx, qy, dx, dy, spread):
    """Return True when ``_sweeps_past`` holds at every row of a group of rows.

    The group's axles lie in qx x qy (``group_box``), its d in dx x dy and its spreads are
    at most ``spread``.  Per corner, r = corner - q ranges over the corner less that box,
    |r| is at most its farthest point's, and cross(d, r), <d, r> range over
    ``product_range``'s sums; each bound is the row test's own arithmetic on the group's
    ends, and rounding is monotone, so a test that holds here holds at each row as
    ``_sweeps_past`` computes it.
    """
    left = right = behind = True
    for corner in range(4):
        corner_x = box[0] - cover if corner < 2 else box[1] + cover
        corner_y = box[2] - cover if corner % 2 == 0 else box[3] + cover
        low_rx, high_rx = corner_x - qx[1], corner_x - qx[0]
        low_ry, high_ry = corner_y - qy[1], corner_y - qy[0]
        reach = spread * math.sqrt(max(low_rx * low_rx, high_rx * high_rx)
                                   + max(low_ry * low_ry, high_ry * high_ry))
        low_a, high_a = product_range(dx[0], dx[1], low_ry, high_ry)
        low_b, high_b = product_range(dy[0], dy[1], low_rx, high_rx)
        left = left and (low_a - high_b) - reach > 0.0
        right = right and (high_a - low_b) + reach < 0.0
        ahead_x = product_range(dx[0], dx[1], low_rx, high_rx)[1]
        ahead_y = product_range(dy[0], dy[1], low_ry, high_ry)[1]
        behind = behind and (ahead_x + ahead_y) + reach < 0.0
        if not (left or right or behind):
            return False
    return left or right or behind



@kernel(signature('b1', F2, 'f8', 'f8', F2, F2, F2, 'f8', 'f8'))
def stop_sweeps_past(bands, first_time, last_time, boxes, velocities, offsets, cover,
                     inv_horizon):
    """Return True when ``footprint_min_h_along`` skips every row a stop's bands hold.

    ``bands`` (``RobotModel.stop_bands`` of the axle): every row, the start too, at a
    time in [first_time, last_time], has its axle in the bands' box, its velocity in one
    band's and |omega| at most column 9; each band passes the group tests
    (``_far_from_box``, ``_group_sweeps_past``) for every part, so every row's tests hold
    and the minimum is +inf.
    """
    square, turn = bands[0, 8], bands[0, 9]
    for b in range(1, bands.shape[0]):
        square, turn = max(square, bands[b, 8]), max(turn, bands[b, 9])
    moved = max(abs(first_time), abs(last_time))
    for n in range(boxes.shape[0]):
        ovx, ovy, ox, oy = velocities[n, 0], velocities[n, 1], offsets[n, 0], offsets[n, 1]
        obstacle_speed = math.hypot(ovx, ovy)
        box = boxes[n]
        reach = moved * obstacle_speed
        if _far_from_box(box, cover, (bands[0, 0] - ox - reach, bands[0, 1] - ox + reach),
                         (bands[0, 2] - oy - reach, bands[0, 3] - oy + reach), square, turn,
                         obstacle_speed, inv_horizon):
            continue  # footprint_min_h_along's own test on the whole path
        for b in range(bands.shape[0]):
            band = bands[b]
            low_qx, high_qx, low_qy, high_qy = group_box(band, first_time, last_time, ovx,
                                                         ovy, ox, oy)
            if not (_far_from_box(box, cover, (low_qx, high_qx), (low_qy, high_qy), band[8],
                                  band[9], obstacle_speed, inv_horizon)
                    or _group_sweeps_past(box, cover, (low_qx, high_qx), (low_qy, high_qy),
                                          (band[4] - ovx, band[5] - ovx),
                                          (band[6] - ovy, band[7] - ovy), band[9] * cover)):
                return False
    return True



@kernel(signature('f8', F2, F2, I1, F2, F2, 'f8', 'f8', 'f8', F2, F2, 'f8', F1, F2, 'f8'))
def footprint_min_h_along(x, y, counts, boxes, footprint, cover, inv_horizon, eps_sq,
                          velocities, offsets, age, start, path, period):
    """Return the smallest h of any part at ``start`` and every ``path`` row (footprint cone).

    ``horizon.min_h_along`` for a turning footprint: rows [x, y, vx, vy, theta, omega] of
    the axle (``unicycle.AxlePaths``), ``start`` at ``age`` and row k at age + (k + 1)
    period.  A row where the footprint overlaps a part (no cone) is left out, as the filter
    leaves such a part out of its rows.  Pruning (``_far_from_box``, ``_sweeps_past``)
    skips only rows where h >= 0, so the value is exact where negative, else only >= 0
    (+inf: nothing evaluated).  ``_far_from_box`` is also taken on the box of a group of
    rows (``path_groups``, ``group_box``) with its fastest speed and turn, and on the box
    of all of them, and ``_sweeps_past`` on a group's bounds (``_group_sweeps_past``):
    where they hold there they hold at each row, as computed, so the value is the rows'
    one at a time, bit for bit.  (Measured: without the group test, a box driving at 1 m/s
    between two rows of parts, at 1 kHz, tested each of its braking path's rows against
    every part near it, and this kernel cost more than the rest of the step.)
    """
    width = x.shape[1] + footprint.shape[1]
    cx, cy = np.empty((1, width)), np.empty((1, width))
    feet = np.empty(width, dtype=np.int64)
    scratch = np.empty((PLANE_ROWS + 4, 1))
    rows = path.shape[0]
    size = group_size(rows)
    groups = path_groups(path, size, True)
    turns = np.zeros(groups.shape[0])
    for k in range(rows):
        turns[k // size] = max(turns[k // size], abs(path[k, 5]))
    # The start and every group in one box, with their fastest speed and turn.
    low_x, high_x, low_y, high_y = start[0], start[0], start[1], start[1]
    square = start[2] * start[2] + start[3] * start[3]
    turn = abs(start[5])
    for g in range(groups.shape[0]):
        low_x, high_x = min(low_x, groups[g, 0]), max(high_x, groups[g, 1])
        low_y, high_y = min(low_y, groups[g, 2]), max(high_y, groups[g, 3])
        square, turn = max(square, groups[g, 8]), max(turn, turns[g])
    moved = max(abs(age), abs(age + rows * period))
    best = math.inf
    for n in range(counts.shape[0]):
        ovx, ovy, ox, oy = velocities[n, 0], velocities[n, 1], offsets[n, 0], offsets[n, 1]
        obstacle_speed = math.hypot(ovx, ovy)
        box = boxes[n]
        reach = moved * obstacle_speed
        if _far_from_box(box, cover, (low_x - ox - reach, high_x - ox + reach),
                         (low_y - oy - reach, high_y - oy + reach), square, turn,
                         obstacle_speed, inv_horizon):
            continue  # every row is that far
        best = min(best, _row_h(x, y, counts[n], n, footprint, cover, start, age, ovx, ovy,
                                ox, oy, obstacle_speed, box, inv_horizon, eps_sq, cx, cy, feet,
                                scratch))
        for g in range(groups.shape[0]):
            first, end = g * size, min((g + 1) * size, rows)
            low_qx, high_qx, low_qy, high_qy = group_box(
                groups[g], age + (first + 1) * period, age + end * period, ovx, ovy, ox, oy)
            if _far_from_box(box, cover, (low_qx, high_qx), (low_qy, high_qy), groups[g, 8],
                             turns[g], obstacle_speed, inv_horizon):
                continue  # so is every row of the group
            if _group_sweeps_past(box, cover, (low_qx, high_qx), (low_qy, high_qy),
                                  (groups[g, 4] - ovx, groups[g, 5] - ovx),
                                  (groups[g, 6] - ovy, groups[g, 7] - ovy), turns[g] * cover):
                continue  # every row heads past
            for k in range(first, end):
                best = min(best, _row_h(x, y, counts[n], n, footprint, cover, path[k],
                                        age + (k + 1) * period, ovx, ovy, ox, oy,
                                        obstacle_speed, box, inv_horizon, eps_sq, cx, cy, feet,
                                        scratch))
    return best



@kernel
def _row_h(x, y, count, n, footprint, cover, row, t, ovx, ovy, ox, oy, obstacle_speed, box,
           inv_horizon, eps_sq, cx, cy, feet, scratch):
    """Return h of part n at ``row`` at time t, or inf where a pruning test skips it.

    ``_far_from_box`` and ``_sweeps_past`` hold only where h >= 0.
    """
    qx, qy = row[0] - t * ovx - ox, row[1] - t * ovy - oy
    if _far_from_box(box, cover, (qx, qx), (qy, qy), row[2] * row[2] + row[3] * row[3],
                     abs(row[5]), obstacle_speed, inv_horizon):
        return math.inf
    if _sweeps_past(box, cover, qx, qy, row[2] - ovx, row[3] - ovy, abs(row[5]) * cover):
        return math.inf
    return _value_at(x, y, count, n, footprint, cover, row, qx, qy, ovx, ovy, inv_horizon,
                     eps_sq, cx, cy, feet, scratch)
