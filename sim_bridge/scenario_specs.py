"""A checked scenario: ``Scenario``, its robots, obstacles and rates, the seeded random obstacles.

Scenario files are read into these by ``sim_bridge.scenario`` (the YAML schema).

A control period is a whole number of physics steps, ``control_substeps``:
``physics_rate / control_rate`` must be an integer (to ``RATE_TOLERANCE``,
relative), or the rates are refused with the valid ones nearby (240 / 100 Hz
is refused, 240 / 120 Hz is 2 steps); nothing is rounded.  Every ``Scenario``
is checked when made, also by ``dataclasses.replace`` (the bridge's rate
parameters), and the loader names the field.
"""
import dataclasses
import math

import numpy as np

from polyc2bf_ros.core.geometry.polygons import convex_hull, signed_distance

DEFAULT_Z = (0.0, 1.0)
# Sides of the polygon circumscribing a cylinder obstacle: the node's ``cylinder_sides``.
CYLINDER_SIDES = 12
# Random polygons have 3..8 vertices; at most this many draws per requested obstacle.
RANDOM_VERTICES = (3, 8)
RANDOM_ATTEMPTS = 200
# Relative tolerance on physics_rate / control_rate being a whole number (float error only).
RATE_TOLERANCE = 1e-9
RATE_SUGGESTIONS = 4  # valid control rates listed when one is refused


class ScenarioError(ValueError):
    """A scenario file is missing, unreadable or invalid; the message names the field."""


