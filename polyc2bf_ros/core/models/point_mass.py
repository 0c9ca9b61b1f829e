"""Point mass with acceleration input, in 2-D and 3-D (paper eq. 18).

State x = [p, v] with p, v in R^d, input u = a in R^d::

    x_dot = [v, 0] + [0; I] u,   r = p,  r_dot = v,  r_ddot = 0 + I u
"""
import numpy as np

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
