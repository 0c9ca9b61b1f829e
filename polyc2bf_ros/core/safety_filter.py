"""The PolyC2BF safety filter: (state, obstacles, nominal input) -> (safe input, info).

Over 500 lines on purpose: one step over one prepared state (rows, QP, fallbacks, the
braking check and evasion hooks); the kernels that assemble its rows are
``kernels.filter_rows``.

Per control step, for every convex obstacle part i (paper eq. 5)::

    minimise   sum_j W_j (u_j - u_nom_j)^2
    subject to Lf h_i + Lg h_i u + gamma h_i >= m        for every obstacle part i
               u_min <= u <= u_max

W = ``RobotModel.input_weights``: all ones (the paper's ||u - u_nom||^2) unless the
model is told otherwise (the unicycle's ``steering_weight``).

Discrete time: the node holds u for one control period T, while the
continuous CBF condition only holds at the sample instants.  Over a hold
interval h drifts from its first-order prediction by at most T^2/2 max|h_ddot|,
so each row is tightened by a margin m = ``margin_gain`` * T [m^2/s^2]: with
margin_gain >= max|h_ddot|/2 the held input keeps h_dot + gamma h >= 0 on
average over the interval.  The closed-loop tests show the default is enough
at the node's rates, except at a silhouette vertex, which no margin covers:
held at h = m / gamma, the filter keeps a fixed angle between v_rel and the
boundary ray k, so the reference point reaches the vertex k on a spiral (the
cone bounds the direction of v_rel, not the distance), where k_hat turns at
|v| / |k| -> inf and the vertex pair switches (p jumps, and h with it).  The
point then grazes the inflated obstacle by millimetres; the escape below takes
it out.  This is inherent to collision cones, not a sampling artefact.

3-D models see each obstacle (a vertical prism) in two planes (paper
section III, quadrotor): the horizontal plane (footprint polygon) and the
vertical plane spanned by the footprint's thin axis and z (the prism's shadow
rectangle); ``polyc2bf_ros.core.geometry.views`` says which plane is used where.

Pruning: a row whose left side is >= m for *every* u in the input box can
never be active; dropping it leaves the feasible set unchanged, so the
solution is exactly the same.  The QP front end answers most steps without a
solver run: u_ref (u_nom, or the escape input) itself when it lies in the box
and meets every row, or its projection onto one row (``qp._single_active``).

Hot path: per step, a few compiled kernels (``polyc2bf_ros.core.kernels.jit``: built
ahead of time, or by numba): per plane one pass computes viewpoints, cones and
barrier terms of all obstacles (``ConeModel.plane``), one more the QP rows, the
QP's front end and the active parts (``_rows_and_answer``; the solver runs only
when the front end cannot answer);
``SafetyFilter`` runs them all on construction (``warm_up``) so that the first
real step is as fast as the others.

Preparation: per obstacle set the cone model's geometry (inflated polygons,
enclosing circles, vertical shadows) is computed once and cached.  A set that
is a translation of a base set (``ObstacleSet.translated``: moving obstacles,
other robots, tracked markers) reuses the base's cached geometry and moves the
viewpoints the other way (``polyc2bf_ros.core.geometry.views``): the same cones to
rounding, without preparing or copying any geometry per step.

Fallbacks, always flagged in ``FilterInfo.status``:

* ``recovering``: the QP is feasible but the step started outside the safe set (some
  h < 0, the deepest in ``min_h``): its rows ask h_dot >= margin - gamma h > 0, driving h
  back up.  A CBF guarantees safety only from inside its safe set, so this is flagged,
  never reported as ``ok``.
* ``slack``: the QP is infeasible; solve it again with one shared slack
  s >= 0 on every (unit-norm) row (weight ``slack_weight``), input bounds kept
  hard.
* ``brake``: the slack QP failed too; apply the model's braking input.
* ``escape``: the reference point is inside an (inflated) obstacle, where no
  cone exists; the nominal input is replaced by one that accelerates the
  reference point out along the shortest way out, still subject to the other
  obstacles' rows.  Per part n the cone model gives, in each plane the part is
  seen in, the depth d and the outward unit vector e of the region without a
  cone (``ConeModel.exits``).  A 3-D model sees the prism through two
  extrusions that both contain it, and is out of the prism once it is out of
  either, so the plane with the smaller depth is taken::

      e_n = P_n^T e (plane of min d),       escape direction = sum_n e_n / |sum_n e_n|

  over the parts the point is inside: over a wall's top edge the vertical plane
  gives straight up, not a crawl sideways along the wall.
* ``backup``: ``braking_check`` (planar models with a ``braking_path``): the input
  found (also an escape's) would leave the robot a less clear way to brake to rest than
  braking now, or (``braking_check_barrier``) a way to rest along which some h falls
  lower; brake now (``polyc2bf_ros.core.barrier.braking_check``).
* ``invalid_input``: NaN/Inf in state, nominal input or obstacles; brake.
"""
import enum
import functools
import itertools
import math
import time
from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from polyc2bf_ros.core.barrier.cone_barrier import BarrierTerms
from polyc2bf_ros.core.barrier.cone_models import CONE_AXES, CONE_MODELS
from polyc2bf_ros.core.barrier.cones import Cones, PlanarPolygons, PLANE_CONES, PLANE_K
from polyc2bf_ros.core.barrier.footprint_cone import FootprintCone
from polyc2bf_ros.core.barrier.obstacle_geometry import ObstacleGeometry
from polyc2bf_ros.core.geometry.footprint import covering_radius, NO_FOOTPRINT, parse_footprint
from polyc2bf_ros.core.geometry.views import choose_planes
from polyc2bf_ros.core.kernels.barrier import tighten_for_obstacle_accel
from polyc2bf_ros.core.kernels.braking import (
    bands_within,
    clear_around,
    grow_bands,
    path_clearance,
    stop_clear,
)
from polyc2bf_ros.core.kernels.cones import PLANE_ROWS
from polyc2bf_ros.core.kernels.filter_rows import _active_parts, _rows_and_answer, ACTIVE_TOLERANCE
from polyc2bf_ros.core.models import make_model, MODEL_NAMES, ReferenceKinematics
from polyc2bf_ros.core.obstacles.ground import ground_offsets
from polyc2bf_ros.core.obstacles.obstacle_set import Obstacle, ObstacleSet
from polyc2bf_ros.core.qp.backends import make_solver, SOLVERS
from polyc2bf_ros.core.qp.solver import QPStatus, solve_with_shared_slack

