"""Planar polygon geometry for PolyC2BF: cleaning, hulls, silhouettes and distances.

A polygon is an ``(n, 2)`` float64 array of vertices in counter-clockwise (CCW) order without
a repeated closing point. ``PolygonBatch`` packs N convex polygons into padded ``(N, V, 2)``
arrays (kept internally in vertex-major ``(V, N)`` layout) so that the per-control-step
queries (silhouette vertices, signed distance) run as a handful of numpy operations, with no
Python loop over obstacles.

Conventions: ``cross(u, v) = u_x v_y - u_y v_x`` (positive when v is CCW of u); for a CCW
polygon a point p lies left of edge ``e_k = v_{k+1} - v_k`` when ``cross(e_k, p - v_k) > 0``.
"""
from dataclasses import dataclass, field
from functools import cached_property
from typing import NamedTuple, Optional, Sequence

import numpy as np

from polyc2bf_ros.core.kernels import geometry_batch as batch_geometry
from polyc2bf_ros.core.kernels.geometry_batch import REL_TOL as _REL_TOL


class InvalidPolygonError(ValueError):
    """Raised when points do not describe a usable polygon; the message says why."""


def _cross(u, v):
    """Return the z-component of ``u x v`` for arrays of shape (..., 2)."""
    return u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]


