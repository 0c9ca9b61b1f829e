"""Collision cones seen from the robot's reference point, behind one interface.

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

from polyc2bf_ros.core.geometry.polygons import PolygonBatch
from polyc2bf_ros.core.kernels import geometry_batch as batch_geometry
from polyc2bf_ros.core.kernels.cones import (
    _circle_cones,
    _circle_exits,
    _circle_plane,
    _polygon_cones,
    _polygon_exits,
    _polygon_plane,
    CONE_ROWS,
    PLANE_ROWS,
)

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
    (``batch_geometry.edge_rows`` pads the rest); ``boxes`` (N, 4) each polygon's bounding
    box [low x, high x, low y, high y] (``kernels.cones.polygon_box``), for the braking
    check's kernels to skip far polygons without reading their vertices; ``hints`` (N, 3)
    where the horizon barrier found each polygon's nearest edge and silhouette (a, b)
    last (``kernels.cones.hinted_seen_edge``, ``hinted_silhouette``: a start, not a
    result).
    """

    x: np.ndarray
    y: np.ndarray
    edge_x: np.ndarray
    edge_y: np.ndarray
    inv_sq: np.ndarray
    counts: np.ndarray
    boxes: np.ndarray
    hints: np.ndarray

    @classmethod
    def from_rows(cls, x, y, counts):
        """Lay out (N, W) vertex rows (filled up to ``counts``) once per obstacle update."""
        edge_x, edge_y, inv_sq = np.empty_like(x), np.empty_like(x), np.empty_like(x)
        boxes = np.empty((len(counts), 4))
        batch_geometry.edge_rows(x, y, counts, edge_x, edge_y, inv_sq, boxes)
        return cls(x, y, edge_x, edge_y, inv_sq, counts, boxes,
                   np.zeros((len(counts), 3), dtype=np.int64))

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
                    velocity_epsilon, checked=True):
        """Return the smallest h of any planar obstacle along a braking path; inf: unsupported.

        ``start`` is the reference point's [x, y, vx, vy] at ``age``, ``path`` (K, 4) rows
        the same (k + 1) periods on (``RobotModel.braking_path``).  The braking check's
        barrier test (``SafetyFilter``, ``braking_check_barrier``) uses it; a cone model
        without it (the default here) is checked for clearance alone.  Exact where it is
        negative; where it is not, it may be any value >= 0 (pruning; the test asks only
        for the sign, and for the value where negative).  ``checked=False`` as ``plane``.
        """
        return math.inf

    def stop_skipped(self, prepared, velocities, offsets, first_time, last_time, bands):
        """Return True when ``min_h_along`` is surely >= 0 on every path ``bands`` bound.

        ``bands`` (``RobotModel.stop_bands``) hold every row, the start at ``first_time``
        and the last row by ``last_time``; the braking check then keeps an input without
        computing its path (``SafetyFilter._stop_certified``).  True here while
        ``min_h_along`` is this class's +inf; a model with its own ``min_h_along`` and no
        test of its own is never certified.
        """
        return type(self).min_h_along is ConeModel.min_h_along


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