BARRIERS = (*CONE_MODELS, FootprintCone.name)
"""``FilterConfig.barrier``'s values: a cone model, or the turning footprint's cone."""
DRIVE_SHARE = 0.25
"""Share of the way out a turning footprint's drive inputs must cover to escape by them."""
CLEARANCE_ROUNDING = 1e-12
"""m by which c(B(x+)) may fall short of c(B(x)) and still count as no worse (rounding).

A body sliding along an edge has the same clearance in exact arithmetic; computed, the two
differ by 1e-19 to 1e-16 m either way, which refused every input of a box backing out
between two posts within the margin.  Over 10^6 steps it adds up to 1 um at most."""
BRAKING_MESSAGE = 'braking check: the input leaves no clear way to stop; braking'
"""``FilterInfo.message`` when the braking check leaves the model's braking input alone."""
EVASION_STEP = 0.05
"""s between the points of an evasion's look ahead (rounded to whole control periods)."""
EVASION_REACH = 0.5
"""m beyond the braking check's clearance up to which an evasion's look ahead measures."""
EVASION_GAIN = 0.01
"""m of clearance an evasion must gain over holding the filter's input."""
STOP_HOLD = (0.2, 0.01, 0.02, 0.2)
"""How far ``_stop_certified`` widens a stop it certifies, to keep the certificate for the
next steps: m in position, m/s in velocity, rad/s in |omega|, s after its last time.  On an
unchanged obstacle set a stop inside the widened one is certified by it (the tests are
monotone in the boxes and times) with no pass over the parts: cruising at 1 m/s and 100 Hz
between rows of parts 1 m off, 9 steps in 10 (``bench/bench_core.py --in-reach``).  While
the robot speeds up by more than 0.01 m/s a period each step certifies its own stop."""
STOP_HOLD_RETRY = 8
"""Steps ``_stop_certified`` certifies only their own stop after a widened one failed (parts
near the stop): each try costs a pass over the parts."""
_NO_PARTS = np.empty(0)
"""``path_clearance``'s ``per_part`` when no part's own value is wanted."""
SPEED_TOLERANCE = 1e-3
"""m/s an evasion at its speed limit may still add: a turn alone speeds up a point ahead of
the axle by a little (l omega), and is no speeding up (``_speed_limit``)."""


class FilterStatus(str, enum.Enum):
    """What the filter did on a step."""

    OK = 'ok'
    RECOVERING = 'recovering'
    SLACK = 'slack'
    BRAKE = 'brake'
    ESCAPE = 'escape'
    BACKUP = 'backup'
    EVADE = 'evade'
    INVALID_INPUT = 'invalid_input'


@dataclass
class FilterConfig:
    """Filter parameters; ``validate`` explains any bad value.

    The default barrier is the horizon-aware PolyC2BF on the exact cone with the braking
    check (design.md 3.9-3.10): on the 200 BARN worlds it reaches the goal in all of them
    with a path-following nominal and collides in none, where the inflated-silhouette
    PolyC2BF (eq. 7) stalled in 26 % and grazed 1.5 %.  ``robot_radius`` is the body's
    radius around its centre; the filter adds the model's ``guard_offset``.  ``footprint``
    (Nav2's polygon string, ``geometry.footprint``), when set, replaces it: the body is
    then guarded as the disc about the origin that covers the polygon (``body_radius``).
    """

    barrier: str = 'polyc2bf_horizon'
    robot_radius: float = 0.3
    footprint: str = NO_FOOTPRINT
    gamma: float = 1.0
    control_period: float = 0.01
    margin_gain: float = 1.0
    solver: str = 'daqp'
    velocity_epsilon: float = 0.05
    slack_weight: float = 1e4
    prune: bool = True
    escape_speed: float = 0.3
    escape_gain: float = 2.0
    inflation_segments: int = 16
    horizon: float = 1.0
    cone_axis: str = 'bisector'
    braking_check: bool = True
    braking_check_barrier: bool = True
    braking_margin: float = 0.002
    braking_obstacle_accel: float = 0.0
    ground_z: float = -math.inf
    obstacle_accel: float = 0.0
    obstacle_velocity_error: float = 0.0
    evasion_horizon: float = 1.0
    evasion_commit: bool = False
    evasion_max_speed: float = 0.0
    max_reverse_speed: float = 0.0

    @property
    def body_radius(self):
        """Return the radius of the disc guarded: ``robot_radius``, or the footprint's cover.

        Parsed on each call: a filter's ``geometry.robot_radius`` holds it once.
        """
        points = parse_footprint(self.footprint)
        return self.robot_radius if points is None else covering_radius(points)

    @property
    def margin(self):
        """Return the sample-and-hold margin m = margin_gain * control_period."""
        return self.margin_gain * self.control_period

    def validate(self):
        """Raise ValueError naming the first invalid field and why."""
        if self.barrier not in BARRIERS:
            raise ValueError(f'barrier must be one of {sorted(BARRIERS)}, got {self.barrier!r}')
        if self.barrier == FootprintCone.name and parse_footprint(self.footprint) is None:
            raise ValueError(f"barrier {FootprintCone.name} guards a footprint polygon: set "
                             "footprint to '[[x, y], ...]'")
        if self.solver not in SOLVERS:
            raise ValueError(f'solver must be one of {sorted(SOLVERS)}, got {self.solver!r}')
        positive = ('gamma', 'control_period', 'velocity_epsilon', 'slack_weight',
                    'escape_gain')
        non_negative = ('robot_radius', 'margin_gain', 'escape_speed', 'braking_margin',
                        'braking_obstacle_accel', 'obstacle_accel', 'obstacle_velocity_error',
                        'evasion_horizon', 'evasion_max_speed', 'max_reverse_speed')
        for name in positive + non_negative:
            value = getattr(self, name)
            if not np.isfinite(value) or value < 0 or (name in positive and value == 0):
                kind = 'positive' if name in positive else 'non-negative'
                raise ValueError(f'{name} must be finite and {kind}, got {value!r}')
        if self.cone_axis not in CONE_AXES:
            raise ValueError(f'cone_axis must be one of {list(CONE_AXES)}, '
                             f'got {self.cone_axis!r}')
        if not (self.horizon > 0.0):
            raise ValueError(f'horizon must be positive (inf: none), got {self.horizon!r}')
        if math.isnan(self.ground_z) or self.ground_z == math.inf:
            raise ValueError(f'ground_z must be a height or -inf (no ground), '
                             f'got {self.ground_z!r}')
        if not isinstance(self.footprint, str):
            raise ValueError('footprint must be a string "[[x, y], ...]" (Nav2\'s format), '
                             f'got {self.footprint!r}')
        parse_footprint(self.footprint)  # FootprintError (a ValueError) says what is wrong
        if not 3 <= self.inflation_segments <= 256:
            raise ValueError('inflation_segments must be in [3, 256], '
                             f'got {self.inflation_segments!r}')
        return self


@dataclass(slots=True)
class FilterInfo:
    """Diagnostics of one step; ``h`` has one entry per obstacle part (NaN if inside).

    ``min_h`` is the smallest of them that is not NaN (+inf without obstacles).
    """

    status: FilterStatus
    h: np.ndarray = field(default_factory=lambda: np.zeros(0))
    min_h: float = math.inf
    active: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    solve_time_s: float = 0.0
    num_obstacles: int = 0
    num_constraints: int = 0
    slack: float = 0.0
    message: str = ''
    evaluation: object = field(default=None, repr=False)

    @property
    def cones(self):
        """Return the step's cones (views into its ``Evaluation``), or None without one."""
        return None if self.evaluation is None else self.evaluation.cones


@dataclass(slots=True)
class Evaluation:
    """Per obstacle part: viewpoint, cone and barrier terms in the plane used (``block``).

    ``block`` is a ``ConeModel.plane`` block; ``valid`` (N,) where its cone exists,
    ``usable`` where any plane's does; ``vertical`` (N,) tells where a 3-D model uses
    the vertical plane (None for planar models); ``viewpoints`` holds each plane's
    (2, N) viewpoints, for the escape direction.
    """

    block: np.ndarray
    valid: np.ndarray
    usable: np.ndarray
    vertical: Optional[np.ndarray]
    viewpoints: tuple

    @property
    def cones(self):
        """Return the cones (views into ``block``)."""
        return Cones.from_block(self.block[PLANE_CONES], self.valid)

    def axis(self, index):
        """Return (p_x, p_y): the cone axis of part ``index``, ``cones.p[:, index]`` as floats."""
        first = PLANE_CONES.start
        return float(self.block[first, index]), float(self.block[first + 1, index])

    @property
    def terms(self):
        """Return h, Lf h, Lg h (views into ``block``)."""
        return BarrierTerms.from_block(self.block[PLANE_ROWS:])

    @property
    def inside(self):
        """Return where no cone exists: the reference point is inside the (inflated) part."""
        return ~self.usable

    @property
    def plane(self):
        """Return the plane used per obstacle: 0 horizontal, 1 vertical."""
        if self.vertical is None:
            return np.zeros(self.usable.shape, dtype=int)
        return self.vertical.astype(int)


