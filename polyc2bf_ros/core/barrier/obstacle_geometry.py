"""What a filter prepares of an obstacle set before any step: its views, once per geometry.

The views (``views.prepare_views``: silhouettes, cones, for 3-D models the vertical planes)
depend only on the cone model's settings, the robot's position dimension and the guard
radius, and, for 3-D models with a ground, on the ground's height.  ``ObstacleGeometry``
holds exactly those, so the node's obstacle worker prepares sets off the control path
without building a filter (its solver, its warm-up steps), and the filter that steps on
the set finds the views under the same ``key`` in ``ObstacleSet.geometry``.  The filter
hands its own (``SafetyFilter.geometry``) to the worker, so the two always agree, whatever
the model's parameters; two are equal when they prepare the same views for the same body.
"""
import math

import numpy as np

from polyc2bf_ros.core.barrier.cone_models import make_cone_model
from polyc2bf_ros.core.barrier.footprint_cone import FootprintCone
from polyc2bf_ros.core.geometry.footprint import parse_footprint
from polyc2bf_ros.core.geometry.polygons import convex_hull
from polyc2bf_ros.core.geometry.views import prepare_views
from polyc2bf_ros.core.obstacles.ground import grounded

SCAN_BODY_MARGIN = 0.03
"""m: scan endpoints this far inside a guarded footprint's edge are still obstacles.

A robot guarded by its polygon comes to ``braking_margin`` of an obstacle, and a scan placed
at a pose a moment stale puts the obstacle's near side a few millimetres inside the
footprint.  Dropped as the robot's own, the obstacle vanished: a Jackal in BARN from its
laser, first 50 worlds, with every endpoint inside the box dropped, collided in 14 % / 2 %
of the go-to-goal / path runs by 1-2 mm; with those 3 cm inside kept (through a
footprint-shaped self-filter), 4 % / 4 %; with the disc inside the box less 3 cm
(``own_radius``), bench/README.md.  A disc robot keeps its guard offset beyond its
self-filter disc.
"""


def _outward_normals(polygon):
    """Return the unit outward normal of each edge of a convex CCW polygon (k, 2)."""
    edges = np.roll(polygon, -1, axis=0) - polygon
    return np.column_stack((edges[:, 1], -edges[:, 0])) / np.hypot(*edges.T)[:, None]


def inner_radius(polygon):
    """Return the radius of the largest disc about the origin inside a convex polygon.

    The least distance from the origin to an edge's line (0 or less: the origin is outside).
    """
    return float(np.min(np.einsum('ij,ij->i', _outward_normals(polygon), polygon)))


def half_width(polygon):
    """Return half the least width of a convex polygon: min over edge normals n of the extent.

    A convex polygon's width across a direction is least across one of its edges' normals.
    """
    extents = polygon @ _outward_normals(polygon).T
    return float(0.5 * np.min(extents.max(axis=0) - extents.min(axis=0)))


class ObstacleGeometry:
    """Prepares obstacle sets' views for one cone model, dimension, guard radius and ground."""

    def __init__(self, model, config):
        """For ``model`` (a ``RobotModel``) and a validated ``FilterConfig``.

        The guard radius is the body's radius (``FilterConfig.body_radius``: a footprint's
        covering disc, else ``robot_radius``) grown by the model's offset l: the guarded
        point keeps R + l, so the body around its centre keeps R (``guard_offset``).
        ``footprint``: the parsed polygon (``geometry.footprint``), or None.  ``turning``:
        the footprint's convex hull is guarded itself with ``barrier`` ``polyc2bf_footprint``
        (``footprint_cone``; a model that ``turns_footprint`` only), else the covering
        disc is.  ``passage_radius``: half the narrowest gap the guarded
        body passes, the guard radius for a disc, half the footprint's least width for a
        turning one (``half_width``; it passes aligned with the gap).  ``own_radius``: scan
        endpoints this near the origin are the robot's own: the guarded disc's radius, or a
        turning footprint's ``inner_radius`` less ``SCAN_BODY_MARGIN``.
        """
        self.dim = model.position_dim
        self.footprint = parse_footprint(config.footprint)
        self.robot_radius = float(config.body_radius)
        self.turning = config.barrier == FootprintCone.name
        if self.turning and not model.turns_footprint:
            raise ValueError(f'barrier {FootprintCone.name}: the {model.name} model has no '
                             'heading to turn a footprint with; use polyc2bf_horizon (the '
                             "footprint's covering disc)")
        self.passage_radius = self.robot_radius + model.guard_offset
        self.own_radius = self.robot_radius
        if self.turning:
            hull = convex_hull(self.footprint)
            self.guard_radius = self.robot_radius
            self.passage_radius = half_width(hull)
            self.own_radius = max(0.0, inner_radius(hull) - SCAN_BODY_MARGIN)
            self.cone_model = FootprintCone(hull, config.horizon,
                                            config.obstacle_accel,
                                            config.obstacle_velocity_error, config.gamma)
        else:
            self.guard_radius = float(self.robot_radius + model.guard_offset)
            self.cone_model = make_cone_model(config.barrier, self.guard_radius,
                                              config.inflation_segments, config.horizon,
                                              config.cone_axis)
        self.ground = (float(config.ground_z) if self.dim == 3 and math.isfinite(config.ground_z)
                       else None)
        settings = sorted((name, value) for name, value in vars(self.cone_model).items()
                          if not name.startswith('_'))
        self.key = (type(self.cone_model).__name__, tuple(settings), self.dim, self.guard_radius)

    def __eq__(self, other):
        """Equal when both prepare the same views for the same body."""
        return (isinstance(other, ObstacleGeometry) and self.key == other.key
                and self.ground == other.ground and self.robot_radius == other.robot_radius)

    def __hash__(self):
        """Hash of what equality compares."""
        return hash((self.key, self.ground, self.robot_radius))

    def prepare(self, obstacles):
        """Compute the views of a finite set now (a translated set: of its base)."""
        if obstacles.base is not None:
            obstacles = obstacles.base
        if obstacles.is_finite():
            self.views(self.grounded(obstacles))

    def grounded(self, obstacles):
        """Return ``obstacles`` standing on the ground (``obstacles.ground``), if there is one."""
        if self.ground is None:
            return obstacles
        return grounded(obstacles, self.ground, self.guard_radius)

    def views(self, obstacles):
        """Return the views of ``obstacles``, computed once per set and ``key``."""
        views = obstacles.geometry.get(self.key)
        if views is None:
            views = prepare_views(obstacles, self.cone_model, self.dim, self.guard_radius)
            obstacles.geometry[self.key] = views
        return views
