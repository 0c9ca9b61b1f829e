"""Scenario files: robots, obstacles and timing of one simulated run, checked on load.

YAML schema (units: m, s, rad, Hz)::

    name: long_wall
    duration: 30.0
    physics_rate: 240          # optional, default 240
    control_rate: 120          # optional, default 120; must divide physics_rate
    seed: 0                    # optional, default 0; drives random_obstacles
    robots:                    # names are the robots' ROS namespaces
      - {name: a1, type: quadruped, start: [x, y, yaw], goal: [x, y], radius: 0.4}
      - {name: base, type: diff_drive, start: [x, y, yaw], goal: [x, y],
         path: [[x, y], ...]}  # optional: what the ``path`` nominal follows
      - {name: cf, type: crazyflie, start: [x, y, z, yaw], goal: [x, y, z]}
    obstacles:                 # optional
      - polygon: [[x, y], ...] # convex or simple non-convex, either orientation
        z: [z_min, z_max]      # optional, default [0, 1]
      - cylinder: [x, y]       # instead of polygon: an upright cylinder
        radius: 0.075          # (required with cylinder)
        velocity: [vx, vy]     # optional, default [0, 0]: constant translation
        name: wall             # optional, default obstacle_<i>
        appear_at: 3.0         # optional, default 0: pop-up time [s]
    random_obstacles:          # optional, seeded convex polygons
      count: 30
      region: [[xmin, ymin], [xmax, ymax]]   # where their centres fall
      size: [min, max]         # diameter of the circle their vertices lie on
      height: [min, max]       # z_max, sampled; z_min = 0
      clearance: 1.0           # min distance from every robot's start and goal
      spacing: 0.0             # optional: min gap between obstacles (circumcircles)

``radius`` (optional) is the robot's footprint circle as other robots see it,
and a ``diff_drive`` base's body (a disc); the types, their default radii and
start and goal layouts are ``sim_bridge.robots.ROBOT_TYPES``.  A cylinder
obstacle is a true cylinder in the simulator and is published (and seen by the
filter) as the ``CYLINDER_SIDES``-gon circumscribing it, as the node turns a
CYLINDER marker.
An obstacle with ``appear_at`` = t_a > 0 is a pop-up: before sim time t_a it
does not exist (no body, no clearance or collision, no marker); ``polygon`` is
its footprint at t_a, from which it then moves with ``velocity``.  Starts are
checked only against obstacles present at t = 0, goals against every obstacle
as listed.  Every problem raises ``ScenarioError``
naming the file and the field path, e.g.
``robots[1].start: expected 3 numbers [x, y, yaw] for a quadruped, got 2``.

A control period is a whole number of physics steps, ``control_substeps``:
``physics_rate / control_rate`` must be an integer (to ``RATE_TOLERANCE``,
relative), or the rates are refused with the valid ones nearby (240 / 100 Hz
is refused, 240 / 120 Hz is 2 steps); nothing is rounded.  Every ``Scenario``
is checked when made, also by ``dataclasses.replace`` (the bridge's rate
parameters), and the loader names the field.
"""
import dataclasses
import math
import re
import sys
from pathlib import Path

import numpy as np
import yaml

from polyc2bf_ros.core.geometry.polygons import (
    clean_polygon,
    convex_hull,
    InvalidPolygonError,
    signed_distance,
)
from sim_bridge.robots import robot_type

PACKAGE = 'polyc2bf_ros'
DEFAULT_Z = (0.0, 1.0)
# Sides of the polygon circumscribing a cylinder obstacle: the node's ``cylinder_sides``.
CYLINDER_SIDES = 12
# Random polygons have 3..8 vertices; at most this many draws per requested obstacle.
RANDOM_VERTICES = (3, 8)
RANDOM_ATTEMPTS = 200
_NAME = re.compile(r'[A-Za-z][A-Za-z0-9_]*\Z')
DEFAULT_PHYSICS_RATE = 240.0  # Hz
DEFAULT_CONTROL_RATE = 120.0  # Hz: 2 physics steps
# Relative tolerance on physics_rate / control_rate being a whole number (float error only).
RATE_TOLERANCE = 1e-9
RATE_SUGGESTIONS = 4  # valid control rates listed when one is refused


class ScenarioError(ValueError):
    """A scenario file is missing, unreadable or invalid; the message names the field."""


