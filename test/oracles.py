"""Reference implementations the tests compare production code with (not shipped).

``ReferenceSolver`` solves the QP exactly by enumeration; ``silhouette_pair`` and
``inflate_polygon`` are the one-polygon forms of the batch geometry the filter runs;
``barrier_terms`` evaluates the barrier of every cone by the filter's per-cone function;
``quaternion_matrix`` reads a message quaternion as a rotation matrix;
``path_clearance_by_rows`` and ``min_h_along_by_rows`` are the braking check's kernels row
by row, as they were before they pruned rows in groups (same arithmetic, so the kernels
must agree with them bit for bit); ``configuration_polygon`` and ``footprint_barrier`` are
``barrier.footprint_cone``'s math for one part in plain numpy.
"""
import math

import numpy as np

from polyc2bf_ros.conversions import rotation
from polyc2bf_ros.core.barrier.cone_barrier import BarrierTerms
from polyc2bf_ros.core.geometry import polygons as geometry
from polyc2bf_ros.core.kernels import geometry_batch as batch_geometry, scan as scan_kernels
from polyc2bf_ros.core.kernels.barrier import barrier_column
from polyc2bf_ros.core.kernels.braking import _signed_distance, box_gap
from polyc2bf_ros.core.kernels.horizon import _misses_box, _value
from polyc2bf_ros.core.qp import proxsuite_backend as qp_proxsuite, solver as qp

# Exact up to rounding: far tighter than a solver's certificate (``qp_proxsuite._MULTIPLIER_TOL``).
_MULTIPLIER_TOL = 1e-12


def silhouette_pair(viewpoint, polygon) -> tuple[int, int]:
    """Return the tangent vertex indices (i, j) of a convex CCW polygon seen from outside.

    i is the clockwise-most vertex (smallest signed angle from the ray to the vertex centroid),
    j the counter-clockwise-most; ties (an edge on a tangent ray) go to the vertex nearer the
    viewpoint. Raises ValueError when the viewpoint is inside or on the polygon.
    """
    batch = geometry.PolygonBatch.from_polygons([polygon])
    i, j, outside = geometry.silhouette_indices(viewpoint, batch)
    if not outside[0]:
        raise ValueError('viewpoint is inside or on the polygon; it has no silhouette')
    return int(i[0]), int(j[0])


def inflate_polygon(polygon, radius, segments=16) -> np.ndarray:
    """Return a convex polygon containing every point within ``radius`` of the polygon.

    The Minkowski sum of the polygon's convex hull with the regular ``segments``-gon
    circumscribing the disk of ``radius`` (vertex distance ``R = radius / cos(pi /
    segments)``; ``batch_geometry.minkowski_regular``). It contains the exact offset set and
    exceeds it by at most ``R - radius = radius * (1 / cos(pi / segments) - 1)`` (about
    1.9 % of radius for 16 segments).

    Every vertex turns left: where an edge of the hull is parallel to one of the
    ``segments``-gon, the merge can leave a vertex on the straight line through its
    neighbours (or a repeated one); those are dropped (``|cross(e_in, e_out)| <= 1e-12
    |e_in| |e_out|``), which moves the boundary by at most 1e-12 of an edge length.
    """
    pts = geometry._as_points(polygon, 'polygon')
    if not (np.isfinite(radius) and radius >= 0):
        raise ValueError(f'inflation radius must be finite and >= 0, got {radius}')
    if segments < 3:
        raise ValueError(f'segments must be >= 3, got {segments}')
    if radius == 0:
        return pts
    hull = geometry.convex_hull(pts)
    width = len(hull) + segments
    x, y, count = np.empty((1, width)), np.empty((1, width)), np.empty(1, dtype=np.intp)
    batch_geometry.minkowski_regular(hull[None], np.array([len(hull)]), float(radius),
                                     int(segments), x, y, count)
    return geometry._drop_collinear(np.column_stack((x[0, :count[0]], y[0, :count[0]])))


