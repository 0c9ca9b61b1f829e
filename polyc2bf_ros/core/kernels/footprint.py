"""Kernels of ``barrier.footprint_cone``, whose docstring has the math.

The math in compiled form; every kernel lives in ``core/kernels`` (``jit.kernel_sources``).
"""
import math

import numpy as np

from polyc2bf_ros.core.kernels.cones import PLANE_ROWS, silhouette
from polyc2bf_ros.core.kernels.jit import B1, F1, F2, I1, kernel, signature

_TINY = 1e-12


@kernel
def _reflected(footprint, j, cos, sin):
    """Return -R(theta) f_j, footprint vertex j turned to the heading and reflected."""
    fx, fy = footprint[0, j], footprint[1, j]
    return -(cos * fx - sin * fy), -(sin * fx + cos * fy)



@kernel
def configuration_polygon(x, y, count, n, footprint, cos, sin, cx, cy, feet):
    """Write C(theta) = O_n + (-R(theta) F) into ``cx[0]``, ``cy[0]``; return its vertex count.

    Both polygons CCW (a point reflection keeps the order); their edge sequences, each from
    its lowest (then leftmost) vertex, are merged by angle, parallel edges together, so C
    has at most n + m vertices.  ``feet[k]`` is j of vertex k = o_i + (-R f_j).
    """
    a = 0
    for k in range(1, count):
        if y[n, k] < y[n, a] or (y[n, k] == y[n, a] and x[n, k] < x[n, a]):
            a = k
    size = footprint.shape[1]
    b = 0
    low_x, low_y = _reflected(footprint, 0, cos, sin)
    for j in range(1, size):
        qx, qy = _reflected(footprint, j, cos, sin)
        if qy < low_y or (qy == low_y and qx < low_x):
            b, low_x, low_y = j, qx, qy
    i = j = vertices = 0
    while i < count or j < size:
        qx, qy = _reflected(footprint, b, cos, sin)
        cx[0, vertices], cy[0, vertices], feet[vertices] = x[n, a] + qx, y[n, a] + qy, b
        vertices += 1
        next_a = a + 1 if a + 1 < count else 0
        next_b = b + 1 if b + 1 < size else 0
        nqx, nqy = _reflected(footprint, next_b, cos, sin)
        cross = ((x[n, next_a] - x[n, a]) * (nqy - qy) - (y[n, next_a] - y[n, a]) * (nqx - qx))
        take_a = j == size or (i < count and cross >= 0.0)
        take_b = i == count or (j < size and cross <= 0.0)
        if take_a:
            i, a = i + 1, next_a
        if take_b:
            j, b = j + 1, next_b
    return vertices



@kernel
def nearest_boundary(cx, cy, count, qx, qy):
    """Return (k, t, w_x, w_y, inside): C's boundary point nearest q, w = it - q.

    On edge k (vertex k to k + 1) at t in [0, 1]; inside: q is left of (or on) every edge.
    """
    best, nearest, near_t, best_x, best_y, inside = math.inf, 0, 0.0, 0.0, 0.0, True
    for k in range(count):
        nxt = k + 1 if k + 1 < count else 0
        px, py = cx[0, k] - qx, cy[0, k] - qy
        ex, ey = cx[0, nxt] - cx[0, k], cy[0, nxt] - cy[0, k]
        square = ex * ex + ey * ey
        t = min(max(-(px * ex + py * ey) / square, 0.0), 1.0) if square > 0.0 else 0.0
        wx, wy = px + t * ex, py + t * ey
        if wx * wx + wy * wy < best:
            best, nearest, near_t, best_x, best_y = wx * wx + wy * wy, k, t, wx, wy
        inside = inside and ex * py <= ey * px
    return nearest, near_t, best_x, best_y, inside



