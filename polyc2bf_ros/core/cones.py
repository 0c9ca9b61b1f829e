"""Collision cones seen from the robot's reference point, behind one interface.

Every cone model maps convex polygons (in a plane, relative to a viewpoint q)
to a cone with apex q, axis vector p and a shape term::

    s(p) = ||p|| cos(phi) = <p, k_hat>                  (PolyC2BF, paper eq. 9)
    s(p) = sqrt(||p||^2 - R^2)                          (C3BF, paper eq. 3)

with its gradient ds/dp, so that one barrier serves all of them
(``polyc2bf_ros.core.barrier``).

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
"""
import abc
from dataclasses import dataclass

import numpy as np

from polyc2bf_ros.core.geometry import (
    inflate_polygon,
    minimum_enclosing_circle,
    PolygonBatch,
    signed_distance_batch,
)

_TINY = 1e-12


def dot2(a, b):
    """Return the column-wise dot product of planar vectors stored as (2, N) rows x, y."""
    return a[0] * b[0] + a[1] * b[1]


@dataclass(frozen=True)
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

    @property
    def k_norm(self):
        """Return ||k||, the distance to the cone's boundary point."""
        return np.sqrt(dot2(self.k, self.k))


@dataclass(frozen=True)
class PlanarPolygons:
    """Convex polygons laid out for the hot path: vertices (2, V, N), edges (V, N) each.

    ``previous`` indexes the edge before each vertex slot; padding slots repeat the
    last vertex and the closing edge, so chains of edges never break in the padding.
    """

    batch: PolygonBatch
    vertices: np.ndarray
    edge_x: np.ndarray
    edge_y: np.ndarray
    previous: np.ndarray
    columns: np.ndarray

    @classmethod
    def from_batch(cls, batch):
        """Precompute the layout once per obstacle update."""
        edge_x, edge_y, _ = batch.edge_table
        slots = batch.x.shape[0]
        return cls(batch=batch, vertices=np.stack([batch.x, batch.y]), edge_x=edge_x,
                   edge_y=edge_y, previous=np.roll(np.arange(slots), 1),
                   columns=np.arange(len(batch)))

    def __len__(self):
        """Return the number of polygons."""
        return len(self.batch)


class ConeModel(abc.ABC):
    """Turns planar convex polygons into cones seen from per-obstacle viewpoints."""

    name: str

    @abc.abstractmethod
    def prepare(self, batch: PolygonBatch):
        """Precompute per-obstacle geometry once per obstacle update (not per step)."""

    @abc.abstractmethod
    def cones(self, prepared, viewpoints) -> Cones:
        """Return the cones seen from ``viewpoints``: (2, N), or (2,) shared by all."""


def _column(viewpoints):
    """Return viewpoints shaped (2, 1, N) or (2, 1, 1) to broadcast against (2, V, N)."""
    return viewpoints.reshape(2, 1, -1)


def _polygon_cones(polygons, viewpoints, extension):
    """Build PolyC2BF cones from silhouette vertices (see module docstring).

    Edge k faces the viewpoint q when q is strictly right of it, cross(e_k, v_k - q) > 0;
    the facing edges form one chain whose end vertices are the tangent vertices.
    """
    rel = polygons.vertices - _column(viewpoints)
    facing = polygons.edge_x * rel[1] > polygons.edge_y * rel[0]
    incoming = facing[polygons.previous]
    ends = np.stack([(incoming > facing).argmax(axis=0), (facing > incoming).argmax(axis=0)])
    ab = rel[:, ends, polygons.columns]  # (2 coords, 2 vertices, N)
    p = 0.5 * (ab[:, 0] + ab[:, 1])
    if extension:
        along = ab[:, 1] - ab[:, 0]
        along *= extension / np.maximum(np.sqrt(dot2(along, along)), _TINY)
        ab[:, 0] -= along
        ab[:, 1] += along
    norms = np.maximum(np.sqrt(ab[0] * ab[0] + ab[1] * ab[1]), _TINY)
    cosines = (p[0] * ab[0] + p[1] * ab[1]) / norms  # <p, a_hat>, <p, b_hat>
    first = cosines[0] < cosines[1]  # the closer vertex makes the larger angle with p
    s = np.where(first, cosines[0], cosines[1])
    k_norm = np.where(first, norms[0], norms[1])
    k = np.where(first, ab[:, 0], ab[:, 1])
    k_hat = k / k_norm
    ds_dp = k_hat + (p - s * k_hat) / k_norm
    return Cones(p=p, k=k, s=s, ds_dp=ds_dp, valid=facing.any(axis=0))


