"""Numpy closed-loop rollouts: nominal controller -> filter -> sample-and-hold plant.

Used by the core's closed-loop tests and the core benchmark's sanity runs; the
PyBullet bridge is the full-physics counterpart.  The filter runs every
``control_period``; between samples the input is held and the model's own
dynamics are integrated with RK4 at ``physics_step``.
"""
from dataclasses import dataclass, field

import numpy as np

from polyc2bf_ros.core.geometry.polygons import convex_hull, signed_distance, signed_distance_batch
from polyc2bf_ros.core.obstacles.obstacle_set import Obstacle, ObstacleSet


def rk4_step(model, x, u, dt):
    """Advance x by dt under constant input u with classic Runge-Kutta 4."""
    k1 = model.state_derivative(x, u)
    k2 = model.state_derivative(x + 0.5 * dt * k1, u)
    k3 = model.state_derivative(x + 0.5 * dt * k2, u)
    k4 = model.state_derivative(x + dt * k3, u)
    return x + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)


@dataclass
class Rollout:
    """Trajectory and per-step filter results of one closed-loop run."""

    states: np.ndarray
    inputs: np.ndarray
    nominal: np.ndarray
    statuses: list = field(default_factory=list)
    clearances: np.ndarray = field(default_factory=lambda: np.zeros(0))

    @property
    def min_clearance(self):
        """Return the smallest clearance seen (inf without obstacles)."""
        return float(self.clearances.min()) if self.clearances.size else float('inf')


def clearance(model, state, obstacles, robot_radius):
    """Return min over obstacles of signed distance(body centre, obstacle) - radius.

    The body is the disc (3-D: sphere) of ``robot_radius`` around ``model.body_centre``,
    not around the guarded point.  A 3-D obstacle is the prism footprint x [z_min, z_max]:
    with h the signed distance to the footprint and v = max(z_min - z, z - z_max), the
    distance to the prism is sqrt(h^2 + v^2) beside and above (or below) it, else
    max(h, v): exact for a convex prism.
    """
    if not len(obstacles):
        return float('inf')
    position = model.body_centre(state)
    horizontal = signed_distance_batch(position[:2], obstacles.footprints)
    if position.size == 3:
        vertical = np.maximum(obstacles.z_ranges[:, 0] - position[2],
                              position[2] - obstacles.z_ranges[:, 1])
        corner = (horizontal > 0) & (vertical > 0)
        horizontal = np.where(corner, np.hypot(horizontal, vertical),
                              np.maximum(horizontal, vertical))
    return float((horizontal - robot_radius).min())


def rollout(model, safety_filter, controller, x0, goal, obstacles, duration,
            physics_step=None):
    """Run ``duration`` seconds of closed loop; obstacles move with their velocities."""
    period = safety_filter.config.control_period
    physics_step = physics_step or period
    substeps = max(1, int(round(period / physics_step)))
    steps = int(round(duration / period))
    x = np.asarray(x0, dtype=float)
    states, inputs, nominal, statuses, clearances = [x], [], [], [], []
    for k in range(steps):
        age = k * period
        u_nom = controller(x, goal)
        u, info = safety_filter.step(x, obstacles, u_nom, obstacle_age=age)
        for _ in range(substeps):
            x = rk4_step(model, x, u, period / substeps)
        states.append(x)
        inputs.append(u)
        nominal.append(u_nom)
        statuses.append(info.status)
        moved = obstacles.translated((age + period) * obstacles.velocities[:, :2])
        clearances.append(clearance(model, x, moved, safety_filter.geometry.robot_radius))
    return Rollout(states=np.array(states), inputs=np.array(inputs),
                   nominal=np.array(nominal), statuses=statuses,
                   clearances=np.array(clearances))



def random_clutter(seed, count=30, region=((1.0, -4.0), (11.0, 4.0)),
                   keep_clear=((0.0, 0.0), (12.0, 0.0)), clearance=1.2):
    """Return ``count`` seeded random convex polygons in ``region``, away from ``keep_clear``.

    Each is the hull of 3-8 points in a box of 0.2-0.6 m half-size; polygons whose
    signed distance to any ``keep_clear`` point is below ``clearance`` are redrawn.
    """
    rng = np.random.default_rng(seed)
    polygons = []
    while len(polygons) < count:
        centre = rng.uniform(*region)
        count_points = rng.integers(3, 9)
        offsets = rng.uniform(-0.5, 0.5, size=(count_points, 2))
        hull = convex_hull(centre + offsets * rng.uniform(0.4, 1.2, size=2))
        if len(hull) >= 3 and min(signed_distance(p, hull) for p in keep_clear) >= clearance:
            polygons.append(hull)
    return ObstacleSet.from_obstacles([Obstacle(polygon=p) for p in polygons])