def _rate_problem(physics_rate, rate, kind='control'):
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
    problem = _rate_problem(physics_rate, rate, kind)
    if problem is not None:
        raise ScenarioError(f'{name} {problem}')
    return round(physics_rate / rate)


def control_substeps(physics_rate, control_rate):
    """Return n = physics_rate / control_rate, the physics steps per control period.

    The one place the count is computed (``rate_steps``).
    """
    return rate_steps(physics_rate, control_rate, 'control_rate', 'control')


def _scenario_dir():
    """Return the scenarios shipped beside the running code.

    From a source checkout that is ``<repo>/config/scenarios``; installed, it is
    ``<share>/polyc2bf_ros/config/scenarios`` found with the ament index (colcon)
    or under ``sys.prefix`` (pip into a virtualenv).
    """
    source = Path(__file__).resolve().parents[1] / 'config' / 'scenarios'
    if source.is_dir():
        return source
    try:
        from ament_index_python.packages import get_package_share_directory
        share = Path(get_package_share_directory(PACKAGE))
    except (ImportError, LookupError, OSError):
        share = Path(sys.prefix) / 'share' / PACKAGE
    return share / 'config' / 'scenarios'


SCENARIO_DIR = _scenario_dir()


def _frozen(values):
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

    ``path`` (P, 2), optional: the waypoints the ``path`` nominal controller follows.
    """

    name: str
    type: str
    start: np.ndarray
    goal: np.ndarray
    radius: float
    path: np.ndarray = None

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
    velocity: np.ndarray = dataclasses.field(default_factory=lambda: _frozen([0.0, 0.0]))
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
                                      polygon=_frozen(polygon), z=(0.0, float(height))))
    if len(obstacles) < spec.count:
        raise ScenarioError(f'random_obstacles.count: placed only {len(obstacles)} of '
                            f'{spec.count} obstacles in the region with the given clearance '
                            'and spacing; enlarge the region or reduce count')
    return tuple(obstacles)


class FieldReader:
    """Checks one parsed document field by field; errors carry the field path."""

    def __init__(self, source, error=ScenarioError):
        """Remember the prefix of every message (the file) and the exception to raise."""
        self.source = source
        self.error = error

    def fail(self, path, problem):
        """Raise ``error`` for ``path``."""
        raise self.error(f'{self.source}: {path or "document"}: {problem}')

    def mapping(self, value, path, required, optional=()):
        """Check that ``value`` is a mapping with the required keys and no unknown ones."""
        if not isinstance(value, dict):
            self.fail(path, f'expected a mapping, got {type(value).__name__}')
        for key in value:
            if key not in required and key not in optional:
                allowed = ', '.join(list(required) + list(optional))
                self.fail(f'{path}.{key}' if path else key,
                          f'unknown key; expected one of: {allowed}')
        for key in required:
            if key not in value:
                self.fail(f'{path}.{key}' if path else key, 'missing')
        return value

    def number(self, value, path, minimum=None, positive=False):
        """Return ``value`` as a finite float, optionally >= minimum or > 0."""
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            self.fail(path, f'expected a number, got {value!r}')
        if not math.isfinite(value):
            self.fail(path, f'expected a finite number, got {value!r}')
        if positive and value <= 0:
            self.fail(path, f'must be > 0, got {value!r}')
        if minimum is not None and value < minimum:
            self.fail(path, f'must be >= {minimum}, got {value!r}')
        return float(value)

    def numbers(self, value, path, count, what=''):
        """Return a list of ``count`` finite numbers as a float array."""
        if not isinstance(value, (list, tuple)):
            self.fail(path, f'expected a list of {count} numbers {what}, got {value!r}')
        if len(value) != count:
            self.fail(path, f'expected {count} numbers {what}, got {len(value)}')
        return np.array([self.number(v, f'{path}[{i}]') for i, v in enumerate(value)])

    def interval(self, value, path, minimum=None):
        """Return [low, high] with low < high."""
        low, high = self.numbers(value, path, 2, '[min, max]')
        if low >= high:
            self.fail(path, f'min must be below max, got [{low}, {high}]')
        if minimum is not None and low < minimum:
            self.fail(path, f'min must be >= {minimum}, got {low}')
        return float(low), float(high)

    def name(self, value, path):
        """Return a ROS-name-like token: a letter, then letters, digits or underscores."""
        if not isinstance(value, str) or not _NAME.match(value):
            self.fail(path, f'expected a name of letters, digits and _, got {value!r}')
        return value


def _robot(reader, data, path):
    """Parse one entry of ``robots``."""
    reader.mapping(data, path, ('name', 'type', 'start', 'goal'), ('radius', 'path'))
    name = reader.name(data['name'], f'{path}.name')
    kind = data['type']
    try:
        robot = robot_type(kind)
    except ValueError as exc:
        reader.fail(f'{path}.type', str(exc))
    size = robot.goal_size
    start = reader.numbers(data['start'], f'{path}.start', size + 1,
                           f'{robot.start_fields} for a {kind}')
    goal = reader.numbers(data['goal'], f'{path}.goal', size, f'{robot.goal_fields} for a {kind}')
    radius = robot.radius
    if 'radius' in data:
        radius = reader.number(data['radius'], f'{path}.radius', positive=True)
    waypoints = None
    if 'path' in data:
        points = data['path']
        if not isinstance(points, list) or len(points) < 2:
            reader.fail(f'{path}.path', f'expected a list of >= 2 points [x, y], got {points!r}')
        waypoints = _frozen([reader.numbers(p, f'{path}.path[{i}]', 2, '[x, y]')
                             for i, p in enumerate(points)])
    return RobotSpec(name=name, type=kind, start=_frozen(start), goal=_frozen(goal),
                     radius=radius, path=waypoints)


def _obstacle(reader, data, path, index):
    """Parse one entry of ``obstacles``."""
    shape = 'cylinder' if 'cylinder' in data else 'polygon'
    reader.mapping(data, path, (shape,) + (('radius',) if shape == 'cylinder' else ()),
                   ('z', 'velocity', 'name', 'appear_at'))
    radius = None
    if shape == 'cylinder':
        centre = reader.numbers(data['cylinder'], f'{path}.cylinder', 2, '[x, y]')
        radius = reader.number(data['radius'], f'{path}.radius', positive=True)
        polygon = cylinder_polygon(centre, radius)
    else:
        try:
            polygon = clean_polygon(data['polygon'])
        except InvalidPolygonError as exc:
            reader.fail(f'{path}.polygon', str(exc))
    z = reader.interval(data['z'], f'{path}.z') if 'z' in data else DEFAULT_Z
    velocity = np.zeros(2)
    if 'velocity' in data:
        velocity = reader.numbers(data['velocity'], f'{path}.velocity', 2, '[vx, vy]')
    name = reader.name(data['name'], f'{path}.name') if 'name' in data else f'obstacle_{index}'
    appear_at = reader.number(data.get('appear_at', 0.0), f'{path}.appear_at', minimum=0.0)
    return ObstacleSpec(name=name, polygon=_frozen(polygon), z=z, velocity=_frozen(velocity),
                        appear_at=appear_at, radius=radius)


def _random(reader, data, path):
    """Parse ``random_obstacles``."""
    reader.mapping(data, path, ('count', 'region', 'size', 'height', 'clearance'), ('spacing',))
    count = data['count']
    if isinstance(count, bool) or not isinstance(count, int) or count < 0:
        reader.fail(f'{path}.count', f'expected a whole number >= 0, got {count!r}')
    region = data['region']
    if not isinstance(region, list) or len(region) != 2:
        reader.fail(f'{path}.region', f'expected [[xmin, ymin], [xmax, ymax]], got {region!r}')
    low = reader.numbers(region[0], f'{path}.region[0]', 2, '[xmin, ymin]')
    high = reader.numbers(region[1], f'{path}.region[1]', 2, '[xmax, ymax]')
    if np.any(low >= high):
        reader.fail(f'{path}.region', 'the first corner must be below-left of the second')
    return RandomObstacles(
        count=count, region=_frozen([low, high]),
        size=reader.interval(data['size'], f'{path}.size', minimum=0.0),
        height=reader.interval(data['height'], f'{path}.height', minimum=0.0),
        clearance=reader.number(data['clearance'], f'{path}.clearance', minimum=0.0),
        spacing=reader.number(data.get('spacing', 0.0), f'{path}.spacing', minimum=0.0))


def _check_free(reader, robots, obstacles):
    """Reject starts and goals inside (or within the robot radius of) an obstacle.

    Starts are checked against the obstacles present at t = 0, goals against all.
    """
    for i, robot in enumerate(robots):
        for field, point in (('start', robot.position), ('goal', robot.goal)):
            for obstacle in obstacles:
                if field == 'start' and obstacle.appear_at > 0.0:
                    continue
                if point.size == 3 and not (obstacle.z[0] - robot.radius < point[2]
                                            < obstacle.z[1] + robot.radius):
                    continue
                gap = signed_distance(point[:2], obstacle.polygon)
                if gap < 0:
                    reader.fail(f'robots[{i}].{field}',
                                f'{point.tolist()} is inside obstacle {obstacle.name!r}')
                if gap < robot.radius:
                    reader.fail(f'robots[{i}].{field}',
                                f'{point.tolist()} is {gap:.3f} m from obstacle '
                                f'{obstacle.name!r}, less than the robot radius {robot.radius}')


def scenario_from_dict(data, source='<dict>'):
    """Check a parsed YAML document and return its Scenario (ScenarioError if invalid)."""
    reader = FieldReader(source)
    reader.mapping(data, '', ('name', 'duration', 'robots'),
                   ('physics_rate', 'control_rate', 'seed', 'obstacles', 'random_obstacles'))
    physics_rate = reader.number(data.get('physics_rate', DEFAULT_PHYSICS_RATE), 'physics_rate',
                                 positive=True)
    control_rate = reader.number(data.get('control_rate', DEFAULT_CONTROL_RATE), 'control_rate',
                                 positive=True)
    if control_rate > physics_rate:
        reader.fail('control_rate', f'{control_rate} Hz exceeds physics_rate {physics_rate} Hz')
    problem = _rate_problem(physics_rate, control_rate)
    if problem is not None:
        reader.fail('control_rate', problem)
    seed = data.get('seed', 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        reader.fail('seed', f'expected a whole number >= 0, got {seed!r}')
    robots_data = data['robots']
    if not isinstance(robots_data, list) or not robots_data:
        reader.fail('robots', 'expected a non-empty list of robots')
    robots = tuple(_robot(reader, r, f'robots[{i}]') for i, r in enumerate(robots_data))
    names = [r.name for r in robots]
    for i, name in enumerate(names):
        if name in names[:i]:
            reader.fail(f'robots[{i}].name', f'duplicate robot name {name!r}')
    obstacles_data = data.get('obstacles') or []
    if not isinstance(obstacles_data, list):
        reader.fail('obstacles', 'expected a list of obstacles')
    obstacles = tuple(_obstacle(reader, o, f'obstacles[{i}]', i)
                      for i, o in enumerate(obstacles_data))
    _check_free(reader, robots, obstacles)
    random_spec = None
    if data.get('random_obstacles') is not None:
        random_spec = _random(reader, data['random_obstacles'], 'random_obstacles')
    scenario = Scenario(
        name=reader.name(data['name'], 'name'),
        duration=reader.number(data['duration'], 'duration', positive=True),
        physics_rate=physics_rate, control_rate=control_rate, seed=seed, robots=robots,
        obstacles=obstacles, random_obstacles=random_spec)
    try:
        scenario.all_obstacles()
    except ScenarioError as exc:
        raise ScenarioError(f'{source}: {exc}') from None
    return scenario


def scenario_names():
    """Return the names of the shipped scenarios, sorted."""
    return sorted(p.stem for p in SCENARIO_DIR.glob('*.yaml'))


def load_scenario(path_or_name):
    """Load a scenario from a YAML file path or a shipped scenario's name."""
    path = Path(path_or_name)
    if path.suffix not in ('.yaml', '.yml') and len(path.parts) == 1:
        path = SCENARIO_DIR / f'{path_or_name}.yaml'
        if not path.is_file():
            raise ScenarioError(f'no scenario named {str(path_or_name)!r} in {SCENARIO_DIR}; '
                                f'shipped: {", ".join(scenario_names())}')
    try:
        data = yaml.safe_load(path.read_text())
    except OSError as exc:
        raise ScenarioError(f'{path}: cannot read: {exc.strerror}') from None
    except yaml.YAMLError as exc:
        raise ScenarioError(f'{path}: not valid YAML: {exc}') from None
    return scenario_from_dict(data, source=str(path))
