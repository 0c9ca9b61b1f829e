"""Kernels of ``barrier.cones``, whose docstring has the math.

The math in compiled form; every kernel lives in ``core/kernels`` (``jit.kernel_sources``).
"""
import math

from polyc2bf_ros.core.kernels.barrier import barrier_column
from polyc2bf_ros.core.kernels.jit import B1, F1, F2, F3, I1, kernel, signature
from polyc2bf_ros.core.kernels.views import viewpoint

_TINY = 1e-12
CONE_ROWS = 7
"""Rows of a cone block: p (2), k (2), s (1), ds_dp (2), one column per obstacle."""
PLANE_ROWS = 2 + CONE_ROWS
"""Rows of a plane block before the barrier terms: viewpoint (2), then the cone."""


@kernel
def polygon_box(x, y, count, n):
    """Return (low_x, high_x, low_y, high_y): the bounding box of polygon n."""
    low_x = high_x = x[n, 0]
    low_y = high_y = y[n, 0]
    for k in range(count):
        low_x, high_x = min(low_x, x[n, k]), max(high_x, x[n, k])
        low_y, high_y = min(low_y, y[n, k]), max(high_y, y[n, k])
    return low_x, high_x, low_y, high_y



@kernel
def nearest_edge(x, y, edge_x, edge_y, inv_sq, count, n, qx, qy):
    """Return (|d|^2, k, d_x, d_y, inside) for the edge of polygon ``n`` nearest to q.

    d = r_k - t_k e_k is the offset of q from edge k's nearest point, r_k = q - v_k,
    t_k = clip(<r_k, e_k> / |e_k|^2, 0, 1); inside: q is left of (or on) every edge.
    """
    best, nearest, best_x, best_y, inside = math.inf, 0, 0.0, 0.0, True
    for k in range(count):
        dx, dy, rx, ry = _edge_offset(x, y, edge_x, edge_y, inv_sq, n, k, qx, qy)
        if dx * dx + dy * dy < best:
            best, nearest, best_x, best_y = dx * dx + dy * dy, k, dx, dy
        inside = inside and edge_x[n, k] * ry >= edge_y[n, k] * rx
    return best, nearest, best_x, best_y, inside



@kernel
def _edge_offset(x, y, edge_x, edge_y, inv_sq, n, k, qx, qy):
    """Return (d_x, d_y, r_x, r_y): q's offset d from edge k's nearest point, r = q - v_k."""
    rx, ry = -(x[n, k] - qx), -(y[n, k] - qy)
    t = min(max((rx * edge_x[n, k] + ry * edge_y[n, k]) * inv_sq[n, k], 0.0), 1.0)
    return rx - t * edge_x[n, k], ry - t * edge_y[n, k], rx, ry



@kernel
def nearest_seen_edge(x, y, edge_x, edge_y, inv_sq, count, n, qx, qy, a, b):
    """Return ``nearest_edge``'s (|d|^2, d_x, d_y) over the edges that can hold the nearest point.

    q outside polygon n, which it sees between silhouette vertices A = v_a and B = v_b
    (``silhouette``, ``seen``).  The nearest point P of a convex polygon is seen from q:
    inside a facing edge, or a vertex of the facing chain (at a vertex, q - P lies in
    the normal cone of its two edges, so one of them faces q).  So only the chain's edges
    b .. a - 1 and the two beside it, b - 1 and a (which may end or start at A or B), hold
    P; the others are strictly farther.  They are taken in increasing index, as
    ``nearest_edge`` takes them, so that a tie at a vertex keeps the same edge (bit for
    bit, ``test_cones.py``); a chain that leaves fewer than two edges out takes them all.
    """
    square, nearest = _nearest_seen_index(x, y, edge_x, edge_y, inv_sq, count, n, qx, qy, a, b)
    dx, dy, _, _ = _edge_offset(x, y, edge_x, edge_y, inv_sq, n, nearest, qx, qy)
    return square, dx, dy



