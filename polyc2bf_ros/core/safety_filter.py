"""The PolyC2BF safety filter: (state, obstacles, nominal input) -> (safe input, info).

Per control step, for every convex obstacle part i (paper eq. 5)::

    minimise   ||u - u_nom||^2
    subject to Lf h_i + Lg h_i u + gamma h_i >= m        for every obstacle part i
               u_min <= u <= u_max

Discrete time: the node holds u for one control period T, while the
continuous CBF condition only holds at the sample instants.  Over a hold
interval h drifts from its first-order prediction by at most T^2/2 max|h_ddot|,
so each row is tightened by a margin m = ``margin_gain`` * T [m^2/s^2]: with
margin_gain >= max|h_ddot|/2 the held input keeps h_dot + gamma h >= 0 on
average over the interval.  The closed-loop tests show the default is enough
at the node's rates.

3-D models see each obstacle (a vertical prism) in two planes (paper
section III, quadrotor): the horizontal plane (footprint polygon) and the
vertical plane spanned by the footprint's thin axis and z (the prism's shadow
rectangle).  Projections are constant, as the paper assumes, and
conservative: a point outside either shadow is outside the prism.  The plane
whose cone has the smaller ||k|| is used.

Pruning: a row whose left side is >= m for *every* u in the input box can
never be active; dropping it leaves the feasible set unchanged, so the
solution is exactly the same.

Fallbacks, always flagged in ``FilterInfo.status``:

* ``slack``: the QP is infeasible; solve it again with one shared slack
  s >= 0 on every row (weight ``slack_weight``), input bounds kept hard.
* ``brake``: the slack QP failed too; apply the model's braking input.
* ``escape``: the reference point is inside an (inflated) obstacle, where no
  cone exists; the nominal input is replaced by one that accelerates the
  reference point out along (q - obstacle centroid), still subject to the
  other obstacles' rows.
* ``invalid_input``: NaN/Inf in state, nominal input or obstacles; brake.
"""
import enum
import time
from dataclasses import dataclass, field

import numpy as np

from polyc2bf_ros.core.barrier import barrier_terms
from polyc2bf_ros.core.cones import CONE_MODELS, make_cone_model
from polyc2bf_ros.core.geometry import PolygonBatch, thin_axis, vertical_shadow
from polyc2bf_ros.core.qp import make_solver, QPStatus, solve_with_shared_slack, SOLVERS

ACTIVE_TOLERANCE = 1e-7


class FilterStatus(str, enum.Enum):
    """What the filter did on a step."""

    OK = 'ok'
    SLACK = 'slack'
    BRAKE = 'brake'
    ESCAPE = 'escape'
    INVALID_INPUT = 'invalid_input'


@dataclass
class FilterConfig:
    """Filter parameters; ``validate`` explains any bad value.

    The default barrier is the inflated-silhouette PolyC2BF: in the clutter
    test (30 random polygons, 50 seeds) the paper's w/2 width rule let the
    unicycle graze obstacles in 2 seeds, the inflated variant in none.
    """

    barrier: str = 'polyc2bf_inflated'
    robot_radius: float = 0.3
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

    @property
    def margin(self):
        """Return the sample-and-hold margin m = margin_gain * control_period."""
        return self.margin_gain * self.control_period

    def validate(self):
        """Raise ValueError naming the first invalid field and why."""
        if self.barrier not in CONE_MODELS:
            raise ValueError(f'barrier must be one of {sorted(CONE_MODELS)}, got {self.barrier!r}')
        if self.solver not in SOLVERS:
            raise ValueError(f'solver must be one of {sorted(SOLVERS)}, got {self.solver!r}')
        positive = ('gamma', 'control_period', 'velocity_epsilon', 'slack_weight',
                    'escape_gain')
        non_negative = ('robot_radius', 'margin_gain', 'escape_speed')
        for name in positive + non_negative:
            value = getattr(self, name)
            if not np.isfinite(value) or value < 0 or (name in positive and value == 0):
                kind = 'positive' if name in positive else 'non-negative'
                raise ValueError(f'{name} must be finite and {kind}, got {value!r}')
        if not 3 <= self.inflation_segments <= 256:
            raise ValueError('inflation_segments must be in [3, 256], '
                             f'got {self.inflation_segments!r}')
        return self


@dataclass
class FilterInfo:
    """Diagnostics of one step; ``h`` has one entry per obstacle part (NaN if inside)."""

    status: FilterStatus
    h: np.ndarray = field(default_factory=lambda: np.zeros(0))
    active: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    solve_time_s: float = 0.0
    num_obstacles: int = 0
    num_constraints: int = 0
    slack: float = 0.0
    message: str = ''
    cones: object = None

    @property
    def min_h(self):
        """Return the smallest finite h, or +inf without obstacles."""
        finite = self.h[np.isfinite(self.h)]
        return float(finite.min()) if finite.size else float('inf')


