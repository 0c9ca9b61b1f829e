"""Dynamic worlds: 60 seeded courses of moving cylinders to the DynaBARN specification.

DynaBARN (Nair, Xiao, Stone et al., "DynaBARN: Benchmarking Metric Ground Navigation in
Dynamic Environments", SSRR 2022) is 60 Gazebo worlds of cylinders moving on smooth
paths across a course, 20 each easy, medium and hard.  Its worlds are compiled Gazebo
plugins, so this module generates its own to the paper's specification (the generator
below, deterministic for a seed):

- the course is ``COURSE_LENGTH`` = 20 m long and ``COURSE_WIDTH`` = 12 m wide,
  x in [0, 20], y in [-6, 6]; the robot (BARN's ``diff_drive`` disc of
  ``robots.DIFF_DRIVE_RADIUS`` = 0.2 m, as ``sim_bridge.barn`` builds it) starts at
  (0, 0) facing +x, its goal is (20, 0), its reference path the straight segment;
- cylinders of radius ``CYLINDER_RADIUS`` = 0.5 m, ``CYLINDER_HEIGHT`` tall; world ids
  0-19 are easy (5-14 cylinders at 0.5-0.9 m/s), 20-39 medium (15-19 at 1.0-1.4 m/s),
  40-59 hard (20-24 at 1.4-1.9 m/s) (``DIFFICULTIES``); count and each cylinder's speed
  are uniform in the difficulty's ranges;
- each cylinder runs round a closed C2 loop at its constant speed v
  (``LoopTrajectory``): the periodic cubic spline P(u) (``PeriodicSpline``, knots at the
  cumulative chord lengths) through K = 4-6 waypoints on a jittered ellipse (centre uniform
  in the course, semi-axes a ~ U(1.5, 7) m, b = a U(0.35, 1), turned by U(0, pi); waypoint
  k at angle 2 pi (k + U(-0.3, 0.3)) / K and U(0.75, 1) of the ellipse's radius there),
  entered at a uniform arc-length phase, in a random direction.  A loop is redrawn
  unless it stays inside the course (centre; 1 cm inside at the checked points) and its
  curvature kappa needs at most
  ``MAX_OBSTACLE_ACCEL`` of centripetal acceleration::

      v^2 max kappa <= 2 m/s^2,   kappa = |P' x P''| / |P'|^3

  (the acceleration of a brisk walker; a filter's ``obstacle_accel`` bound is compared
  with it), checked on 64 points per spline segment.  At constant speed the
  acceleration is only the centripetal v^2 kappa; the loop is C2, so it is continuous;
- no cylinder comes within ``START_CLEARANCE`` = 2 m (its surface: centre distance 2.5 m)
  of the start or the goal during the first ``CLEAR_TIME`` = 3 s: the phase is redrawn
  (then the loop) until it holds, checked every 0.01 s with the distance covered in
  between as margin.  Cylinders may overlap each other (they do not touch physically).

Protocol (``ContactReferee``): the run ends at the first contact of the robot's body
with a cylinder, at the goal (within ``GOAL_RADIUS`` = 1 m, as BARN), or at
``TIME_LIMIT`` = 60 s.  Contact is exact for a disc and an upright cylinder, tested after
every control period::

    gap = |p - c(t)| - r_cylinder - r_disc <= 0

and classified at that period: *at fault* when the robot's own velocity component
toward the cylinder's centre, v [cos theta, sin theta] . (c - p) / |c - p|, exceeds
``AT_FAULT_SPEED`` = 0.05 m/s, *passive* otherwise (it stood, or moved away, and was
caught).
"""
import bisect
import dataclasses
import functools
import math
from typing import NamedTuple

import numpy as np

from sim_bridge.barn import CYLINDER_HEIGHT, GOAL_RADIUS, ROBOT_NAME
from sim_bridge.robots import DIFF_DRIVE_RADIUS
from sim_bridge.scenario import scenario_from_dict
from sim_bridge.scenario_specs import cylinder_polygon, ObstacleSpec, ScenarioError

