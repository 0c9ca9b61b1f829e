"""Collision cones seen from the robot's reference point, behind one interface.

Over 500 lines on purpose: the cone models behind that one interface and their compiled
plane kernels.

Every cone model maps convex polygons (in a plane, relative to a viewpoint q)
to a cone with apex q, axis vector p and a shape term::

    s(p) = ||p|| cos(phi) = <p, k_hat>                  (PolyC2BF, paper eq. 7)
    s(p) = sqrt(||p||^2 - R^2)                          (C3BF, paper eq. 3)

with its gradient ds/dp, so that one barrier serves all of them
(``polyc2bf_ros.core.barrier.cone_barrier``).

PolyC2BF cones (paper section III): take the silhouette (tangent) vertices
A, B of the polygon seen from q, extend segment AB by ``extension`` at both
ends (A' = A - e u, B' = B + e u, u = (B - A)/|B - A|), aim p at the midpoint
(A + B)/2 and let k be whichever of A', B' makes the larger angle with p (the
closer vertex, paper's Remark 1).  For a fixed vertex pair, k = p + delta with
delta constant in the obstacle frame, so ds/dp = k_hat + (p - s k_hat)/||k||.

* ``PaperCone``: the paper's rule, extension = w/2 with w the robot width.
* ``InflatedCone``: the polygon is first inflated by the robot radius
  (Minkowski sum with a circumscribed regular polygon, so the cone contains
  the exact inflated obstacle), then extension = 0: its rays are the exact
  silhouette of the inflated obstacle up to radius*(1/cos(pi/segments) - 1).
* ``CircleCone``: C3BF, the polygon's minimum enclosing circle grown by the
  robot radius.

Where no cone exists (the viewpoint q inside the inflated obstacle, or within
``extension`` of the polygon), ``exits`` gives the shortest way out of that
region: with d(q) the signed distance to the polygon (negative inside) or the
circle, the depth is ``extension - d(q)`` (``R - |q - c|`` for a circle) and the
direction is grad d: (q - c)/|q - c| for the nearest boundary point c outside,
the outward normal of the nearest edge inside (for a convex polygon the
nearest boundary point from inside lies on that edge).

On the filter's hot path ``plane`` runs, per obstacle, the viewpoint, the cone
and the barrier terms in one compiled pass; it is built from the same
per-obstacle functions as ``fill`` (``polygon_cone``, ``circle_cone``) and
``barrier.barrier_column``, so both give the same numbers.
"""
import abc
import math
from dataclasses import dataclass

import numpy as np

from polyc2bf_ros.core.barrier.cone_barrier import barrier_column
from polyc2bf_ros.core.geometry import batch as batch_geometry
from polyc2bf_ros.core.geometry.polygons import PolygonBatch
from polyc2bf_ros.core.geometry.views import viewpoint
from polyc2bf_ros.core.kernels.jit import B1, F1, F2, F3, I1, kernel, signature

_TINY = 1e-12
CONE_ROWS = 7
"""Rows of a cone block: p (2), k (2), s (1), ds_dp (2), one column per obstacle."""
PLANE_ROWS = 2 + CONE_ROWS
"""Rows of a plane block before the barrier terms: viewpoint (2), then the cone."""
PLANE_CONES = slice(2, PLANE_ROWS)
"""The cone rows of a plane block (a cone block: ``Cones.from_block``)."""
PLANE_K = slice(4, 6)
"""The boundary rays k in a plane block (after the viewpoint and p)."""


def dot2(a, b):
    """Return the column-wise dot product of planar vectors stored as (2, N) rows x, y."""
    return a[0] * b[0] + a[1] * b[1]


@dataclass(slots=True)
class Cones:
    """Per-obstacle cones as (2, N) planar vectors (rows x, y) and (N,) scalars.

    Axis ``p``, boundary ray ``k``, ``s = <p, k_hat>`` and ``ds_dp``; ``valid`` is
    False where the viewpoint is inside the (inflated) obstacle, where no cone
    exists (the other fields are finite there but meaningless).
    """

    p: np.ndarray
    k: np.ndarray
    s: np.ndarray
    ds_dp: np.ndarray
    valid: np.ndarray

    @classmethod
    def from_block(cls, block, valid):
        """Return cones viewing the rows of a (``CONE_ROWS``, N) block (no copy)."""
        return cls(p=block[0:2], k=block[2:4], s=block[4], ds_dp=block[5:7], valid=valid)

    @property
    def k_norm(self):
        """Return ||k||, the distance to the cone's boundary point."""
        return np.sqrt(dot2(self.k, self.k))


