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
         path: [[x, y], ...],  # optional: what the ``path`` nominal follows
         speed: 1.0}           # optional: the nominal's cruise speed [m/s]
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
filter) as the ``CYLINDER_SIDES``-gon circumscribing it (``scenario_specs``), as the
node turns a CYLINDER marker.
An obstacle with ``appear_at`` = t_a > 0 is a pop-up: before sim time t_a it
does not exist (no body, no clearance or collision, no marker); ``polygon`` is
its footprint at t_a, from which it then moves with ``velocity``.  Starts are
checked only against obstacles present at t = 0, goals against every obstacle
as listed.  Every problem raises ``ScenarioError``
naming the file and the field path, e.g.
``robots[1].start: expected 3 numbers [x, y, yaw] for a quadruped, got 2``.

The checked ``Scenario``, its parts and its rate checks are ``sim_bridge.scenario_specs``.
"""
import math
import re
import sys
from pathlib import Path

import numpy as np
import yaml

from polyc2bf_ros.core.geometry.polygons import (
    clean_polygon,
    InvalidPolygonError,
    signed_distance,
)
from sim_bridge.robots import robot_type
from sim_bridge.scenario_specs import (
    cylinder_polygon,
    DEFAULT_Z,
    frozen,
    ObstacleSpec,
    RandomObstacles,
    rate_problem,
    RobotSpec,
    Scenario,
    ScenarioError,
)

PACKAGE = 'polyc2bf_ros'
_NAME = re.compile(r'[A-Za-z][A-Za-z0-9_]*\Z')
DEFAULT_PHYSICS_RATE = 240.0  # Hz
DEFAULT_CONTROL_RATE = 120.0  # Hz: 2 physics steps


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
    reader.mapping(data, path, ('name', 'type', 'start', 'goal'), ('radius', 'path', 'speed'))
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
        waypoints = frozen([reader.numbers(p, f'{path}.path[{i}]', 2, '[x, y]')
                             for i, p in enumerate(points)])
    speed = None
    if 'speed' in data:
        if not robot.unicycle:
            reader.fail(f'{path}.speed', f'a {kind} has no cruise speed (ground robots only)')
        speed = reader.number(data['speed'], f'{path}.speed', positive=True)
    return RobotSpec(name=name, type=kind, start=frozen(start), goal=frozen(goal),
                     radius=radius, path=waypoints, speed=speed)


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
    return ObstacleSpec(name=name, polygon=frozen(polygon), z=z, velocity=frozen(velocity),
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
        count=count, region=frozen([low, high]),
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
    problem = rate_problem(physics_rate, control_rate)
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
