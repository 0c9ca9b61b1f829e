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
    silhouette_indices,
)

_TINY = 1e-12
_ORIGIN = np.zeros(2)


@dataclass(frozen=True)
class Cones:
    """Per-obstacle cones (N rows): axis p, boundary k, s = <p, k_hat>, ds/dp, validity.

    ``valid`` is False where the viewpoint is inside the (inflated) obstacle,
    where no cone exists; the other fields are finite there but meaningless.
    """

    p: np.ndarray
    k: np.ndarray
    s: np.ndarray
    ds_dp: np.ndarray
    valid: np.ndarray

    @property
    def k_norm(self):
        """Return ||k||, the distance to the cone's boundary point."""
        return np.linalg.norm(self.k, axis=1)


class ConeModel(abc.ABC):
    """Turns planar convex polygons into cones seen from per-obstacle viewpoints."""

    name: str

    @abc.abstractmethod
    def prepare(self, batch: PolygonBatch):
        """Precompute per-obstacle geometry once per obstacle update (not per step)."""

    @abc.abstractmethod
    def cones(self, prepared, viewpoints) -> Cones:
        """Return the cones seen from ``viewpoints`` (N,2), one per polygon."""


def _polygon_cones(batch, viewpoints, extension, outside):
    """Build PolyC2BF cones from silhouette vertices (see module docstring)."""
    n = len(batch)
    relative = batch.translated(-viewpoints)
    rel = relative.vertices
    first, second, seen = silhouette_indices(_ORIGIN, relative)
    rows = np.arange(n)
    a = rel[rows, first]
    b = rel[rows, second]
    along = b - a
    along /= np.maximum(np.linalg.norm(along, axis=1), _TINY)[:, None]
    a_ext = a - extension * along
    b_ext = b + extension * along
    p = 0.5 * (a + b)
    cos_a = np.einsum('ij,ij->i', p, a_ext) / np.maximum(np.linalg.norm(a_ext, axis=1), _TINY)
    cos_b = np.einsum('ij,ij->i', p, b_ext) / np.maximum(np.linalg.norm(b_ext, axis=1), _TINY)
    k = np.where((cos_a < cos_b)[:, None], a_ext, b_ext)
    k_norm = np.maximum(np.linalg.norm(k, axis=1), _TINY)
    k_hat = k / k_norm[:, None]
    s = np.einsum('ij,ij->i', p, k_hat)
    ds_dp = k_hat + (p - s[:, None] * k_hat) / k_norm[:, None]
    return Cones(p=p, k=k, s=s, ds_dp=ds_dp, valid=seen & outside)


class PaperCone(ConeModel):
    """PolyC2BF with the paper's width rule: silhouette segment extended by w/2."""

    name = 'polyc2bf_paper'

    def __init__(self, robot_radius):
        """Use extension w/2 = robot_radius."""
        self.extension = float(robot_radius)

    def prepare(self, batch):
        """Use the polygons as they are."""
        return batch

    def cones(self, prepared, viewpoints):
        """Return paper cones; inside means within w/2 of the polygon."""
        outside = np.ones(len(prepared), dtype=bool)
        if self.extension > 0.0:
            outside = _signed_distances(prepared, viewpoints) > self.extension
        return _polygon_cones(prepared, viewpoints, self.extension, outside)


def _signed_distances(batch, viewpoints):
    """Return the signed distance from each viewpoint to its own polygon."""
    return signed_distance_batch(_ORIGIN, batch.translated(-viewpoints))


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
        return PolygonBatch.from_polygons(
            [inflate_polygon(poly, self.radius, self.segments) for poly in polygons])

    def cones(self, prepared, viewpoints):
        """Return tangent cones of the inflated polygons, no extension."""
        return _polygon_cones(prepared, viewpoints, 0.0, np.ones(len(prepared), dtype=bool))


@dataclass(frozen=True)
class Circles:
    """Circle obstacles: centres (N,2) and radii (N,)."""

    centres: np.ndarray
    radii: np.ndarray


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
        centres = np.array([c for c, _ in circles], dtype=float).reshape(-1, 2)
        radii = np.array([r for _, r in circles], dtype=float) + self.radius
        return Circles(centres, radii)

    def cones(self, prepared, viewpoints):
        """Return C3BF cones: s = sqrt(|p|^2 - R^2), ds/dp = p / s."""
        p = prepared.centres - viewpoints
        clearance_sq = np.einsum('ij,ij->i', p, p) - prepared.radii ** 2
        valid = clearance_sq > 0.0
        s = np.sqrt(np.maximum(clearance_sq, _TINY))
        ds_dp = p / s[:, None]
        # Boundary ray: p rotated by the half-angle phi, scaled to the tangent length s.
        dist = np.maximum(np.linalg.norm(p, axis=1), _TINY)
        cos_phi, sin_phi = s / dist, prepared.radii / dist
        rotated = np.stack([cos_phi * p[:, 0] - sin_phi * p[:, 1],
                            sin_phi * p[:, 0] + cos_phi * p[:, 1]], axis=1)
        k = rotated * (s / dist)[:, None]
        return Cones(p=p, k=k, s=s, ds_dp=ds_dp, valid=valid)


CONE_MODELS = {cls.name: cls for cls in (PaperCone, InflatedCone, CircleCone)}


def make_cone_model(name, robot_radius, segments=16) -> ConeModel:
    """Build the cone model called ``name``."""
    if name == InflatedCone.name:
        return InflatedCone(robot_radius, segments)
    if name not in CONE_MODELS:
        raise ValueError(f'unknown barrier {name!r}; choose one of {", ".join(CONE_MODELS)}')
    return CONE_MODELS[name](robot_radius)