def _as_points(points, what='points'):
    """Return a finite float64 (n, 2) copy of ``points`` or raise InvalidPolygonError."""
    try:
        pts = np.array(points, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InvalidPolygonError(f'{what} are not a numeric (n, 2) array: {exc}') from exc
    if pts.ndim != 2 or pts.shape[1] != 2:
        raise InvalidPolygonError(f'{what} must have shape (n, 2), got {pts.shape}')
    if not np.isfinite(pts).all():
        raise InvalidPolygonError(f'{what} contain NaN or infinite values')
    return pts


def _drop_repeats(pts):
    """Remove points equal to their cyclic predecessor (duplicates and a closing point)."""
    keep = np.any(pts != np.roll(pts, 1, axis=0), axis=1)
    return pts[keep] if keep.any() else pts[:1]


def _turns(pts):
    """Return per-vertex ``(turn, tol)`` of the incoming and outgoing edges.

    ``turn = cross(in, out)`` is > 0 for a left turn; ``|turn| <= tol`` means the boundary goes
    straight on (or doubles back) there.
    """
    incoming = pts - np.roll(pts, 1, axis=0)
    outgoing = np.roll(incoming, -1, axis=0)
    turn = _cross(incoming, outgoing)
    tol = _REL_TOL * np.hypot(*incoming.T) * np.hypot(*outgoing.T)
    return turn, tol


def _drop_collinear(pts):
    """Remove repeated points and vertices where the boundary does not turn, until none is left."""
    while True:
        pts = _drop_repeats(pts)
        if len(pts) < 3:
            return pts
        turn, tol = _turns(pts)
        straight = np.abs(turn) <= tol
        if not straight.any():
            return pts
        pts = pts[~straight]


def _all_collinear(pts):
    """Return True when every point lies on one line through the first point."""
    rel = pts - pts[0]
    far = rel[np.argmax(np.einsum('ij,ij->i', rel, rel))]
    return bool(np.all(np.abs(_cross(far, rel)) <= _REL_TOL * np.hypot(*far) * np.hypot(*rel.T)))


def _first_crossing(pts):
    """Return indices (a, b) of two non-adjacent edges that touch or cross, or None.

    Edge k runs from ``pts[k]`` to ``pts[k + 1]``. Two segments meet iff each one's endpoints
    are not strictly on one side of the other's line, except collinear segments, which meet iff
    their bounding boxes overlap. Orientation signs are exact.
    """
    n = len(pts)
    a, b = np.triu_indices(n, k=2)
    keep = ~((a == 0) & (b == n - 1))
    a, b = a[keep], b[keep]
    p, q = pts[a], np.roll(pts, -1, axis=0)[a]
    r, s = pts[b], np.roll(pts, -1, axis=0)[b]
    o1, o2 = np.sign(_cross(q - p, r - p)), np.sign(_cross(q - p, s - p))
    o3, o4 = np.sign(_cross(s - r, p - r)), np.sign(_cross(s - r, q - r))
    overlap = np.all((np.maximum(np.minimum(p, q), np.minimum(r, s))
                      <= np.minimum(np.maximum(p, q), np.maximum(r, s))), axis=1)
    collinear = (o1 == 0) & (o2 == 0)
    meet = (o1 * o2 <= 0) & (o3 * o4 <= 0) & (overlap | ~collinear)
    if not meet.any():
        return None
    first = np.argmax(meet)
    return int(a[first]), int(b[first])


def clean_polygon(points) -> np.ndarray:
    """Return ``points`` as a simple CCW polygon without repeated or collinear vertices.

    Accepts CW or CCW input, with or without a repeated closing point. Raises
    InvalidPolygonError (with the reason) for non-finite values, a wrong shape, fewer than 3
    distinct points, collinear points (zero area) or self-intersecting edges.
    """
    pts = _drop_repeats(_as_points(points, 'polygon points'))
    if len(np.unique(pts, axis=0)) < 3:
        raise InvalidPolygonError('polygon needs at least 3 distinct points')
    if _all_collinear(pts):
        raise InvalidPolygonError('polygon points are all collinear (zero area)')
    pts = _drop_collinear(pts)
    if len(pts) < 3:
        raise InvalidPolygonError('polygon has zero area once its straight spikes are removed')
    crossing = _first_crossing(pts)
    if crossing is not None:
        raise InvalidPolygonError(
            'polygon is self-intersecting: edges {} and {} meet'.format(*crossing))
    return pts if signed_area(pts) > 0 else pts[::-1].copy()


def signed_area(polygon) -> float:
    """Return the shoelace area ``sum_k cross(v_k, v_{k+1}) / 2``, positive for CCW order."""
    pts = np.asarray(polygon, dtype=np.float64)
    pts = pts - pts[0]
    return 0.5 * float(np.sum(_cross(pts, np.roll(pts, -1, axis=0))))


def _monotone_chain(points):
    """Return the lower hull of lexicographically sorted points as a list of (x, y) tuples."""
    chain = []
    for x, y in points:
        while len(chain) >= 2:
            (ax, ay), (bx, by) = chain[-2], chain[-1]
            if (bx - ax) * (y - ay) - (by - ay) * (x - ax) > 0:
                break
            chain.pop()
        chain.append((x, y))
    return chain


def convex_hull(points) -> np.ndarray:
    """Return the convex hull of ``points`` as a CCW (k, 2) array without collinear vertices.

    Andrew's monotone chain. Degenerate input (all points equal or collinear) gives k < 3:
    the single point or the two extreme points.
    """
    pts = np.unique(_as_points(points), axis=0).tolist()
    if len(pts) < 3:
        return np.array(pts, dtype=np.float64).reshape(-1, 2)
    lower = _monotone_chain(pts)
    upper = _monotone_chain(pts[::-1])
    return np.array(lower[:-1] + upper[:-1], dtype=np.float64)


def _left_turning(pts):
    """Return True when the boundary of ``pts`` never turns right (up to tolerance)."""
    turn, tol = _turns(pts)
    return bool(np.all(turn >= -tol))


def is_convex(polygon) -> bool:
    """Return True when the polygon (either orientation) is convex.

    All turns have one sign and the edge directions wind exactly once (so a pentagram, which
    only turns left but winds twice, is not convex). Straight vertices are allowed.
    """
    pts = _drop_repeats(_as_points(polygon, 'polygon'))
    if len(pts) < 3:
        return False
    both = np.stack((pts, pts[::-1]))
    ok = np.empty(2, dtype=np.bool_)
    batch_geometry.convex_ccw(both, np.full(2, len(pts)), ok)
    return bool(ok.any())


def _ear_clip(pts):
    """Triangulate a simple CCW polygon; return triangles and diagonals as index tuples.

    A vertex b with neighbours a, c is an ear when it turns left and no other remaining vertex
    lies in the closed triangle (a, b, c); clipping it adds the diagonal (a, c).
    """
    remaining = list(range(len(pts)))
    triangles, diagonals = [], []
    while len(remaining) > 3:
        for pos, b in enumerate(remaining):
            a, c = remaining[pos - 1], remaining[(pos + 1) % len(remaining)]
            if _is_ear(pts, remaining, a, b, c):
                triangles.append((a, b, c))
                diagonals.append((a, c))
                del remaining[pos]
                break
        else:
            raise InvalidPolygonError('no ear found: polygon is not simple')
    triangles.append(tuple(remaining))
    return triangles, diagonals


def _is_ear(pts, remaining, a, b, c):
    """Return True when (a, b, c) turns left and contains no other remaining vertex."""
    pa, pb, pc = pts[a], pts[b], pts[c]
    if _cross(pb - pa, pc - pb) <= 0:
        return False
    others = pts[[k for k in remaining if k not in (a, b, c)]]
    inside = ((_cross(pb - pa, others - pa) >= 0) & (_cross(pc - pb, others - pb) >= 0)
              & (_cross(pa - pc, others - pc) >= 0))
    return not inside.any()


def _starting_at(part, start):
    """Return the cyclic vertex list ``part`` rotated to begin at ``start``."""
    k = part.index(start)
    return part[k:] + part[:k]


def _part_with_edge(parts, u, v):
    """Return the index of the part whose boundary has the directed edge u -> v."""
    return next(index for index, part in enumerate(parts)
                if u in part and part[(part.index(u) + 1) % len(part)] == v)


def decompose_convex(polygon) -> list[np.ndarray]:
    """Split a simple polygon into convex CCW parts whose union is the polygon.

    Hertel-Mehlhorn: ear-clip into triangles, then drop each triangulation diagonal whose
    removal keeps the merged part convex. Every kept diagonal is needed at a reflex endpoint,
    so there are at most 2r + 1 parts for r reflex vertices (at most 4x the optimum). Input is
    expected clean (see clean_polygon); CW input is reversed. A convex polygon is returned
    whole. If ear clipping fails on a numerically degenerate polygon, InvalidPolygonError is
    raised; the convex hull is then a conservative substitute.
    """
    pts = _as_points(polygon, 'polygon')
    if signed_area(pts) < 0:
        pts = pts[::-1].copy()
    if _left_turning(pts):
        return [pts]
    triangles, diagonals = _ear_clip(pts)
    parts = [list(t) for t in triangles]
    for a, c in diagonals:
        left = _part_with_edge(parts, c, a)
        right = _part_with_edge(parts, a, c)
        merged = _starting_at(parts[left], a) + _starting_at(parts[right], c)[1:-1]
        if _left_turning(pts[merged]):
            parts[left] = merged
            del parts[right]
    return [_drop_collinear(pts[part]) for part in parts]


def _inverse_square_lengths(ex, ey):
    """Return ``1 / |e|^2`` per edge, 0 for zero-length edges (their nearest point is v_k)."""
    sq = ex * ex + ey * ey
    return np.divide(1.0, sq, out=np.zeros_like(sq), where=sq > 0)


def _segment_square_distances(rx, ry, ex, ey, inv_sq):
    """Return ``|r - t e|^2`` with ``t = clip(<r, e> / |e|^2, 0, 1)``, r = p - v_k, elementwise."""
    t = (rx * ex + ry * ey) * inv_sq
    np.maximum(t, 0.0, out=t)
    np.minimum(t, 1.0, out=t)
    dx = rx - t * ex
    dy = ry - t * ey
    return dx * dx + dy * dy


def point_in_polygon(point, polygon) -> bool:
    """Return True when the point is inside or on the boundary of a simple polygon.

    Boundary: some edge has ``cross(e_k, p - v_k) == 0`` and ``0 <= <p - v_k, e_k> <= |e_k|^2``.
    Interior: non-zero winding number, counted from upward edges with p on their left and
    downward edges with p on their right (sign tests only, no division).
    """
    p = np.asarray(point, dtype=np.float64)
    start = np.asarray(polygon, dtype=np.float64)
    end = np.roll(start, -1, axis=0)
    edge = end - start
    rel = p - start
    side = _cross(edge, rel)
    along = np.einsum('ij,ij->i', rel, edge)
    if np.any((side == 0) & (along >= 0) & (along <= np.einsum('ij,ij->i', edge, edge))):
        return True
    below_start = start[:, 1] <= p[1]
    below_end = end[:, 1] <= p[1]
    upward = below_start & ~below_end & (side > 0)
    downward = ~below_start & below_end & (side < 0)
    return bool(np.count_nonzero(upward) != np.count_nonzero(downward))


def signed_distance(point, polygon) -> float:
    """Return the Euclidean distance from the point to the polygon boundary, negative inside.

    Works for simple non-convex polygons: ``min_k dist(p, edge_k)``, signed by
    point_in_polygon (so boundary points give 0).
    """
    p = np.asarray(point, dtype=np.float64)
    pts = np.asarray(polygon, dtype=np.float64)
    edges = np.roll(pts, -1, axis=0) - pts
    dist = np.sqrt(np.min(_segment_square_distances(
        p[0] - pts[:, 0], p[1] - pts[:, 1], edges[:, 0], edges[:, 1],
        _inverse_square_lengths(edges[:, 0], edges[:, 1]))))
    return -float(dist) if point_in_polygon(p, pts) else float(dist)


def _rotate_rows(a, step):
    """Return ``a`` with rows rotated so that row k holds ``a[(k + step) % len(a)]``."""
    return np.concatenate((a[step:], a[:step]))


class _EdgeTable(NamedTuple):
    """Translation-invariant edge data of a batch, each array (V, N) C-contiguous."""

    ex: np.ndarray
    ey: np.ndarray
    inv_sq: np.ndarray


@dataclass(frozen=True, eq=False)
class PolygonBatch:
    """N convex CCW polygons padded to a common vertex count V.

    ``vertices`` (N, V, 2) repeats each polygon's last vertex up to V, so min / max / argmin
    over vertices need no mask; ``counts`` (N,) holds the true vertex counts. Derived on
    first use, in vertex-major (V, N) layout so that reductions over vertices are fast: the
    coordinates ``x``, ``y`` and the ``edge_table`` of edges ``v_next(k) - v_k`` with
    ``next(k) = k + 1`` if ``k + 1 < count`` else 0, so every padding slot carries a copy of
    the closing edge. ``from_polygons`` checks its input (``batch_geometry.convex_ccw``);
    ``pack`` and the constructor trust it, and ``translated`` reuses the edge table.
    """

    vertices: np.ndarray
    counts: np.ndarray
    known_edges: Optional[_EdgeTable] = field(default=None, repr=False)

    def __post_init__(self):
        """Coerce the arrays and check their shapes."""
        vertices = np.asarray(self.vertices, dtype=np.float64)
        counts = np.asarray(self.counts, dtype=np.intp)
        if vertices.ndim != 3 or vertices.shape[2] != 2 or counts.shape != vertices.shape[:1]:
            raise InvalidPolygonError(
                f'batch needs vertices (N, V, 2) and counts (N,), got {vertices.shape} '
                f'and {counts.shape}')
        object.__setattr__(self, 'vertices', vertices)
        object.__setattr__(self, 'counts', counts)

    @cached_property
    def x(self) -> np.ndarray:
        """Return the (V, N) x coordinates."""
        return np.ascontiguousarray(self.vertices[..., 0].T)

    @cached_property
    def y(self) -> np.ndarray:
        """Return the (V, N) y coordinates."""
        return np.ascontiguousarray(self.vertices[..., 1].T)

    @cached_property
    def edge_table(self) -> _EdgeTable:
        """Return the (V, N) edges and their inverse square lengths (class docstring)."""
        if self.known_edges is not None:
            return self.known_edges
        x, y = self.x, self.y
        wraps = np.arange(1, x.shape[0] + 1)[:, None] >= self.counts
        ex = np.where(wraps, x[0], _rotate_rows(x, 1)) - x
        ey = np.where(wraps, y[0], _rotate_rows(y, 1)) - y
        return _EdgeTable(ex, ey, _inverse_square_lengths(ex, ey))

    @classmethod
    def pack(cls, polygons: Sequence[np.ndarray]) -> 'PolygonBatch':
        """Pad (n, 2) arrays with n >= 3 and finite values, unchecked otherwise."""
        arrays = [np.asarray(polygon, dtype=np.float64) for polygon in polygons]
        if not arrays:
            return cls(np.zeros((0, 3, 2)), np.zeros(0, dtype=np.intp))
        try:
            points = np.concatenate(arrays)
        except ValueError:
            points = None
        if points is None or points.ndim != 2 or points.shape[1] != 2:
            index = next(i for i, a in enumerate(arrays) if a.ndim != 2 or a.shape[1] != 2)
            raise InvalidPolygonError(
                f'polygon {index} of the batch must have shape (n, 2), got {arrays[index].shape}')
        counts = np.fromiter(map(len, arrays), dtype=np.intp, count=len(arrays))
        if counts.min() < 3:
            raise InvalidPolygonError(
                f'polygon {int(np.argmin(counts))} of the batch has fewer than 3 vertices')
        vertices = np.empty((len(arrays), max(3, counts.max()), 2))
        if not batch_geometry.pad(points, counts, vertices):
            raise InvalidPolygonError('batch polygons contain NaN or infinite values')
        return cls(vertices, counts)

    @classmethod
    def from_polygons(cls, polygons: Sequence[np.ndarray]) -> 'PolygonBatch':
        """Pack and check convex CCW polygons; no polygons give shapes (0, 3, 2) and (0,)."""
        batch = cls.pack(polygons)
        bad = ~batch.convex_ccw()
        if bad.any():
            raise InvalidPolygonError(
                f'polygon {int(np.argmax(bad))} of the batch is not a convex CCW polygon with '
                'at least 3 distinct consecutive vertices and positive area')
        return batch

    def convex_ccw(self) -> np.ndarray:
        """Return (N,) True where the polygon is convex, CCW and simple with positive area."""
        ok = np.empty(len(self), dtype=np.bool_)
        batch_geometry.convex_ccw(self.vertices, self.counts, ok)
        return ok

    def __len__(self) -> int:
        """Return the number of polygons N."""
        return len(self.counts)

    def translated(self, offsets) -> 'PolygonBatch':
        """Return the batch with polygon n shifted by ``offsets[n]`` (the edge table is reused)."""
        offsets = np.asarray(offsets, dtype=np.float64)
        return PolygonBatch(self.vertices + offsets[:, None, :], self.counts, self.edge_table)


def signed_distance_batch(point, batch: PolygonBatch) -> np.ndarray:
    """Return the (N,) signed distances from the point to each convex polygon of the batch.

    ``d_n = min_k dist(p, edge_k)``, negated when p is left of (or on) every edge.
    """
    px, py = np.asarray(point, dtype=np.float64).tolist()
    ex, ey, inv_sq = batch.edge_table
    rx = px - batch.x
    ry = py - batch.y
    dist = np.sqrt(np.minimum.reduce(_segment_square_distances(rx, ry, ex, ey, inv_sq), axis=0))
    inside = np.logical_and.reduce(ex * ry >= ey * rx, axis=0)
    return np.where(inside, -dist, dist)


def silhouette_indices(viewpoint,
                       batch: PolygonBatch) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return the tangent vertex indices ``(i, j, outside)`` of every polygon seen from p.

    Edge k faces p when p is strictly right of it, ``cross(e_k, p - v_k) < 0``. Seen from an
    outside point the facing edges of a convex polygon form one chain; its last vertex is the
    clockwise-most tangent vertex i and its first vertex the counter-clockwise-most j. An edge
    lying on a tangent ray does not face p, so the vertex nearer p is chosen. ``outside[n]`` is
    False when no edge faces p (p inside or on polygon n); i and j are then 0. Padding slots
    hold copies of the closing edge, so the chain never breaks or ends inside the padding.
    """
    px, py = np.asarray(viewpoint, dtype=np.float64).tolist()
    ex, ey, _ = batch.edge_table
    facing = ex * (py - batch.y) < ey * (px - batch.x)
    incoming_faces = _rotate_rows(facing, -1)
    cw_most = np.argmax(incoming_faces > facing, axis=0)
    ccw_most = np.argmax(facing > incoming_faces, axis=0)
    return cw_most, ccw_most, np.logical_or.reduce(facing, axis=0)


def minimum_enclosing_circle(points) -> tuple[np.ndarray, float]:
    """Return ``(centre, radius)`` of the smallest circle containing all points.

    Welzl's incremental algorithm on a fixed shuffled order (expected O(n); see
    ``batch_geometry``): whenever a point lies outside the current circle, it is on the
    boundary of the new one.
    """
    pts = _as_points(points)
    if len(pts) == 0:
        raise InvalidPolygonError('minimum enclosing circle needs at least one point')
    cx, cy, radius = batch_geometry.enclosing_circle(pts, len(pts))
    return np.array([cx, cy]), float(radius)


def thin_axis(polygon) -> np.ndarray:
    """Return the unit direction along which a convex polygon is thinnest.

    The minimum width ``max_i <v_i, n> - min_i <v_i, n>`` of a convex polygon is attained at an
    edge normal n, so all edge normals are tried. The sign is that of the edge's outward
    normal for CCW input.
    """
    pts = _drop_repeats(_as_points(polygon, 'polygon'))
    if len(pts) < 2:
        raise InvalidPolygonError('thin axis needs at least 2 distinct points')
    return np.array(batch_geometry.thin_axis(np.ascontiguousarray(pts), len(pts)))


def vertical_shadow(footprint, z_min, z_max, axis) -> np.ndarray:
    """Return the CCW (4, 2) rectangle in (s, z) that the prism footprint x [z_min, z_max] casts.

    The vertical plane is spanned by the horizontal ``axis`` (normalised here) and world z;
    ``s = <xy, axis>`` ranges over ``[min_i <v_i, axis>, max_i <v_i, axis>]``. This is the exact
    projection of the prism, so a point outside the rectangle is outside the prism.
    """
    pts = _as_points(footprint, 'footprint')
    axis = np.asarray(axis, dtype=np.float64)
    norm = np.hypot(*axis) if axis.shape == (2,) else 0.0
    if not (np.isfinite(norm) and norm > 0):
        raise ValueError(f'axis must be a finite non-zero 2-vector, got {axis}')
    if not z_min <= z_max:
        raise ValueError(f'need z_min <= z_max, got {z_min} > {z_max}')
    low, high = batch_geometry.extent(pts, len(pts), *(axis / norm).tolist())
    return np.array([[low, z_min], [high, z_min], [high, z_max], [low, z_max]], dtype=np.float64)
