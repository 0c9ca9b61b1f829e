"""Quadrotor with rotor-thrust inputs (paper eq. 13-17), parameters from Crazyflie 2.1.

State x = [p (3), v (3), roll, pitch, yaw, w (3 body rates)], input u = f (4 rotor
thrusts, N).  With R = Rz(yaw) Ry(pitch) Rx(roll) (body to world), the
mixer [T, tau] = M f of ``polyc2bf_ros.core.models.crazyflie`` and inertia I::

    p_dot = v
    v_dot = [0, 0, -g] + R e_z T / m
    [roll, pitch, yaw]_dot = E(roll, pitch) w      (E singular at pitch = +-90 deg)
    w_dot = I^-1 (tau - w x I w)

The guarded point is b = [0, 0, l] in the body frame (paper eq. 14)::

    r      = p + R b
    r_dot  = v + R (w x b)
    r_ddot = drift + B f
      drift = [0, 0, -g] + R (w x (w x b)) + R [b]x I^-1 (w x I w)
      B     = R e_z 1^T / m - R [b]x I^-1 M_tau

(using w_dot x b = -[b]x w_dot); with it, Lg h is the paper's eq. 17 for the X layout.
``reference`` evaluates these in one compiled kernel.
"""

import numpy as np

from polyc2bf_ros.core.kernels.quadrotor import _body_point, rotation_matrix
from polyc2bf_ros.core.models import crazyflie as cf
from polyc2bf_ros.core.models.base import ReferenceKinematics, register_model, RobotModel


def euler_rate_matrix(roll, pitch):
    """Return E with [roll, pitch, yaw]_dot = E w for body rates w."""
    cr, sr = np.cos(roll), np.sin(roll)
    tp, cp = np.tan(pitch), np.cos(pitch)
    return np.array([
        [1.0, sr * tp, cr * tp],
        [0.0, cr, -sr],
        [0.0, sr / cp, cr / cp],
    ])


@register_model
class Quadrotor(RobotModel):
    """Crazyflie-like quadrotor driven by four rotor thrusts in [0, max_rotor_thrust]."""

    name = 'quadrotor'
    state_dim = 12
    input_dim = 4
    position_dim = 3

    def __init__(self, offset_l=0.05, mass=cf.MASS, inertia=cf.INERTIA,
                 max_rotor_thrust=cf.MAX_ROTOR_THRUST, attitude_gain=20.0):
        """Set the body-point offset l [m] along body z, mass, inertia and thrust limit."""
        self.offset_l = float(offset_l)
        self.guard_offset = abs(self.offset_l)
        self.mass = float(mass)
        self.inertia = np.asarray(inertia, dtype=float)
        self.inertia_inv = np.linalg.inv(self.inertia)
        self.input_lower = np.zeros(4)
        self.input_upper = np.full(4, float(max_rotor_thrust))
        self.attitude_gain = float(attitude_gain)
        self._b = np.array([0.0, 0.0, self.offset_l])
        self._torque_map = self.inertia_inv @ cf.MIXER[1:]
        self._gravity = np.array([0.0, 0.0, -cf.GRAVITY])

    def f(self, x):
        """Return the drift: free fall, Euler kinematics and gyroscopic terms."""
        w = x[9:12]
        return np.concatenate([
            x[3:6], self._gravity, euler_rate_matrix(x[6], x[7]) @ w,
            -self.inertia_inv @ np.cross(w, self.inertia @ w)])

    def g(self, x):
        """Return the map from rotor thrusts to linear and angular accelerations."""
        g = np.zeros((12, 4))
        g[3:6] = np.outer(rotation_matrix(*x[6:9])[:, 2], np.ones(4)) / self.mass
        g[9:12] = self._torque_map
        return g

    def reference(self, x, out=None):
        """Return the kinematics of the body point b = [0, 0, l] (in ``out`` if given)."""
        ref = ReferenceKinematics.empty(3, 4) if out is None else out
        _body_point(self.as_state(x), self._b, self.inertia, self.inertia_inv,
                    self._torque_map, self.mass, cf.GRAVITY, ref.position, ref.velocity,
                    ref.drift, ref.input_matrix)
        return ref

    def braking_input(self, x):
        """Level the attitude and cancel vertical speed (a hover brake).

        Collective thrust T = m (g - 2 v_z) / (cos roll cos pitch), body torques
        tau = -I (k^2 [roll, pitch, 0] + 2 k w) with k = ``attitude_gain``;
        non-finite state entries count as zero.
        """
        x = np.where(np.isfinite(x), np.asarray(x, dtype=float), 0.0)
        roll, pitch = x[6], x[7]
        tilt = max(np.cos(roll) * np.cos(pitch), 0.5)
        thrust = self.mass * (cf.GRAVITY - 2.0 * x[5]) / tilt
        k = self.attitude_gain
        torque = -self.inertia @ (k * k * np.array([roll, pitch, 0.0]) + 2.0 * k * x[9:12])
        return self.clip_input(cf.thrusts_from_wrench(np.concatenate([[thrust], torque])))