@kernel
def _nearest_seen_index(x, y, edge_x, edge_y, inv_sq, count, n, qx, qy, a, b):
    """Return (|d|^2, k): ``nearest_seen_edge``'s distance and edge."""
    if (a - b) % count + 2 >= count:
        square, nearest, _, _, _ = nearest_edge(x, y, edge_x, edge_y, inv_sq, count, n, qx, qy)
        return square, nearest
    first = b - 1 if b > 0 else count - 1
    wraps = first > a  # the window runs past the last edge: 0 .. a, then first .. count - 1
    best, nearest = _nearest_in(x, y, edge_x, edge_y, inv_sq, n, qx, qy,
                                0 if wraps else first, a + 1, math.inf, 0)
    if wraps:
        best, nearest = _nearest_in(x, y, edge_x, edge_y, inv_sq, n, qx, qy, first, count,
                                    best, nearest)
    return best, nearest



@kernel
def hinted_seen_edge(x, y, edge_x, edge_y, inv_sq, count, n, qx, qy, a, b, hints):
    """Return ``nearest_seen_edge``'s (|d|^2, d_x, d_y), trying edge ``hints[n, 0]`` first.

    ``hints[n, 0]``: the edge this returned for polygon n last (any index is valid); it is
    updated.  Seen from q outside, the facing chain is a curve r(phi) in polar angle about
    q.  A point of it no farther than the chain's points around it is no farther than any
    point of the polygon around it either (the ray from q to such a point crosses the
    chain first, nearby), so it is a local, hence the global, minimum of the distance to
    q over the convex polygon: P.  So a chain edge k (b .. a - 1) no farther than edges
    k - 1 and k + 1 holds P, and only a neighbour sharing P's vertex can tie with it:
    the smallest index of those ties is the scan's edge, bit for bit
    (``test_cones.py``).  Three edges instead of the chain where P stays on one edge or
    moves to the next between steps (the horizon barrier's step, bench/README.md core
    step); else the scan.
    """
    k = hints[n, 0]
    if (a - b) % count + 2 < count and 0 <= k < count and (k - b) % count < (a - b) % count:
        before = k - 1 if k > 0 else count - 1
        after = k + 1 if k + 1 < count else 0
        dx, dy, _, _ = _edge_offset(x, y, edge_x, edge_y, inv_sq, n, k, qx, qy)
        here = dx * dx + dy * dy
        bx, by, _, _ = _edge_offset(x, y, edge_x, edge_y, inv_sq, n, before, qx, qy)
        ax, ay, _, _ = _edge_offset(x, y, edge_x, edge_y, inv_sq, n, after, qx, qy)
        if here <= bx * bx + by * by and here <= ax * ax + ay * ay:
            if here == bx * bx + by * by and before < k:
                k, dx, dy = before, bx, by
            if here == ax * ax + ay * ay and after < k:
                k, dx, dy = after, ax, ay
            return here, dx, dy
    square, k = _nearest_seen_index(x, y, edge_x, edge_y, inv_sq, count, n, qx, qy, a, b)
    hints[n, 0] = k
    dx, dy, _, _ = _edge_offset(x, y, edge_x, edge_y, inv_sq, n, k, qx, qy)
    return square, dx, dy



@kernel
def _nearest_in(x, y, edge_x, edge_y, inv_sq, n, qx, qy, low, high, best, nearest):
    """Return (|d|^2, k) of the first nearest edge k in low .. high - 1, or the ones given.

    Compares and selects without branches (the loop ``nearest_seen_edge`` runs per part).
    """
    for k in range(low, high):
        dx, dy, _, _ = _edge_offset(x, y, edge_x, edge_y, inv_sq, n, k, qx, qy)
        square = dx * dx + dy * dy
        nearest = k if square < best else nearest
        best = square if square < best else best
    return best, nearest



