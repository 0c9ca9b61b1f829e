"""Per-robot run metrics sampled from a SimWorld (doc/design.md, result records).

Call ``RunMetrics.update()`` once per control period (it runs
``SimWorld.min_clearance`` per robot, ``getClosestPoints`` queries too costly
for every physics step).  Per robot:

- ``collision``: some sample had a closest-point distance to an obstacle or
  another robot below ``-COLLISION_TOLERANCE`` (1 mm penetration);
- ``min_clearance_m``: the smallest such distance seen (None if nothing ever
  came within ``CLEARANCE_RANGE``);
- ``goal_reached`` / ``time_to_goal_s``: first sample with the position
  ([x, y] quadruped, [x, y, z] Crazyflie) within ``goal_tolerance`` of the goal;
- ``path_length_m``: sum of |p_k - p_{k-1}| over samples.
"""
import math
from dataclasses import dataclass

from sim_bridge.world import COLLISION_TOLERANCE

GOAL_TOLERANCE = 0.25  # m


@dataclass
class RobotMetrics:
    """Running metrics of one robot."""

    collision: bool = False
    collision_time_s: float = None
    min_clearance_m: float = math.inf
    goal_reached: bool = False
    time_to_goal_s: float = None
    path_length_m: float = 0.0

    def to_json(self):
        """Return a JSON-ready dict (an infinite clearance becomes None)."""
        clearance = self.min_clearance_m
        return {'collision': self.collision, 'collision_time_s': self.collision_time_s,
                'min_clearance_m': None if math.isinf(clearance) else round(clearance, 4),
                'goal_reached': self.goal_reached, 'time_to_goal_s': self.time_to_goal_s,
                'path_length_m': round(self.path_length_m, 4)}


class RunMetrics:
    """Metrics of every robot of a world, fed by ``update()``."""

    def __init__(self, world, goal_tolerance=GOAL_TOLERANCE):
        """Start from the robots' current positions."""
        self.world = world
        self.goal_tolerance = float(goal_tolerance)
        self.robots = {name: RobotMetrics() for name in world.robot_names}
        self._goals = {name: world.robot_spec(name).goal.tolist() for name in world.robot_names}
        self._last = {name: self._position(name) for name in world.robot_names}

    def _position(self, robot):
        """Return the robot's position in its goal's dimension, as a list."""
        return self.world.robot_state(robot)[:len(self._goals[robot])].tolist()

    def update(self):
        """Sample every robot at the world's current time."""
        time = round(self.world.time, 6)
        for name, metrics in self.robots.items():
            position = self._position(name)
            metrics.path_length_m += math.dist(position, self._last[name])
            self._last[name] = position
            clearance = self.world.min_clearance(name)
            metrics.min_clearance_m = min(metrics.min_clearance_m, clearance)
            if clearance < -COLLISION_TOLERANCE and not metrics.collision:
                metrics.collision, metrics.collision_time_s = True, time
            if (not metrics.goal_reached
                    and math.dist(position, self._goals[name]) <= self.goal_tolerance):
                metrics.goal_reached, metrics.time_to_goal_s = True, time

    def to_json(self):
        """Return ``{robot: {collision, min_clearance_m, goal_reached, ...}}``, JSON-ready."""
        return {name: metrics.to_json() for name, metrics in self.robots.items()}
