"""BARN worlds: the file format, its checked loader, each world as a Scenario, the protocol.

BARN (Perille et al., "Benchmarking Metric Ground Navigation", SSRR 2020) is 300
cluttered worlds of upright cylinders; ``bench/data/barn/barn_worlds.json`` holds
200 of them as plain numbers (``bench/data/barn/README.md``: source, licence,
citation).  Any file of this format loads::

    {"worlds": [{"world": 17,                        # id, a whole number >= 0
                 "cylinder_radius": 0.075,            # m
                 "start": [x, y, heading],            # m, m, rad
                 "goal": [x, y],
                 "reference_path_length_m": 12.6,     # > 0; OT = length / 2 m/s
                 "reference_path": [[x, y], ...],     # >= 2 points, start to goal
                 "centers": [[x, y], ...]},           # the cylinders
                ...],
     ...}                                             # other keys are not read

``load_worlds`` checks every field and raises ``BarnError`` naming the file,
the world and the field, e.g. ``barn.json: world 17 (worlds[3]): centers[5]:
expected 2 numbers [x, y], got 3``.

A world is run as the Scenario ``BarnWorld.scenario()`` builds (checked like a
scenario file, so a start or goal inside a cylinder is refused): one robot ``base``
at the start, by default a ``diff_drive`` (a disc of ``robots.DIFF_DRIVE_RADIUS``) with the
nominals' default 1 m/s, or a ``jackal`` (its box, ``robots.JACKAL_SIZE``) and any cruise
speed (BARN's Jackal drives at up to 2 m/s), its ``path`` the reference path, every
cylinder an obstacle ``CYLINDER_HEIGHT`` tall (a true cylinder in PyBullet, its
circumscribed 12-gon for the filter, as for a CYLINDER marker), ``TIME_LIMIT`` s long,
the project's default rates.  It is built once per world.  Every cylinder stays in the
filter's obstacle set: a collision cone is blind to distance (h scales with |p_rel|, the condition
h_dot + gamma h >= m does not get easier far away), so no distance cut-off is
exact, and merging touching cylinders into convex parts changes the cones the
filter sees (a merged wall's cone spans the wall's ends).  The simulator makes
a cylinder's body only when a closest-point query first reaches it
(``sim_bridge.world``), which is exact.

Protocol (BARN's ``run.py``), ``BarnReferee`` deciding each period:

- collision: the body's closest-point distance below -1 mm (``RunMetrics``); the
  run ends;
- success: within ``GOAL_RADIUS`` of the goal, no collision, under ``TIME_LIMIT``;
- deadlock (this project's addition): the robot stayed within ``STOP_RADIUS`` of
  one point for ``STOP_TIME`` s; the run ends early;
- timeout: none of these by ``TIME_LIMIT``;
- metric = success * OT / clip(T, 2 OT, 8 OT), OT = reference path length / 2 m/s
  (``barn_metric``); its maximum is 0.5.
"""
import dataclasses
import json
import math
from pathlib import Path

import numpy as np

from sim_bridge.robots import ROBOT_TYPES
from sim_bridge.scenario import FieldReader, SCENARIO_DIR, scenario_from_dict
from sim_bridge.scenario_specs import ScenarioError

# The shipped copy: <repo>/bench/data/barn from a checkout, <share>/polyc2bf_ros/bench/...
# when installed (SCENARIO_DIR is <root>/config/scenarios in both).
WORLDS_FILE = SCENARIO_DIR.parents[1] / 'bench' / 'data' / 'barn' / 'barn_worlds.json'
ROBOT_NAME = 'base'
CYLINDER_HEIGHT = 1.0       # m, as in BARN's worlds
TIME_LIMIT = 100.0          # s
GOAL_RADIUS = 1.0           # m
OPTIMAL_SPEED = 2.0         # m/s: OT = reference path length / this
STOP_TIME = 10.0            # s
STOP_RADIUS = 0.1           # m
WORLD_FIELDS = ('world', 'cylinder_radius', 'start', 'goal', 'reference_path_length_m',
                'reference_path', 'centers')


class BarnError(ScenarioError):
    """A BARN world file is unreadable or malformed; the message names world and field."""


@dataclasses.dataclass(frozen=True, eq=False)
class BarnWorld:
    """One checked BARN world (arrays in m; ``start`` is [x, y, heading])."""

    world: int
    cylinder_radius: float
    start: np.ndarray
    goal: np.ndarray
    reference_path_length_m: float
    reference_path: np.ndarray
    centers: np.ndarray
    source: str = ''

    @property
    def name(self):
        """Return the scenario name, ``barn_017``."""
        return f'barn_{self.world:03d}'

    @property
    def optimal_time(self):
        """Return BARN's optimal time OT = reference path length / 2 m/s [s]."""
        return self.reference_path_length_m / OPTIMAL_SPEED

    def scenario(self, robot_type='diff_drive', speed=None):
        """Return the world as a checked Scenario with one ground robot of ``robot_type``.

        ``speed`` [m/s]: the nominals' cruise speed (None: their default).
        """
        robot = {'name': ROBOT_NAME, 'type': robot_type, 'start': self.start.tolist(),
                 'goal': self.goal.tolist(), 'radius': float(ROBOT_TYPES[robot_type].radius),
                 'path': self.reference_path.tolist()}
        if speed is not None:
            robot['speed'] = float(speed)
        obstacles = [{'cylinder': centre, 'radius': self.cylinder_radius,
                      'z': [0.0, CYLINDER_HEIGHT], 'name': f'cylinder_{i}'}
                     for i, centre in enumerate(self.centers.tolist())]
        try:
            return scenario_from_dict({'name': self.name, 'duration': TIME_LIMIT,
                                       'robots': [robot], 'obstacles': obstacles},
                                      source=f'{self.source}: world {self.world}')
        except ScenarioError as exc:
            raise BarnError(str(exc)) from None