@kernel
def silhouette(x, y, count, n, qx, qy):
    """Return (a, b, seen): the silhouette vertices A, B of polygon n seen from q.

    Edge k faces the viewpoint q when q is strictly right of it, cross(e_k, v_k - q) > 0;
    the facing edges form one chain: A is the vertex where it ends (the first whose
    incoming edge faces and outgoing edge does not), B the one where it starts.  ``seen``
    is False when no edge faces q (q inside or on the polygon): there is no cone.
    """
    last = count - 1
    # Edges v_next - v_k from the vertices (as ``PlanarPolygons`` stores them, bit for
    # bit): half the memory the loop reads, which is what it waits for on a cold cache.
    incoming = ((x[n, 0] - x[n, last]) * (y[n, last] - qy)
                > (y[n, 0] - y[n, last]) * (x[n, last] - qx))
    a = b = -1
    seen = False
    for k in range(count):
        nxt = k + 1 if k < last else 0
        facing = ((x[n, nxt] - x[n, k]) * (y[n, k] - qy)
                  > (y[n, nxt] - y[n, k]) * (x[n, k] - qx))
        if incoming and not facing and a < 0:
            a = k
        if facing and not incoming and b < 0:
            b = k
        seen = seen or facing
        incoming = facing
        if a >= 0 and b >= 0:
            break  # both ends of the (single) facing chain found
    return max(a, 0), max(b, 0), seen



@kernel
def hinted_silhouette(x, y, count, n, qx, qy, hints):
    """Return ``silhouette``'s (a, b, seen), trying polygon n's last ends ``hints[n, 1:]`` first.

    The facing edges of a convex polygon form one chain: where edge a - 1 faces q and
    edge a does not, and edge b - 1 does not and edge b does, A = v_a and B = v_b are its
    ends, the scan's (bit for bit, ``test_cones.py``).  Four edge tests where the ends
    stay between steps; else the scan, whose ends are kept.
    """
    a, b = hints[n, 1], hints[n, 2]
    if (0 <= a < count and 0 <= b < count and _faces(x, y, count, n, qx, qy, a - 1)
            and not _faces(x, y, count, n, qx, qy, a)
            and not _faces(x, y, count, n, qx, qy, b - 1)
            and _faces(x, y, count, n, qx, qy, b)):
        return a, b, True
    a, b, seen = silhouette(x, y, count, n, qx, qy)
    hints[n, 1], hints[n, 2] = a, b
    return a, b, seen



@kernel
def _faces(x, y, count, n, qx, qy, k):
    """Return True when edge k (-1: the last) of polygon n faces q, as ``silhouette`` tests it."""
    k = k if k >= 0 else count - 1
    nxt = k + 1 if k < count - 1 else 0
    return (x[n, nxt] - x[n, k]) * (y[n, k] - qy) > (y[n, nxt] - y[n, k]) * (x[n, k] - qx)



@kernel
def midpoint_cone(ax, ay, bx, by, extension):
    """Return (px, py, kx, ky, s, ds_dpx, ds_dpy): the paper's cone of silhouette rays a, b.

    a = A - q, b = B - q; the segment is extended by ``extension`` at both ends (module
    docstring), p aims at its midpoint and k is the extended end with the larger angle.
    """
    px, py = 0.5 * (ax + bx), 0.5 * (ay + by)
    if extension != 0.0:
        ux, uy = bx - ax, by - ay
        scale = extension / max(math.sqrt(ux * ux + uy * uy), _TINY)
        ux *= scale
        uy *= scale
        ax, ay, bx, by = ax - ux, ay - uy, bx + ux, by + uy
    a_norm = max(math.sqrt(ax * ax + ay * ay), _TINY)
    b_norm = max(math.sqrt(bx * bx + by * by), _TINY)
    a_cos = (px * ax + py * ay) / a_norm
    b_cos = (px * bx + py * by) / b_norm
    if a_cos < b_cos:  # the closer vertex makes the larger angle with p
        s, k_norm, kx, ky = a_cos, a_norm, ax, ay
    else:
        s, k_norm, kx, ky = b_cos, b_norm, bx, by
    hx, hy = kx / k_norm, ky / k_norm
    return px, py, kx, ky, s, hx + (px - s * hx) / k_norm, hy + (py - s * hy) / k_norm



