"""Reference (nominal) controllers; they know nothing about obstacles.

Go-to-goal: like the paper's PD reference controllers, these stand in for any
planner.  Path following (``UnicyclePathController``, pure pursuit along a
``ReferencePath``): a planner's path plus a local controller, the way a safety
filter is deployed under a navigation stack.  Each returns the model's input
(accelerations or rotor thrusts), or a velocity command.

They run every control period for every robot of a simulation, so the small
vector algebra is spelled out on floats (norms and dot products stay numpy's,
``v.dot(v)``, and angles ``np.arctan2``, whose SIMD version rounds differently
from ``math.atan2``), and the quadrotor's law is one function compiled by numba on
first use (only a process that flies a quadrotor loads numba for it).
"""
import bisect
import functools
import math
from dataclasses import dataclass

import numpy as np

from polyc2bf_ros.core.kernels.jit import JIT_OPTIONS
from polyc2bf_ros.core.kernels.quadrotor import rotation_matrix
from polyc2bf_ros.core.models import crazyflie as cf

_INERTIA = np.ascontiguousarray(cf.INERTIA, dtype=np.float64)


def _norm(vector):
    """Return the Euclidean norm of a 1-D vector (what ``np.linalg.norm`` computes)."""
    return math.sqrt(vector.dot(vector))


def _clip_norm(vector, limit):
    """Scale ``vector`` down so that its norm is at most ``limit``."""
    norm = _norm(vector)
    return vector if norm <= limit else vector * (limit / norm)


@dataclass
class _UnicycleLaw:
    """What the unicycle nominals share: gains, limits and u = [(v* - v), (omega* - omega)] / tau.

    A subclass gives ``velocity_command(state, target)`` -> [v*, omega*].
    """

    max_speed: float = 1.0
    distance_gain: float = 1.0
    heading_gain: float = 2.0
    max_turn_rate: float = 1.5
    time_constant: float = 0.3
    goal_tolerance: float = 0.1

    def turn_rate(self, angle):
        """Return omega* = clip(k_theta angle, +-omega_max)."""
        return min(max(self.heading_gain * angle, -self.max_turn_rate), self.max_turn_rate)

    def __call__(self, state, target):
        """Return the acceleration input [a, alpha] toward ``target`` (goal or path)."""
        return (self.velocity_command(state, target) - state[3:5]) / self.time_constant


@dataclass
class UnicycleGoalController(_UnicycleLaw):
    """Drive at v* = min(k_d dist, v_max) towards the goal, steer on the heading error.

    v* = min(k_d |e|, v_max),  omega* = k_theta wrap(atan2(e_y, e_x) - theta),
    u = [(v* - v) / tau, (omega* - omega) / tau]; the robot stops within ``goal_tolerance``.
    """

    def velocity_command(self, state, goal):
        """Return the desired [v, omega]."""
        x, y, theta = state[:3].tolist()   # floats: numpy scalars cost 3x here
        error_x, error_y = float(goal[0]) - x, float(goal[1]) - y
        distance = math.sqrt(error_x * error_x + error_y * error_y)
        if distance < self.goal_tolerance:
            return np.zeros(2)
        heading = math.atan2(error_y, error_x) - theta
        heading = (heading + math.pi) % (2 * math.pi) - math.pi
        speed = min(self.distance_gain * distance, self.max_speed) * max(math.cos(heading), 0.0)
        return np.array([speed, self.turn_rate(heading)])


class ReferencePath:
    """Waypoints (P, 2) with their arc lengths, and how far along them a follower is.

    Repeated consecutive waypoints are dropped.  ``progress`` [m of arc] only grows:
    ``advance`` moves it to the path point nearest the robot within a window ahead,
    so a path that passes near itself is not short-cut.
    """

    def __init__(self, points):
        """Take (P, 2) finite waypoints, P >= 1 (ValueError otherwise)."""
        points = np.asarray(points, dtype=float)
        if points.ndim != 2 or points.shape[1] != 2 or not len(points) \
                or not np.isfinite(points).all():
            raise ValueError(f'a path is (P >= 1, 2) finite points, got shape {points.shape}')
        keep = np.concatenate([[True], np.any(np.diff(points, axis=0) != 0.0, axis=1)])
        self.points = points[keep]
        lengths = np.hypot(*np.diff(self.points, axis=0).T)
        self.arc = np.concatenate([[0.0], np.cumsum(lengths)])
        # Per segment as floats (this runs every control period): start, edge, length, arc.
        self._segments = [(*a, *e, length, s) for a, e, length, s in zip(
            self.points[:-1].tolist(), np.diff(self.points, axis=0).tolist(),
            lengths.tolist(), self.arc[:-1].tolist())]
        self._starts = self.arc[:-1].tolist()
        self._end = tuple(self.points[-1].tolist())
        self.progress = 0.0

    @property
    def length(self):
        """Return the path's length [m]."""
        return float(self.arc[-1])

    def advance(self, position, window):
        """Move ``progress`` to the nearest point with arc in [progress, progress + window].

        Per segment i (start a_i at arc s_i, edge e_i of length L_i) the projection
        t = <p - a_i, e_i> / L_i^2 is clipped to the window's part of the segment.
        """
        x, y = float(position[0]), float(position[1])
        low_arc, high_arc = self.progress, self.progress + window
        first = max(bisect.bisect_right(self._starts, low_arc) - 1, 0)
        best, best_arc = math.inf, self.progress
        for ax, ay, ex, ey, length, start in self._segments[first:]:
            if start > high_arc:
                break
            low = max(low_arc - start, 0.0) / length
            high = min(high_arc - start, length) / length
            t = min(max(((x - ax) * ex + (y - ay) * ey) / (length * length), low), high)
            distance = math.hypot(x - ax - t * ex, y - ay - t * ey)
            if low <= high and distance < best:
                best, best_arc = distance, start + t * length
        self.progress = max(self.progress, best_arc)
        return self.progress

    def point_at(self, arc):
        """Return the path point (x, y) at arc length ``arc`` (clipped to the path's ends)."""
        index = bisect.bisect_right(self._starts, arc) - 1
        if index < 0 or not self._segments:
            return tuple(self.points[0].tolist())
        ax, ay, ex, ey, length, start = self._segments[index]
        if arc >= start + length:
            return self._end
        t = (arc - start) / length
        return ax + t * ex, ay + t * ey