@dataclass(frozen=True)
class _Prepared:
    """Everything per obstacle set that does not change between steps, and row buffers.

    ``count`` obstacle parts; ``footprints`` their polygons for the braking check
    (``cones.PlanarPolygons``; planar models with ``braking_check``, else None);
    ``velocities`` (N, d) are their c_dot in the robot's d dimensions and ``offsets``
    (N, d) how far they moved from where ``views`` has them (zero unless the set is a
    translation, see ``polyc2bf_ros.core.geometry.views``); ``rows_a`` (N, m), ``rows_b`` and
    ``index`` (N,) are scratch space for the QP rows (the first rows of a step are valid);
    ``velocity_errors`` (3, N): how far each part's velocity may be off, for the braking
    check, then for an evasion's look ahead, then the part's own bound alone
    (``_velocity_errors``); ``accelerations`` (N, 2) their stated planar accelerations
    (``ObstacleSet.accelerations``; ``steady`` when none), which an evasion's look ahead
    follows (``_look_ahead``) and the braking check too (``_path_clearance``), and
    ``fastest_speeding_up`` the largest one's norm [m/s^2]; ``steady`` (N, 2) zeros, the
    accelerations of a set that states none; ``moving``: some part moves in the plane
    (``velocities``' first two columns).  A translation (each step while obstacles move)
    shares the buffers and the zeros.
    """

    count: int
    views: tuple
    velocities: np.ndarray
    offsets: np.ndarray
    finite: bool
    rows_a: np.ndarray
    rows_b: np.ndarray
    index: np.ndarray
    velocity_errors: np.ndarray
    accelerations: np.ndarray
    fastest_speeding_up: float
    steady: np.ndarray
    moving: bool
    footprints: Optional[object] = None

    def translated(self, offsets, velocities, velocity_errors, accelerations,
                   fastest_speeding_up, moving):
        """Return the same views and buffers with obstacles moved by ``offsets`` (N, d)."""
        return _Prepared(count=self.count, views=self.views, velocities=velocities,
                         offsets=offsets, finite=self.finite, rows_a=self.rows_a,
                         rows_b=self.rows_b, index=self.index, footprints=self.footprints,
                         velocity_errors=velocity_errors, accelerations=accelerations,
                         fastest_speeding_up=fastest_speeding_up, steady=self.steady,
                         moving=moving)


def compile_kernels():
    """Build one filter per model and barrier, so every kernel has run once.

    Just in time (``polyc2bf_ros.core.kernels.jit``) this compiles them all into numba's
    on-disk cache (~10 s cold); with the kernels built ahead of time it is quick.
    """
    for model in MODEL_NAMES:
        for barrier in CONE_MODELS:
            SafetyFilter(make_model(model), FilterConfig(barrier=barrier))


def _all_finite(array):
    """Return True when every entry of a float array is finite."""
    return all(map(math.isfinite, array.ravel().tolist()))


def _speed(row):
    """Return the speed [m/s] of a path's row (columns 2, 3: the velocity)."""
    return math.hypot(float(row[2]), float(row[3]))


class _BrakingNow:
    """What braking at the step's state x gives: B(x), c(B(x)) and H(x), each once, on use."""

    def __init__(self, safety_filter, state, prepared, age):
        """Keep what the values are computed from."""
        self._filter, self._state, self._prepared, self._age = (safety_filter, state,
                                                                prepared, age)

    @functools.cached_property
    def path(self):
        """Return B(x) (``RobotModel.braking_path``)."""
        return self._filter.braking_path(self._state)

    @functools.cached_property
    def clearance(self):
        """Return c(B(x)), capped at the margin: (static parts, moving parts)."""
        return self._filter._path_clearance(self.path, self._prepared, self._age)

    @functools.cached_property
    def moving_parts(self):
        """Return (N,) each moving part's own c(B(x)) (the margin for the others)."""
        return self._filter._moving_parts(self.path, self._prepared, self._age)

    @functools.cached_property
    def min_h(self):
        """Return H(x), the smallest h at x and along B(x)."""
        return self._filter._min_h_along(self._filter._paths.point_row(self._state),
                                         self.path, self._prepared, self._age)