@dataclass(frozen=True)
class Evaluation:
    """Per obstacle part: cones, barrier terms, inside flag, outward direction, plane used.

    ``plane`` is 0 for the horizontal plane, 1 for the vertical one (3-D models).
    """

    cones: object
    terms: object
    inside: np.ndarray
    outward: np.ndarray
    plane: np.ndarray
    rank: np.ndarray

    def escape_direction(self):
        """Return the unit sum of outward directions of the obstacles we are inside."""
        direction = self.outward[self.inside].sum(axis=0)
        norm = np.linalg.norm(direction)
        return direction / norm if norm > 1e-9 else np.zeros_like(direction)


@dataclass(frozen=True)
class _View:
    """Obstacles seen in one plane: prepared cone geometry and the (N,2,d) projections."""

    prepared: object
    projection: np.ndarray
    centroids: np.ndarray
    enabled: np.ndarray


@dataclass(frozen=True)
class _Prepared:
    """Everything per obstacle set that does not change between steps."""

    views: tuple
    velocities: np.ndarray
    finite: bool


class SafetyFilter:
    """PolyC2BF / C3BF safety filter for one robot model."""

    def __init__(self, model, config=None):
        """Bind a model and a (validated) configuration."""
        self.model = model
        self.config = (config or FilterConfig()).validate()
        self.cone_model = make_cone_model(self.config.barrier, self.config.robot_radius,
                                          self.config.inflation_segments)
        self.solver = make_solver(self.config.solver)
        self._weights = np.ones(model.input_dim)
        self._cache_key = None
        self._cache = None

    def step(self, state, obstacles, u_nom, obstacle_age=0.0):
        """Return (u_safe, FilterInfo); obstacles are extrapolated by ``obstacle_age`` s."""
        start = time.perf_counter()
        state = np.asarray(state, dtype=float)
        u_nom = np.asarray(u_nom, dtype=float)
        prepared = self._prepare(obstacles)
        if not (np.isfinite(state).all() and np.isfinite(u_nom).all()
                and np.isfinite(obstacle_age) and prepared.finite):
            return self._brake(state, FilterStatus.INVALID_INPUT, start,
                               'non-finite state, nominal input or obstacle')
        ref = self.model.reference(state)
        evaluation = self._evaluate(prepared, ref, obstacle_age)
        terms, inside, cones = evaluation.terms, evaluation.inside, evaluation.cones
        config = self.config
        u_ref, status, message = u_nom, FilterStatus.OK, ''
        if inside.any():
            u_ref = self._escape_input(ref, evaluation.escape_direction())
            status = FilterStatus.ESCAPE
            message = (f'reference point inside {int(inside.sum())} (inflated) obstacle '
                       'part(s); escaping along the outward direction')
        keep = ~inside
        rows_a = terms.lg_h[keep]
        rows_b = config.margin - terms.lf_h[keep] - config.gamma * terms.h[keep]
        index = np.flatnonzero(keep)
        if config.prune and index.size:
            worst = np.minimum(rows_a * self.model.input_lower,
                               rows_a * self.model.input_upper).sum(axis=1)
            needed = worst < rows_b
            rows_a, rows_b, index = rows_a[needed], rows_b[needed], index[needed]
        lower, upper = self.model.input_lower, self.model.input_upper
        result = self.solver.solve(u_ref, self._weights, rows_a, rows_b, lower, upper)
        slack = 0.0
        u = result.x
        if result.status != QPStatus.OPTIMAL:
            u, slack, slack_result = solve_with_shared_slack(
                self.solver, u_ref, self._weights, rows_a, rows_b, lower, upper,
                config.slack_weight)
            if slack_result.status != QPStatus.OPTIMAL:
                return self._brake(state, FilterStatus.BRAKE, start,
                                   'QP and slack QP failed', terms.h, inside, cones)
            if status == FilterStatus.OK:
                status = FilterStatus.SLACK
        residual = rows_a @ u - rows_b
        h = np.where(inside, np.nan, terms.h)
        return u, FilterInfo(
            status=status, h=h, active=index[residual <= ACTIVE_TOLERANCE + slack],
            solve_time_s=time.perf_counter() - start, num_obstacles=len(h),
            num_constraints=int(index.size), slack=float(slack), message=message,
            cones=cones)

    def _brake(self, state, status, start, message, h=None, inside=None, cones=None):
        """Return the braking input with a flagged status."""
        u = np.nan_to_num(self.model.braking_input(state), nan=0.0, posinf=0.0, neginf=0.0)
        h = np.zeros(0) if h is None else np.where(inside, np.nan, h)
        return self.model.clip_input(u), FilterInfo(
            status=status, h=h, solve_time_s=time.perf_counter() - start,
            num_obstacles=len(h), message=message, cones=cones)

    def _escape_input(self, ref, direction):
        """Return the input accelerating the reference point out along ``direction``.

        Desired acceleration a* = k (v_esc d - r_dot); u = lstsq(B, a* - drift), clipped.
        """
        config = self.config
        desired = config.escape_gain * (config.escape_speed * direction - ref.velocity)
        u, *_ = np.linalg.lstsq(ref.input_matrix, desired - ref.drift, rcond=None)
        return self.model.clip_input(u)

    def evaluate(self, state, obstacles, obstacle_age=0.0):
        """Return the barrier evaluation at ``state`` without solving the QP."""
        return self._evaluate(self._prepare(obstacles), self.model.reference(
            np.asarray(state, dtype=float)), obstacle_age)

    def _evaluate(self, prepared, ref, age):
        """Evaluate cones and barrier terms in every plane, keep the smaller-||k|| plane."""
        dim = ref.position.size
        velocities = prepared.velocities[:, :dim]
        best = None
        for plane, view in enumerate(prepared.views):
            viewpoints = _project_rows(view.projection, ref.position - age * velocities)
            cones = self.cone_model.cones(view.prepared, viewpoints)
            v_rel = _project_rows(view.projection, velocities - ref.velocity)
            terms = barrier_terms(cones, v_rel, -view.projection @ ref.drift,
                                  -view.projection @ ref.input_matrix,
                                  self.config.velocity_epsilon)
            usable = cones.valid & view.enabled
            outward = np.einsum('nij,ni->nj', view.projection, viewpoints - view.centroids)
            candidate = Evaluation(cones=cones, terms=terms, inside=~usable, outward=outward,
                                   plane=np.full(len(usable), plane),
                                   rank=np.where(usable, cones.k_norm, np.inf))
            best = candidate if best is None else _select(candidate.rank < best.rank,
                                                          best, candidate)
        return best

    def _prepare(self, obstacles):
        """Build (and cache per obstacle set) the planar views of the obstacles."""
        if obstacles is self._cache_key:
            return self._cache
        finite = obstacles.is_finite()
        dim = self.model.position_dim
        n = len(obstacles)
        footprints = obstacles.footprints if finite else PolygonBatch.from_polygons([])
        if not finite:
            n = 0
        views = [self._view(footprints, np.broadcast_to(np.eye(2, dim), (n, 2, dim)),
                            np.ones(n, dtype=bool))]
        if dim == 3 and n:
            views.append(self._vertical_view(obstacles))
        self._cache_key = obstacles
        self._cache = _Prepared(views=tuple(views), finite=finite,
                                velocities=obstacles.velocities[:n] if finite else
                                np.zeros((0, 3)))
        return self._cache

    def _view(self, batch, projection, enabled):
        """Prepare one plane's geometry for the cone model."""
        return _View(prepared=self.cone_model.prepare(batch), projection=projection,
                     centroids=batch.centroids(), enabled=enabled)

    def _vertical_view(self, obstacles):
        """Project each prism onto the vertical plane through its footprint's thin axis."""
        batch = obstacles.footprints
        shadows, projections = [], []
        enabled = np.isfinite(obstacles.z_ranges).all(axis=1)
        for i in range(len(batch)):
            footprint = batch.vertices[i, :batch.counts[i]]
            axis = thin_axis(footprint)
            z_min, z_max = obstacles.z_ranges[i] if enabled[i] else (-1.0, 1.0)
            shadows.append(vertical_shadow(footprint, z_min, z_max, axis))
            projections.append([[axis[0], axis[1], 0.0], [0.0, 0.0, 1.0]])
        return self._view(PolygonBatch.from_polygons(shadows), np.array(projections), enabled)


def _project_rows(projection, points):
    """Return P_n points_n for projections (N,2,d) and points (N,d) or (d,)."""
    points = np.broadcast_to(points, (projection.shape[0], projection.shape[2]))
    return np.einsum('nij,nj->ni', projection, points)


def _select(take, a, b):
    """Row-wise choose b where take else a, for arrays and dataclasses of arrays."""
    if isinstance(a, np.ndarray):
        mask = take.reshape((-1,) + (1,) * (a.ndim - 1))
        return np.where(mask, b, a)
    return type(a)(**{k: _select(take, v, getattr(b, k)) for k, v in vars(a).items()})
