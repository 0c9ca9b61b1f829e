"""Robot model interface shared by every model the filter supports.

A model is a control-affine system x_dot = f(x) + g(x) u (paper eq. 1) plus
the kinematics of the *reference point* whose collision cones are guarded
(paper eq. 11-12 for the unicycle, eq. 17 for the quadrotor).  The barrier
only needs, at the current state, the reference point's position r, its
velocity r_dot and its acceleration split into drift and input parts::

    r_ddot = a_drift(x) + B(x) u

Relative quantities follow (obstacles translate at constant velocity c_dot)::

    p_rel = c - r,   v_rel = c_dot - r_dot,   v_rel_dot = -a_drift - B u
"""
import abc
import math
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

MODELS: dict[str, type['RobotModel']] = {}


def register_model(cls):
    """Class decorator: make a model available to ``make_model`` by its ``name``."""
    MODELS[cls.name] = cls
    return cls


@dataclass(slots=True)
class ReferenceKinematics:
    """Position, velocity and acceleration r_ddot = drift + input_matrix @ u of the point.

    ``position``, ``velocity`` and ``drift`` are (d,), ``input_matrix`` is (d, m), all
    float64 and C-contiguous (the barrier kernel reads them directly).  ``state``: the
    state x they were computed at, where the model's footprint turns with it
    (``turns_footprint``; the footprint cone reads the heading there), else empty.
    """

    position: np.ndarray
    velocity: np.ndarray
    drift: np.ndarray
    input_matrix: np.ndarray
    state: np.ndarray = field(default_factory=lambda: np.empty(0))

    @classmethod
    def empty(cls, dim, inputs):
        """Return kinematics with uninitialised arrays, for a kernel to fill."""
        return cls(position=np.empty(dim), velocity=np.empty(dim), drift=np.empty(dim),
                   input_matrix=np.empty((dim, inputs)))


