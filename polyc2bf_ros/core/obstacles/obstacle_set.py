"""Obstacle records and the padded, vectorised set the filter consumes.

An obstacle is a polygonal footprint (convex or simple non-convex) in the
odometry frame, translating at constant velocity, optionally bounded in z
(a vertical prism, for 3-D models).  Non-convex footprints are split into
convex parts when the set is built; every part is one constraint row.

Obstacles that only move (other robots, moving boxes, tracked markers whose
shape is unchanged) need not be rebuilt: ``ObstacleSet.translated`` moves the
parts of a built set, and the set it returns remembers the set it was built
from (``base``) and by how much each part moved (``offsets``), so that the
filter translates the geometry it prepared for ``base`` instead of preparing
it again.

Non-convex footprints above ``max_parts`` convex parts are replaced by their convex hull
(``polygon_limits``; conservative) and their keys listed in ``capped``.  ``geometry`` is the
filter's per-set cache of prepared views (``SafetyFilter.prepare``), so a set prepared off
the control path arrives ready.
"""
from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from polyc2bf_ros.core.geometry.polygon_limits import bounded_convex_parts, MAX_PARTS
from polyc2bf_ros.core.geometry.polygons import is_convex, PolygonBatch
from polyc2bf_ros.core.kernels.obstacle_set import _finite


@dataclass(frozen=True)
class Obstacle:
    """One obstacle: footprint polygon (k,2), velocity (2,) or (3,), z range, key.

    ``velocity_error`` [m/s] >= 0: how far its true velocity may be from ``velocity`` (an
    obstacle whose velocity is not known: ``scan_tracker``, step 5); the braking check
    allows for it (``barrier.braking_check``).  ``acceleration`` (2,) or None (none known):
    its estimated planar acceleration (``marker_tracker``), which an evasion's look ahead
    follows.
    """

    polygon: np.ndarray
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    z_min: float = -np.inf
    z_max: float = np.inf
    key: str = ''
    velocity_error: float = 0.0
    acceleration: Optional[np.ndarray] = None