@kernel
def polygon_cone(x, y, edge_x, edge_y, inv_sq, count, n, qx, qy, extension):
    """Return (px, py, kx, ky, s, ds_dpx, ds_dpy, valid): the PolyC2BF cone of polygon n.

    ``silhouette``, then ``midpoint_cone``.  With ``extension`` > 0 the cone is only valid
    when q is farther than it from the polygon.
    """
    a, b, seen = silhouette(x, y, count, n, qx, qy)
    px, py, kx, ky, s, ds_dpx, ds_dpy = midpoint_cone(
        x[n, a] - qx, y[n, a] - qy, x[n, b] - qx, y[n, b] - qy, extension)
    if seen and extension > 0.0:
        square = nearest_edge(x, y, edge_x, edge_y, inv_sq, count, n, qx, qy)[0]
        seen = math.sqrt(square) > extension
    return px, py, kx, ky, s, ds_dpx, ds_dpy, seen



@kernel
def store_cone(out, first, n, cone):
    """Write ``cone``'s p, k, s, ds/dp into rows ``first``... of column ``n``; return valid."""
    out[first, n], out[first + 1, n], out[first + 2, n], out[first + 3, n] = cone[:4]
    out[first + 4, n], out[first + 5, n], out[first + 6, n] = cone[4:7]
    return cone[7]



@kernel
def fill_plane_terms(block, projections, velocities, position_rate, drift, input_matrix,
                     eps_sq):
    """Write the barrier terms of the cones in a plane ``block`` (rows ``PLANE_ROWS``...).

    A loop of its own after the cones: one loop doing both ran ~40 % slower (numba 0.68).
    """
    for n in range(block.shape[1]):  # p in rows 2-3, s in row 6, ds/dp in rows 7-8
        barrier_column(block[2, n], block[3, n], block[6, n], block[7, n], block[8, n],
                       projections, velocities, position_rate, drift, input_matrix, eps_sq,
                       block, PLANE_ROWS, n)



@kernel(signature('void', F2, F2, F2, F2, F2, I1, F2, 'f8', F2, B1))
def _polygon_cones(x, y, edge_x, edge_y, inv_sq, counts, viewpoints, extension, out, valid):
    """Write the ``polygon_cone`` of every polygon seen from ``viewpoints`` (2, 1 or N)."""
    shared = viewpoints.shape[1] == 1
    for n in range(counts.shape[0]):
        j = 0 if shared else n
        valid[n] = store_cone(out, 0, n, polygon_cone(
            x, y, edge_x, edge_y, inv_sq, counts[n], n, viewpoints[0, j], viewpoints[1, j],
            extension))



@kernel(signature('void', F2, F2, F2, F2, F2, I1, 'f8', F3, F1, F2, F2, 'f8', F1, F1, F2, 'f8',
                  F2, B1))
def _polygon_plane(x, y, edge_x, edge_y, inv_sq, counts, extension, projections, position,
                   velocities, offsets, age, position_rate, drift, input_matrix,
                   velocity_epsilon, block, valid):
    """Per polygon: viewpoint, ``polygon_cone`` and barrier terms (``ConeModel.fill_plane``)."""
    for n in range(counts.shape[0]):
        qx, qy = viewpoint(projections, position, velocities, offsets, age, n)
        block[0, n], block[1, n] = qx, qy
        valid[n] = store_cone(block, 2, n, polygon_cone(x, y, edge_x, edge_y, inv_sq, counts[n],
                                                        n, qx, qy, extension))
    fill_plane_terms(block, projections, velocities, position_rate, drift, input_matrix,
                     velocity_epsilon * velocity_epsilon)