class RobotModel(abc.ABC):
    """Control-affine robot model with bounded inputs and a guarded reference point."""

    name: ClassVar[str]
    state_dim: ClassVar[int]
    input_dim: ClassVar[int]
    position_dim: ClassVar[int]

    input_lower: np.ndarray
    input_upper: np.ndarray

    @abc.abstractmethod
    def f(self, x):
        """Return the drift term of the control-affine dynamics (paper eq. 1)."""

    @abc.abstractmethod
    def g(self, x):
        """Return the input matrix (state_dim x input_dim) of the dynamics (paper eq. 1)."""

    @abc.abstractmethod
    def reference(self, x, out=None) -> ReferenceKinematics:
        """Return the reference point's kinematics at state x.

        ``out`` (``ReferenceKinematics.empty(position_dim, input_dim)``), if given, may be
        filled and returned instead of new arrays: the filter reuses one per step.
        """

    @abc.abstractmethod
    def braking_input(self, x):
        """Return the input that brings the robot to rest fastest (defined for any x)."""

    #: Indices of the inputs that steer rather than speed up or slow down (the unicycle's
    #: angular acceleration).  When the braking check refuses the filter's input it first
    #: tries the brake with these taken from that input, so a robot held at the edge of
    #: an obstacle's band can still turn away from it (``SafetyFilter``, design.md 3.10).
    steering_inputs = ()

    #: True when x[2] is the heading a footprint turns with and x[3:5] its speed and turn
    #: rate (the unicycle): the filter then guards a footprint polygon exactly
    #: (``barrier.footprint_cone``, ``body_paths``), else by its covering disc.
    turns_footprint = False

    @property
    def input_weights(self):
        """Return W (input_dim,): the filter minimises sum_j W_j (u_j - u_nom_j)^2.

        All ones, the paper's min-norm QP (eq. 5), unless a model says otherwise.
        """
        return np.ones(self.input_dim)

    #: Distance from the body's centre to the guarded reference point (the offset l of the
    #: unicycle and the quadrotor): the filter keeps the point ``robot_radius`` + this from
    #: every obstacle, so the body's disc (sphere) of ``robot_radius`` around its centre is
    #: clear: dist(c, O) >= dist(r, O) - |r - c| >= robot_radius.
    guard_offset = 0.0

    def body_centre(self, x):
        """Return the body's centre (position_dim,) at state x: what ``robot_radius`` is around."""
        return np.asarray(x, dtype=float)[:self.position_dim]

    def braking_path(self, x, period):
        """Return the reference point's path (K, 2 position_dim) under ``braking_input``.

        Row k is where the point is (k + 1) periods after applying the brake at x (held
        for one period at a time, as the node does), then its velocity there; the last row
        is at rest.  None: the model has no braking path, and ``braking_check`` does not
        apply to it.
        """
        return None

    #: Columns of a row of the paths below: the point's position, then its velocity.
    columns = 4

    def body_paths(self):
        """Return the body origin's paths, rows [x, y, vx, vy, theta, omega] (``turns_footprint``).

        An object with this model's ``point_row``, ``braking_path``, ``braking_after`` and
        ``held_path`` and ``columns`` 6, whose rows follow the origin of the footprint with
        its heading and turn rate: the filter measures a turning footprint along them.
        """
        raise NotImplementedError(f'{self.name} has no heading to turn a footprint with')

    def point_row(self, x):
        """Return the reference point's position, then velocity, at x: a path's row."""
        ref = self.reference(x)
        return np.concatenate((ref.position, ref.velocity))

    def one_period(self, x, u, period):
        """Return x+, the state ``period`` s after x with ``u`` held: the midpoint rule.

        middle = x + (T / 2) x_dot(x, u), x+ = x + T x_dot(middle, u) (``state_derivative``;
        exact for the point mass, where an Euler step misplaced it by T^2 u / 2).
        """
        middle = x + 0.5 * period * self.state_derivative(x, u)
        return x + period * self.state_derivative(middle, u)

    def braking_after(self, x, u, period):
        """Return the braking check's rows for ``u``: the point at x+, then ``braking_path``.

        (K + 1, 2 position_dim), C-contiguous float64: row 0 ``point_row`` at
        x+ = ``one_period(x, u, period)``, rows 1.. ``braking_path(x+, period)``.  None when
        the model has no braking path.  A model may compute it in one compiled call, with
        exactly this arithmetic.
        """
        after = self.one_period(x, u, period)
        path = self.braking_path(after, period)
        if path is None:
            return None
        return np.vstack((self.point_row(after), path))

    def stop_bands(self, x, u, period):
        """Return (bands, rows): bounds of ``braking_after(x, u, period)``'s rows, uncomputed.

        ``bands`` (B, 10), rows as ``kernels.braking.path_groups`` gives them and the
        largest |omega|: every row lies in row 0's position box, and its velocity in the
        velocity box of at least one band (``kernels.unicycle._stop_bands``); ``rows``
        bounds how many rows there are; a model may write ``bands`` into one buffer that its
        next call overwrites.  The braking check keeps an input without computing its path
        when these clear every part (``SafetyFilter._stop_certified``).  None: no bound.
        """
        return None

    def held_path(self, x, u, step, rows):
        """Return (path, state): the point's path with ``u`` held from x, and its last state.

        The path is (rows, 2 position_dim); row k is the point's position, then its
        velocity, (k + 1) ``step`` s after x with the input ``u`` held all along (the
        filter's evasion looks ahead along these).  None: the model has none, and the
        filter does not evade with it.
        """
        return None

    #: The braking check's stops (``braking_path``, ``braking_reach``) decelerate at this
    #: share of the input limits after coasting ``braking_coast`` s (``plan_braking``).
    braking_share = 1.0
    braking_coast = 0.0

    def plan_braking(self, share=1.0, coast=0.0):
        """Plan the braking check's stops for a base that may brake slower and act later.

        Each stop decelerates at ``share`` (0 < share <= 1) of the input limits, its damped
        tail with ``brake_time_constant / share``, after coasting ``coast`` [s] at the
        velocity it starts with (design.md 3.13, robust margin); ``braking_input`` still
        asks for the full brake.  Return self.
        """
        if not (math.isfinite(share) and 0.0 < share <= 1.0):
            raise ValueError(f'braking share must be in (0, 1], got {share!r}')
        if not (math.isfinite(coast) and coast >= 0.0):
            raise ValueError(f'braking coast must be a finite number >= 0, got {coast!r}')
        self.braking_share, self.braking_coast = float(share), float(coast)
        self.braking_limits = np.ascontiguousarray(self.input_upper * self.braking_share,
                                                   dtype=np.float64)
        return self

    def braking_reach(self, x, period):
        """Return (rho, t): a bound on the braking check's path from one period after x.

        For every admissible input held over ``period`` from x, ``braking_path`` from the
        state reached stays within rho of the body position ``x[:position_dim]`` and ends
        within t of x (``SafetyFilter`` skips the check when nothing comes within rho).
        (inf, inf): no bound.
        """
        return math.inf, math.inf

    def as_state(self, x):
        """Return x as a C-contiguous float64 state vector; ValueError on a wrong shape."""
        x = np.ascontiguousarray(x, dtype=np.float64)
        if x.shape != (self.state_dim,):
            raise ValueError(f'{self.name} state must have shape ({self.state_dim},), '
                             f'got {x.shape}')
        return x

    def state_derivative(self, x, u):
        """Return x_dot = f(x) + g(x) u."""
        return self.f(x) + self.g(x) @ np.asarray(u, dtype=float)

    def clip_input(self, u):
        """Clip u to the input box."""
        return np.clip(u, self.input_lower, self.input_upper)


def damped_brake(rates, limit, time_constant):
    """Return -rates / time_constant clipped to +-limit, zero where rates are not finite.

    Used by models whose brake drives velocities to zero as fast as the input
    bounds allow without overshooting within one time constant.
    """
    rates = np.where(np.isfinite(rates), rates, 0.0)
    return np.clip(-rates / time_constant, -limit, limit)
