"""The ground as an obstacle for 3-D models (``FilterConfig.ground_z``).

A 3-D model sees every obstacle as a vertical prism, footprint x [z_min, z_max], and
treats the space below z_min as free: a wall standing on the floor, reported with
z_min = 0, has a vertical cone whose lower ray aims under it, and the robot was routed
into the floor.  With a ground at height g (``ground_z``, finite):

* the floor is one more obstacle part, a slab of ``GROUND_HALF_WIDTH`` on each side of the
  origin from g - ``GROUND_DEPTH`` to g.  The robot is always above its footprint, so it
  is seen in its vertical plane only (``views``): the cone of its top edge, a half-plane
  below the robot, and with ``polyc2bf_horizon`` a descent slower than (z - g - R) / tau;
* every prism with z_min <= g + R (R the guard radius) stands on the floor: its z_min
  becomes g - ``GROUND_DEPTH``, so no cone routes below it.

The grounded set is built once per obstacle set and kept in the set's geometry cache; a
translated set (``ObstacleSet.translated``) uses its base's, with the floor not moving.
The floor is the last part: ``FilterInfo.h`` has one entry more than the set has parts.
"""
import numpy as np

from polyc2bf_ros.core.obstacles.obstacle_set import Obstacle, ObstacleSet

GROUND_HALF_WIDTH = 1.0e4
"""Half the side [m] of the floor slab: beyond any robot's reach."""
GROUND_DEPTH = 1.0e3
"""How far [m] below the ground the slab, and every prism standing on it, extends."""
GROUND_KEY = 'ground'


def grounded(obstacles, ground_z, radius):
    """Return ``obstacles`` (a set that is not a translation) standing on a ground at ``ground_z``.

    Prisms whose z_min is at or below ground_z + ``radius`` reach down to the slab's bottom;
    the floor slab is appended as the last part.  Cached in ``obstacles.geometry``.
    """
    key = (GROUND_KEY, float(ground_z), float(radius))
    cached = obstacles.geometry.get(key)
    if cached is not None:
        return cached
    bottom = ground_z - GROUND_DEPTH
    batch = obstacles.footprints
    parts = []
    for n in range(len(obstacles)):
        z_min, z_max = obstacles.z_ranges[n]
        standing = z_min <= ground_z + radius
        parts.append(Obstacle(polygon=batch.vertices[n, :batch.counts[n]],
                              velocity=obstacles.velocities[n],
                              z_min=bottom if standing else z_min, z_max=z_max,
                              key=obstacles.keys[obstacles.owner[n]] if obstacles.keys
                              else ''))
    side = GROUND_HALF_WIDTH
    parts.append(Obstacle(polygon=np.array([[-side, -side], [side, -side], [side, side],
                                            [-side, side]]),
                          z_min=bottom, z_max=ground_z, key=GROUND_KEY))
    result = ObstacleSet.from_obstacles(parts)
    obstacles.geometry[key] = result
    return result


def ground_offsets(offsets, velocities):
    """Return a translated set's (offsets, velocities) with the floor's (zero) row appended."""
    return (np.vstack([offsets, np.zeros((1, offsets.shape[1]))]),
            np.vstack([velocities, np.zeros((1, velocities.shape[1]))]))
