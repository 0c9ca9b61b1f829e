"""Obstacle records and the padded, vectorised set the filter consumes.

An obstacle is a polygonal footprint (convex or simple non-convex) in the
odometry frame, translating at constant velocity, optionally bounded in z
(a vertical prism, for 3-D models).  Non-convex footprints are split into
convex parts when the set is built; every part is one constraint row.
"""
from dataclasses import dataclass, field

import numpy as np

from polyc2bf_ros.core.geometry import decompose_convex, is_convex, PolygonBatch


@dataclass(frozen=True)
class Obstacle:
    """One obstacle: footprint polygon (k,2), velocity (2,) or (3,), z range, key."""

    polygon: np.ndarray
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    z_min: float = -np.inf
    z_max: float = np.inf
    key: str = ''


@dataclass(frozen=True)
class ObstacleSet:
    """Convex obstacle parts as padded arrays: footprints, velocities (N,3), z ranges (N,2).

    ``owner[n]`` is the index into ``keys`` of the obstacle part ``n`` came from.
    """

    footprints: PolygonBatch
    velocities: np.ndarray
    z_ranges: np.ndarray
    owner: np.ndarray
    keys: tuple = ()

    @classmethod
    def empty(cls):
        """Return a set with no obstacles."""
        return cls.from_obstacles([])

    @classmethod
    def from_obstacles(cls, obstacles):
        """Build the set, splitting non-convex footprints into convex parts."""
        parts, velocities, z_ranges, owner = [], [], [], []
        for index, obstacle in enumerate(obstacles):
            polygon = np.asarray(obstacle.polygon, dtype=float)
            pieces = [polygon] if is_convex(polygon) else decompose_convex(polygon)
            velocity = np.zeros(3)
            given = np.asarray(obstacle.velocity, dtype=float).ravel()
            velocity[:given.size] = given[:3]
            for piece in pieces:
                parts.append(piece)
                velocities.append(velocity)
                z_ranges.append((obstacle.z_min, obstacle.z_max))
                owner.append(index)
        return cls(footprints=PolygonBatch.from_polygons(parts),
                   velocities=np.array(velocities, dtype=float).reshape(-1, 3),
                   z_ranges=np.array(z_ranges, dtype=float).reshape(-1, 2),
                   owner=np.array(owner, dtype=int),
                   keys=tuple(o.key for o in obstacles))

    def __len__(self):
        """Return the number of convex parts."""
        return len(self.footprints)

    def is_finite(self):
        """Return True when vertices and velocities are finite (z bounds may be infinite)."""
        return bool(np.isfinite(self.footprints.vertices).all()
                    and np.isfinite(self.velocities).all()
                    and not np.isnan(self.z_ranges).any())
