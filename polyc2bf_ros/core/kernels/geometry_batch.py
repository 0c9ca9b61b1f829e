"""Compiled geometry of whole obstacle sets: one kernel call per obstacle update.

Every new obstacle set (each obstacle message; each step while obstacles move)
is checked, laid out and, per cone model, inflated or circled.  Done per polygon
in Python that cost milliseconds for 50 polygons, more than the filter step; these
kernels loop over all polygons of a padded batch (``vertices`` (N, V, 2), each
polygon's first ``counts[n]`` slots, CCW) at a few hundred nanoseconds per polygon.

* ``convex_ccw``: at least 3 vertices, no zero-length edge, no right turn
  ``cross(e_{k-1}, e_k) >= -tol |e_{k-1}| |e_k|`` (tol = 1e-12) and no reversal
  (a straight turn with ``<e_{k-1}, e_k> < 0``), positive area, and the edge
  directions wind exactly once: with left turns only, the direction passes
  angle 0 (``e_{k-1,y} < 0 <= e_{k,y}``) once per turn, so a pentagram fails.
* ``minkowski_regular``: the Minkowski sum of a convex polygon P and the
  regular ``segments``-gon Q of circumradius R = r / cos(pi / segments) (which
  circumscribes the disk of radius r, so P + Q contains every point within r
  of P), q_j = R (cos theta_j, sin theta_j), theta_j = 2 pi j / s.  The
  boundary of P + Q is the edges of P and Q merged by angle: start at the sum
  of both lowest vertices (whose edges start at angle 0) and follow, each
  step, the edge that turns least, cross(e_P, e_Q) > 0 meaning e_P; at most
  n + s vertices, O(n + s) per polygon.
* ``enclosing_circles``: Welzl's incremental minimum enclosing circle (move a
  point outside the current circle onto its boundary), on a fixed shuffled
  order (expected O(n)).
* ``vertical_shadows``: per prism footprint the thin axis a (the edge normal
  of minimum width max <v, n> - min <v, n>, attained at an edge normal for a
  convex polygon), the shadow rectangle [s_min, s_max] x [z_min, z_max] in the
  (s = <a, xy>, z) plane and the extent of <l, xy>, l = (-a_y, a_x), the long axis.
"""
import math

import numpy as np

from polyc2bf_ros.core.kernels.cones import polygon_box
from polyc2bf_ros.core.kernels.jit import B1, F1, F2, F3, I1, kernel, signature

REL_TOL = 1e-12
"""Sine of the smallest angle treated as a real turn of a polygon boundary."""


@kernel(signature('void', F3, I1, B1))
def convex_ccw(vertices, counts, ok):
    """Write per polygon whether it is convex, CCW and simple (module docstring)."""
    for n in range(counts.shape[0]):
        count = counts[n]
        good = count >= 3
        area = 0.0
        crossings = 0
        k = 0
        while good and k < count:
            prev = k - 1 if k > 0 else count - 1
            nxt = k + 1 if k + 1 < count else 0
            in_x = vertices[n, k, 0] - vertices[n, prev, 0]
            in_y = vertices[n, k, 1] - vertices[n, prev, 1]
            out_x = vertices[n, nxt, 0] - vertices[n, k, 0]
            out_y = vertices[n, nxt, 1] - vertices[n, k, 1]
            turn = in_x * out_y - in_y * out_x
            out_sq = out_x * out_x + out_y * out_y
            tol = REL_TOL * math.sqrt((in_x * in_x + in_y * in_y) * out_sq)
            straight_back = abs(turn) <= tol and in_x * out_x + in_y * out_y < 0.0
            good = out_sq > 0.0 and turn >= -tol and not straight_back
            if in_y < 0.0 <= out_y:
                crossings += 1
            area += ((vertices[n, k, 0] - vertices[n, 0, 0]) * out_y
                     - (vertices[n, k, 1] - vertices[n, 0, 1]) * out_x)
            k += 1
        ok[n] = good and area > 0.0 and crossings == 1


@kernel(signature('b1', F2, I1, F3))
def pad(points, counts, vertices):
    """Copy concatenated polygons (sum of counts, 2) into (N, V, 2), repeating each last vertex.

    Return True when every coordinate is finite.
    """
    finite = True
    start = 0
    for n in range(counts.shape[0]):
        for k in range(vertices.shape[1]):
            source = start + min(k, counts[n] - 1)
            vertices[n, k, 0], vertices[n, k, 1] = points[source, 0], points[source, 1]
        for k in range(counts[n]):
            finite = (finite and math.isfinite(points[start + k, 0])
                      and math.isfinite(points[start + k, 1]))
        start += counts[n]
    return finite


