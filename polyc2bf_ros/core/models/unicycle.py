"""Acceleration-controlled unicycle (paper eq. 8-12), the quadruped's model.

State x = [x_p, y_p, theta, v, omega], input u = [a, alpha]::

    x_dot = [v cos(theta), v sin(theta), omega, 0, 0] + [[0,0],[0,0],[0,0],[1,0],[0,1]] u

The reference point sits a distance l ahead of the axle (paper eq. 9); with
l = 0 the steering column of Lgh vanishes::

    r     = [x_p + l cos(theta), y_p + l sin(theta)]
    r_dot = [v cos(theta) - l omega sin(theta), v sin(theta) + l omega cos(theta)]
    r_ddot = drift + B u,
      drift = [-v omega sin(theta) - l omega^2 cos(theta),
                v omega cos(theta) - l omega^2 sin(theta)]
      B     = [[cos(theta), -l sin(theta)],
               [sin(theta),  l cos(theta)]]

which is minus the paper's v_rel_dot expression.
"""
import math

import numpy as np

from polyc2bf_ros.core.kernels.unicycle import (
    _braking_after,
    _braking_path,
    _held_path,
    _offset_point,
    _stop_bands,
)
from polyc2bf_ros.core.models.base import (
    damped_brake,
    ReferenceKinematics,
    register_model,
    RobotModel,
)

STOP_BANDS = 6
"""Speed bands of ``stop_bands``: |v| in [V / 2, V], ..., [0, V / 32].  The barrier's tests
need a band slow enough to lie tau |v| from a part, and bands fast enough to keep the
direction of motion: six cover a stop from 2 m/s down to 6 cm/s."""