@dataclass
class UnicyclePathController(_UnicycleLaw):
    """Pure pursuit along a ``ReferencePath``: steer on the arc through a point ahead.

    Progress s (``ReferencePath.advance`` within ``search`` m ahead); carrot c = path(s + L)
    with the speed-scaled look-ahead L = clip(``lookahead_time`` |v|, ``min_lookahead``,
    ``max_lookahead``) (slow in a turn, close to the path); (dx, dy) = c in the robot frame,
    d = |c - p|, alpha = atan2(dy, dx); r = d + (path length - s - L)^+ is what is left to
    drive.  Then::

        kappa  = 2 dy / d^2                           (the arc through p and c)
        v*     = min(v_max, k_d r, sqrt(a_lat / |kappa|), omega_max / |kappa|)
        omega* = v* kappa

    and where the carrot lies more than ``turn_in_place`` rad off the heading, v* = 0
    and omega* = clip(k_theta alpha, +-omega_max).  Within ``goal_tolerance`` of the
    path's end the robot stops; u = [(v* - v) / tau, (omega* - omega) / tau].
    """

    lookahead_time: float = 0.5
    min_lookahead: float = 0.15
    max_lookahead: float = 0.5
    search: float = 1.0
    max_lateral_accel: float = 0.5
    turn_in_place: float = 1.0

    def velocity_command(self, state, path):
        """Return the desired [v, omega] and advance ``path.progress``."""
        x, y, theta = state[:3].tolist()
        progress = path.advance((x, y), self.search)
        end_x, end_y = path.point_at(path.length)
        if (progress >= path.length - self.goal_tolerance
                and math.hypot(end_x - x, end_y - y) < self.goal_tolerance):
            return np.zeros(2)
        lookahead = min(max(self.lookahead_time * abs(state[3]), self.min_lookahead),
                        self.max_lookahead)
        carrot_x, carrot_y = path.point_at(progress + lookahead)
        carrot_x, carrot_y = carrot_x - x, carrot_y - y
        c, s = math.cos(theta), math.sin(theta)
        dx, dy = c * carrot_x + s * carrot_y, c * carrot_y - s * carrot_x
        distance = math.hypot(dx, dy)
        if distance < 1e-9:
            return np.zeros(2)
        alpha = math.atan2(dy, dx)
        if abs(alpha) > self.turn_in_place:
            return np.array([0.0, self.turn_rate(alpha)])
        left = distance + max(path.length - progress - lookahead, 0.0)
        curvature = 2.0 * dy / distance ** 2
        speed = min(self.max_speed, self.distance_gain * left)
        if curvature != 0.0:
            speed = min(speed, math.sqrt(self.max_lateral_accel / abs(curvature)),
                        self.max_turn_rate / abs(curvature))
        return np.array([speed, speed * curvature])


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
        state = np.ascontiguousarray(state, dtype=np.float64)
        _compiled_wrench()(state, np.ascontiguousarray(goal, dtype=np.float64),
                           float(self.position_gain), float(self.velocity_gain),
                           float(self.max_accel), float(self.attitude_gain),
                           float(self.rate_gain), float(self.mass), _INERTIA,
                           rotation_matrix(state[6], state[7], state[8]), wrench)
        return wrench

    def __call__(self, state, goal):
        """Return rotor thrusts (not clipped; the filter clips to the input box)."""
        return cf.thrusts_from_wrench(self.wrench(state, goal))


@functools.cache
def _compiled_wrench():
    """Return ``_quadrotor_wrench`` compiled by numba (on first use; cached on disk)."""
    import numba
    return numba.njit(**JIT_OPTIONS)(_quadrotor_wrench)


def _quadrotor_wrench(state, goal, position_gain, velocity_gain, max_accel, attitude_gain,
                      rate_gain, mass, inertia, rot, out):
    """Write ``QuadrotorGoalController``'s [T, tau] into ``out`` (law in the class docstring).

    e = goal - p; a* = k_p e scaled to norm <= a_max, - k_d v + g e_z; with R = ``rot``
    the body-to-world rotation and b = R e_z, T = m <a*, b>; e_R = R^T (b x a*/|a*|) in
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