@kernel(signature('void', F2, F2, I1, F2, F2, F2, F2))
def edge_rows(x, y, counts, edge_x, edge_y, inv_sq, boxes):
    """Fill the edges v_next(k) - v_k and 1 / |e|^2 (0 for a zero edge) of (N, W) vertex rows.

    Padding slots (k >= counts[n]) repeat the last vertex in ``x``, ``y`` (written here)
    and the closing edge in the edge rows.  ``boxes`` (N, 4): each polygon's bounding box
    (``cones.polygon_box``).
    """
    for n in range(counts.shape[0]):
        boxes[n, 0], boxes[n, 1], boxes[n, 2], boxes[n, 3] = polygon_box(x, y, counts[n], n)
        last = counts[n] - 1
        for k in range(x.shape[1]):
            if k > last:
                x[n, k], y[n, k] = x[n, last], y[n, last]
            nxt = k + 1 if k < last else 0
            ex, ey = x[n, nxt] - x[n, k], y[n, nxt] - y[n, k]
            square = ex * ex + ey * ey
            edge_x[n, k], edge_y[n, k] = ex, ey
            inv_sq[n, k] = 1.0 / square if square > 0.0 else 0.0


@kernel
def _next(k, count):
    """Return k + 1 modulo count, for 0 <= k < count."""
    return k + 1 if k + 1 < count else 0


@kernel
def _lowest(x, y, count):
    """Return the index of the lowest vertex (smallest y, then smallest x)."""
    best = 0
    for k in range(1, count):
        if y[k] < y[best] or (y[k] == y[best] and x[k] < x[best]):
            best = k
    return best


@kernel(signature('void', F3, I1, 'f8', 'i8', F2, F2, I1))
def minkowski_regular(vertices, counts, radius, segments, x, y, out_counts):
    """Write the Minkowski sums P_n + Q as (N, V + segments) vertex rows (module docstring).

    Both edge sequences, each from its lowest vertex, are merged by angle: the edge of P
    comes first while cross(e_P, e_Q) > 0; parallel edges are taken together.  Rows are
    left unpadded (``edge_rows`` pads them).
    """
    reach = radius / math.cos(math.pi / segments)
    qx = np.empty(segments)
    qy = np.empty(segments)
    for j in range(segments):
        qx[j] = reach * math.cos(2.0 * math.pi * j / segments)
        qy[j] = reach * math.sin(2.0 * math.pi * j / segments)
    q0 = _lowest(qx, qy, segments)
    for n in range(counts.shape[0]):
        count = counts[n]
        px, py = vertices[n, :, 0], vertices[n, :, 1]
        p0 = _lowest(px, py, count)
        a, b, a1, b1 = p0, q0, _next(p0, count), _next(q0, segments)
        i = j = m = 0
        while i < count or j < segments:
            x[n, m], y[n, m] = px[a] + qx[b], py[a] + qy[b]
            m += 1
            cross = (px[a1] - px[a]) * (qy[b1] - qy[b]) - (py[a1] - py[a]) * (qx[b1] - qx[b])
            take_p = j == segments or (i < count and cross >= 0.0)
            take_q = i == count or (j < segments and cross <= 0.0)
            if take_p:
                i, a, a1 = i + 1, a1, _next(a1, count)
            if take_q:
                j, b, b1 = j + 1, b1, _next(b1, segments)
        out_counts[n] = m


@kernel
def _circle_through_three(ax, ay, bx, by, cx, cy):
    """Return (centre x, centre y, radius) of the circumcircle, or the widest pair's circle."""
    abx, aby, acx, acy = bx - ax, by - ay, cx - ax, cy - ay
    ab2, ac2 = abx * abx + aby * aby, acx * acx + acy * acy
    det = 2.0 * (abx * acy - aby * acx)
    if abs(det) <= 2.0 * REL_TOL * math.sqrt(ab2 * ac2):
        bcx, bcy = cx - bx, cy - by
        bc2 = bcx * bcx + bcy * bcy
        if ab2 >= ac2 and ab2 >= bc2:
            return 0.5 * (ax + bx), 0.5 * (ay + by), 0.5 * math.sqrt(ab2)
        if ac2 >= bc2:
            return 0.5 * (ax + cx), 0.5 * (ay + cy), 0.5 * math.sqrt(ac2)
        return 0.5 * (bx + cx), 0.5 * (by + cy), 0.5 * math.sqrt(bc2)
    ox = (acy * ab2 - aby * ac2) / det
    oy = (abx * ac2 - acx * ab2) / det
    return ax + ox, ay + oy, math.sqrt(ox * ox + oy * oy)