@dataclass(frozen=True)
class PlanarPolygons:
    """Convex polygons laid out for the cone kernel: (N, W) arrays, one row per polygon.

    Vertex coordinates ``x``, ``y``, edges ``edge_x``, ``edge_y`` (from each vertex to
    the next) and their ``inv_sq`` = 1 / |e|^2, each polygon's first ``counts[n]`` slots
    (``batch_geometry.edge_rows`` pads the rest).
    """

    x: np.ndarray
    y: np.ndarray
    edge_x: np.ndarray
    edge_y: np.ndarray
    inv_sq: np.ndarray
    counts: np.ndarray

    @classmethod
    def from_rows(cls, x, y, counts):
        """Lay out (N, W) vertex rows (filled up to ``counts``) once per obstacle update."""
        edge_x, edge_y, inv_sq = np.empty_like(x), np.empty_like(x), np.empty_like(x)
        batch_geometry.edge_rows(x, y, counts, edge_x, edge_y, inv_sq)
        return cls(x, y, edge_x, edge_y, inv_sq, counts)

    @classmethod
    def from_batch(cls, batch):
        """Lay out a ``PolygonBatch``."""
        return cls.from_rows(np.ascontiguousarray(batch.vertices[..., 0]),
                             np.ascontiguousarray(batch.vertices[..., 1]), batch.counts)

    @property
    def batch(self):
        """Return the polygons as a ``PolygonBatch``."""
        return PolygonBatch(np.stack((self.x, self.y), axis=-1), self.counts)

    def __len__(self):
        """Return the number of polygons."""
        return self.counts.shape[0]


class ConeModel(abc.ABC):
    """Turns planar convex polygons into cones seen from per-obstacle viewpoints.

    Two entry points: ``fill`` (``cones``) gives the cones seen from given viewpoints;
    ``fill_plane`` (``plane``), the filter's per-step path, computes the viewpoints, the
    cones and their barrier terms in one compiled pass.
    """

    name: str

    @abc.abstractmethod
    def prepare(self, batch: PolygonBatch):
        """Precompute per-obstacle geometry once per obstacle update (not per step)."""

    def cones(self, prepared, viewpoints) -> Cones:
        """Return the cones seen from ``viewpoints``: (2, N), or (2,) shared by all."""
        viewpoints = np.ascontiguousarray(viewpoints, dtype=np.float64).reshape(2, -1)
        block = np.empty((CONE_ROWS, len(prepared)))
        valid = np.empty(len(prepared), dtype=np.bool_)
        self.fill(prepared, viewpoints, block, valid)
        return Cones.from_block(block, valid)

    @abc.abstractmethod
    def fill(self, prepared, viewpoints, block, valid):
        """Write the cones seen from ``viewpoints`` (2, 1 or N) into ``block`` and ``valid``."""

    def plane(self, prepared, view, velocities, offsets, age, reference, velocity_epsilon,
              checked=True):
        """Return (block, valid) of one plane: per obstacle, viewpoint, cone, barrier terms.

        The filter's hot path in one compiled pass: ``block`` (``PLANE_ROWS`` + 2 + m, N)
        holds rows 0-1 the viewpoints P_n (r - age c_dot_n - o_n) of ``view``
        (``polyc2bf_ros.core.geometry.views``), then the cone (``CONE_ROWS``, as ``fill``), then h,
        Lf h, Lg h (``polyc2bf_ros.core.barrier.cone_barrier``) at the ``reference`` kinematics.
        ``checked=False`` skips the kernel's argument check (``jit``): only for arrays
        known to be C-contiguous float64, as the filter's own.
        """
        count = view.projections.shape[0]
        block = np.empty((PLANE_ROWS + 2 + reference.input_matrix.shape[1], count))
        valid = np.empty(count, dtype=np.bool_)
        self.fill_plane(prepared, view.projections, velocities, offsets, float(age), reference,
                        velocity_epsilon, block, valid, checked)
        return block, valid

    @abc.abstractmethod
    def fill_plane(self, prepared, projections, velocities, offsets, age, reference,
                   velocity_epsilon, block, valid, checked):
        """Write ``plane``'s block and validity."""

    def exits(self, prepared, viewpoints):
        """Return (3, N): the unit outward direction (rows 0-1) and the depth (row 2).

        The shortest way out of the region without a cone (module docstring); the depth
        is > 0 exactly where ``fill`` reports no cone, up to the boundary itself.
        """
        viewpoints = np.ascontiguousarray(viewpoints, dtype=np.float64).reshape(2, -1)
        out = np.empty((3, len(prepared)))
        self.fill_exits(prepared, viewpoints, out)
        return out

    @abc.abstractmethod
    def fill_exits(self, prepared, viewpoints, out):
        """Write ``exits`` of ``viewpoints`` (2, 1 or N) into ``out`` (3, N)."""

    def min_h_along(self, prepared, velocities, offsets, age, start, path, period,
                    velocity_epsilon):
        """Return the smallest h of any planar obstacle along a braking path; inf: unsupported.

        ``start`` is the reference point's [x, y, vx, vy] at ``age``, ``path`` (K, 4) rows
        the same (k + 1) periods on (``RobotModel.braking_path``).  The braking check's
        barrier test (``SafetyFilter``, ``braking_check_barrier``) uses it; a cone model
        without it (the default here) is checked for clearance alone.
        """
        return math.inf


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
        rx, ry = -(x[n, k] - qx), -(y[n, k] - qy)
        t = min(max((rx * edge_x[n, k] + ry * edge_y[n, k]) * inv_sq[n, k], 0.0), 1.0)
        dx, dy = rx - t * edge_x[n, k], ry - t * edge_y[n, k]
        if dx * dx + dy * dy < best:
            best, nearest, best_x, best_y = dx * dx + dy * dy, k, dx, dy
        inside = inside and edge_x[n, k] * ry >= edge_y[n, k] * rx
    return best, nearest, best_x, best_y, inside


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