@dataclass(frozen=True)
class ObstacleSet:
    """Convex obstacle parts as padded arrays: footprints, velocities (N,3), z ranges (N,2).

    ``owner[n]`` is the index into ``keys`` of the obstacle part ``n`` came from.  A set
    made by ``translated`` has ``base``, the set it was translated from (itself never a
    translation), and ``offsets`` (N, 3): part n is base part n moved by ``offsets[n]``
    in x, y and z; otherwise both are None.  ``capped``: keys of the footprints replaced by
    their convex hull (more than ``max_parts`` parts); ``geometry``: prepared views by
    filter geometry (``SafetyFilter.prepare``); ``velocity_errors`` (N,): the parts'
    ``Obstacle.velocity_error``, None when all are 0; ``accelerations`` (N, 2): the parts'
    ``Obstacle.acceleration``, None when all are 0.
    """

    footprints: PolygonBatch
    velocities: np.ndarray
    z_ranges: np.ndarray
    owner: np.ndarray
    keys: tuple = ()
    base: Optional['ObstacleSet'] = field(default=None, repr=False, compare=False)
    offsets: Optional[np.ndarray] = field(default=None, repr=False, compare=False)
    capped: tuple = ()
    geometry: dict = field(default_factory=dict, repr=False, compare=False)
    velocity_errors: Optional[np.ndarray] = field(default=None, repr=False, compare=False)
    accelerations: Optional[np.ndarray] = field(default=None, repr=False, compare=False)

    @classmethod
    def empty(cls):
        """Return a set with no obstacles."""
        return cls.from_obstacles([])

    @classmethod
    def from_obstacles(cls, obstacles, max_parts=MAX_PARTS):
        """Build the set, splitting non-convex footprints into at most ``max_parts`` parts.

        Convex CCW footprints (``PolygonBatch.convex_ccw``, one kernel call for all) are
        used as they are; only the others go through ``bounded_convex_parts``.
        """
        obstacles = list(obstacles)
        footprints = PolygonBatch.pack([obstacle.polygon for obstacle in obstacles])
        convex = footprints.convex_ccw()
        velocities = _velocities(obstacles)
        z_ranges = np.empty((len(obstacles), 2))
        z_ranges[:, 0] = [obstacle.z_min for obstacle in obstacles]
        z_ranges[:, 1] = [obstacle.z_max for obstacle in obstacles]
        owner = np.arange(len(obstacles))
        errors = [obstacle.velocity_error for obstacle in obstacles]
        errors = np.array(errors, dtype=np.float64) if any(errors) else None
        accelerations = None
        if any(o.acceleration is not None for o in obstacles):
            accelerations = np.zeros((len(obstacles), 2))
            for row, obstacle in zip(accelerations, obstacles):
                if obstacle.acceleration is not None:
                    row[:] = obstacle.acceleration[:2]
            accelerations = accelerations if accelerations.any() else None
        capped = ()
        if not convex.all():
            pieces, hulled = zip(*[_convex_parts(o.polygon, ok, max_parts)
                                   for o, ok in zip(obstacles, convex)])
            capped = tuple(o.key for o, hull in zip(obstacles, hulled) if hull)
            owner = np.repeat(owner, [len(parts) for parts in pieces])
            footprints = PolygonBatch.from_polygons([part for parts in pieces for part in parts])
            velocities, z_ranges = velocities[owner], z_ranges[owner]
            errors = None if errors is None else errors[owner]
            accelerations = None if accelerations is None else accelerations[owner]
        return cls(footprints=footprints, velocities=velocities, z_ranges=z_ranges, owner=owner,
                   keys=tuple(obstacle.key for obstacle in obstacles), capped=capped,
                   velocity_errors=errors, accelerations=accelerations)

    def translated(self, offsets, velocities=None, accelerations=None):
        """Return the set with part n moved by ``offsets[n]`` ((N, 2) x, y or (N, 3) x, y, z).

        ``velocities`` (N, 3) replaces the parts' velocities, ``accelerations`` (N, 2)
        their planar accelerations (default: both kept).  The result's
        ``base`` is this set's base, or this set if it has none, with the offsets added up,
        so a chain of translations computes every vertex from the base in one addition
        (``PolygonBatch.translated``, which reuses the base's edge table).
        """
        count = len(self)
        offsets = np.asarray(offsets, dtype=np.float64)
        if offsets.ndim != 2 or offsets.shape[0] != count or offsets.shape[1] not in (2, 3):
            raise ValueError(f'offsets must have shape ({count}, 2) or ({count}, 3), '
                             f'got {offsets.shape}')
        velocities = self.velocities if velocities is None else np.asarray(velocities,
                                                                          dtype=np.float64)
        if velocities.shape != (count, 3):
            raise ValueError(f'velocities must have shape ({count}, 3), got {velocities.shape}')
        if accelerations is None:
            accelerations = self.accelerations
        else:
            accelerations = np.asarray(accelerations, dtype=np.float64)
            if accelerations.shape != (count, 2):
                raise ValueError(f'accelerations must have shape ({count}, 2), '
                                 f'got {accelerations.shape}')
        moves = np.zeros((count, 3))
        moves[:, :offsets.shape[1]] = offsets
        base = self
        if self.base is not None:
            base, moves = self.base, moves + self.offsets
        return ObstacleSet(footprints=base.footprints.translated(moves[:, :2]),
                           velocities=velocities, z_ranges=base.z_ranges + moves[:, 2:],
                           owner=base.owner, keys=base.keys, base=base, offsets=moves,
                           capped=base.capped, velocity_errors=self.velocity_errors,
                           accelerations=accelerations)

    def __len__(self):
        """Return the number of convex parts."""
        return len(self.footprints)

    def is_finite(self):
        """Return True when vertices, velocities and accelerations are finite (z may be inf)."""
        return (_finite(self.footprints.vertices, self.velocities, self.z_ranges)
                and (self.accelerations is None or bool(np.isfinite(self.accelerations).all())))


def _convex_parts(polygon, convex_ccw, max_parts):
    """Return ``(convex parts, hulled)`` of a footprint: itself if convex, else bounded parts."""
    polygon = np.asarray(polygon, dtype=float)
    if convex_ccw or is_convex(polygon):
        return [polygon], False
    return bounded_convex_parts(polygon, max_parts)


def _velocities(obstacles):
    """Return the (N, 3) velocities, zero-padded from (2,) or (3,) (first 3 entries kept)."""
    out = np.zeros((len(obstacles), 3))
    try:
        given = np.array([obstacle.velocity for obstacle in obstacles], dtype=float)
    except ValueError:  # mixed lengths
        given = None
    if given is not None and given.ndim == 2:
        out[:, :min(3, given.shape[1])] = given[:, :3]
        return out
    for row, obstacle in zip(out, obstacles):
        velocity = np.asarray(obstacle.velocity, dtype=float).ravel()[:3]
        row[:velocity.size] = velocity
    return out