@kernel(signature('void', F2, F2, I1, F2, 'f8', F2, F2))
def _footprint_exits(x, y, counts, footprint, theta, viewpoints, out):
    """Write the shortest way out of each C(theta) for the axle at ``viewpoints`` into ``out``.

    Column n: the unit direction from the axle q (``viewpoints`` column n, or 0 when it
    has one) to C's nearest boundary point, and its depth |w| where q lies inside C (the
    bodies overlap: no cone), else -|w|.
    """
    width = x.shape[1] + footprint.shape[1]
    cx, cy = np.empty((1, width)), np.empty((1, width))
    feet = np.empty(width, dtype=np.int64)
    cos, sin = math.cos(theta), math.sin(theta)
    for n in range(counts.shape[0]):
        column = n if viewpoints.shape[1] > 1 else 0
        qx, qy = viewpoints[0, column], viewpoints[1, column]
        count = configuration_polygon(x, y, counts[n], n, footprint, cos, sin, cx, cy, feet)
        _, _, wx, wy, inside = nearest_boundary(cx, cy, count, qx, qy)
        depth = math.sqrt(wx * wx + wy * wy)
        scale = 1.0 / depth if depth > _TINY else 0.0
        out[0, n], out[1, n] = wx * scale, wy * scale
        out[2, n] = depth if inside else -depth



@kernel(signature('void', F2, F2, I1, F2, F1, F2, F2, 'f8', 'f8', 'f8', 'f8', 'f8', 'f8', F2,
                  B1))
def _footprint_plane(x, y, counts, footprint, state, velocities, offsets, age, inv_horizon,
                     eps_sq, accel, velocity_error, gamma, block, valid):
    """Per part: viewpoint c, the bisector horizon cone on C(theta) and its h, Lf h, Lg h.

    ``state`` the unicycle's [x, y, theta, v, omega] at the axle, ``footprint`` (2, m) CCW
    in the body frame; part n has moved by ``offsets[n]`` and moves at ``velocities[n]``.
    Rows 0-1 of ``block`` the viewpoint, 2-6 p = L u, the nearer ray, s = L c
    (``horizon_cone``'s bisector cone), 7-8 dh/do (every vertex moved alike), then h, Lf h
    and Lg h (a, alpha); a moving part's Lf h is made robust to ``accel`` and
    ``velocity_error`` as ``barrier.tighten_for_obstacle_accel`` does (footprint_cone).
    """
    width = x.shape[1] + footprint.shape[1]
    cx, cy = np.empty((1, width)), np.empty((1, width))
    feet = np.empty(width, dtype=np.int64)
    theta, speed, omega = state[2], state[3], state[4]
    cos, sin = math.cos(theta), math.sin(theta)
    cover = 0.0
    for j in range(footprint.shape[1]):
        cover = max(cover, math.hypot(footprint[0, j], footprint[1, j]))
    for n in range(counts.shape[0]):
        ovx, ovy = velocities[n, 0], velocities[n, 1]
        qx = state[0] - age * ovx - offsets[n, 0]
        qy = state[1] - age * ovy - offsets[n, 1]
        block[0, n], block[1, n] = qx, qy
        count = configuration_polygon(x, y, counts[n], n, footprint, cos, sin, cx, cy, feet)
        ia, ib, seen = silhouette(cx, cy, count, 0, qx, qy)
        k, t, wx, wy, _ = nearest_boundary(cx, cy, count, qx, qy)
        valid[n] = _footprint_column(cx, cy, count, feet, footprint, ia, ib, seen, k, t, wx,
                                     wy, qx, qy, cos, sin, speed, omega, ovx, ovy,
                                     inv_horizon, eps_sq, accel, velocity_error, gamma,
                                     cover, block, n)