@kernel(signature('UniTuple(f8, 3)', F2, 'i8'))
def enclosing_circle(points, count):
    """Return (centre x, centre y, radius) of the smallest circle holding points[:count]."""
    order = np.arange(count)
    state = np.uint64(88172645463325252)  # xorshift64: a fixed shuffle, same on every call
    for i in range(count - 1, 0, -1):
        state ^= state << np.uint64(13)
        state ^= state >> np.uint64(7)
        state ^= state << np.uint64(17)
        swap = int(state % np.uint64(i + 1))
        order[i], order[swap] = order[swap], order[i]
    largest = 0.0
    for i in range(count):
        largest = max(largest, abs(points[i, 0]), abs(points[i, 1]))
    slack = 1e-12 * (1.0 + largest)
    px, py = points[order[0], 0], points[order[0], 1]
    cx, cy, r = px, py, 0.0
    for i in range(1, count):
        ix, iy = points[order[i], 0], points[order[i], 1]
        if math.hypot(ix - cx, iy - cy) <= r + slack:
            continue
        cx, cy, r = ix, iy, 0.0
        for j in range(i):
            jx, jy = points[order[j], 0], points[order[j], 1]
            if math.hypot(jx - cx, jy - cy) <= r + slack:
                continue
            cx, cy, r = 0.5 * (ix + jx), 0.5 * (iy + jy), 0.5 * math.hypot(ix - jx, iy - jy)
            for k in range(j):
                kx, ky = points[order[k], 0], points[order[k], 1]
                if math.hypot(kx - cx, ky - cy) > r + slack:
                    cx, cy, r = _circle_through_three(ix, iy, jx, jy, kx, ky)
    return cx, cy, r


@kernel(signature('void', F3, I1, F2, F1))
def enclosing_circles(vertices, counts, centres, radii):
    """Write each polygon's minimum enclosing circle: centres (2, N), radii (N,)."""
    for n in range(counts.shape[0]):
        centres[0, n], centres[1, n], radii[n] = enclosing_circle(vertices[n], counts[n])


@kernel(signature('UniTuple(f8, 2)', F2, 'i8', 'f8', 'f8'))
def extent(points, count, ax, ay):
    """Return (min, max) of <v, a> over points[:count]."""
    low, high = math.inf, -math.inf
    for i in range(count):
        s = points[i, 0] * ax + points[i, 1] * ay
        low, high = min(low, s), max(high, s)
    return low, high


@kernel(signature('UniTuple(f8, 2)', F2, 'i8'))
def thin_axis(points, count):
    """Return the unit outward edge normal (a_x, a_y) of minimum width (module docstring)."""
    best, best_x, best_y = math.inf, 1.0, 0.0
    for k in range(count):
        nxt = k + 1 if k + 1 < count else 0
        ex, ey = points[nxt, 0] - points[k, 0], points[nxt, 1] - points[k, 1]
        norm = math.sqrt(ex * ex + ey * ey)
        if norm == 0.0:
            continue
        low, high = extent(points, count, ey / norm, -ex / norm)
        if high - low < best:
            best, best_x, best_y = high - low, ey / norm, -ex / norm
    return best_x, best_y


@kernel(signature('void', F3, I1, F2, 'f8', F3, F2, F3, F2, B1))
def vertical_shadows(vertices, counts, z_ranges, band_margin, projections, long_axes, shadows,
                     band, enabled):
    """Write each prism's vertical view (module docstring).

    P_n (N, 2, 3) = [[a_x, a_y, 0], [0, 0, 1]], long axes l (N, 2), shadow rectangles
    (N, 4, 2), bands (N, 2) of <l, xy> grown by ``band_margin``, and ``enabled``: a finite
    z range with z_max > z_min (the others get a shadow over z in [-1, 1], only to keep
    the batch well-formed).
    """
    for n in range(counts.shape[0]):
        ax, ay = thin_axis(vertices[n], counts[n])
        low, high = extent(vertices[n], counts[n], ax, ay)
        z_min, z_max = z_ranges[n, 0], z_ranges[n, 1]
        enabled[n] = math.isfinite(z_min) and math.isfinite(z_max) and z_max > z_min
        if not enabled[n]:
            z_min, z_max = -1.0, 1.0
        projections[n, 0, 0], projections[n, 0, 1], projections[n, 0, 2] = ax, ay, 0.0
        projections[n, 1, 0], projections[n, 1, 1], projections[n, 1, 2] = 0.0, 0.0, 1.0
        long_axes[n, 0], long_axes[n, 1] = -ay, ax
        shadows[n, 0, 0], shadows[n, 0, 1] = low, z_min
        shadows[n, 1, 0], shadows[n, 1, 1] = high, z_min
        shadows[n, 2, 0], shadows[n, 2, 1] = high, z_max
        shadows[n, 3, 0], shadows[n, 3, 1] = low, z_max
        along_low, along_high = extent(vertices[n], counts[n], -ay, ax)
        band[n, 0], band[n, 1] = along_low - band_margin, along_high + band_margin