class ReferenceSolver(qp.QPSolver):
    """Exact active-set enumeration, for tests (cost grows like C(m + 2n, n)).

    Every subset of at most n independent constraints (rows and finite bounds) gives a
    candidate (``_projections``); the optimum is the feasible candidate with multipliers
    >= 0 (of least cost, should rounding leave several), and no feasible candidate means
    the problem is infeasible.
    """

    name = 'reference'
    shortcut = False

    def _solve(self, x_ref, weights, A, b, lower, upper):
        """Enumerate; ``iterations`` is the number of candidates."""
        G, h = qp_proxsuite._constraints(A, b, lower, upper)
        pool = range(h.shape[0])
        candidates = [qp_proxsuite._projections(x_ref, weights, G, h, pool, k)
                      for k in range(min(x_ref.shape[0], h.shape[0]) + 1)]
        X = np.concatenate([points for points, _ in candidates])
        tolerance = -_MULTIPLIER_TOL * (1.0 + np.abs(weights * x_ref).max())
        certified = np.concatenate([(lam >= tolerance).all(axis=1) for _, lam in candidates])
        feasible = qp_proxsuite._satisfies(X, G, h)
        if not feasible.any():
            return x_ref, qp.QPStatus.INFEASIBLE, X.shape[0]
        # The optimum is the feasible candidate whose multipliers are >= 0 (KKT; some
        # independent active set certifies it even at a degenerate vertex).  Least cost
        # alone cannot tell points ~1e-8 apart: near the optimum the cost is flat to
        # below its rounding, and a candidate outside the box by rounding can undercut it.
        optimal = feasible & certified
        pick = optimal if optimal.any() else feasible
        cost = ((X[pick] - x_ref) ** 2 * weights).sum(axis=1)
        return X[pick][cost.argmin()].copy(), qp.QPStatus.OPTIMAL, X.shape[0]


def barrier_terms(cones, projections, velocities, reference, velocity_epsilon) -> BarrierTerms:
    """Evaluate h, Lf h, Lg h for N cones seen through per-obstacle projections.

    ``projections`` (N, 2, d) are the P_n, ``velocities`` (N, d) the obstacles' c_dot and
    ``reference`` the robot's ``ReferenceKinematics`` (d-dimensional); one
    ``barrier.barrier_column`` call per cone, as the filter's fused plane kernel makes.
    """
    block = np.empty((2 + reference.input_matrix.shape[1], cones.s.shape[0]))
    for n in range(cones.s.shape[0]):
        barrier_column(cones.p[0, n], cones.p[1, n], cones.s[n], cones.ds_dp[0, n],
                       cones.ds_dp[1, n], projections, velocities, reference.velocity,
                       reference.drift, reference.input_matrix, velocity_epsilon ** 2, block,
                       0, n)
    return BarrierTerms.from_block(block)


def quaternion_matrix(q):
    """Return the rotation matrix (3, 3) of Quaternion ``q``, normalised (zero: identity)."""
    return np.array(rotation(q.x, q.y, q.z, q.w)).reshape(3, 3)


def path_clearance_by_rows(x, y, edge_x, edge_y, inv_sq, counts, boxes, velocities, offsets,
                           accelerations, age, path, period, cutoff, accel, velocity_errors,
                           closing_only, footprint, cover, per_part):
    """Return ``kernels.braking.path_clearance`` measured at every row of every part.

    The parts whose bounding box stays out of reach of the path's are skipped, as the
    kernel does; every other part is measured at every row.  A guarded point only
    (``footprint`` (2, 0), ``cover`` 0).
    """
    assert footprint.shape[1] == 0 and cover == 0.0
    per_part[:] = cutoff
    rows = path.shape[0]
    if rows == 0:
        return cutoff, cutoff
    low_x, high_x = float(path[:, 0].min()), float(path[:, 0].max())
    low_y, high_y = float(path[:, 1].min()), float(path[:, 1].max())
    last = age + rows * period
    best, best_moving = cutoff, cutoff
    for n in range(counts.shape[0]):
        vx, vy = velocities[n, 0], velocities[n, 1]
        velocity_error = velocity_errors[n]
        ax, ay = accelerations[n, 0], accelerations[n, 1]
        moving = vx != 0.0 or vy != 0.0 or ax != 0.0 or ay != 0.0 or velocity_error > 0.0
        horizon = max(abs(age), abs(last))
        reach = cutoff + horizon * (math.sqrt(vx * vx + vy * vy)
                                    + 0.5 * horizon * math.hypot(ax, ay))
        if moving:
            reach += horizon * (velocity_error + 0.5 * accel * horizon)
        ox, oy = offsets[n, 0], offsets[n, 1]
        if (low_x - ox - reach > boxes[n, 1] or high_x - ox + reach < boxes[n, 0]
                or low_y - oy - reach > boxes[n, 3] or high_y - oy + reach < boxes[n, 2]):
            continue
        for k in range(rows):
            t = age + (k + 1) * period
            distance, dx, dy = _signed_distance(x, y, edge_x, edge_y, inv_sq, counts[n], n,
                                                path[k, 0] - t * vx - 0.5 * ax * t * t - ox,
                                                path[k, 1] - t * vy - 0.5 * ay * t * t - oy)
            if not moving:
                best = min(best, distance)
            elif (not closing_only or distance <= 0.0
                  or path[k, 2] * dx + path[k, 3] * dy < 0.0):
                value = distance - t * (velocity_error + 0.5 * accel * t)
                best_moving = min(best_moving, value)
                if per_part.shape[0]:
                    per_part[n] = min(per_part[n], value)
    return best, best_moving