@kernel
def _footprint_column(cx, cy, count, feet, footprint, ia, ib, seen, k, t, wx, wy, qx, qy, cos,
                      sin, speed, omega, ovx, ovy, inv_horizon, eps_sq, accel, velocity_error,
                      gamma, cover, block, n):
    """Write column n of ``_footprint_plane``'s block; return False where no cone exists.

    ``cover``: the footprint's covering radius, over which the turning share sigma of v
    fades (``footprint_cone``).
    """
    ax, ay, bx, by = cx[0, ia] - qx, cy[0, ia] - qy, cx[0, ib] - qx, cy[0, ib] - qy
    a_norm = max(math.sqrt(ax * ax + ay * ay), _TINY)
    b_norm = max(math.sqrt(bx * bx + by * by), _TINY)
    ahx, ahy, bhx, bhy = ax / a_norm, ay / a_norm, bx / b_norm, by / b_norm
    mx, my = ahx + bhx, ahy + bhy
    m_norm = math.sqrt(mx * mx + my * my)
    for row in range(2, block.shape[0]):
        block[row, n] = 0.0
    if not seen or not m_norm > _TINY:
        return False
    ux, uy, c = mx / m_norm, my / m_norm, 0.5 * m_norm
    # The vertex mean g (relative to q) and the mean footprint vertex behind C's vertices.
    gx = gy = mean_fx = mean_fy = 0.0
    for j in range(count):
        gx += cx[0, j] - qx
        gy += cy[0, j] - qy
        mean_fx += footprint[0, feet[j]]
        mean_fy += footprint[1, feet[j]]
    gx, gy, mean_fx, mean_fy = gx / count, gy / count, mean_fx / count, mean_fy / count
    length = max(math.sqrt(gx * gx + gy * gy), _TINY)
    # The touching footprint point f* (on C's nearest edge k, k1 at t) and v.
    k1 = k + 1 if k + 1 < count else 0
    fkx, fky = footprint[0, feet[k]], footprint[1, feet[k]]
    fk1x, fk1y = footprint[0, feet[k1]], footprint[1, feet[k1]]
    fsx, fsy = (1.0 - t) * fkx + t * fk1x, (1.0 - t) * fky + t * fk1y
    rfx, rfy = cos * fsx - sin * fsy, sin * fsx + cos * fsy  # R f*
    # The touching points' velocity (the vertices' rates build on it) and the barrier's v,
    # whose turning share sigma = 1 - d / r fades out at the covering radius r.
    true_x, true_y = ovx - speed * cos + omega * rfy, ovy - speed * sin - omega * rfx
    distance = math.sqrt(wx * wx + wy * wy)
    sigma = max(0.0, 1.0 - distance / cover)
    vx, vy = ovx - speed * cos + sigma * omega * rfy, ovy - speed * sin - sigma * omega * rfx
    # sigma_dot = -d_dot / r inside (0, r): d_dot = <w, v_true> / d.
    sigma_dot = (-(wx * true_x + wy * true_y) / (distance * cover)
                 if 0.0 < distance < cover else 0.0)
    along = ux * vx + uy * vy
    norm_v = math.sqrt(vx * vx + vy * vy + eps_sq)
    inner = along + norm_v * c + inv_horizon * distance * (1.0 - c)
    dh_dvx, dh_dvy = length * (ux + c * vx / norm_v), length * (uy + c * vy / norm_v)
    scale = 0.5 * (norm_v - inv_horizon * distance)
    dh_dmx = length * ((vx - along * ux) / m_norm + scale * ux)
    dh_dmy = length * ((vy - along * uy) / m_norm + scale * uy)
    # dh/dP for the special vertices: the rays' ends (through m) and the nearest edge's
    # ends (through d); every vertex also has inner g_hat / count (through L = |g|).
    da_x = ((1.0 - ahx * ahx) * dh_dmx - ahx * ahy * dh_dmy) / a_norm
    da_y = (-ahx * ahy * dh_dmx + (1.0 - ahy * ahy) * dh_dmy) / a_norm
    db_x = ((1.0 - bhx * bhx) * dh_dmx - bhx * bhy * dh_dmy) / b_norm
    db_y = (-bhx * bhy * dh_dmx + (1.0 - bhy * bhy) * dh_dmy) / b_norm
    dd = length * (1.0 - c) * inv_horizon / distance if distance > 0.0 else 0.0
    dk_x, dk_y = dd * (1.0 - t) * wx, dd * (1.0 - t) * wy
    dk1_x, dk1_y = dd * t * wx, dd * t * wy
    common_x, common_y = inner * gx / length, inner * gy / length
    # Vertex rates P_j_dot = v + omega J R (f* - f_j): only f_j differs between vertices.
    geometric = (common_x * _rate_x(true_x, omega, cos, sin, fsx - mean_fx, fsy - mean_fy)
                 + common_y * _rate_y(true_y, omega, cos, sin, fsx - mean_fx, fsy - mean_fy))
    for vertex, gx_, gy_ in ((ia, da_x, da_y), (ib, db_x, db_y), (k, dk_x, dk_y),
                             (k1, dk1_x, dk1_y)):
        dfx, dfy = fsx - footprint[0, feet[vertex]], fsy - footprint[1, feet[vertex]]
        geometric += (gx_ * _rate_x(true_x, omega, cos, sin, dfx, dfy)
                      + gy_ * _rate_y(true_y, omega, cos, sin, dfx, dfy))
    # f*_dot: t slides along the nearest edge while inside (0, 1); f* stays at a vertex.
    t_dot = 0.0
    if 0.0 < t < 1.0:
        px, py = cx[0, k] - qx, cy[0, k] - qy
        ex, ey = cx[0, k1] - cx[0, k], cy[0, k1] - cy[0, k]
        rkx = _rate_x(true_x, omega, cos, sin, fsx - fkx, fsy - fky)
        rky = _rate_y(true_y, omega, cos, sin, fsx - fkx, fsy - fky)
        erx = _rate_x(true_x, omega, cos, sin, fsx - fk1x, fsy - fk1y) - rkx
        ery = _rate_y(true_y, omega, cos, sin, fsx - fk1x, fsy - fk1y) - rky
        square = ex * ex + ey * ey
        t_dot = (-(rkx * ex + rky * ey) - (px * erx + py * ery)
                 - 2.0 * t * (ex * erx + ey * ery)) / square
    fdx, fdy = t_dot * (fk1x - fkx), t_dot * (fk1y - fky)
    rdx, rdy = cos * fdx - sin * fdy, sin * fdx + cos * fdy  # R f*_dot
    # v_dot = -(a e + v omega J e) + sigma (-alpha J R f* + omega^2 R f* - omega J R f*_dot)
    #         - sigma_dot omega J R f*.
    drift_x = (speed * omega * sin + sigma * (omega * omega * rfx + omega * rdy)
               + sigma_dot * omega * rfy)
    drift_y = (-speed * omega * cos + sigma * (omega * omega * rfy - omega * rdx)
               - sigma_dot * omega * rfx)
    lf = geometric + dh_dvx * drift_x + dh_dvy * drift_y
    shift_x = common_x + da_x + db_x + dk_x + dk1_x
    shift_y = common_y + da_y + db_y + dk_y + dk1_y
    if ovx != 0.0 or ovy != 0.0:
        dh_dv = math.sqrt(dh_dvx * dh_dvx + dh_dvy * dh_dvy)
        lf -= accel * dh_dv + velocity_error * (math.sqrt(shift_x * shift_x + shift_y * shift_y)
                                                + gamma * dh_dv)
    near_x, near_y = (ax, ay) if a_norm <= b_norm else (bx, by)
    block[2, n], block[3, n], block[4, n], block[5, n] = length * ux, length * uy, near_x, near_y
    block[6, n], block[7, n], block[8, n] = length * c, shift_x, shift_y
    block[PLANE_ROWS, n], block[PLANE_ROWS + 1, n] = length * inner, lf
    block[PLANE_ROWS + 2, n] = -(dh_dvx * cos + dh_dvy * sin)
    block[PLANE_ROWS + 3, n] = -sigma * (dh_dvx * -rfy + dh_dvy * rfx)  # -sigma dh/dv.J R f*
    return True



@kernel
def _rate_x(vx, omega, cos, sin, dfx, dfy):
    """Return the x of v + omega J R df (a vertex's rate, df = f* - f_j)."""
    return vx - omega * (sin * dfx + cos * dfy)



@kernel
def _rate_y(vy, omega, cos, sin, dfx, dfy):
    """Return the y of v + omega J R df."""
    return vy + omega * (cos * dfx - sin * dfy)