def rate_problem(physics_rate, rate, kind='control'):
    """Return what is wrong with ``rate`` (a ``kind`` rate) as text after its name, or None."""
    ratio = physics_rate / rate
    steps = round(ratio)
    if steps >= 1 and abs(ratio - steps) <= RATE_TOLERANCE * steps:
        return None
    low = max(1, math.floor(ratio) - RATE_SUGGESTIONS // 2 + 1)
    divisors = range(low, low + RATE_SUGGESTIONS)
    valid = ', '.join(f'{physics_rate / n:g} Hz ({n} step{"s" if n > 1 else ""})'
                      for n in divisors)
    if rate > physics_rate:
        problem = f'{rate:g} Hz exceeds physics_rate {physics_rate:g} Hz'
    else:
        problem = (f'{rate:g} Hz does not divide physics_rate {physics_rate:g} Hz '
                   f'({physics_rate:g} / {rate:g} = {ratio:.6g} physics steps per '
                   f'{kind} period, not a whole number; rates are not rounded)')
    return f'{problem}; valid {kind} rates nearby (physics_rate / n): {valid}'


def rate_steps(physics_rate, rate, name, kind):
    """Return n = physics_rate / rate, the physics steps per period of a ``kind`` rate.

    ``ScenarioError`` (a ``ValueError``) starting with ``name`` and naming both rates and
    valid rates nearby unless the ratio is a whole number >= 1 to ``RATE_TOLERANCE``
    (relative): rates are refused, never rounded.
    """
    physics_rate, rate = float(physics_rate), float(rate)
    if not (math.isfinite(physics_rate) and math.isfinite(rate)
            and physics_rate > 0 and rate > 0):
        raise ScenarioError(f'rates must be finite and > 0, got physics_rate {physics_rate:g} '
                            f'Hz, {name} {rate:g} Hz')
    problem = rate_problem(physics_rate, rate, kind)
    if problem is not None:
        raise ScenarioError(f'{name} {problem}')
    return round(physics_rate / rate)


def control_substeps(physics_rate, control_rate):
    """Return n = physics_rate / control_rate, the physics steps per control period.

    The one place the count is computed (``rate_steps``).
    """
    return rate_steps(physics_rate, control_rate, 'control_rate', 'control')


def frozen(values):
    """Return a read-only float64 copy of ``values``."""
    array = np.array(values, dtype=float)
    array.flags.writeable = False
    return array


def cylinder_polygon(centre, radius, sides=CYLINDER_SIDES):
    """Return the CCW ``sides``-gon circumscribing the circle, as the node builds it.

    Vertices at angles 2 pi (i + 1/2) / sides, distance radius / cos(pi / sides).
    """
    angles = 2.0 * np.pi * (np.arange(sides) + 0.5) / sides
    reach = radius / math.cos(math.pi / sides)
    return np.asarray(centre, dtype=float) + reach * np.column_stack([np.cos(angles),
                                                                      np.sin(angles)])


@dataclasses.dataclass(frozen=True, eq=False)
class RobotSpec:
    """One robot: namespace ``name``, ``type``, start pose, goal position, footprint radius.

    ``path`` (P, 2), optional: the waypoints the ``path`` nominal controller follows;
    ``speed`` [m/s], optional (ground robots): the nominal controllers' cruise speed
    (``max_speed``; None: their default, 1 m/s).
    """

    name: str
    type: str
    start: np.ndarray
    goal: np.ndarray
    radius: float
    path: np.ndarray = None
    speed: float = None

    @property
    def nominal_gains(self):
        """Return the nominal controller's settings this robot overrides."""
        return {} if self.speed is None else {'max_speed': self.speed}

    @property
    def position(self):
        """Return the start position: [x, y] (quadruped) or [x, y, z] (crazyflie)."""
        return self.start[:-1]

    @property
    def yaw(self):
        """Return the start heading [rad]."""
        return float(self.start[-1])


@dataclasses.dataclass(frozen=True, eq=False)
class ObstacleSpec:
    """A vertical prism: CCW footprint (k, 2) at ``appear_at``, z range, velocity [vx, vy].

    It exists from sim time ``appear_at`` [s] on (0: from the start).  With ``radius``
    it is the cylinder of that radius about the footprint's vertex mean, and the
    footprint is the polygon circumscribing it (``cylinder_polygon``).

    ``trajectory`` (instead of a constant ``velocity``, which must then be 0): any object
    with ``position(t)`` (2,) [m] and ``velocity(t)`` (2,) [m/s] at sim time t, e.g.
    ``sim_bridge.dynamic_worlds.LoopTrajectory``.  The prism translates rigidly by
    ``position(t) - position(appear_at)`` (``offset``), so ``polygon`` is still its footprint
    at ``appear_at``, and its published velocity is ``velocity(t)``.  Not in scenario files.
    """

    name: str
    polygon: np.ndarray
    z: tuple = DEFAULT_Z
    velocity: np.ndarray = dataclasses.field(default_factory=lambda: frozen([0.0, 0.0]))
    appear_at: float = 0.0
    radius: float = None
    trajectory: object = None

    def __post_init__(self):
        """Refuse a trajectory together with a constant velocity."""
        if self.trajectory is not None and np.any(self.velocity != 0.0):
            raise ScenarioError(f'obstacle {self.name!r}: a trajectory and a velocity '
                                f'{np.asarray(self.velocity).tolist()} exclude each other')

    @property
    def moving(self):
        """Return True when the obstacle translates (a velocity or a trajectory)."""
        return self.trajectory is not None or bool(np.any(self.velocity != 0.0))

    def offset(self, time):
        """Return its translation (2,) at sim ``time`` from its footprint ``polygon``.

        velocity (t - appear_at), or position(t) - position(appear_at) on a trajectory.
        """
        if self.trajectory is None:
            return self.velocity * (time - self.appear_at)
        return (np.asarray(self.trajectory.position(time), dtype=float)
                - self.trajectory.position(self.appear_at))

    def velocity_at(self, time):
        """Return its velocity (2,) at sim ``time``: ``velocity``, or the trajectory's."""
        if self.trajectory is None:
            return self.velocity
        return np.asarray(self.trajectory.velocity(time), dtype=float)


@dataclasses.dataclass(frozen=True, eq=False)
class RandomObstacles:
    """How many convex polygons to scatter, where, how large and how far from robots."""

    count: int
    region: np.ndarray
    size: tuple
    height: tuple
    clearance: float
    spacing: float = 0.0


@dataclasses.dataclass(frozen=True, eq=False)
class Scenario:
    """A checked scenario; ``all_obstacles()`` adds the seeded random ones."""

    name: str
    duration: float
    physics_rate: float
    control_rate: float
    seed: int
    robots: tuple
    obstacles: tuple = ()
    random_obstacles: RandomObstacles = None

    def __post_init__(self):
        """Refuse rates that do not make a whole number of physics steps per period."""
        control_substeps(self.physics_rate, self.control_rate)

    @property
    def substeps(self):
        """Return the physics steps per control period (``control_substeps``)."""
        return control_substeps(self.physics_rate, self.control_rate)

    @property
    def effective_control_rate(self):
        """Return physics_rate / substeps [Hz] (the control_rate, without its float error)."""
        return self.physics_rate / self.substeps

    def with_seed(self, seed):
        """Return a copy whose random obstacles are drawn with ``seed``."""
        return dataclasses.replace(self, seed=int(seed))

    def robot(self, name):
        """Return the robot called ``name`` (KeyError if there is none)."""
        for spec in self.robots:
            if spec.name == name:
                return spec
        raise KeyError(f'scenario {self.name!r} has no robot {name!r}')

    def all_obstacles(self):
        """Return the listed obstacles followed by the random ones drawn with ``seed``."""
        if self.random_obstacles is None:
            return self.obstacles
        return self.obstacles + random_polygons(self.random_obstacles, self.seed,
                                                self.robots, self.obstacles)


def random_polygons(spec, seed, robots, fixed=()):
    """Draw ``spec.count`` convex polygons, deterministic for a given ``seed``.

    Each is the convex hull of 3..8 points at random angles on a circle of
    diameter ``d ~ U(size)`` (radii jittered by U(0.7, 1)) around a centre
    ``c ~ U(region)``.  A draw is rejected when it comes closer than
    ``clearance`` to a robot's start or goal, or when its circumcircle comes
    within ``spacing`` of another obstacle's.
    """
    rng = np.random.default_rng(seed)
    points = np.array([p[:2] for r in robots for p in (r.position, r.goal)])
    centres = np.array([np.mean(o.polygon, axis=0) for o in fixed]).reshape(-1, 2)
    reaches = np.array([np.max(np.linalg.norm(o.polygon - c, axis=1))
                        for o, c in zip(fixed, centres)])
    obstacles = []
    for _ in range(spec.count * RANDOM_ATTEMPTS):
        if len(obstacles) == spec.count:
            break
        centre = rng.uniform(spec.region[0], spec.region[1])
        radius = 0.5 * rng.uniform(*spec.size)
        count = rng.integers(RANDOM_VERTICES[0], RANDOM_VERTICES[1] + 1)
        angles = np.sort(rng.uniform(0.0, 2.0 * np.pi, count))
        radii = radius * rng.uniform(0.7, 1.0, count)
        height = rng.uniform(*spec.height)
        if np.any(np.hypot(*(centres - centre).T) - reaches - radius < spec.spacing):
            continue
        polygon = centre + np.column_stack([radii * np.cos(angles), radii * np.sin(angles)])
        if len(np.unique(polygon, axis=0)) < 3:
            continue
        polygon = convex_hull(polygon)
        # Points outside the circle by more than the clearance need no exact test.
        near = points[np.hypot(*(points - centre).T) - radius < spec.clearance]
        if any(signed_distance(p, polygon) < spec.clearance for p in near):
            continue
        centres = np.vstack([centres, centre])
        reaches = np.append(reaches, radius)
        obstacles.append(ObstacleSpec(name=f'random_{len(obstacles):02d}',
                                      polygon=frozen(polygon), z=(0.0, float(height))))
    if len(obstacles) < spec.count:
        raise ScenarioError(f'random_obstacles.count: placed only {len(obstacles)} of '
                            f'{spec.count} obstacles in the region with the given clearance '
                            'and spacing; enlarge the region or reduce count')
    return tuple(obstacles)