def min_h_along_by_rows(x, y, edge_x, edge_y, inv_sq, counts, boxes, inv_horizon, bisector,
                        velocities, offsets, age, start, path, period, eps_sq):
    """Return ``kernels.horizon.min_h_along`` with its tests taken at every row.

    A part is skipped by the test on the whole path's box, a point by the tests on its own
    position and velocity (the kernel's docstring); the rest are evaluated.
    """
    rows = path.shape[0]
    points = np.vstack([start[None, :4], path[:, :4]])
    low_x, high_x = float(points[:, 0].min()), float(points[:, 0].max())
    low_y, high_y = float(points[:, 1].min()), float(points[:, 1].max())
    fastest = max(math.sqrt(vx * vx + vy * vy) for vx, vy in points[:, 2:4].tolist())
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
        for k in range(-1, rows):
            px, py, pvx, pvy = points[k + 1]
            t = age + (k + 1) * period
            qx, qy = px - t * ovx - ox, py - t * ovy - oy
            vx, vy = ovx - pvx, ovy - pvy
            if bisector and (_misses_box(box, qx, qy, -vx, -vy) or inv_horizon * box_gap(
                    qx, qx, qy, qy, box) >= math.sqrt(vx * vx + vy * vy)):
                continue
            best = min(best, _value(x, y, edge_x, edge_y, inv_sq, counts[n], n, qx, qy, vx,
                                    vy, inv_horizon, bisector, eps_sq))
    return best


def planar_rotation(theta):
    """Return the 2-D rotation matrix R(theta)."""
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, -s], [s, c]])


_J = np.array([[0.0, -1.0], [1.0, 0.0]])


def _lowest_vertex(points):
    """Return the index of the lowest (then leftmost) point."""
    return int(np.lexsort((points[:, 0], points[:, 1]))[0])


def configuration_polygon(obstacle, footprint, theta):
    """Return (C, i, j): the vertices of O + (-R(theta) F), CCW, and each one's o_i, f_j.

    Both edge sequences, each from its lowest vertex, are merged by angle (parallel edges
    together): ``kernels.footprint.configuration_polygon`` in numpy.
    """
    q = -footprint @ planar_rotation(theta).T  # a point reflection keeps the CCW order
    n, m = len(obstacle), len(q)
    a, b = _lowest_vertex(obstacle), _lowest_vertex(q)
    vertices, owners, feet = [], [], []
    i = j = 0
    while i < n or j < m:
        vertices.append(obstacle[a] + q[b])
        owners.append(a)
        feet.append(b)
        ea = obstacle[(a + 1) % n] - obstacle[a]
        eb = q[(b + 1) % m] - q[b]
        cross = ea[0] * eb[1] - ea[1] * eb[0]
        take_a = j == m or (i < n and cross >= 0.0)
        take_b = i == n or (j < m and cross <= 0.0)
        if take_a:
            i, a = i + 1, (a + 1) % n
        if take_b:
            j, b = j + 1, (b + 1) % m
    return np.array(vertices), np.array(owners), np.array(feet)


def _silhouette_of(points):
    """Return (A, B) indices of the silhouette of CCW ``points`` seen from the origin, or None.

    Edge k faces the origin when the origin is strictly right of it; A ends the facing
    chain, B starts it (as ``kernels.cones.silhouette``).
    """
    count = len(points)
    nxt = np.roll(points, -1, axis=0)
    edges = nxt - points
    facing = edges[:, 0] * (-points[:, 1]) - edges[:, 1] * (-points[:, 0]) < 0.0
    if not facing.any() or facing.all():
        return None
    a = b = None
    for k in range(count):
        incoming, outgoing = facing[k - 1], facing[k]
        if incoming and not outgoing:
            a = k
        if outgoing and not incoming:
            b = k
    return a, b


def _nearest_boundary(points):
    """Return (k, t, w): the nearest point w of the polygon's boundary to the origin.

    On edge k from P_k to P_k+1 at parameter t in [0, 1].
    """
    best = None
    for k in range(len(points)):
        p, e = points[k], points[(k + 1) % len(points)] - points[k]
        t = float(np.clip(-(p @ e) / (e @ e), 0.0, 1.0))
        w = p + t * e
        if best is None or w @ w < best[2] @ best[2]:
            best = (k, t, w)
    return best