def _points(reader, value, path, minimum):
    """Return a list of >= ``minimum`` points [x, y] as an (N, 2) array."""
    if not isinstance(value, list):
        reader.fail(path, f'expected a list of points [x, y], got {type(value).__name__}')
    if len(value) < minimum:
        reader.fail(path, f'expected >= {minimum} points [x, y], got {len(value)}')
    return np.array([reader.numbers(p, f'{path}[{i}]', 2, '[x, y]')
                     for i, p in enumerate(value)]).reshape(-1, 2)


def _world(data, index, source):
    """Check ``worlds[index]`` and return its BarnWorld."""
    where = f'worlds[{index}]'
    reader = FieldReader(f'{source}: {where}', BarnError)
    reader.mapping(data, '', ('world',), tuple(data) if isinstance(data, dict) else ())
    world = data['world']
    if isinstance(world, bool) or not isinstance(world, int) or world < 0:
        reader.fail('world', f'expected a whole number >= 0, got {world!r}')
    reader = FieldReader(f'{source}: world {world} ({where})', BarnError)
    reader.mapping(data, '', WORLD_FIELDS, tuple(data))  # other keys are allowed
    return BarnWorld(
        world=world,
        cylinder_radius=reader.number(data['cylinder_radius'], 'cylinder_radius',
                                      positive=True),
        start=reader.numbers(data['start'], 'start', 3, '[x, y, heading]'),
        goal=reader.numbers(data['goal'], 'goal', 2, '[x, y]'),
        reference_path_length_m=reader.number(data['reference_path_length_m'],
                                              'reference_path_length_m', positive=True),
        reference_path=_points(reader, data['reference_path'], 'reference_path', 2),
        centers=_points(reader, data['centers'], 'centers', 0),
        source=source)


def load_worlds(path):
    """Load and check a BARN world file; return its BarnWorlds in file order."""
    source = str(path)
    try:
        data = json.loads(Path(path).read_text())
    except OSError as exc:
        raise BarnError(f'{source}: cannot read: {exc.strerror}') from None
    except json.JSONDecodeError as exc:
        raise BarnError(f'{source}: not valid JSON: {exc}') from None
    reader = FieldReader(source, BarnError)
    reader.mapping(data, '', ('worlds',), tuple(data) if isinstance(data, dict) else ())
    if not isinstance(data['worlds'], list) or not data['worlds']:
        reader.fail('worlds', 'expected a non-empty list of worlds')
    worlds = [_world(item, i, source) for i, item in enumerate(data['worlds'])]
    seen = set()
    for i, world in enumerate(worlds):
        if world.world in seen:
            reader.fail(f'worlds[{i}].world', f'world {world.world} appears twice')
        seen.add(world.world)
    return worlds


def barn_metric(success, time, optimal_time):
    """Return BARN's metric: success * OT / clip(T, 2 OT, 8 OT) (0 for a failure)."""
    if not success:
        return 0.0
    return optimal_time / min(max(time, 2.0 * optimal_time), 8.0 * optimal_time)


class BarnReferee:
    """``until`` of ``run_in_process``: ends a BARN run on collision, success or a stop.

    Called after each period with the sim time, the world and its ``RunMetrics``; returns
    'collision', 'success' or 'deadlock' (module docstring), else None.
    """

    def __init__(self, robot=ROBOT_NAME, goal_radius=GOAL_RADIUS, stop_time=STOP_TIME,
                 stop_radius=STOP_RADIUS):
        """Watch ``robot``; it is 'stopped' while within ``stop_radius`` of an anchor point."""
        self.robot = robot
        self.goal_radius = goal_radius
        self.stop_time = stop_time
        self.stop_radius = stop_radius
        self._anchor = None
        self._since = 0.0

    def __call__(self, time, world, metrics):
        """Return the run's outcome once it is decided, else None."""
        if metrics.robots[self.robot].collision:
            return 'collision'
        position = world.robot_state(self.robot)[:2]
        if math.dist(position, world.robot_spec(self.robot).goal) <= self.goal_radius:
            return 'success'
        if self._anchor is None or math.dist(position, self._anchor) > self.stop_radius:
            self._anchor, self._since = position, time
        elif time - self._since >= self.stop_time:
            return 'deadlock'
        return None
