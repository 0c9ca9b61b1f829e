"""Velocity commands <-> acceleration inputs for velocity-interface robots.

The barrier functions are written for acceleration-controlled models, but most
robots take a velocity command (``geometry_msgs/Twist``).  With ``v`` the
commandable velocity read from the state, ``tau`` the tracking time constant
and ``T`` the control period::

    u_nom  = (v_cmd - v) / tau          nominal velocity -> nominal acceleration
    v_safe = v + u_safe * T             safe acceleration held for one period

With ``tau == T`` (the node's default) an unconstrained step returns
``v_safe == v_cmd`` exactly, so the filter is transparent until a constraint
or an acceleration bound is active; a larger ``tau`` smooths the command.

Coordinates of the command vector per model:

- ``unicycle``: ``[v, omega]`` = Twist ``linear.x, angular.z``; ``v`` and
  ``omega`` are state entries 3 and 4, the input is ``[a, alpha]``.
- ``point_mass_2d``: ``[vx, vy]`` = Twist ``linear.x, linear.y`` in the body
  (heading) frame; the state velocity and the input are in the odometry frame,
  so ``v_cmd`` is rotated by the odometry yaw ``psi``: ``v_world = Rz(psi) v_cmd``
  and back with ``Rz(psi)^T``.
- ``point_mass_3d``: ``[vx, vy, vz]`` = Twist ``linear.x, .y, .z`` in the
  heading frame (body frame without roll and pitch: ``Rz(psi)``), so a tilted
  drone's vertical command stays vertical.
"""
import math

import numpy as np

# model -> (slice of the state holding the commandable velocity, rotate by yaw?)
_LAYOUT = {
    'unicycle': (slice(3, 5), False),
    'point_mass_2d': (slice(2, 4), True),
    'point_mass_3d': (slice(3, 6), True),
}

VELOCITY_MODELS = tuple(_LAYOUT)


class VelocityCommandInterface:
    """Map a velocity command to a nominal acceleration and a safe input back."""

    def __init__(self, model_name, tau, period):
        """Build for ``model_name`` in ``VELOCITY_MODELS``; ``tau``, ``period`` > 0 [s]."""
        if model_name not in _LAYOUT:
            raise ValueError(f'model {model_name!r} has no velocity interface; '
                             f'expected one of {VELOCITY_MODELS}')
        if not (tau > 0.0 and period > 0.0 and math.isfinite(tau) and math.isfinite(period)):
            raise ValueError(f'tau and period must be finite and > 0, got {tau}, {period}')
        self._slice, self._rotate = _LAYOUT[model_name]
        self.velocity_dim = self._slice.stop - self._slice.start
        self.tau = float(tau)
        self.period = float(period)

    def _rotated(self, vector, yaw):
        """Return ``vector`` as a list of floats, turned by Rz(yaw) where the model says so.

        Plain floats: this runs twice per filter step, where numpy's per-call cost on
        two or three numbers would exceed the arithmetic.
        """
        values = [float(v) for v in vector]
        if self._rotate:
            c, s = math.cos(yaw), math.sin(yaw)
            x, y = values[0], values[1]
            values[0], values[1] = c * x - s * y, s * x + c * y
        return values

    def _velocity(self, state):
        """Return the commandable velocity entries of ``state`` (array or float sequence)."""
        if isinstance(state, np.ndarray):
            state = state.tolist()
        return state[self._slice]

    def nominal_input(self, state, cmd, yaw=0.0):
        """``u_nom = (Rz(yaw) v_cmd - v) / tau`` (no rotation for the unicycle)."""
        tau = self.tau
        return np.array([(c - v) / tau for c, v in zip(self._rotated(cmd, yaw),
                                                       self._velocity(state))])

    def safe_command(self, state, u_safe, yaw=0.0):
        """``v_safe = Rz(yaw)^T (v + u_safe T)`` in command coordinates."""
        period = self.period
        v_world = [v + u * period for v, u in zip(self._velocity(state),
                                                  np.asarray(u_safe).tolist())]
        return np.array(self._rotated(v_world, -yaw))