COURSE_LENGTH = 20.0         # m, start to goal
COURSE_WIDTH = 12.0          # m
COURSE = ((0.0, -0.5 * COURSE_WIDTH), (COURSE_LENGTH, 0.5 * COURSE_WIDTH))  # cylinder centres
START = (0.0, 0.0, 0.0)      # x, y, heading
GOAL = (COURSE_LENGTH, 0.0)
CYLINDER_RADIUS = 0.5        # m
MAX_OBSTACLE_ACCEL = 2.0     # m/s^2: v^2 kappa on every loop
START_CLEARANCE = 2.0        # m from a cylinder's surface to the start and the goal ...
CLEAR_TIME = 3.0             # s ... during the first CLEAR_TIME seconds
TIME_LIMIT = 60.0            # s
AT_FAULT_SPEED = 0.05        # m/s toward the cylinder at contact: the robot's fault
DEFAULT_SEED = 2022
WORLDS_PER_DIFFICULTY = 20
WAYPOINTS = (4, 6)           # waypoints per loop
SEMI_AXIS = (1.5, 7.0)       # m, the ellipse's first semi-axis a
AXIS_RATIO = (0.35, 1.0)     # b / a
CHECK_POINTS = 64            # curvature and course checks per spline segment
CHECK_MARGIN = 0.01          # m inside the course at the checked points (none between leaves)
TABLE_POINTS = 32            # arc-length table nodes per spline segment
CLEAR_STEP = 0.01            # s between the start/goal checks
ATTEMPTS = 2000              # loops drawn per cylinder at most
PHASES = 20                  # phases tried per loop


class Difficulty(NamedTuple):
    """Cylinder count [low, high] (inclusive) and speed range [m/s] of a difficulty."""

    count: tuple
    speed: tuple


DIFFICULTIES = {'easy': Difficulty((5, 14), (0.5, 0.9)),
                'medium': Difficulty((15, 19), (1.0, 1.4)),
                'hard': Difficulty((20, 24), (1.4, 1.9))}