def footprint_barrier(state, obstacle, velocity, footprint, tau=1.0, eps=0.05):
    """Return (h, Lf h, Lg h) of one part for the unicycle [x, y, theta, v, omega]; numpy.

    ``barrier.footprint_cone``'s math for one part, written plainly (loops, matrices):
    the kernel ``kernels.footprint._footprint_plane`` must agree with it.  None when the
    axle is inside or on C(theta) (no cone).
    """
    c, theta, speed, omega = state[:2], state[2], state[3], state[4]
    rot = planar_rotation(theta)
    vertices, _, feet = configuration_polygon(obstacle, footprint, theta)
    points = vertices - c
    sil = _silhouette_of(points)
    if sil is None:
        return None
    k, t, w = _nearest_boundary(points)
    count = len(points)
    k1 = (k + 1) % count
    f_foot = footprint[feet]  # f_j(k) for every C vertex
    f_star = (1.0 - t) * f_foot[k] + t * f_foot[k1]
    e = rot[:, 0]
    c_dot = speed * e
    turning = omega * (_J @ rot @ f_star)
    touching = velocity - c_dot - turning  # the touching points' relative velocity
    # Each vertex's velocity relative to c.
    deltas = omega * (_J @ rot @ (f_star - f_foot).T).T
    rates = touching + deltas
    # The barrier's v: the turning share sigma fades out at the covering radius.
    cover = np.max(np.linalg.norm(footprint, axis=1))
    d = np.linalg.norm(w)
    sigma = max(0.0, 1.0 - d / cover)
    sigma_dot = -(w @ touching) / (d * cover) if 0.0 < d < cover else 0.0
    v = velocity - c_dot - sigma * turning
    # Geometry.
    ia, ib = sil
    a, b = points[ia], points[ib]
    na, nb = np.linalg.norm(a), np.linalg.norm(b)
    ah, bh = a / na, b / nb
    mvec = ah + bh
    mn = np.linalg.norm(mvec)
    uvec, cc = mvec / mn, 0.5 * mn
    g = points.mean(axis=0)
    length = np.linalg.norm(g)
    sv = np.sqrt(v @ v + eps * eps)
    inner = uvec @ v + sv * cc + (d / tau) * (1.0 - cc)
    h = length * inner
    # Partials.
    dh_dv = length * (uvec + cc * v / sv)
    dh_dm = length * ((v - (uvec @ v) * uvec) / mn + (sv - d / tau) * 0.5 * uvec)
    grads = np.zeros_like(points)
    grads += inner * (g / length) / count  # through L = |g|
    grads[ia] += ((np.eye(2) - np.outer(ah, ah)) / na) @ dh_dm
    grads[ib] += ((np.eye(2) - np.outer(bh, bh)) / nb) @ dh_dm
    dh_dd = length * (1.0 - cc) / tau
    if d > 0.0:
        grads[k] += dh_dd * (1.0 - t) * w / d
        grads[k1] += dh_dd * t * w / d
    geometric = float(np.sum(grads * rates))
    # f*_dot: t slides along the nearest edge while it is inside (0, 1).
    t_dot = 0.0
    if 0.0 < t < 1.0:
        edge = points[k1] - points[k]
        edge_rate = rates[k1] - rates[k]
        square = edge @ edge
        t_dot = (-(rates[k] @ edge) - (points[k] @ edge_rate)) / square \
            - 2.0 * t * (edge @ edge_rate) / square
    f_star_dot = t_dot * (f_foot[k1] - f_foot[k])
    drift = -(speed * omega * (_J @ e)) + sigma * (
        omega * omega * (rot @ f_star) - omega * (_J @ rot @ f_star_dot)) - sigma_dot * turning
    lf = geometric + dh_dv @ drift
    lg = np.array([-(dh_dv @ e), -sigma * (dh_dv @ (_J @ rot @ f_star))])
    return h, lf, lg


