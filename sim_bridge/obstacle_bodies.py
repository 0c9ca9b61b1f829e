"""An obstacle's PyBullet bodies (``ObstacleBody``) and its published ``Footprint``.

A ``Footprint`` is also how a robot is published to the others (``SimWorld``).

A cylinder obstacle (``ObstacleSpec.radius``) is a PyBullet cylinder
(collision margin 0), so closest points measure the true cylinder, not the
polygon the filter is given.
"""
import dataclasses

import numpy as np
import pybullet as pb

from polyc2bf_ros.core.geometry.polygons import decompose_convex, is_convex


@dataclasses.dataclass(frozen=True, eq=False)
class Footprint:
    """An obstacle as published: CCW polygon (k, 2), z range, velocity [vx, vy, vz].

    ``index`` is its place in the scenario's obstacle list (``robot`` False) or
    robot list (``robot`` True): a stable identity while others come and go.
    """

    name: str
    polygon: np.ndarray
    z_min: float
    z_max: float
    velocity: np.ndarray
    index: int
    robot: bool = False


class ObstacleBody:
    """Static, constant-velocity or trajectory prism: a mass-0 body per convex part, one anchor.

    It is present from ``appear()`` on (at construction when ``appear_at`` is 0); its
    bodies are made then, or with ``lazy`` on the first ``bodies_at``.  ``exact``: collision
    margin 0 (exact closest points; rays miss most such shapes), else Bullet's default.
    A moving one is translated by ``offset(t)`` (``ObstacleSpec.offset``): v (t - t_a), or
    p(t) - p(t_a) along its ``trajectory``, whose ``velocity(t)`` its footprint carries.
    """

    def __init__(self, spec, index, client, lazy, exact=True):
        """Describe the prism; part vertices are relative to the footprint's vertex mean."""
        self.spec = spec
        self.client = client
        self.exact = exact
        self.moving = spec.moving
        self.trajectory = spec.trajectory
        if self.trajectory is not None:  # where the trajectory is when ``polygon`` holds
            self.origin = np.asarray(self.trajectory.position(spec.appear_at), dtype=float)
        self.anchor = np.mean(spec.polygon, axis=0)
        velocity = np.append(spec.velocity, 0.0)
        self.footprint = Footprint(spec.name, spec.polygon, spec.z[0], spec.z[1], velocity,
                                   index)
        self.bodies, self.heights = [], []  # a body per part, and its frame's z
        self.lower = spec.polygon.min(axis=0)
        self.upper = spec.polygon.max(axis=0)
        self.lazy = lazy
        self.present = False
        if spec.appear_at <= 0.0:
            self.appear(0.0)

    def _shapes(self):
        """Return (collision shape, z of the body frame) per body: a cylinder, or mesh parts."""
        z_min, z_max = self.spec.z
        if self.spec.radius is not None:
            shape = pb.createCollisionShape(pb.GEOM_CYLINDER, radius=self.spec.radius,
                                            height=z_max - z_min, physicsClientId=self.client)
            return [(shape, 0.5 * (z_min + z_max))]
        polygon = self.spec.polygon
        shapes = []
        for part in [polygon] if is_convex(polygon) else decompose_convex(polygon):
            local = part - self.anchor
            vertices = [(x, y, z) for z in self.spec.z for x, y in local]
            shapes.append((pb.createCollisionShape(pb.GEOM_MESH, vertices=vertices,
                                                   physicsClientId=self.client), 0.0))
        return shapes

    def appear(self, time):
        """Make it present at ``time``, with its bodies unless they are made on first use."""
        self.present = True
        if not self.lazy:
            self.bodies_at(time)

    def bodies_at(self, time):
        """Return its bodies, made first (a cylinder, or a convex mesh per part) if need be."""
        if not self.bodies:
            for shape, z in self._shapes():
                body = pb.createMultiBody(0.0, shape, basePosition=(*self.anchor, z),
                                          physicsClientId=self.client)
                self.heights.append(z)
                if self.exact:
                    pb.changeDynamics(body, -1, collisionMargin=0.0, physicsClientId=self.client)
                self.bodies.append(body)
            if self.moving:
                self.place(time)
        return self.bodies

    def offset(self, time):
        """Return the translation since it appeared: v (t - t_a), or p(t) - p(t_a)."""
        if self.trajectory is None:
            return self.spec.velocity * (time - self.spec.appear_at)
        return np.asarray(self.trajectory.position(time), dtype=float) - self.origin

    def place(self, time):
        """Move every part to its position at ``time`` (nothing while it has no bodies)."""
        if not self.bodies:
            return
        x, y = self.anchor + self.offset(time)
        for body, z in zip(self.bodies, self.heights):
            pb.resetBasePositionAndOrientation(body, (x, y, z), (0.0, 0.0, 0.0, 1.0),
                                               physicsClientId=self.client)

    def footprint_at(self, time):
        """Return the published footprint at ``time``."""
        if not self.moving:
            return self.footprint
        spec = self.spec
        velocity = self.footprint.velocity
        if self.trajectory is not None:  # the instantaneous velocity
            velocity = np.append(self.trajectory.velocity(time), 0.0)
        return Footprint(spec.name, spec.polygon + self.offset(time), spec.z[0], spec.z[1],
                         velocity, self.footprint.index)