def difficulty_of(world):
    """Return the difficulty of world id ``world`` (0-19 easy, 20-39 medium, 40-59 hard)."""
    names = list(DIFFICULTIES)
    if not 0 <= world < WORLDS_PER_DIFFICULTY * len(names):
        raise ValueError(f'dynamic world ids are 0-{WORLDS_PER_DIFFICULTY * len(names) - 1}, '
                         f'got {world}')
    return names[world // WORLDS_PER_DIFFICULTY]


class PeriodicSpline:
    """The closed (periodic) cubic spline through points y_0 .. y_{K-1} (K, 2), C2 everywhere.

    Knots t_0 = 0 < ... < t_K at the cumulative chord lengths, y_K = y_0, h_i = t_{i+1} - t_i.
    The second derivatives M_i (periodic: M_K = M_0, M_{-1} = M_{K-1}, h_{-1} = h_{K-1})
    solve the cyclic system (one per axis)::

        h_{i-1} M_{i-1} + 2 (h_{i-1} + h_i) M_i + h_i M_{i+1}
            = 6 ((y_{i+1} - y_i) / h_i - (y_i - y_{i-1}) / h_{i-1}),   i = 0 .. K-1

    and on [t_i, t_{i+1}], d = u - t_i::

        P(u) = y_i + b_i d + M_i / 2 d^2 + (M_{i+1} - M_i) / (6 h_i) d^3,
        b_i = (y_{i+1} - y_i) / h_i - h_i (2 M_i + M_{i+1}) / 6

    ``coefficients`` (K, 4, 2): per segment the cubic's, highest power first.
    """

    def __init__(self, points):
        """Solve for the second derivatives (the K x K system is small: numpy's solver)."""
        points = np.asarray(points, dtype=float).reshape(-1, 2)
        count = len(points)
        following = np.roll(points, -1, axis=0)
        h = np.hypot(*(following - points).T)
        if count < 3 or not np.all(h > 0.0):
            raise ValueError('a closed spline needs >= 3 distinct consecutive points')
        self.knots = np.concatenate([[0.0], np.cumsum(h)])
        previous_h = np.roll(h, 1)
        slopes = (following - points) / h[:, None]
        matrix = np.diag(2.0 * (previous_h + h))
        index = np.arange(count)
        matrix[index, (index - 1) % count] += previous_h
        matrix[index, (index + 1) % count] += h
        second = np.linalg.solve(matrix, 6.0 * (slopes - np.roll(slopes, 1, axis=0)))
        next_second = np.roll(second, -1, axis=0)
        self.coefficients = np.stack([
            (next_second - second) / (6.0 * h[:, None]), 0.5 * second,
            slopes - h[:, None] * (2.0 * second + next_second) / 6.0, points], axis=1)

    @property
    def period(self):
        """Return t_K, the parameter length of one loop."""
        return float(self.knots[-1])

    def __call__(self, u, derivative=0):
        """Return P (or its 1st or 2nd ``derivative``) at parameters ``u`` (N,) as (N, 2)."""
        u = np.mod(np.asarray(u, dtype=float), self.period)
        segment = np.clip(np.searchsorted(self.knots, u, side='right') - 1, 0,
                          len(self.coefficients) - 1)
        d = (u - self.knots[segment])[:, None]
        c3, c2, c1, c0 = np.moveaxis(self.coefficients[segment], 1, 0)
        if derivative == 0:
            return ((c3 * d + c2) * d + c1) * d + c0
        if derivative == 1:
            return (3.0 * c3 * d + 2.0 * c2) * d + c1
        return 6.0 * c3 * d + 2.0 * c2


def _dense(spline, count=CHECK_POINTS):
    """Return u at ``count`` points per segment (the knots included, the last one not)."""
    knots = spline.knots
    steps = np.linspace(0.0, 1.0, count, endpoint=False)
    return (knots[:-1, None] + np.diff(knots)[:, None] * steps).ravel()


def max_curvature(spline):
    """Return max kappa = |P' x P''| / |P'|^3 of ``spline`` over its dense samples [1/m]."""
    u = _dense(spline)
    first, second = spline(u, 1), spline(u, 2)
    cross = np.abs(first[:, 0] * second[:, 1] - first[:, 1] * second[:, 0])
    return float(np.max(cross / np.hypot(*first.T) ** 3))


class LoopTrajectory:
    """Constant speed ``speed`` [m/s] round the closed C2 curve through ``waypoints``.

    P(u) is the ``PeriodicSpline`` through them, s(u) = int |P'| its arc length (5-point
    Gauss-Legendre per table interval), L the loop's length.  At sim time t::

        s = (phase + direction speed t) mod L,   position = P(u(s)),
        velocity = direction speed P'(u) / |P'(u)|

    u(s) is the cubic Hermite interpolant of a table of (s, u, du/ds = 1 / |P'(u)|) at
    ``TABLE_POINTS`` per segment, so the speed along P is ``speed`` to ~1e-7 relative and
    position and velocity are continuous.  ``position`` and ``velocity`` (read-only
    arrays) are evaluated in plain floats, and the last time's answer is kept: the world
    asks several times per physics step.  Pickles as its constructor arguments.
    """

    def __init__(self, waypoints, speed, phase=0.0, direction=1):
        """Build the spline and its arc-length table; ``phase`` [m of arc], ``direction`` +-1."""
        self.waypoints = np.array(waypoints, dtype=float).reshape(-1, 2)
        self.speed, self.phase, self.direction = float(speed), float(phase), int(direction)
        if self.direction not in (-1, 1) or not self.speed > 0.0:
            raise ValueError(f'need direction +-1 and speed > 0, got {direction}, {speed}')
        spline = PeriodicSpline(self.waypoints)
        self.spline = spline
        self._knots = spline.knots.tolist()
        # Per segment and axis: (c3, c2, c1, c0) of c3 d^3 + c2 d^2 + c1 d + c0.
        self._coefficients = [tuple(tuple(segment[:, axis].tolist()) for axis in (0, 1))
                              for segment in spline.coefficients]
        nodes = np.append(_dense(spline, TABLE_POINTS), spline.period)
        gauss, weights = np.polynomial.legendre.leggauss(5)
        middle, half = 0.5 * (nodes[1:] + nodes[:-1]), 0.5 * np.diff(nodes)
        samples = middle[:, None] + half[:, None] * gauss
        speeds = np.hypot(*spline(samples.ravel(), 1).T).reshape(samples.shape)
        arcs = np.concatenate([[0.0], np.cumsum(half * (speeds @ weights))])
        self.length = float(arcs[-1])
        self._s, self._u = arcs.tolist(), nodes.tolist()
        self._slope = (1.0 / np.hypot(*spline(nodes, 1).T)).tolist()  # du/ds
        self._time = None
        self._answer = None

    def __reduce__(self):
        """Pickle as the constructor's arguments (the tables are rebuilt identically)."""
        return (LoopTrajectory, (self.waypoints, self.speed, self.phase, self.direction))

    def with_phase(self, phase):
        """Return a copy entering the loop at ``phase`` [m of arc] (the tables are shared)."""
        trajectory = object.__new__(LoopTrajectory)
        trajectory.__dict__.update(self.__dict__)
        trajectory.phase, trajectory._time, trajectory._answer = float(phase), None, None
        return trajectory

    def positions(self, times):
        """Return the centres (N, 2) at sim ``times`` (N,), vectorised (as ``position``)."""
        s = np.mod(self.phase + self.direction * self.speed * np.asarray(times, dtype=float),
                   self.length)
        arcs, nodes, slope = np.array(self._s), np.array(self._u), np.array(self._slope)
        j = np.clip(np.searchsorted(arcs, s, side='right') - 1, 0, len(arcs) - 2)
        h = arcs[j + 1] - arcs[j]
        x = (s - arcs[j]) / h
        x2, x3 = x * x, x * x * x
        u = ((2.0 * x3 - 3.0 * x2 + 1.0) * nodes[j] + (x3 - 2.0 * x2 + x) * h * slope[j]
             + (3.0 * x2 - 2.0 * x3) * nodes[j + 1] + (x3 - x2) * h * slope[j + 1])
        return self.spline(u)

    @property
    def period(self):
        """Return the time [s] of one loop."""
        return self.length / self.speed

    def _evaluate(self, time):
        """Return (position, velocity) at ``time`` (module and class docstrings)."""
        if time == self._time:
            return self._answer
        s = (self.phase + self.direction * self.speed * time) % self.length
        arcs, nodes, slope = self._s, self._u, self._slope
        j = min(max(bisect.bisect_right(arcs, s) - 1, 0), len(arcs) - 2)
        h = arcs[j + 1] - arcs[j]
        x = (s - arcs[j]) / h
        x2, x3 = x * x, x * x * x
        u = ((2.0 * x3 - 3.0 * x2 + 1.0) * nodes[j] + (x3 - 2.0 * x2 + x) * h * slope[j]
             + (3.0 * x2 - 2.0 * x3) * nodes[j + 1] + (x3 - x2) * h * slope[j + 1])
        knots = self._knots
        i = min(max(bisect.bisect_right(knots, u) - 1, 0), len(knots) - 2)
        d = u - knots[i]
        (ax, bx, cx, ex), (ay, by, cy, ey) = self._coefficients[i]
        position = np.array([((ax * d + bx) * d + cx) * d + ex, ((ay * d + by) * d + cy) * d + ey])
        tx, ty = (3.0 * ax * d + 2.0 * bx) * d + cx, (3.0 * ay * d + 2.0 * by) * d + cy
        scale = self.direction * self.speed / math.hypot(tx, ty)
        velocity = np.array([tx * scale, ty * scale])
        position.flags.writeable = velocity.flags.writeable = False
        self._time, self._answer = time, (position, velocity)
        return self._answer

    def position(self, time):
        """Return the centre [x, y] (2,) at sim ``time`` [s]."""
        return self._evaluate(time)[0]

    def velocity(self, time):
        """Return the velocity [vx, vy] (2,) at sim ``time`` [s]: ``speed`` along the tangent."""
        return self._evaluate(time)[1]

    def points(self, count=CHECK_POINTS):
        """Return the loop as ``count`` points per segment, closed (the first repeated)."""
        u = np.append(_dense(self.spline, count), self.spline.period)
        return self.spline(u)


@dataclasses.dataclass(frozen=True, eq=False)
class DynamicWorld:
    """One generated world: id, difficulty, generator seed and a LoopTrajectory per cylinder."""

    world: int
    difficulty: str
    seed: int
    cylinders: tuple

    @property
    def name(self):
        """Return the scenario name, ``dynamic_07``."""
        return f'dynamic_{self.world:02d}'

    def scenario(self, radius=DIFF_DRIVE_RADIUS, duration=TIME_LIMIT):
        """Return the world as a Scenario: the diff-drive disc ``base`` and the moving cylinders.

        The robot is checked as a scenario file's; the cylinders carry their trajectories
        (``ObstacleSpec.trajectory``), ``CYLINDER_HEIGHT`` tall.
        """
        robot = {'name': ROBOT_NAME, 'type': 'diff_drive', 'start': list(START),
                 'goal': list(GOAL), 'radius': float(radius), 'path': [list(START[:2]),
                                                                      list(GOAL)]}
        base = scenario_from_dict({'name': self.name, 'duration': float(duration),
                                   'robots': [robot]}, source=f'dynamic world {self.world}')
        obstacles = []
        for index, trajectory in enumerate(self.cylinders):
            polygon = cylinder_polygon(trajectory.position(0.0), CYLINDER_RADIUS)
            polygon.flags.writeable = False
            obstacles.append(ObstacleSpec(name=f'cylinder_{index}', polygon=polygon,
                                          z=(0.0, CYLINDER_HEIGHT), radius=CYLINDER_RADIUS,
                                          trajectory=trajectory))
        return dataclasses.replace(base, obstacles=tuple(obstacles))


def _inside(points, margin=0.0):
    """Return True when every point (N, 2) is inside the course, ``margin`` from its edges."""
    low, high = np.asarray(COURSE[0]) + margin, np.asarray(COURSE[1]) - margin
    return bool(np.all((points >= low) & (points <= high)))


def _draw_loop(rng, speed):
    """Return the waypoints (K, 2) of a loop that fits the course and the acceleration bound."""
    for _ in range(ATTEMPTS):
        count = int(rng.integers(WAYPOINTS[0], WAYPOINTS[1] + 1))
        centre = rng.uniform(COURSE[0], COURSE[1])
        a = rng.uniform(*SEMI_AXIS)
        b = a * rng.uniform(*AXIS_RATIO)
        if b * b / a < speed * speed / MAX_OBSTACLE_ACCEL:
            continue  # the ellipse itself turns too tightly (radius of curvature b^2 / a)
        turn = rng.uniform(0.0, math.pi)
        angles = 2.0 * math.pi * (np.arange(count) + rng.uniform(-0.3, 0.3, count)) / count
        scale = rng.uniform(0.75, 1.0, count)
        local = np.column_stack([a * np.cos(angles), b * np.sin(angles)]) * scale[:, None]
        rotation = np.array([[math.cos(turn), -math.sin(turn)], [math.sin(turn), math.cos(turn)]])
        waypoints = centre + local @ rotation.T
        if not _inside(waypoints):
            continue
        spline = PeriodicSpline(waypoints)
        if not _inside(spline(_dense(spline)), CHECK_MARGIN):
            continue
        if speed * speed * max_curvature(spline) > MAX_OBSTACLE_ACCEL:
            continue
        return waypoints
    raise ScenarioError(f'no loop for a cylinder at {speed:.2f} m/s in {ATTEMPTS} draws')


def _clear_of_ends(trajectory):
    """Return True when the cylinder keeps START_CLEARANCE from start and goal to CLEAR_TIME."""
    times = np.arange(0.0, CLEAR_TIME + 0.5 * CLEAR_STEP, CLEAR_STEP)
    centres = trajectory.positions(times)
    reach = START_CLEARANCE + CYLINDER_RADIUS + trajectory.speed * CLEAR_STEP
    ends = np.array([START[:2], GOAL])
    distances = np.hypot(*(centres[:, None, :] - ends[None, :, :]).transpose(2, 0, 1))
    return bool(distances.min() >= reach)


def _cylinder(rng, speed):
    """Return a LoopTrajectory at ``speed`` clear of the start and goal (module docstring)."""
    for _ in range(ATTEMPTS):
        waypoints = _draw_loop(rng, speed)
        direction = 1 if rng.uniform() < 0.5 else -1
        loop = LoopTrajectory(waypoints, speed, 0.0, direction)
        for _ in range(PHASES):
            trajectory = loop.with_phase(rng.uniform(0.0, loop.length))
            if _clear_of_ends(trajectory):
                return trajectory
    raise ScenarioError(f'no cylinder at {speed:.2f} m/s clear of the start and goal')


def dynamic_world(world, seed=DEFAULT_SEED):
    """Generate world ``world`` (0-59) of generator ``seed``: deterministic, independent of others.

    Its random stream is ``numpy.random.default_rng([seed, world])``.
    """
    difficulty = difficulty_of(world)
    spec = DIFFICULTIES[difficulty]
    rng = np.random.default_rng([seed, world])
    count = int(rng.integers(spec.count[0], spec.count[1] + 1))
    speeds = rng.uniform(*spec.speed, count)
    cylinders = tuple(_cylinder(rng, float(speed)) for speed in speeds)
    return DynamicWorld(world=world, difficulty=difficulty, seed=seed, cylinders=cylinders)


@functools.lru_cache(maxsize=4)
def dynamic_worlds(seed=DEFAULT_SEED):
    """Return all 60 worlds of generator ``seed`` in id order (a tuple, cached)."""
    count = WORLDS_PER_DIFFICULTY * len(DIFFICULTIES)
    return tuple(dynamic_world(world, seed) for world in range(count))


def classify_contact(position, velocity, centre, threshold=AT_FAULT_SPEED):
    """Return ('at_fault' or 'passive', v_toward): v_toward = v . (c - p) / |c - p| [m/s].

    At fault when the robot's own velocity toward the touched cylinder's centre exceeds
    ``threshold``.
    """
    direction = np.asarray(centre, dtype=float) - np.asarray(position, dtype=float)
    toward = float(np.dot(velocity, direction) / max(np.linalg.norm(direction), 1e-12))
    return ('at_fault' if toward > threshold else 'passive'), toward


class ContactReferee:
    """``until`` of ``run_in_process``: ends a run at contact with a cylinder or at the goal.

    Watches the unicycle ``robot`` (a disc of its scenario ``radius``) against every
    cylinder obstacle of ``scenario`` (static, constant-velocity or on a trajectory).
    After each period: ``'contact_at_fault'`` or ``'contact_passive'`` at the first
    gap <= 0 (module docstring; ``contact`` then holds what happened), else
    ``'success'`` within ``goal_radius`` of the goal, else None.  ``min_clearance`` is the
    smallest gap seen [m] (inf: no cylinder).
    """

    def __init__(self, scenario, robot=ROBOT_NAME, goal_radius=GOAL_RADIUS):
        """Collect the cylinders (centre at t = 0, radius, spec) of ``scenario``."""
        self.robot = robot
        spec = scenario.robot(robot)
        self.radius = spec.radius
        self.goal = spec.goal[:2]
        self.goal_radius = goal_radius
        self._cylinders = [o for o in scenario.all_obstacles() if o.radius is not None]
        self._radii = np.array([o.radius for o in self._cylinders])
        # centre(t) = base + velocity t, or base + position(t) on a trajectory.
        self._bases = []
        for obstacle in self._cylinders:
            base = np.mean(obstacle.polygon, axis=0)
            if obstacle.trajectory is None:
                base = base - obstacle.velocity * obstacle.appear_at
            else:
                base = base - obstacle.trajectory.position(obstacle.appear_at)
            self._bases.append(base)
        self.min_clearance = math.inf
        self.contact = None

    def centres(self, time):
        """Return the cylinders' centres (N, 2) at sim ``time``."""
        return np.array([base + (o.velocity * time if o.trajectory is None
                                 else o.trajectory.position(time))
                         for base, o in zip(self._bases, self._cylinders)]).reshape(-1, 2)

    def __call__(self, time, world, metrics):
        """Return the run's outcome once decided, else None (class docstring)."""
        state = world.robot_state(self.robot)
        position = state[:2]
        now = world.time
        if self._cylinders:
            centres = self.centres(now)
            gaps = np.hypot(*(centres - position).T) - self._radii - self.radius
            index = int(np.argmin(gaps))
            self.min_clearance = min(self.min_clearance, float(gaps[index]))
            if gaps[index] <= 0.0:
                velocity = state[3] * np.array([math.cos(state[2]), math.sin(state[2])])
                kind, toward = classify_contact(position, velocity, centres[index])
                spec = self._cylinders[index]
                away = centres[index] - position
                away /= max(np.linalg.norm(away), 1e-12)
                self.contact = {
                    'kind': kind, 'time_s': round(now, 4), 'cylinder': spec.name,
                    'gap_m': round(float(gaps[index]), 4),
                    'robot_toward_m_s': round(toward, 4),
                    'cylinder_toward_m_s': round(float(-spec.velocity_at(now) @ away), 4),
                    'robot_position': [round(v, 4) for v in position.tolist()],
                    'cylinder_position': [round(v, 4) for v in centres[index].tolist()]}
                return f'contact_{kind}'
        if math.dist(position, self.goal) <= self.goal_radius:
            return 'success'
        return None