class PaperCone(ConeModel):
    """PolyC2BF with the paper's width rule: silhouette segment extended by w/2."""

    name = 'polyc2bf_paper'

    def __init__(self, robot_radius):
        """Use extension w/2 = robot_radius."""
        self.extension = float(robot_radius)

    def prepare(self, batch):
        """Use the polygons as they are."""
        return PlanarPolygons.from_batch(batch)

    def cones(self, prepared, viewpoints):
        """Return paper cones; inside means within w/2 of the polygon."""
        cones = _polygon_cones(prepared, viewpoints, self.extension)
        if self.extension > 0.0:
            offsets = -np.broadcast_to(viewpoints.reshape(2, -1), (2, len(prepared))).T
            distance = signed_distance_batch(np.zeros(2), prepared.batch.translated(offsets))
            cones.valid[:] &= distance > self.extension
        return cones


class InflatedCone(ConeModel):
    """PolyC2BF on the polygon inflated by the robot radius (exact silhouette variant)."""

    name = 'polyc2bf_inflated'

    def __init__(self, robot_radius, segments=16):
        """Inflate by ``robot_radius`` with a circumscribed ``segments``-gon."""
        self.radius = float(robot_radius)
        self.segments = int(segments)

    def prepare(self, batch):
        """Inflate every polygon (once per obstacle update)."""
        polygons = [batch.vertices[i, :batch.counts[i]] for i in range(len(batch))]
        return PlanarPolygons.from_batch(PolygonBatch.from_polygons(
            [inflate_polygon(poly, self.radius, self.segments) for poly in polygons]))

    def cones(self, prepared, viewpoints):
        """Return tangent cones of the inflated polygons, no extension."""
        return _polygon_cones(prepared, viewpoints, 0.0)


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
        """Compute each polygon's minimum enclosing circle."""
        circles = [minimum_enclosing_circle(batch.vertices[i, :batch.counts[i]])
                   for i in range(len(batch))]
        centres = np.array([c for c, _ in circles], dtype=float).reshape(-1, 2).T
        radii = np.array([r for _, r in circles], dtype=float) + self.radius
        return Circles(np.ascontiguousarray(centres), radii)

    def cones(self, prepared, viewpoints):
        """Return C3BF cones: s = sqrt(|p|^2 - R^2), ds/dp = p / s."""
        p = prepared.centres - viewpoints.reshape(2, -1)
        distance_sq = dot2(p, p)
        clearance_sq = distance_sq - prepared.radii ** 2
        s = np.sqrt(np.maximum(clearance_sq, _TINY))
        # Boundary ray: p rotated by the half-angle phi, scaled to the tangent length s.
        cos_phi = s / np.sqrt(np.maximum(distance_sq, _TINY))
        sin_phi = prepared.radii / np.sqrt(np.maximum(distance_sq, _TINY))
        k = cos_phi * np.stack([cos_phi * p[0] - sin_phi * p[1], sin_phi * p[0] + cos_phi * p[1]])
        return Cones(p=p, k=k, s=s, ds_dp=p / s, valid=clearance_sq > 0.0)


CONE_MODELS = {cls.name: cls for cls in (PaperCone, InflatedCone, CircleCone)}


def make_cone_model(name, robot_radius, segments=16) -> ConeModel:
    """Build the cone model called ``name``."""
    if name == InflatedCone.name:
        return InflatedCone(robot_radius, segments)
    if name not in CONE_MODELS:
        raise ValueError(f'unknown barrier {name!r}; choose one of {", ".join(CONE_MODELS)}')
    return CONE_MODELS[name](robot_radius)