def split_to_tolerance_by_levels(px, py, ends, tolerance):
    """``kernels.scan.split_to_tolerance`` in numpy: every piece split one level at a time.

    Per level, each piece's points' squared distances to its chord
    (``geometry._segment_square_distances``); a piece whose largest exceeds ``tolerance^2``
    is split at the first point that reaches it.  Returns the sorted ends.
    """
    tolerance_sq = tolerance ** 2
    interior = np.ones(len(px), dtype=bool)
    interior[ends] = False
    candidates = interior.nonzero()[0]
    cx, cy = px[candidates], py[candidates]
    while candidates.size:
        bounds = candidates.searchsorted(ends)
        counts = bounds[1:] - bounds[:-1]
        filled = counts.nonzero()[0]
        counts, starts = counts[filled], bounds[filled]
        ax, ay = px[ends[filled]], py[ends[filled]]
        ex, ey = px[ends[filled + 1]] - ax, py[ends[filled + 1]] - ay
        inv_sq = geometry._inverse_square_lengths(ex, ey)
        deviation = geometry._segment_square_distances(
            cx - ax.repeat(counts), cy - ay.repeat(counts), ex.repeat(counts),
            ey.repeat(counts), inv_sq.repeat(counts))
        worst = np.maximum.reduceat(deviation, starts)
        split = worst > tolerance_sq
        if not split.any():
            break
        at_worst = (deviation == worst.repeat(counts)).nonzero()[0]
        chosen = at_worst[at_worst.searchsorted(starts[split])]
        ends = np.concatenate((ends, candidates[chosen]))
        ends.sort()
        keep = split.repeat(counts)
        keep[chosen] = False
        candidates, cx, cy = candidates[keep], cx[keep], cy[keep]
    return ends


def front_by_arrays(polygons, px, py, first, last, base, footprint_radius):
    """``kernels.scan.front`` in numpy (``scan_conversion._front``): the pieces' polygons.

    Segment reductions (``reduceat``) over every piece's points at once.
    """
    count = len(polygons)
    if not count:
        return []
    counts = last - first + 1
    starts = np.concatenate(([0], np.cumsum(counts)[:-1]))
    points = first.repeat(counts) + np.arange(counts.sum()) - starts.repeat(counts)
    ax, ay = polygons[:, 0, 0], polygons[:, 0, 1]
    ex, ey = polygons[:, 1, 0] - ax, polygons[:, 1, 1] - ay
    length = np.sqrt(ex * ex + ey * ey)
    ex, ey = ex / length, ey / length
    nx, ny = -ey, ex  # counter-clockwise corners: the normal away from the base is e turned left
    rel_x, rel_y = px[points] - ax.repeat(counts), py[points] - ay.repeat(counts)
    along = rel_x * ex.repeat(counts) + rel_y * ey.repeat(counts)
    ahead = -(rel_x * nx.repeat(counts) + rel_y * ny.repeat(counts))
    depth = np.maximum.reduceat(ahead, starts)
    deepest = (ahead == depth.repeat(counts)).nonzero()[0]
    apex = deepest[deepest.searchsorted(starts)]
    apex_along = along[apex]
    height = (ax - base[0]) * nx + (ay - base[1]) * ny  # of the chord's line above the base
    behind = height < 0.0  # the base on the depth side: moving the near side moves it away
    room = np.where(behind, np.inf, height - footprint_radius)
    pointed = ((depth > scan_kernels.MIN_APEX_DEPTH) & (apex_along > 0.0) & (apex_along < length)
               & (room >= depth))
    rise = np.where(pointed, depth / np.where(pointed, apex_along, 1.0), 0.0)
    fall = np.where(pointed, depth / np.where(pointed, length - apex_along, 1.0), 0.0)
    chain = np.maximum(np.minimum(rise.repeat(counts) * along,
                                  fall.repeat(counts) * (length.repeat(counts) - along)), 0.0)
    residual = np.maximum(np.maximum.reduceat(ahead - chain, starts), 0.0)
    # A rectangle may come as near as its near edge, a segment: beside the base (lateral
    # offset w > 0 of the base beyond the chord's span) its corner stays footprint_radius
    # away while the shift is at most height - sqrt(R^2 - w^2), and any shift is fine once
    # w >= R.
    lateral = np.maximum(np.maximum(-(base[0] - ax) * ex - (base[1] - ay) * ey,
                                    (base[0] - ax) * ex + (base[1] - ay) * ey - length), 0.0)
    clear = footprint_radius ** 2 - lateral * lateral
    edge_room = np.where((clear > 0.0) & ~behind, height - np.sqrt(np.maximum(clear, 0.0)),
                         np.inf)
    shift = np.minimum(residual, np.maximum(np.where(pointed, room - depth, edge_room), 0.0))
    corners = np.empty((count, 5, 2))
    corners[:, 0], corners[:, 2:] = polygons[:, 0], polygons[:, 1:]
    corners[:, 1, 0], corners[:, 1, 1] = px[points[apex]], py[points[apex]]
    corners[:, :3, 0] -= (shift * nx)[:, None]
    corners[:, :3, 1] -= (shift * ny)[:, None]
    rectangles = corners[:, (0, 2, 3, 4)]
    return [corners[k] if pointed[k] else rectangles[k] for k in range(count)]
