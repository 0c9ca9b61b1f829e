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
  s >= 0 on every (unit-norm) row (weight ``slack_weight``), input bounds kept
  hard.
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
from polyc2bf_ros.core.cones import CONE_MODELS, dot2, make_cone_model
from polyc2bf_ros.core.geometry import PolygonBatch, thin_axis, vertical_shadow
from polyc2bf_ros.core.obstacles import ObstacleSet
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

    ``plane`` is 0 for the horizontal plane, 1 for the vertical one (3-D models);
    ``outward`` (d, N) points from each obstacle's centroid to the robot, in world axes.
    """

    cones: object
    terms: object
    inside: np.ndarray
    outward: np.ndarray
    plane: np.ndarray
    rank: np.ndarray

    def escape_direction(self):
        """Return the unit sum of outward directions of the obstacles we are inside."""
        direction = self.outward[:, self.inside].sum(axis=1)
        norm = np.linalg.norm(direction)
        return direction / norm if norm > 1e-9 else np.zeros_like(direction)


@dataclass(frozen=True)
class _View:
    """Obstacles seen in one plane: prepared cone geometry, centroids (2, N), enabled (N,).

    ``axes`` is None for the horizontal plane (world x, y) and (2, N) unit horizontal
    axes for the vertical planes (axis, world z).
    """

    prepared: object
    axes: object
    centroids: np.ndarray
    enabled: np.ndarray


@dataclass(frozen=True)
class _Prepared:
    """Everything per obstacle set that does not change between steps."""

    views: tuple
    velocities: np.ndarray
    moving: bool
    finite: bool

    @property
    def count(self):
        """Return the number of obstacle parts."""
        return self.velocities.shape[1]


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
        self._lower_column = model.input_lower[:, None]
        self._upper_column = model.input_upper[:, None]
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
        if not prepared.count:
            # No obstacle, no row: the QP's solution is u_nom clipped to the box.
            return self.model.clip_input(u_nom), FilterInfo(
                status=FilterStatus.OK, solve_time_s=time.perf_counter() - start)
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
        rows_b = config.margin - terms.lf_h - config.gamma * terms.h
        needed = ~inside
        if config.prune:
            worst = np.minimum(terms.lg_h * self._lower_column,
                               terms.lg_h * self._upper_column).sum(axis=0)
            needed &= worst < rows_b
        index = np.flatnonzero(needed)
        # Unit-norm rows: the same feasible set, but a well-scaled QP (row norms span
        # 1e1..1e4 for the quadrotor) and a slack measured in input units.
        rows_a = terms.lg_h[:, index]
        scale = 1.0 / np.maximum(np.sqrt((rows_a * rows_a).sum(axis=0)), 1e-12)
        rows_b = rows_b[index] * scale
        rows_a = np.ascontiguousarray((rows_a * scale).T)
        lower, upper = self.model.input_lower, self.model.input_upper
        result = self.solver.solve(u_ref, self._weights, rows_a, rows_b, lower, upper)
        slack = 0.0
        u = result.x
        if result.status != QPStatus.OPTIMAL:
            u, slack, slack_result = solve_with_shared_slack(
                self.solver, u_ref, self._weights, rows_a, rows_b, lower, upper,
                config.slack_weight, plain=result)
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
        best = None
        for plane, view in enumerate(prepared.views):
            viewpoint, v_rel, a_drift, b_rel = _in_plane(view.axes, ref, prepared, age)
            cones = self.cone_model.cones(view.prepared, viewpoint)
            terms = barrier_terms(cones, v_rel, a_drift, b_rel, self.config.velocity_epsilon)
            usable = cones.valid & view.enabled
            candidate = Evaluation(
                cones=cones, terms=terms, inside=~usable,
                outward=_to_world(view.axes, viewpoint.reshape(2, -1) - view.centroids,
                                  ref.position.size),
                plane=np.full(usable.size, plane),
                rank=np.where(usable, cones.k_norm, np.inf) if len(prepared.views) > 1
                else None)
            best = candidate if best is None else _select(candidate.rank < best.rank,
                                                          best, candidate)
        return best

    def _prepare(self, obstacles):
        """Build (and cache per obstacle set) the planar views of the obstacles."""
        if obstacles is self._cache_key:
            return self._cache
        finite = obstacles.is_finite()
        if not finite:
            obstacles = ObstacleSet.empty()
        batch = obstacles.footprints
        views = [self._view(batch, None, np.ones(len(batch), dtype=bool))]
        if self.model.position_dim == 3 and len(batch):
            views.append(self._vertical_view(obstacles))
        velocities = np.ascontiguousarray(obstacles.velocities.T)
        self._cache_key = obstacles if finite else None
        self._cache = _Prepared(views=tuple(views), velocities=velocities,
                                moving=bool(velocities.any()), finite=finite)
        return self._cache

    def _view(self, batch, axes, enabled):
        """Prepare one plane's geometry for the cone model."""
        return _View(prepared=self.cone_model.prepare(batch), axes=axes,
                     centroids=np.ascontiguousarray(batch.centroids().T), enabled=enabled)

    def _vertical_view(self, obstacles):
        """Project each prism onto the vertical plane through its footprint's thin axis."""
        batch = obstacles.footprints
        shadows, axes = [], []
        enabled = np.isfinite(obstacles.z_ranges).all(axis=1)
        for i in range(len(batch)):
            footprint = batch.vertices[i, :batch.counts[i]]
            axis = thin_axis(footprint)
            z_min, z_max = obstacles.z_ranges[i] if enabled[i] else (-1.0, 1.0)
            shadows.append(vertical_shadow(footprint, z_min, z_max, axis))
            axes.append(axis)
        return self._view(PolygonBatch.from_polygons(shadows), np.array(axes).T, enabled)


