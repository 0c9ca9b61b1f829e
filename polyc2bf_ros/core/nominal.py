"""Reference (nominal) go-to-goal controllers; they know nothing about obstacles.

Like the paper's PD reference controllers, these stand in for any planner.
Each returns the model's input (accelerations or rotor thrusts).

They run every control period for every robot of a simulation, so the small
vector algebra is spelled out on floats (norms and dot products stay numpy's,
``v.dot(v)``, and angles ``np.arctan2``, whose SIMD version rounds differently
from ``math.atan2``), and the quadrotor's law is one compiled kernel.
"""
import math
from dataclasses import dataclass

import numpy as np

from polyc2bf_ros.core import crazyflie as cf
from polyc2bf_ros.core.jit import F1, F2, kernel, signature
from polyc2bf_ros.core.models.quadrotor import rotation_matrix

_INERTIA = np.ascontiguousarray(cf.INERTIA, dtype=np.float64)


def _norm(vector):
    """Return the Euclidean norm of a 1-D vector (what ``np.linalg.norm`` computes)."""
    return math.sqrt(vector.dot(vector))


def _clip_norm(vector, limit):
    """Scale ``vector`` down so that its norm is at most ``limit``."""
    norm = _norm(vector)
    return vector if norm <= limit else vector * (limit / norm)


@dataclass
class UnicycleGoalController:
    """Drive at v* = min(k_d dist, v_max) towards the goal, steer on the heading error.

    v* = min(k_d |e|, v_max),  omega* = k_theta wrap(atan2(e_y, e_x) - theta),
    u = [(v* - v) / tau, (omega* - omega) / tau]; the robot stops within ``goal_tolerance``.
    """

    max_speed: float = 1.0
    distance_gain: float = 1.0
    heading_gain: float = 2.0
    max_turn_rate: float = 1.5
    time_constant: float = 0.3
    goal_tolerance: float = 0.1

    def velocity_command(self, state, goal):
        """Return the desired [v, omega]."""
        error = np.asarray(goal, dtype=float)[:2] - state[:2]
        distance = _norm(error)
        if distance < self.goal_tolerance:
            return np.zeros(2)
        heading = np.arctan2(error[1], error[0]) - state[2]
        heading = (heading + np.pi) % (2 * np.pi) - np.pi
        speed = min(self.distance_gain * distance, self.max_speed) * max(np.cos(heading), 0.0)
        turn = min(max(self.heading_gain * heading, -self.max_turn_rate), self.max_turn_rate)
        return np.array([speed, turn])

    def __call__(self, state, goal):
        """Return the acceleration input [a, alpha]."""
        return (self.velocity_command(state, goal) - state[3:5]) / self.time_constant


@dataclass
class PointMassGoalController:
    """PD to the goal with a speed limit: a = (v* - v) / tau, v* = clip(k_d e, v_max)."""

    max_speed: float = 1.0
    distance_gain: float = 1.0
    time_constant: float = 0.3

    def velocity_command(self, state, goal):
        """Return the desired velocity."""
        dim = state.size // 2
        error = np.asarray(goal, dtype=float)[:dim] - state[:dim]
        return _clip_norm(self.distance_gain * error, self.max_speed)

    def __call__(self, state, goal):
        """Return the acceleration input."""
        dim = state.size // 2
        return (self.velocity_command(state, goal) - state[dim:]) / self.time_constant


@dataclass
class QuadrotorGoalController:
    """Position PD with gravity compensation and an attitude PD, as a wrench or thrusts.

    a* = clip(k_p e, a_max) - k_d v + g e_z, T = m <a*, R e_z>;
    desired body z = a*/|a*| with yaw* = 0; torque tau = I (k_R e_R - k_w w),
    e_R the small-angle attitude error.  ``thrusts`` maps [T, tau] through the mixer.
    """

    position_gain: float = 2.0
    velocity_gain: float = 2.5
    max_accel: float = 3.0
    attitude_gain: float = 60.0
    rate_gain: float = 14.0
    mass: float = cf.MASS

    def wrench(self, state, goal):
        """Return [T, tau_x, tau_y, tau_z] (``_quadrotor_wrench``: the law in one kernel)."""
        wrench = np.empty(4)
        _quadrotor_wrench(np.ascontiguousarray(state, dtype=np.float64),
                          np.ascontiguousarray(goal, dtype=np.float64), float(self.position_gain),
                          float(self.velocity_gain), float(self.max_accel),
                          float(self.attitude_gain), float(self.rate_gain), float(self.mass),
                          _INERTIA, wrench)
        return wrench

    def __call__(self, state, goal):
        """Return rotor thrusts (not clipped; the filter clips to the input box)."""
        return cf.thrusts_from_wrench(self.wrench(state, goal))


@kernel(signature('void', F1, F1, 'f8', 'f8', 'f8', 'f8', 'f8', 'f8', F2, F1))
def _quadrotor_wrench(state, goal, position_gain, velocity_gain, max_accel, attitude_gain,
                      rate_gain, mass, inertia, out):
    """Write ``QuadrotorGoalController``'s [T, tau] into ``out`` (law in the class docstring).

    e = goal - p; a* = k_p e scaled to norm <= a_max, - k_d v + g e_z; with R the
    body-to-world rotation and b = R e_z, T = m <a*, b>; e_R = R^T (b x a*/|a*|) in
    x, y and -wrap(yaw) in z; tau = I (k_R e_R - k_w w).
    """
    ex = position_gain * (goal[0] - state[0])
    ey = position_gain * (goal[1] - state[1])
    ez = position_gain * (goal[2] - state[2])
    norm = math.sqrt(ex * ex + ey * ey + ez * ez)
    if norm > max_accel:
        scale = max_accel / norm
        ex, ey, ez = ex * scale, ey * scale, ez * scale
    ax = ex - velocity_gain * state[3]
    ay = ey - velocity_gain * state[4]
    az = ez - velocity_gain * state[5] + cf.GRAVITY
    rot = rotation_matrix(state[6], state[7], state[8])
    bx, by, bz = rot[0, 2], rot[1, 2], rot[2, 2]
    out[0] = mass * (ax * bx + ay * by + az * bz)
    length = math.sqrt(ax * ax + ay * ay + az * az)
    dx, dy, dz = ax / length, ay / length, az / length
    cx, cy, cz = by * dz - bz * dy, bz * dx - bx * dz, bx * dy - by * dx
    error = (attitude_gain * (rot[0, 0] * cx + rot[1, 0] * cy + rot[2, 0] * cz)
             - rate_gain * state[9],
             attitude_gain * (rot[0, 1] * cx + rot[1, 1] * cy + rot[2, 1] * cz)
             - rate_gain * state[10],
             attitude_gain * -((state[8] + math.pi) % (2.0 * math.pi) - math.pi)
             - rate_gain * state[11])
    for i in range(3):
        out[1 + i] = inertia[i, 0] * error[0] + inertia[i, 1] * error[1] + inertia[i, 2] * error[2]