class _PolygonCone(ConeModel):
    """PolyC2BF cones of (prepared) polygons, silhouette segment extended by ``extension``."""

    extension = 0.0

    def fill(self, prepared, viewpoints, block, valid):
        """Run the silhouette kernel."""
        _polygon_cones(prepared.x, prepared.y, prepared.edge_x, prepared.edge_y,
                       prepared.inv_sq, prepared.counts, viewpoints, self.extension, block,
                       valid)

    def fill_plane(self, prepared, projections, velocities, offsets, age, reference,
                   velocity_epsilon, block, valid, checked):
        """Run the fused silhouette kernel."""
        kernel = _polygon_plane if checked else _polygon_plane.unchecked
        kernel(prepared.x, prepared.y, prepared.edge_x, prepared.edge_y,
               prepared.inv_sq, prepared.counts, self.extension, projections,
               reference.position, velocities, offsets, age, reference.velocity,
               reference.drift, reference.input_matrix, velocity_epsilon, block, valid)

    def fill_exits(self, prepared, viewpoints, out):
        """Run the exit kernel."""
        _polygon_exits(prepared.x, prepared.y, prepared.edge_x, prepared.edge_y,
                       prepared.inv_sq, prepared.counts, viewpoints, self.extension, out)


class PaperCone(_PolygonCone):
    """PolyC2BF with the paper's width rule: silhouette segment extended by w/2.

    Inside (no cone) means within w/2 of the polygon.
    """

    name = 'polyc2bf_paper'

    def __init__(self, robot_radius):
        """Use extension w/2 = robot_radius."""
        self.extension = float(robot_radius)

    def prepare(self, batch):
        """Use the polygons as they are."""
        return PlanarPolygons.from_batch(batch)


class InflatedCone(_PolygonCone):
    """PolyC2BF on the polygon inflated by the robot radius (exact silhouette variant)."""

    name = 'polyc2bf_inflated'

    def __init__(self, robot_radius, segments=16):
        """Inflate by ``robot_radius`` with a circumscribed ``segments``-gon."""
        self.radius = float(robot_radius)
        self.segments = int(segments)

    def prepare(self, batch):
        """Inflate every polygon (once per obstacle update): ``minkowski_regular``."""
        if self.radius == 0.0:
            return PlanarPolygons.from_batch(batch)
        width = batch.vertices.shape[1] + self.segments
        x, y = np.empty((len(batch), width)), np.empty((len(batch), width))
        counts = np.empty(len(batch), dtype=np.intp)
        batch_geometry.minkowski_regular(batch.vertices, batch.counts, self.radius,
                                         self.segments, x, y, counts)
        return PlanarPolygons.from_rows(x, y, counts)


@dataclass(frozen=True)
class Circles:
    """Circle obstacles: centres (2, N) and radii (N,)."""

    centres: np.ndarray
    radii: np.ndarray

    def __len__(self):
        """Return the number of circles."""
        return self.radii.size


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


class CircleCone(ConeModel):
    """C3BF baseline: minimum enclosing circle plus robot radius."""

    name = 'c3bf'

    def __init__(self, robot_radius):
        """Grow every circle by ``robot_radius``."""
        self.radius = float(robot_radius)

    def prepare(self, batch):
        """Compute each polygon's minimum enclosing circle (``enclosing_circles``)."""
        centres, radii = np.empty((2, len(batch))), np.empty(len(batch))
        batch_geometry.enclosing_circles(batch.vertices, batch.counts, centres, radii)
        return Circles(centres, radii + self.radius)

    def fill(self, prepared, viewpoints, block, valid):
        """Run the circle kernel."""
        _circle_cones(prepared.centres, prepared.radii, viewpoints, block, valid)

    def fill_plane(self, prepared, projections, velocities, offsets, age, reference,
                   velocity_epsilon, block, valid, checked):
        """Run the fused circle kernel."""
        kernel = _circle_plane if checked else _circle_plane.unchecked
        kernel(prepared.centres, prepared.radii, projections, reference.position, velocities,
               offsets, age, reference.velocity, reference.drift, reference.input_matrix,
               velocity_epsilon, block, valid)

    def fill_exits(self, prepared, viewpoints, out):
        """Run the circle exit kernel."""
        _circle_exits(prepared.centres, prepared.radii, viewpoints, out)