class SafetyFilter:
    """PolyC2BF / C3BF safety filter for one robot model.

    Holds per-obstacle-set scratch buffers and the solver's workspaces: use one per thread.
    """

    def __init__(self, model, config=None):
        """Bind a model and a (validated) configuration, and compile the hot path."""
        self.model = model
        self.config = (config or FilterConfig()).validate()
        # What prepared views depend on (cone model, dimension, guard radius R + l, ground):
        # shared with the node's obstacle worker, which prepares sets without a filter.
        self.geometry = ObstacleGeometry(model, self.config)
        self.guard_radius, self.cone_model = self.geometry.guard_radius, self.geometry.cone_model
        self.solver = make_solver(self.config.solver)
        self._state_shape, self._input_shape = (model.state_dim,), (model.input_dim,)
        self._weights = np.ascontiguousarray(model.input_weights, dtype=np.float64)
        self._lower = np.ascontiguousarray(model.input_lower, dtype=np.float64)
        self._upper = np.ascontiguousarray(model.input_upper, dtype=np.float64)
        # The step's input box: a unicycle's lower drive bound follows the reverse limit
        # (``_bound_reverse``), in place, so the row kernel's settings below see it.
        reverse = float(self.config.max_reverse_speed)
        self._reverse = reverse if reverse > 0.0 and model.name == 'unicycle' else math.inf
        self._drive_box = (float(self._lower[0]), float(self._upper[0]))
        # Plain floats and bools, so every filter shares one compiled version of each kernel.
        self._row_settings = (float(self.config.margin), float(self.config.gamma),
                              self._lower, self._upper, bool(self.config.prune))
        self._epsilon = float(self.config.velocity_epsilon)
        # Robust rows for moving parts (barrier.py); planar models: a 3-D model's ground
        # moves with the robot.
        planar = model.position_dim == 2
        self._obstacle_accel = float(self.config.obstacle_accel) if planar else 0.0
        self._velocity_error = float(self.config.obstacle_velocity_error) if planar else 0.0
        self._braking = bool(self.config.braking_check) and model.position_dim == 2
        # A turning footprint (``footprint_cone``): the check follows the axle with its
        # heading and measures the bodies' distance apart.
        self._turning = self.geometry.turning
        # What the check and the evasion measure along: the guarded point's paths (the
        # model's), or the axle's with its heading (``RobotModel.body_paths``).
        self._paths = model.body_paths() if self._turning else model
        self._barrier_check = self._braking and bool(self.config.braking_check_barrier)
        # The braking check measures paths against the obstacles' own polygons: the robot
        # keeps braking_margin, i.e. a guarded point guard_radius + braking_margin, a
        # footprint braking_margin (its distance is 0 at contact).
        self._contact = 0.0 if self._turning else self.guard_radius
        self._clearance = self._contact + float(self.config.braking_margin)
        # The footprint the paths carry ((2, 0): a point), how far it reaches from its origin,
        # and so how far beyond a path's points an obstacle can matter (``_far_from_all``).
        self._body = self.cone_model.points if self._turning else np.zeros((2, 0))
        self._cover = self.guard_radius if self._turning else 0.0
        self._reach_margin = self._clearance + self._cover
        self._braking_accel = float(self.config.braking_obstacle_accel)
        # Evasion: inputs held over the look ahead, the input box's corners, edge midpoints
        # and centre (design.md 3.10, evasion).
        period = float(self.config.control_period)
        self._evasion_step = period * max(1, round(EVASION_STEP / period))
        self._evasion_rows = max(1, round(self.config.evasion_horizon / self._evasion_step))
        self._evasion = (self._braking and self.config.evasion_horizon > 0.0
                         and self._paths.held_path(np.zeros(model.state_dim),
                                                   np.zeros(model.input_dim), period, 1)
                         is not None)
        # How far the largest input bound carries the point over the look ahead, a H^2 / 2.
        self._evasion_spread = (0.5 * float(np.max(self._upper))
                                * (self._evasion_rows * self._evasion_step) ** 2)
        self._evasion_commit = bool(self.config.evasion_commit)
        self._evasion_speed = float(self.config.evasion_max_speed) or math.inf
        self._evasion_inputs = np.array(list(itertools.product(*zip(
            self._lower, np.clip(0.0, self._lower, self._upper), self._upper))))
        # The step's reference kinematics, refilled each step (it never leaves the step).
        self._reference = ReferenceKinematics.empty(model.position_dim, model.input_dim)
        self._cache_key = self._cache = None
        self._base_key = self._base = None
        # The widened stop ``_stop_certified`` certified last, and on which obstacle set.
        self._held_prepared, self._held_bands, self._held_times = None, None, (0.0, 0.0)
        self._hold_wait = 0
        self.warm_up()

    def warm_up(self):
        """Run the hot path once on a made-up scene, so its kernels compile (or load) now.

        Numba compiles a kernel on its first call (seconds without the on-disk cache,
        milliseconds with it); doing that here keeps it out of the first real step.
        """
        square = np.array([[2.0, -0.5], [3.0, -0.5], [3.0, 0.5], [2.0, 0.5]])
        scene = ObstacleSet.from_obstacles([
            Obstacle(polygon=square, velocity=np.array([-0.1, 0.0, 0.0]), z_min=0.0, z_max=2.0),
            Obstacle(polygon=square + [-1.0, 2.0])])
        state = np.zeros(self.model.state_dim)
        self.step(state, scene, (self._lower + self._upper) / 2, 0.01)
        # A translated set takes another path (the base's views, viewpoints moved).
        self.step(state, scene.translated(np.full((2, 3), 0.1)), self._upper, 0.01)
        self.escape_direction(self.evaluate(state, scene), scene)
        # And the QP front end's shortcut, which a step the fast path answers skips.
        self.solver.solve(self._upper + 1.0, self._weights, np.eye(self.model.input_dim)[:1],
                          self._lower[:1], self._lower, self._upper)

    def step(self, state, obstacles, u_nom, obstacle_age=0.0):
        """Return (u_safe, FilterInfo); obstacles are extrapolated by ``obstacle_age`` s."""
        start = time.perf_counter()
        state = np.asarray(state, dtype=float)
        u_nom = np.ascontiguousarray(u_nom, dtype=float)
        if state.shape != self._state_shape or u_nom.shape != self._input_shape:
            raise ValueError(f'{self.model.name}: state must have shape '
                             f'({self.model.state_dim},) and u_nom ({self.model.input_dim},), '
                             f'got {state.shape} and {u_nom.shape}')
        prepared = self._prepare(obstacles)
        if not (_all_finite(state) and _all_finite(u_nom) and math.isfinite(obstacle_age)
                and prepared.finite):
            return self._brake(state, FilterStatus.INVALID_INPUT, start,
                               'non-finite state, nominal input or obstacle')
        if not prepared.count:
            # No obstacle, no row: the QP's solution is u_nom clipped to the box.
            return self.model.clip_input(u_nom), FilterInfo(
                status=FilterStatus.OK, solve_time_s=time.perf_counter() - start)
        if self._reverse < math.inf:
            self._bound_reverse(state, u_nom)
        ref = self.model.reference(state, self._reference)
        evaluation = self._evaluate(prepared, ref, obstacle_age)
        h, x = np.empty(prepared.count), np.empty(self.model.input_dim)
        active = np.empty(prepared.count, dtype=np.intp)
        count, inside, min_h, answered = _rows_and_answer.unchecked(
            evaluation.block[PLANE_ROWS:], evaluation.usable, *self._row_settings,
            prepared.rows_a, prepared.rows_b, prepared.index, h, u_nom, self._weights,
            self.solver.shortcut, x, active)
        if answered >= 0:
            u, slack, status, message = x, 0.0, FilterStatus.OK, ''
            active = active[:answered]
        else:
            solved = self._solve_rows(prepared, count, inside, ref, evaluation, u_nom, active)
            if solved is None:
                return self._brake(state, FilterStatus.BRAKE, start, 'QP and slack QP failed',
                                   h, min_h, evaluation)
            u, slack, status, message, active = solved
        if status == FilterStatus.OK and min_h < 0.0:
            status = FilterStatus.RECOVERING
            message = f'outside the safe set: min h = {min_h:.3g}; driving h back up'
        if self._braking and status in (FilterStatus.OK, FilterStatus.RECOVERING,
                                        FilterStatus.SLACK, FilterStatus.ESCAPE):
            now = None
            # The bounds of u's stop, shared by the check and the evasion's look ahead.
            stop = self._paths.stop_bands(state, u, self.config.control_period)
            if not (self._stop_certified(stop, prepared, obstacle_age)
                    or self._far_from_all(state, prepared, obstacle_age)):
                now = _BrakingNow(self, state, prepared, obstacle_age)
                if self._must_brake(state, u, prepared, obstacle_age, now):
                    u, message = self._backup_input(state, u, prepared, obstacle_age, now,
                                                    count)
                    status = FilterStatus.BACKUP
                    stop = self._paths.stop_bands(state, u, self.config.control_period)
            if self._evasion and self._moving_near(state, prepared, obstacle_age, ref):
                now = now or _BrakingNow(self, state, prepared, obstacle_age)
                evasion = self._evade(state, u, prepared, obstacle_age, now, stop)
                if evasion is not None:
                    u, message = evasion
                    status = FilterStatus.EVADE
        return u, FilterInfo(
            status=status, h=h, min_h=min_h, active=active,
            solve_time_s=time.perf_counter() - start, num_obstacles=prepared.count,
            num_constraints=count, slack=float(slack),
            message=message, evaluation=evaluation)

    def _bound_reverse(self, state, u_nom):
        """Keep a unicycle's next speed v + a T at or above min(-v_r, v + a_nom T).

        v_r = ``max_reverse_speed``: the filter backs the robot no faster than that, or than
        the nominal asks.  A box whose laser faces forward backs blind: pushed off a post
        ahead, the filter (turning its nose clear at the nominal's rate) reversed it at up
        to 1.4 m/s (BARN world 188, a Jackal from its laser, go-to-goal) and, following a
        faster route, at 2 m/s into a post no beam had ever lit (contact).  The drive
        bound a >= (floor - v) / T, within the model's +-a_max (already backing faster: the
        hardest braking).
        """
        period = self.config.control_period
        speed = float(state[3])
        floor = min(-self._reverse, speed + float(u_nom[0]) * period)
        lowest, highest = self._drive_box
        self._lower[0] = min(max((floor - speed) / period, lowest), highest)

    def _solve_rows(self, prepared, count, inside, ref, evaluation, u_nom, active):
        """Solve the QP on the step's ``count`` rows where the one-pass kernel could not.

        u_ref is the escape input when ``inside`` parts are unusable (``_escape_input``),
        else u_nom; an
        infeasible QP is solved again with the shared slack.  Return (u, slack, status,
        message, active parts), or None when the slack QP failed too.
        """
        u_ref, status, message = u_nom, FilterStatus.OK, ''
        if inside:
            u_ref = self._escape_input(ref, self._escape_direction(prepared, evaluation), u_nom)
            status = FilterStatus.ESCAPE
            message = (f'reference point inside {inside} (inflated) obstacle part(s); '
                       'escaping along the outward direction')
        rows_a, rows_b = prepared.rows_a[:count], prepared.rows_b[:count]
        result = self.solver.solve_checked(u_ref, self._weights, rows_a, rows_b, self._lower,
                                           self._upper)
        u, slack = result.x, 0.0
        if result.status != QPStatus.OPTIMAL:
            u, slack, slack_result = solve_with_shared_slack(
                self.solver, u_ref, self._weights, rows_a, rows_b, self._lower, self._upper,
                self.config.slack_weight, plain=result)
            if slack_result.status != QPStatus.OPTIMAL:
                return None
            if status == FilterStatus.OK:
                status = FilterStatus.SLACK
        active = active[:_active_parts(rows_a, u, rows_b, prepared.index,
                                       ACTIVE_TOLERANCE + slack, active)]
        return u, slack, status, message, active

    def _must_brake(self, state, u, prepared, age, now, moving=True):
        """Return True when holding ``u`` leaves a less clear way to stop than braking now.

        ``polyc2bf_ros.core.barrier.braking_check``: kept when c(B(x+)) >= margin or >= c(B(x))
        (distances to the footprints less the guard radius; less ``CLEARANCE_ROUNDING``),
        also where c(B(x)) <= 0;
        moving parts, where the path closes on them, apart.
        With ``braking_check_barrier`` the same test on H(x) = min h over x and B(x): kept
        when H(x+) >= 0 or >= H(x); braked only while H(x) >= 0.  x+ and B(x+):
        ``RobotModel.braking_after``.
        ``now`` (``_BrakingNow``) holds what braking at x gives, computed
        once per step however many inputs are tested.  ``moving`` False: the static test
        alone (a committed evasion, ``_evade``).
        """
        period = self.config.control_period
        rows = self._paths.braking_after(state, u, period)  # the point at x+, then B(x+)
        after_path = rows[1:]
        after, after_moving = self._path_clearance(after_path, prepared, age + period)
        # c(B(x)) is computed only where c(B(x+)) falls under the margin.
        if after < self._clearance and after < now.clearance[0] - CLEARANCE_ROUNDING:
            return True
        if not moving:
            return False
        if after_moving < self._clearance and (
                after_moving < now.clearance[1] - CLEARANCE_ROUNDING
                if now.clearance[1] >= self._contact  # B(x) meets no moving part
                else self._closes_on_a_part(after_path, prepared, age + period, now)):
            return True
        if not self._barrier_check:
            return False
        after = self._min_h_along(rows[0], after_path, prepared, age + period)
        return after < 0.0 and after < now.min_h and now.min_h >= 0.0

    def _min_h_along(self, start, path, prepared, age):
        """Return H: the smallest h at the point's ``start`` row and along its braking ``path``.

        ``ConeModel.min_h_along`` (inf for a cone model without it); planar models only.
        Unchecked kernel: the filter's own arrays, and rows of ``RobotModel.braking_after``
        or ``point_row`` and ``braking_path`` (C-contiguous float64).
        """
        return self.cone_model.min_h_along(
            prepared.views[0].prepared, prepared.velocities, prepared.offsets, age, start,
            path, self.config.control_period, self._epsilon, False)

    def _far_from_all(self, state, prepared, age):
        """Return True when no obstacle part comes near any path ``_must_brake`` would check.

        ``kernels.braking.clear_around`` with the model's bound rho on those paths
        (``RobotModel.braking_reach``) and reach rho + the margin: c(B(x+)) is then the
        margin, whatever the input.  Never where a part states an acceleration, which the
        check moves it with (``_path_clearance``) and this test does not.
        Unchecked kernel: the filter's own arrays.
        """
        reach, duration = self.model.braking_reach(state, self.config.control_period)
        if reach == math.inf or prepared.fastest_speeding_up > 0.0:
            return False
        footprints = prepared.footprints
        return clear_around.unchecked(
            footprints.boxes, prepared.velocities, prepared.offsets, prepared.velocity_errors[0],
            self._braking_accel, max(abs(age), abs(age + duration)), float(state[0]),
            float(state[1]), reach + self._reach_margin, False)

    def _stop_certified(self, stop, prepared, age):
        """Return True when the check surely keeps u, its path bounded, not computed.

        ``stop``: ``RobotModel.stop_bands`` of the state and u, which bounds x+ and B(x+)
        (their rows' positions, velocities by speed band, times); ``_bands_clear`` tells
        whether ``_must_brake`` returns False for every path they hold.  A certified stop is
        kept widened by ``STOP_HOLD`` (``kernels.braking.grow_bands``, certified itself):
        while the obstacle set is the same, a stop inside it (``bands_within``) is
        certified without a pass over the parts.  The same decisions, fewer passes.
        """
        if stop is None:
            return False
        bands, rows = stop
        period = self.config.control_period
        first = age + period
        last = first + rows * period
        held = self._held_bands
        if prepared is not self._held_prepared:
            # A new set (a message, or moved parts): no certificate to keep or to make.
            self._held_prepared, self._held_bands, self._hold_wait = prepared, None, 0
            return self._bands_clear(bands, first, last, prepared)
        if held is not None and bands_within.unchecked(bands, first, last, held,
                                                       *self._held_times):
            return True
        self._held_bands = None
        if self._hold_wait > 0:  # a widened stop failed lately: parts are near
            self._hold_wait -= 1
            return self._bands_clear(bands, first, last, prepared)
        reach, speed, turn, later = STOP_HOLD
        if held is None or held.shape != bands.shape:
            held = np.empty_like(bands)
        grow_bands.unchecked(bands, reach, speed, turn, held)
        if self._bands_clear(held, first, last + later, prepared):
            self._held_bands, self._held_times = held, (first, last + later)
            return True
        self._hold_wait = STOP_HOLD_RETRY
        return self._bands_clear(bands, first, last, prepared)

    def _bands_clear(self, bands, first, last, prepared):
        """Return True when ``_must_brake`` keeps u on each path ``bands`` hold over [first, last].

        When no part, grown by its motion, comes within the check's clearance of their box
        (``stop_clear``: c(B(x+)) is the margin, also over the moving parts) and the cone
        model's pruning tests hold on every band (``ConeModel.stop_skipped``: H(x+) >= 0).
        The same decision as the check's, with none of its paths: among obstacles the
        stop's box mostly misses them (``bench/bench_core.py --in-reach``).
        """
        footprints = prepared.footprints
        return stop_clear.unchecked(
            bands, first, last, footprints.boxes, prepared.velocities, prepared.offsets,
            prepared.accelerations, prepared.velocity_errors[0], self._braking_accel,
            self._clearance, self._cover, False) and (
            not self._barrier_check or self.cone_model.stop_skipped(
                prepared.views[0].prepared, prepared.velocities, prepared.offsets, first, last,
                bands))

    def _backup_input(self, state, u, prepared, age, now, count):
        """Return (input, message) once the braking check refused ``u``.

        The first the check keeps of: for a turning footprint, ``u``'s drive with the
        steering braked (the turn is most often what swings a corner into the margin: a
        box at rest nose-in between posts, asked to back out while turning, stood for
        good); the brake with the model's steering inputs taken from ``u``; the same with
        them reversed (a unicycle at rest at the band's edge turns away instead of
        standing for good); otherwise the brake.  A turning footprint's steered
        candidates must hold the step's ``count`` QP rows too: its corners sweep as it
        turns, which the check's clearance test alone lets come to the margin and past
        h = 0.  The driven one does not turn, and is held to the check alone: in tight
        spots the rows are often infeasible (the slack QP answered), and every candidate
        missed them.
        """
        brake = self.model.clip_input(self.model.braking_input(state))
        steering = list(self.model.steering_inputs)
        if not steering:
            return brake, BRAKING_MESSAGE
        rows_a, rows_b = prepared.rows_a[:count], prepared.rows_b[:count]
        candidates = []
        if self._turning:
            driven = u.copy()
            driven[steering] = brake[steering]
            candidates.append((driven, False, 'keeping the drive, braking the steering'))
        for sign, how in ((1.0, 'keeping'), (-1.0, 'reversing')):
            steered = brake.copy()
            steered[steering] = sign * u[steering]
            candidates.append((steered, self._turning, f'braking the speed, {how} the steering'))
        for candidate, turns, how in candidates:
            if turns and np.any(rows_a @ candidate < rows_b - ACTIVE_TOLERANCE):
                continue
            if not self._must_brake(state, candidate, prepared, age, now):
                return candidate, f'braking check: {how}'
        return brake, BRAKING_MESSAGE

    def _moving_near(self, state, prepared, age, reference=None):
        """Return True when a moving part may come within an evasion's look ahead.

        ``clear_around`` over the moving parts, with ``_evasion_reach``, each straying by
        the largest stated acceleration too.
        """
        if not prepared.moving:
            return False
        position, reach, horizon = self._evasion_reach(state, reference)
        return not clear_around.unchecked(
            prepared.footprints.boxes, prepared.velocities, prepared.offsets,
            prepared.velocity_errors[1], prepared.fastest_speeding_up, abs(age) + horizon,
            position[0], position[1], reach, True)

    def _untrusted_near(self, state, prepared, age):
        """Return True when a part with its own velocity bound may come as near.

        ``_moving_near`` over the parts whose velocity is not known
        (``ObstacleSet.velocity_errors``: a scan track that is not trusted, or one that
        moves and may hide another), each grown by
        its bound over the horizon: a committed evasion wagers on stated velocities, which
        such a part does not have.
        """
        own = prepared.velocity_errors[2]
        if not own.any():
            return False
        unknown = own > 0.0
        position, reach, horizon = self._evasion_reach(state)
        return not clear_around(
            prepared.footprints.boxes[unknown], prepared.velocities[unknown],
            prepared.offsets[unknown], own[unknown], 0.0, abs(age) + horizon, position[0],
            position[1], reach, False)

    def _evasion_reach(self, state, reference=None):
        """Return (position, reach, horizon H) of an evasion's look ahead.

        The reach is how far any held input moves the point the look ahead follows (the
        reference point, or a turning footprint's axle) over H, |r_dot| H + a H^2 / 2 (a the
        largest input bound, the model's input matrix at most 1 per unit), plus the look
        ahead's cutoff and the footprint's covering radius.  ``reference``: the step's
        reference kinematics at ``state``, the same row as ``point_row`` where the look
        ahead follows the reference point.
        """
        horizon = self._evasion_rows * self._evasion_step
        if reference is None or self._turning:
            row = self._paths.point_row(state)
            position, velocity = row[:2], row[2:4]
        else:
            position, velocity = reference.position, reference.velocity
        reach = (math.hypot(velocity[0], velocity[1]) * horizon + self._evasion_spread
                 + self._reach_margin + EVASION_REACH)
        return (float(position[0]), float(position[1])), reach, horizon

    def _evade(self, state, u, prepared, age, now, stop):
        """Return (input, message) of an evasion when ``u`` runs into a moving part, or None.

        ``stop``: ``RobotModel.stop_bands`` of the state and ``u`` (``_look_ahead_clear``).

        design.md 3.10 (evasion).  The look ahead of ``u``: held for one period, then the
        brake, then at rest, over ``evasion_horizon`` H.  When a moving part, at its stated
        velocity (less ``obstacle_velocity_error`` t), comes within the braking check's
        clearance of it, each of ``_evasion_inputs`` is held instead, for H / 2 then braking
        and for all of H; the input whose look ahead stays clearest of every part, by
        ``EVASION_GAIN`` more than ``u``'s, is returned if the braking check keeps it, or,
        with ``evasion_commit``, if that look ahead keeps the check's clearance of every part
        all along and the check's static test keeps it (committed: the way out may lie
        across a moving part's braking path, never across a standing one's), and no part
        whose velocity is not known comes near (``_untrusted_near``).  Once the point
        moves at ``evasion_max_speed``, no look ahead that speeds it up further is taken:
        a base that lags stops later than planned, and sooner from a slower evasion
        (``_speed_limit``).
        """
        if self._look_ahead_clear(stop, prepared, age):
            return None
        static, moving = self._look_ahead(
            self._then_brake(np.zeros((0, self._paths.columns)),
                             self.model.one_period(state, u, self.config.control_period), 1),
            prepared, age)
        if moving >= self._clearance:
            return None
        held = min(static, moving)
        # A committed input wagers on stated velocities: not with an unknown one near.
        may_commit = self._evasion_commit and not self._untrusted_near(state, prepared, age)
        limit = self._speed_limit(state)
        scores = [self._evasion_score(state, candidate, prepared, age, limit)
                  for candidate in self._evasion_inputs]
        for index in sorted(range(len(scores)), key=lambda i: -scores[i]):
            candidate, score = self._evasion_inputs[index], scores[index]
            if score <= held + EVASION_GAIN:
                break
            # Committed (clear all along): the check's static test alone.
            committed = may_commit and score >= self._clearance
            if not self._must_brake(state, candidate, prepared, age, now, moving=not committed):
                return candidate.copy(), (
                    f'evading a moving obstacle: {np.round(candidate, 2).tolist()} keeps '
                    f'{score - self._contact:.2f} m clear over '
                    f'{self.config.evasion_horizon:g} s, the filter input '
                    f'{held - self._contact:.2f} m')
        return None

    def _look_ahead_clear(self, stop, prepared, age):
        """Return True when u's look ahead surely keeps the clearance of every moving part.

        Its rows are rows of B(x+) (then the last at rest) at age + step ... age + H, so
        inside the box of ``stop`` (``RobotModel.stop_bands`` of the state and u);
        ``stop_clear`` over the moving parts, at their stated accelerations and velocity
        errors, with the check's clearance, gives ``_evade``'s own answer (no evasion)
        without computing the look ahead.
        """
        if stop is None:
            return False
        footprints = prepared.footprints
        return stop_clear.unchecked(
            stop[0], age + self._evasion_step, age + self._evasion_rows * self._evasion_step,
            footprints.boxes, prepared.velocities, prepared.offsets, prepared.accelerations,
            prepared.velocity_errors[1], 0.0, self._clearance, self._cover, True)

    def _evasion_score(self, state, candidate, prepared, age, limit):
        """Return the better smallest clearance of ``candidate``'s look aheads (``_evade``).

        -inf when their shared first row is faster than ``limit`` (``_speed_limit``).
        """
        if candidate[0] < self._lower[0]:  # backs faster than ``max_reverse_speed``
            return -math.inf
        paths = self._evasion_paths(state, candidate)
        if _speed(paths[0][0]) > limit:
            return -math.inf
        return max(min(self._look_ahead(path, prepared, age)) for path in paths)

    def _speed_limit(self, state):
        """Return the fastest an evasion's look ahead may go at its first row [m/s].

        Below ``evasion_max_speed`` (0: no limit) any; from there on, the point's speed
        now, so that an evasion may hold or shed speed but not add to it (``_evade``).
        Measured on the dynamic suite with a base 30 ms late and lagging 0.1 s,
        compensated, and ``evasion_commit``: unlimited, 4 of the 20 hard worlds ended at
        fault, the robot still braking from the 1.1-1.7 m/s that committed evasions had
        sped it up to; limited to the nominal's 1 m/s, none of the 60 (design.md 3.10).
        """
        now = _speed(self._paths.point_row(state))
        return math.inf if now < self._evasion_speed else now + SPEED_TOLERANCE

    def _evasion_paths(self, state, candidate):
        """Return the look aheads of ``candidate``: held for H / 2 then the brake, and for H."""
        rows, step = self._evasion_rows, self._evasion_step
        half = max(rows // 2, 1)
        first, middle = self._paths.held_path(state, candidate, step, half)
        paths = [self._then_brake(first, middle, 0)]
        if rows > half:  # the rest of the hold goes on from where half of it ends
            paths.append(np.vstack([first, self._paths.held_path(middle, candidate, step,
                                                                rows - half)[0]]))
        return paths

    def _then_brake(self, rows, after, periods):
        """Return a look ahead's rows, ``step`` s apart up to the horizon.

        ``rows``, then the brake from state ``after``, ``periods`` control periods past the
        last of ``rows`` (or past the start), then at rest where the brake ends.
        """
        ratio = round(self._evasion_step / self.config.control_period)
        brake = self._paths.braking_path(after, self.config.control_period)
        first = ratio - 1 - periods
        if first < 0:  # a step of one period: ``after`` itself is the next row
            rows, first = np.vstack([rows, self._paths.point_row(after)]), 0
        ahead = np.vstack([rows, brake[first::ratio]])[:self._evasion_rows]
        at_rest = brake[-1].copy()
        at_rest[2:4] = 0.0
        rest = np.tile(at_rest, (self._evasion_rows - len(ahead), 1))
        return np.vstack([ahead, rest])

    def _look_ahead(self, path, prepared, age):
        """Return (static, moving) clearances of a look-ahead ``path`` (rows ``step`` s apart).

        ``path_clearance`` at every row, moving parts along their stated velocity and
        acceleration (c + v t + a t^2 / 2) less ``obstacle_velocity_error`` t, up to the
        clearance plus ``EVASION_REACH``.
        """
        footprints = prepared.footprints
        return path_clearance.unchecked(
            footprints.x, footprints.y, footprints.edge_x, footprints.edge_y,
            footprints.inv_sq, footprints.counts, footprints.boxes, prepared.velocities,
            prepared.offsets, prepared.accelerations, float(age),
            np.ascontiguousarray(path, dtype=np.float64),
            self._evasion_step, self._clearance + EVASION_REACH, 0.0,
            prepared.velocity_errors[1], False, self._body, self._cover, _NO_PARTS)

    def braking_path(self, state):
        """Return B(x), the braking path the check measures (a turning footprint's axle's)."""
        return self._paths.braking_path(state, self.config.control_period)

    def _closes_on_a_part(self, after_path, prepared, age, now):
        """Return True when B(x+) is nearer some moving part than B(x), part by part.

        Asked only once B(x) meets a moving part: then the smallest clearance over the
        parts is that part's, and would hide an input closing on another (design.md 3.10).
        """
        after = self._moving_parts(after_path, prepared, age)
        return bool(np.any((after < self._clearance)
                           & (after < now.moving_parts - CLEARANCE_ROUNDING)))

    def _moving_parts(self, path, prepared, age):
        """Return (N,) each moving part's own c(B) of a braking ``path`` (``per_part``)."""
        parts = np.empty(prepared.count)
        self._path_clearance(path, prepared, age, parts)
        return parts

    def _path_clearance(self, path, prepared, age, per_part=_NO_PARTS):
        """Return c(B), capped at the margin, of a braking ``path``: (static, moving parts).

        ``path_clearance``: of the guarded point, or of a turning footprint (``_body``);
        ``per_part`` (N,), if given, gets each moving part's own (``path_clearance``).
        Each part moves at its velocity and stated acceleration (markers'; zero for the
        others) and may stray from that motion by ``obstacle_velocity_error`` t +
        ``braking_obstacle_accel`` t^2 / 2: the bounds are on how far its velocity and
        its acceleration may be off their estimates.  A cylinder on a 1.8 m/s loop of 3 m
        radius speeds sideways at 1.1 m/s^2 and is 0.55 m off its line after 1 s; at
        constant velocity with 1 m/s^2 the check let robots back across such curves
        (two at-fault contacts on unseen dynamic worlds, bench/README.md).

        Unchecked kernel: the footprints, velocities and offsets are the filter's own and
        the path a fresh C-contiguous float64 array (``RobotModel.braking_path``).
        """
        footprints = prepared.footprints
        return path_clearance.unchecked(
            footprints.x, footprints.y, footprints.edge_x, footprints.edge_y,
            footprints.inv_sq, footprints.counts, footprints.boxes, prepared.velocities,
            prepared.offsets, prepared.accelerations, float(age), path,
            self.config.control_period, self._clearance, self._braking_accel,
            prepared.velocity_errors[0], True, self._body, self._cover, per_part)

    def _brake(self, state, status, start, message, h=None, min_h=math.inf, evaluation=None):
        """Return the braking input with a flagged status."""
        u = np.nan_to_num(self.model.braking_input(state), nan=0.0, posinf=0.0, neginf=0.0)
        h = np.zeros(0) if h is None else h
        return self.model.clip_input(u), FilterInfo(
            status=status, h=h, min_h=min_h, solve_time_s=time.perf_counter() - start,
            num_obstacles=len(h), message=message, evaluation=evaluation)

    def _escape_input(self, ref, direction, u_nom):
        """Return the input accelerating the reference point out along ``direction``.

        Desired acceleration a* = k (v_esc d - r_dot); u = lstsq(B, a* - drift), clipped.
        A turning footprint sweeps its corners as it turns, and near the axle the lateral
        share of a* asks for a turn as large as 1 / offset_l: its steering inputs brake
        (``braking_input``) and the others take a* alone.  (Measured: steering out of a
        scan obstacle that had just appeared over its corner, a Jackal turned at 1.5 rad/s
        into the cylinder behind it, BARN from the laser.)  Where those others move the point
        along d by less than ``DRIVE_SHARE`` of it (the way out runs across the heading: a
        scan polygon drawn over the box's side), they take u_nom's values instead: a* would
        leave the box standing inside for good (3 of 17 traced Jackal runs from the laser,
        until the referee called a deadlock), and the braking check keeps any input from
        stopping deeper in.
        """
        config = self.config
        desired = config.escape_gain * (config.escape_speed * direction - ref.velocity)
        if not self._turning:
            u, *_ = np.linalg.lstsq(ref.input_matrix, desired - ref.drift, rcond=None)
            return self.model.clip_input(u)
        u = self.model.braking_input(ref.state)
        steer = list(self.model.steering_inputs)
        drive = [i for i in range(self.model.input_dim) if i not in steer]
        columns = ref.input_matrix[:, drive]
        share, *_ = np.linalg.lstsq(columns, direction, rcond=None)
        if np.linalg.norm(columns @ share) < DRIVE_SHARE:
            u[drive] = u_nom[drive]
        else:
            u[drive], *_ = np.linalg.lstsq(columns, desired - ref.drift
                                           - ref.input_matrix[:, steer] @ u[steer], rcond=None)
        return self.model.clip_input(u)

    def escape_direction(self, evaluation, obstacles):
        """Return the unit direction (world axes) out of the parts ``evaluation`` is inside.

        Zero when it is inside none (see the module docstring).
        """
        return self._escape_direction(self._prepare(obstacles), evaluation)

    def _escape_direction(self, prepared, evaluation):
        """Sum the shortest ways out of the parts we are inside, each in its shallower plane."""
        depth = np.full(prepared.count, np.inf)
        direction = np.zeros((prepared.count, self.model.position_dim))
        for view, viewpoints in zip(prepared.views, evaluation.viewpoints):
            exits = self.cone_model.exits(view.prepared, viewpoints)
            shallower = evaluation.inside & view.enabled & (exits[2] < depth)
            depth[shallower] = exits[2, shallower]
            direction[shallower] = np.einsum('nid,in->nd', view.projections[shallower],
                                             exits[:2, shallower])
        total = direction.sum(axis=0)
        norm = np.linalg.norm(total)
        return total / norm if norm > 1e-9 else np.zeros_like(total)

    def evaluate(self, state, obstacles, obstacle_age=0.0):
        """Return the barrier evaluation at ``state`` without solving the QP."""
        return self._evaluate(self._prepare(obstacles), self.model.reference(
            np.asarray(state, dtype=float)), obstacle_age)

    def _evaluate(self, prepared, ref, age):
        """Evaluate cones and barrier terms in every plane; 3-D: pick the plane per part."""
        views = prepared.views
        block, valid = self._plane(views[0], prepared, ref, age)
        if len(views) == 1:
            return Evaluation(block, valid, valid, None, (block[:2],))
        block_vertical, valid_vertical = self._plane(views[1], prepared, ref, age)
        vertical, usable = choose_planes(valid, block[PLANE_K], valid_vertical,
                                         block_vertical[PLANE_K], views[1], ref.position,
                                         prepared.velocities, prepared.offsets, age)
        return Evaluation(np.where(vertical, block_vertical, block),
                          np.where(vertical, valid_vertical, valid), usable, vertical,
                          (block[:2], block_vertical[:2]))

    def _plane(self, view, prepared, ref, age):
        """Return (block, valid) of one view (``ConeModel.plane``).

        Unchecked kernel: every array here is the filter's own (``_prepare``, the model).
        With ``obstacle_accel`` or ``obstacle_velocity_error`` > 0 the moving parts' Lf h is
        made robust to their acceleration and velocity error
        (``barrier.tighten_for_obstacle_accel``).
        """
        block, valid = self.cone_model.plane(view.prepared, view, prepared.velocities,
                                             prepared.offsets, age, ref, self._epsilon, False)
        if (self._obstacle_accel > 0.0 or self._velocity_error > 0.0) and not self._turning:
            tighten_for_obstacle_accel.unchecked(
                block, PLANE_ROWS, view.projections, prepared.velocities, ref.velocity,
                self._epsilon * self._epsilon, self._obstacle_accel, self._velocity_error,
                self._row_settings[1])
        return block, valid

    def prepare(self, obstacles):
        """Precompute the views of an obstacle set now (``step`` does it on first use).

        They are stored in the set (``ObstacleSet.geometry``, under ``geometry.key``), not
        in the filter, so another thread may prepare a set the filter has not seen yet
        (``ObstacleGeometry.prepare``).  A translated set prepares its base.
        """
        self.geometry.prepare(obstacles)

    def _prepare(self, obstacles):
        """Build (and cache per obstacle set) the planar views of the obstacles.

        A translation of a base set (``ObstacleSet.translated``) takes the views of its
        base, prepared once and cached beside, and its offsets move the viewpoints.
        """
        if obstacles is self._cache_key:
            return self._cache
        finite = obstacles.is_finite()
        dim = self.model.position_dim
        if finite and obstacles.base is not None:
            # base + finite offsets is finite, so the base's geometry is (its velocities
            # are replaced).
            if obstacles.base is not self._base_key:
                self._base_key = obstacles.base
                self._base = self._fresh(self.geometry.grounded(obstacles.base), True)
            offsets, velocities = obstacles.offsets[:, :dim], obstacles.velocities[:, :dim]
            if self.geometry.ground is not None:
                offsets, velocities = ground_offsets(offsets, velocities)
            moving_parts = velocities[:, :2].any(axis=1)
            accelerations, fastest = self._accelerations(obstacles, self._base.steady)
            prepared = self._base.translated(
                np.ascontiguousarray(offsets, dtype=np.float64),
                np.ascontiguousarray(velocities, dtype=np.float64),
                self._velocity_errors(moving_parts, obstacles), accelerations, fastest,
                bool(moving_parts.any()))
        else:
            chosen = obstacles if finite else ObstacleSet.empty()
            prepared = self._fresh(self.geometry.grounded(chosen), finite)
        self._cache_key, self._cache = (obstacles if finite else None), prepared
        return prepared

    def _fresh(self, obstacles, finite):
        """Prepare the views of ``obstacles`` and row buffers for as many parts."""
        dim, count = self.model.position_dim, len(obstacles)
        steady = np.zeros((count, 2))
        accelerations, fastest = self._accelerations(obstacles, steady)
        moving_parts = obstacles.velocities[:, :2].any(axis=1)
        return _Prepared(
            count=count, views=self.geometry.views(obstacles),
            velocities=np.ascontiguousarray(obstacles.velocities[:, :dim], dtype=np.float64),
            offsets=np.zeros((count, dim)), finite=finite,
            rows_a=np.empty((count, self.model.input_dim)), rows_b=np.empty(count),
            index=np.empty(count, dtype=np.intp),
            footprints=PlanarPolygons.from_batch(obstacles.footprints) if self._braking
            else None, velocity_errors=self._velocity_errors(moving_parts, obstacles),
            accelerations=accelerations, fastest_speeding_up=fastest, steady=steady,
            moving=bool(moving_parts.any()))

    def _accelerations(self, obstacles, steady):
        """Return ((N, 2) the parts' stated planar accelerations, the largest norm).

        ``steady`` (zeros) without them, and for a model with a ground part (whose rows
        the set's do not match).
        """
        stated = obstacles.accelerations
        if stated is None or self.geometry.ground is not None:
            return steady, 0.0
        stated = np.ascontiguousarray(stated[:, :2], dtype=np.float64)
        return stated, float(np.hypot(*stated.T).max(initial=0.0))

    def _velocity_errors(self, moving_parts, obstacles):
        """Return (3, N): how far each part's velocity may be off.

        Row 1, an evasion's look ahead (``_look_ahead``, ``_moving_near``):
        ``obstacle_velocity_error`` for a part that moves (``moving_parts``), else 0.
        Row 2: the part's own
        ``ObstacleSet.velocity_errors`` (planar models, whose sets have no ground part),
        else 0.  Row 0, the braking check: the larger of rows 1 and 2, so that a part
        whose velocity is not known counts as moving there.
        """
        errors = np.empty((3, len(moving_parts)))
        np.multiply(moving_parts, self._velocity_error, out=errors[1])  # error >= 0 or 0
        if obstacles.velocity_errors is not None and self.geometry.ground is None:
            errors[2] = obstacles.velocity_errors
            np.maximum(errors[1], errors[2], out=errors[0])
        else:
            errors[2], errors[0] = 0.0, errors[1]
        return errors