@kernel(signature('void', F2, F2, F2, F2, F2, I1, F2, 'f8', F2))
def _polygon_exits(x, y, edge_x, edge_y, inv_sq, counts, viewpoints, extension, out):
    """Write the shortest way out of each polygon grown by ``extension`` (module docstring)."""
    shared = viewpoints.shape[1] == 1
    for n in range(counts.shape[0]):
        j = 0 if shared else n
        square, k, dx, dy, inside = nearest_edge(x, y, edge_x, edge_y, inv_sq, counts[n], n,
                                                  viewpoints[0, j], viewpoints[1, j])
        distance = math.sqrt(square)
        if inside or distance == 0.0:  # the nearest edge's outward normal
            norm = math.sqrt(inv_sq[n, k])
            out[0, n], out[1, n] = edge_y[n, k] * norm, -edge_x[n, k] * norm
        else:
            out[0, n], out[1, n] = dx / distance, dy / distance
        out[2, n] = extension + distance if inside else extension - distance



@kernel
def circle_cone(cx, cy, radius, qx, qy):
    """Return (px, py, kx, ky, s, ds_dpx, ds_dpy, valid): the C3BF cone of one circle.

    s = sqrt(|p|^2 - R^2), ds/dp = p / s; the boundary ray k is p rotated by the
    half-angle phi (cos phi = s / |p|, sin phi = R / |p|) and scaled to the tangent
    length s.
    """
    px, py = cx - qx, cy - qy
    distance_sq = px * px + py * py
    clearance_sq = distance_sq - radius * radius
    s = math.sqrt(max(clearance_sq, _TINY))
    distance = math.sqrt(max(distance_sq, _TINY))
    cos_phi, sin_phi = s / distance, radius / distance
    return (px, py, cos_phi * (cos_phi * px - sin_phi * py),
            cos_phi * (sin_phi * px + cos_phi * py), s, px / s, py / s, clearance_sq > 0.0)



@kernel(signature('void', F2, F1, F2, F2, B1))
def _circle_cones(centres, radii, viewpoints, out, valid):
    """Write the ``circle_cone`` of every circle seen from ``viewpoints`` (2, 1 or N)."""
    shared = viewpoints.shape[1] == 1
    for n in range(radii.shape[0]):
        j = 0 if shared else n
        valid[n] = store_cone(out, 0, n, circle_cone(centres[0, n], centres[1, n], radii[n],
                                                     viewpoints[0, j], viewpoints[1, j]))



@kernel(signature('void', F2, F1, F3, F1, F2, F2, 'f8', F1, F1, F2, 'f8', F2, B1))
def _circle_plane(centres, radii, projections, position, velocities, offsets, age,
                  position_rate, drift, input_matrix, velocity_epsilon, block, valid):
    """Per circle: viewpoint, ``circle_cone`` and barrier terms (``ConeModel.fill_plane``)."""
    for n in range(radii.shape[0]):
        qx, qy = viewpoint(projections, position, velocities, offsets, age, n)
        block[0, n], block[1, n] = qx, qy
        valid[n] = store_cone(block, 2, n, circle_cone(centres[0, n], centres[1, n], radii[n],
                                                       qx, qy))
    fill_plane_terms(block, projections, velocities, position_rate, drift, input_matrix,
                     velocity_epsilon * velocity_epsilon)



@kernel(signature('void', F2, F1, F2, F2))
def _circle_exits(centres, radii, viewpoints, out):
    """Write the shortest way out of each circle: (q - c)/|q - c|, depth R - |q - c|."""
    shared = viewpoints.shape[1] == 1
    for n in range(radii.shape[0]):
        j = 0 if shared else n
        dx, dy = viewpoints[0, j] - centres[0, n], viewpoints[1, j] - centres[1, n]
        distance = math.sqrt(dx * dx + dy * dy)
        if distance > 0.0:
            out[0, n], out[1, n] = dx / distance, dy / distance
        else:  # at the centre every direction is shortest
            out[0, n], out[1, n] = 1.0, 0.0
        out[2, n] = radii[n] - distance