def _in_plane(axes, ref, prepared, age):
    """Return viewpoint, v_rel, a_drift (relative) and B_rel projected into one plane.

    Obstacles are extrapolated by ``age`` seconds: seen from the obstacle frame the
    viewpoint moves by -age c_dot.  Horizontal plane: the x, y rows.  Vertical plane
    n: rows (axis_n . xy, z), constant per obstacle (the paper's constant projection).
    """
    position, velocities = ref.position, prepared.velocities
    dim = position.size
    if axes is None:
        viewpoint = position[:2]
        if prepared.moving and age:
            viewpoint = viewpoint[:, None] - age * velocities[:2]
        v_rel = velocities[:2] - ref.velocity[:2, None]
        return viewpoint, v_rel, -ref.drift[:2, None], -ref.input_matrix[:2]
    viewpoint_3d = position[:, None] - age * velocities[:dim]
    v_rel_3d = velocities[:dim] - ref.velocity[:, None]
    viewpoint = np.stack([dot2(axes, viewpoint_3d), viewpoint_3d[2]])
    v_rel = np.stack([dot2(axes, v_rel_3d), v_rel_3d[2]])
    a_drift = -np.stack([axes[0] * ref.drift[0] + axes[1] * ref.drift[1],
                         np.full(axes.shape[1], ref.drift[2])])
    b_horizontal = -(axes[0][:, None] * ref.input_matrix[0] + axes[1][:, None]
                     * ref.input_matrix[1])
    b_rel = np.stack([b_horizontal, np.broadcast_to(-ref.input_matrix[2],
                                                    b_horizontal.shape)], axis=1)
    return viewpoint, v_rel, a_drift, b_rel


def _to_world(axes, planar, dim):
    """Map planar (2, N) directions back to ``dim`` world axes."""
    if axes is None:
        return planar if dim == 2 else np.vstack([planar, np.zeros_like(planar[:1])])
    return np.stack([axes[0] * planar[0], axes[1] * planar[0], planar[1]])


def _select(take, a, b):
    """Per obstacle (last axis) choose b where take else a, also inside dataclasses."""
    if isinstance(a, np.ndarray):
        return np.where(take, b, a)
    return type(a)(**{k: _select(take, v, getattr(b, k)) for k, v in vars(a).items()})
