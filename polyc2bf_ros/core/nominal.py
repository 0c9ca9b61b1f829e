"""Reference (nominal) go-to-goal controllers; they know nothing about obstacles.

Like the paper's PD reference controllers, these stand in for any planner.
Each returns the model's input (accelerations or rotor thrusts).

They run every control period for every robot of a simulation, so the small
vector algebra is spelled out on floats; norms and dot products stay numpy's
(``v.dot(v)``, ``@``) and angles ``np.arctan2`` (its SIMD version rounds
differently from ``math.atan2``), so the commands are the same to the bit.
"""
import math
from dataclasses import dataclass

import numpy as np

from polyc2bf_ros.core import crazyflie as cf
from polyc2bf_ros.core.models.quadrotor import rotation_matrix

_GRAVITY_UP = np.array([0.0, 0.0, cf.GRAVITY])


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
        """Return [T, tau_x, tau_y, tau_z]."""
        error = np.asarray(goal, dtype=float)[:3] - state[0:3]
        accel = _clip_norm(self.position_gain * error, self.max_accel)
        accel = accel - self.velocity_gain * state[3:6] + _GRAVITY_UP
        roll, pitch, yaw = state[6:9].tolist()
        rot = rotation_matrix(roll, pitch, yaw)
        thrust = self.mass * accel @ rot[:, 2]
        # Attitude error in the body frame: rotate body z onto z_desired = a*/|a*|, yaw to 0.
        (bx, by, bz), (dx, dy, dz) = rot[:, 2].tolist(), (accel / _norm(accel)).tolist()
        tilt_error = rot.T @ np.array([by * dz - bz * dy, bz * dx - bx * dz, bx * dy - by * dx])
        yaw_error = -((yaw + math.pi) % (2 * math.pi) - math.pi)
        attitude_error = np.array([tilt_error[0], tilt_error[1], yaw_error])
        wrench = np.empty(4)
        wrench[0] = thrust
        wrench[1:] = cf.INERTIA @ (self.attitude_gain * attitude_error
                                   - self.rate_gain * state[9:12])
        return wrench

    def __call__(self, state, goal):
        """Return rotor thrusts (not clipped; the filter clips to the input box)."""
        return cf.thrusts_from_wrench(self.wrench(state, goal))