@register_model
class Unicycle(RobotModel):
    """Acceleration-controlled unicycle with reference-point offset ``offset_l``."""

    name = 'unicycle'
    state_dim = 5
    input_dim = 2
    position_dim = 2
    steering_inputs = (1,)   # alpha
    turns_footprint = True

    def __init__(self, offset_l=0.2, max_accel=2.0, max_angular_accel=4.0,
                 brake_time_constant=0.05, steering_weight=1.0):
        """Set the offset l [m], |a| <= max_accel, |alpha| <= max_angular_accel.

        ``steering_weight`` w [m^2]: the filter's cost is (a - a_nom)^2 + w (alpha -
        alpha_nom)^2 (``input_weights``).  1 is the paper's QP; w = l^2 makes it the squared
        change of the guarded point's acceleration |B du|^2 (B^T B = diag(1, l^2), module
        docstring), so the filter turns as readily as it brakes.
        """
        if not (math.isfinite(steering_weight) and steering_weight > 0.0):
            raise ValueError(f'steering_weight must be positive and finite, '
                             f'got {steering_weight!r}')
        self.offset_l = float(offset_l)
        self._weights = np.array([1.0, float(steering_weight)])
        self.guard_offset = abs(self.offset_l)
        self.input_upper = np.array([max_accel, max_angular_accel], dtype=float)
        self.input_lower = -self.input_upper
        self._limits = (float(max_accel), float(max_angular_accel))  # plain floats: per step
        self.brake_time_constant = float(brake_time_constant)
        self._bands = np.empty((STOP_BANDS, 10))
        self.plan_braking()

    @property
    def input_weights(self):
        """Return [1, steering_weight]: the cost's weights on a and alpha."""
        return self._weights.copy()

    def f(self, x):
        """Return [v cos(theta), v sin(theta), omega, 0, 0]."""
        _, _, theta, v, omega = x
        return np.array([v * np.cos(theta), v * np.sin(theta), omega, 0.0, 0.0])

    def state_derivative(self, x, u):
        """Return x_dot = f(x) + g(x) u directly (a third of the generic product's cost)."""
        _, _, theta, v, omega = x
        return np.array([v * math.cos(theta), v * math.sin(theta), omega, u[0], u[1]])

    def g(self, x):
        """Return the constant input matrix: a drives v, alpha drives omega."""
        g = np.zeros((5, 2))
        g[3, 0] = g[4, 1] = 1.0
        return g

    def reference(self, x, out=None):
        """Return the kinematics of the point l ahead of the axle (in ``out`` if given)."""
        ref = ReferenceKinematics.empty(2, 2) if out is None else out
        # Unchecked: as_state and ReferenceKinematics.empty give C-contiguous float64.
        ref.state = self.as_state(x)
        _offset_point.unchecked(ref.state, self.offset_l, ref.position, ref.velocity,
                                ref.drift, ref.input_matrix)
        return ref

    def braking_input(self, x):
        """Decelerate v and omega to zero at the input limits."""
        return damped_brake(np.asarray(x, dtype=float)[3:5], self.input_upper,
                            self.brake_time_constant)

    def braking_path(self, x, period):
        """Return the reference point's path under the brake (``RobotModel.braking_path``)."""
        return self._brake_rows(x, period, self.offset_l, 4)

    def _brake_rows(self, x, period, offset, columns):
        """Return the rows of the point ``offset`` ahead (``columns`` 6: theta, omega too)."""
        x = self.as_state(x)
        limits = self.braking_limits
        stop = abs(x[3]) / limits[0] + abs(x[4]) / limits[1]
        time_constant = self.brake_time_constant / self.braking_share
        out = np.empty((int(stop / period) + int(8 * time_constant / period) + 2, columns))
        # Unchecked: as_state, braking_limits and out are C-contiguous float64.
        rows = _braking_path.unchecked(x, offset, limits, time_constant, self.braking_coast,
                                       float(period), out)
        return out[:rows]

    def braking_after(self, x, u, period):
        """Return the point at x+, then its path under the brake (``RobotModel.braking_after``).

        One kernel call.  ``out`` holds the rows of any x+ the input reaches: |v+| <=
        |v| + |a| T and |omega+| <= |omega| + |alpha| T bound ``braking_path``'s row count
        from x+; one more for row 0, three for rounding.  Should it not, the kernel says how
        many rows it needs, and a second call writes them.
        """
        return self._brake_after_rows(x, u, period, self.offset_l, 4)

    def _brake_after_rows(self, x, u, period, offset, columns):
        """Return the rows of the point ``offset`` ahead (``columns`` 6: theta, omega too)."""
        x, u = self.as_state(x), np.ascontiguousarray(u, dtype=np.float64)
        limits = self.braking_limits
        time_constant = self.brake_time_constant / self.braking_share
        stop = ((abs(float(x[3])) + period * abs(float(u[0]))) / limits[0]
                + (abs(float(x[4])) + period * abs(float(u[1]))) / limits[1])
        out = np.empty((int(stop / period) + int(8 * time_constant / period) + 6, columns))
        while True:
            # Unchecked: as_state, the input, braking_limits and out are C-contiguous float64.
            rows = _braking_after.unchecked(x, u, offset, limits, time_constant,
                                            self.braking_coast, float(period), out)
            if rows >= 0:
                return out[:rows]
            out = np.empty((-rows, columns))

    def stop_bands(self, x, u, period):
        """Return the reference point's ``RobotModel.stop_bands``; None when T > tau."""
        return self._stop_bands(x, u, period, self.offset_l)

    def _stop_bands(self, x, u, period, offset):
        """Return ``stop_bands`` of the point ``offset`` ahead of the axle."""
        if period > self.brake_time_constant:
            return None
        # Unchecked: as_state, the input, braking_limits and the bands are C-contiguous.
        rows = _stop_bands.unchecked(self.as_state(x), np.ascontiguousarray(u, dtype=np.float64),
                                     offset, self.braking_limits,
                                     self.brake_time_constant / self.braking_share,
                                     self.braking_coast, float(period), self._bands)
        return self._bands, rows

    def held_path(self, x, u, step, rows):
        """Return the reference point's path with ``u`` held (``RobotModel.held_path``)."""
        return self._held_rows(x, u, step, rows, self.offset_l, 4)

    def _held_rows(self, x, u, step, rows, offset, columns):
        """Return the point's rows ``offset`` ahead (``columns`` 6: theta, omega too), the end."""
        out, end = np.empty((int(rows), columns)), np.empty(5)
        # Unchecked: as_state, the input, out and end are C-contiguous float64.
        _held_path.unchecked(self.as_state(x), offset,
                             np.ascontiguousarray(u, dtype=np.float64), float(step), out, end)
        return out, end

    def body_paths(self):
        """Return the axle's paths with the heading (``RobotModel.body_paths``)."""
        return AxlePaths(self)

    def braking_reach(self, x, period):
        """Return (rho, t) of ``RobotModel.braking_reach``; (inf, inf) when T > tau.

        Over the period |v| <= |v_0| + a_max T = v' and |omega| <= |omega_0| + alpha_max T =
        w'; the brake then lowers both (T <= tau: no overshoot), so the reference point moves
        at most v' + |l| w' through the period, the coast c (``plan_braking``) and the
        path's K rows (``braking_path``: K <= (v' / a_max + w' / alpha_max + 8 tau) / (s T) + 2,
        s the braking share), and starts |l| from the body:
        rho = |l| + (v' + |l| w') ((K + 1) T + c), t = (K + 1) T + c.
        """
        if period > self.brake_time_constant:
            return math.inf, math.inf
        accel, angular = self._limits
        speed = abs(float(x[3])) + accel * period
        turn = abs(float(x[4])) + angular * period
        share = self.braking_share
        rows = int((speed / accel + turn / angular) / share / period) \
            + int(8 * self.brake_time_constant / share / period) + 2
        duration = (rows + 1) * period + self.braking_coast
        return self.guard_offset + (speed + self.guard_offset * turn) * duration, duration


class AxlePaths:
    """The unicycle's axle's paths, rows [x, y, vx, vy, theta, omega] (``body_paths``).

    The same kernels as the reference point's, at offset 0 with the heading and turn rate
    in two more columns: where a footprint polygon about the axle is at each row, and how
    it turns there.
    """

    columns = 6

    def __init__(self, model):
        """Follow ``model``'s state."""
        self.model = model

    def point_row(self, x):
        """Return the axle's row at x."""
        x = self.model.as_state(x)
        c, s = math.cos(x[2]), math.sin(x[2])
        return np.array([x[0], x[1], x[3] * c, x[3] * s, x[2], x[4]])

    def braking_path(self, x, period):
        """Return the axle's rows under the brake (``Unicycle.braking_path`` at offset 0)."""
        return self.model._brake_rows(x, period, 0.0, self.columns)

    def braking_after(self, x, u, period):
        """Return the axle at x+, then its rows under the brake (``braking_after``)."""
        return self.model._brake_after_rows(x, u, period, 0.0, self.columns)

    def stop_bands(self, x, u, period):
        """Return the axle's ``RobotModel.stop_bands`` (offset 0)."""
        return self.model._stop_bands(x, u, period, 0.0)

    def held_path(self, x, u, step, rows):
        """Return the axle's rows with ``u`` held, and the last state (``held_path``)."""
        return self.model._held_rows(x, u, step, rows, 0.0, self.columns)
