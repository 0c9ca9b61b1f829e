"""Point mass with acceleration input, in 2-D and 3-D (paper eq. 18).

State x = [p, v] with p, v in R^d, input u = a in R^d::

    x_dot = [v, 0] + [0; I] u,   r = p,  r_dot = v,  r_ddot = 0 + I u
"""
import math

import numpy as np

from polyc2bf_ros.core.kernels.point_mass import _braking_path
from polyc2bf_ros.core.models.base import (
    damped_brake,
    ReferenceKinematics,
    register_model,
    RobotModel,
)


class PointMass(RobotModel):
    """Double integrator in ``position_dim`` dimensions with a per-axis acceleration box."""

    def __init__(self, max_accel=3.0, brake_time_constant=0.05):
        """Set the per-axis bound |a_i| <= max_accel [m/s^2]."""
        d = self.position_dim
        self.input_upper = np.full(d, float(max_accel))
        self.input_lower = -self.input_upper
        self.brake_time_constant = float(brake_time_constant)
        self._g = np.vstack([np.zeros((d, d)), np.eye(d)])
        self._drift, self._input_matrix = np.zeros(d), np.eye(d)  # shared: never written
        self.plan_braking()

    def f(self, x):
        """Return [v, 0]."""
        d = self.position_dim
        return np.concatenate([x[d:], np.zeros(d)])

    def g(self, x):
        """Return [0; I]."""
        return self._g

    def reference(self, x, out=None):
        """Return the point's own position and velocity, r_ddot = u (views: ``out`` unused)."""
        d = self.position_dim
        x = self.as_state(x)
        return ReferenceKinematics(position=x[:d], velocity=x[d:], drift=self._drift,
                                   input_matrix=self._input_matrix)

    def braking_input(self, x):
        """Decelerate each axis to rest at the acceleration limit."""
        d = self.position_dim
        return damped_brake(np.asarray(x, dtype=float)[d:], self.input_upper,
                            self.brake_time_constant)

    def braking_path(self, x, period):
        """Return the point's path under the brake (``RobotModel.braking_path``)."""
        x = self.as_state(x)
        d = self.position_dim
        if self.braking_coast:  # at constant velocity (``plan_braking``)
            x = np.concatenate([x[:d] + self.braking_coast * x[d:], x[d:]])
        limit = float(self.braking_limits[0])
        stop = float(np.max(np.abs(x[d:]))) / limit
        time_constant = self.brake_time_constant / self.braking_share
        out = np.empty((int(stop / period) + int(8 * time_constant / period) + 2,
                        2 * d))
        # Unchecked: as_state, the coasted state and out are C-contiguous float64.
        rows = _braking_path.unchecked(x, limit, time_constant, float(period), out)
        return out[:rows]

    def held_path(self, x, u, step, rows):
        """Return the point's path with ``u`` held (``RobotModel.held_path``).

        Exact: p + v t + u t^2 / 2 and v + u t at t = (k + 1) step.
        """
        d = self.position_dim
        x, u = self.as_state(x), np.asarray(u, dtype=float)
        t = (np.arange(int(rows)) + 1.0)[:, None] * float(step)
        path = np.hstack([x[:d] + x[d:] * t + 0.5 * u * t * t, x[d:] + u * t])
        return path, path[-1].copy()

    def braking_reach(self, x, period):
        """Return (rho, t) of ``RobotModel.braking_reach``; (inf, inf) when T > tau.

        Over the period each |v_i| <= |v_i0| + a_max T = v'_i; the brake then lowers each
        (T <= tau: no overshoot), through the coast c (``plan_braking``) and the path's K
        rows (``braking_path``: K <= max v'_i / (s a_max T) + 8 tau / (s T) + 2, s the braking
        share): rho = |v'| ((K + 1) T + c), t = (K + 1) T + c.
        """
        if period > self.brake_time_constant:
            return math.inf, math.inf
        limit = float(self.input_upper[0])
        speeds = np.abs(np.asarray(x, dtype=float)[self.position_dim:]) + limit * period
        rows = int(float(speeds.max()) / float(self.braking_limits[0]) / period) \
            + int(8 * self.brake_time_constant / self.braking_share / period) + 2
        duration = (rows + 1) * period + self.braking_coast
        return float(np.sqrt(speeds @ speeds)) * duration, duration


@register_model
class PointMass2D(PointMass):
    """Holonomic ground robot: x = [x, y, vx, vy], u = [ax, ay]."""

    name = 'point_mass_2d'
    state_dim = 4
    input_dim = 2
    position_dim = 2


@register_model
class PointMass3D(PointMass):
    """Holonomic aerial robot: x = [x, y, z, vx, vy, vz], u = [ax, ay, az]."""

    name = 'point_mass_3d'
    state_dim = 6
    input_dim = 3
    position_dim = 3
