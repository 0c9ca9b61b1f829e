"""Planar views of the obstacles: the plane in which each cone is built (paper section III).

Planar models see every obstacle in the horizontal plane.  3-D models see each
obstacle, a vertical prism (footprint x [z_min, z_max]), in two planes, each
through a constant projection P_n (2 x 3) as the paper assumes (eq. 14 and its
footnote)::

    horizontal   P   = [[1, 0, 0], [0, 1, 0]]     footprint polygon
    vertical     P_n = [[a_x, a_y, 0], [0, 0, 1]]  shadow rectangle in (s, z), s = <a_n, xy>

with a_n the footprint's thin axis (``batch_geometry.vertical_shadows``; a
prism without a finite, non-empty z range has no vertical view).  Each view
models the prism by an extrusion that contains it: the horizontal one extends
it to all heights, the vertical one without end along the footprint's long
axis l_n (a wall).  Avoiding either extrusion avoids the prism, so either cone
is safe.

Choice of plane: the paper keeps the plane whose cone has the smaller ||k||.
The vertical view's endless wall passes right beside, above or below a robot
anywhere along the long axis, however far the actual prism is: in the core
benchmark an 8-gon 15 m away, topped 0.1 m below the (inflated) robot, looked
0.1 m away in its vertical plane, won the ||k|| comparison and forbade
descending; with 200 such prisms the QP was infeasible from the first step.  So
the vertical plane is a candidate only where that wall is a fair model: where
the robot's reference point lies within the footprint's extent along l_n grown
by ``band_margin`` (the robot radius), or where the horizontal cone does not
exist (the robot above or below the footprint).  Among the candidates the
smaller ||k|| wins, as in the paper.

Translated sets (``ObstacleSet.translated``) keep the views of their base:
the cone of a polygon moved by o, seen from q, is the cone of the polygon seen
from q - o (p, k and s are differences of points), and a band moves with its
prism.  So obstacle n moved by o_n (x, y, z) is seen from the viewpoint
P_n (r - age c_dot_n - o_n) and compared with its band at
<l_n, r - age c_dot_n - o_n>; a set built from scratch has o = 0 (subtracting
0.0 changes no bit).
"""
from dataclasses import dataclass
from typing import Optional

import numpy as np

from polyc2bf_ros.core.geometry.polygons import PolygonBatch
from polyc2bf_ros.core.kernels import geometry_batch as batch_geometry
from polyc2bf_ros.core.kernels.views import _choose_planes, _viewpoints


@dataclass(frozen=True)
class View:
    """Obstacles seen in one plane, prepared once per obstacle update.

    ``prepared`` is the cone model's geometry, ``projections`` (N, 2, d) the P_n and
    ``enabled`` (N,) where the view exists
    (a vertical view needs a finite z range).  Vertical views also carry the long axes
    l_n (N, 2) and the ``band`` (N, 2) of <l_n, xy> in which they are candidates.
    """

    prepared: object
    projections: np.ndarray
    enabled: np.ndarray
    long_axes: Optional[np.ndarray] = None
    band: Optional[np.ndarray] = None

    def viewpoints(self, position, velocities, offsets, age):
        """Return the (2, N) viewpoints P_n (r - age c_dot_n - o_n) (see module docstring).

        Obstacles moved by ``age`` s and by ``offsets`` (N, d) from where the view has them.
        """
        out = np.empty((2, self.projections.shape[0]))
        _viewpoints(self.projections, position, velocities, offsets, float(age), out)
        return out


def prepare_views(obstacles, cone_model, dim, band_margin):
    """Return the views of ``obstacles`` for a ``dim``-dimensional robot (see module docstring)."""
    batch = obstacles.footprints
    projections = np.zeros((len(batch), 2, dim))
    projections[:, 0, 0] = projections[:, 1, 1] = 1.0
    views = [_view(cone_model, batch, projections, np.ones(len(batch), dtype=bool))]
    if dim == 3 and len(batch):
        views.append(_vertical_view(obstacles, cone_model, band_margin))
    return tuple(views)


def _view(cone_model, batch, projections, enabled, **band):
    """Prepare one plane's geometry for the cone model."""
    return View(prepared=cone_model.prepare(batch), projections=projections, enabled=enabled,
                **band)


def _vertical_view(obstacles, cone_model, band_margin):
    """Project each prism onto the vertical plane through its footprint's thin axis."""
    batch = obstacles.footprints
    count = len(batch)
    projections, long_axes = np.empty((count, 2, 3)), np.empty((count, 2))
    shadows, band = np.empty((count, 4, 2)), np.empty((count, 2))
    enabled = np.empty(count, dtype=np.bool_)
    batch_geometry.vertical_shadows(batch.vertices, batch.counts, obstacles.z_ranges,
                                    float(band_margin), projections, long_axes, shadows, band,
                                    enabled)
    return _view(cone_model, PolygonBatch(shadows, np.full(count, 4)), projections, enabled,
                 long_axes=long_axes, band=band)


def choose_planes(valid_h, k_h, valid_v, k_v, view, position, velocities, offsets, age):
    """Return (vertical, usable) per obstacle from cone validity and rays k in both planes.

    ``view`` is the vertical view; ``k_h``, ``k_v`` are (2, N); ``offsets`` (N, 3) how far
    the obstacles moved from where the view has them.
    """
    count = valid_h.shape[0]
    take, usable = np.empty(count, dtype=bool), np.empty(count, dtype=bool)
    _choose_planes(valid_h, k_h, valid_v, k_v, view.enabled, view.long_axes, view.band,
                   position, velocities, offsets, float(age), take, usable)
    return take, usable
