"""The collision-cone barrier h and its Lie derivatives, for any cone model.

For relative position p (cone axis) and relative velocity v (paper eq. 7)::

    h = <p, v> + |v|_e s(p),        |v|_e = sqrt(|v|^2 + eps^2)

``|v|`` is not differentiable at v = 0, so the smooth norm |v|_e replaces it
(eps = ``velocity_epsilon``).  Since |v| <= |v|_e <= |v| + eps, the smoothed h
exceeds the paper's h by at most eps * s <= eps |p|: negligible once the
robot moves faster than eps, and at rest it lets the robot start moving.

Partial derivatives::

    dh/dp = v + |v|_e ds/dp
    dh/dv = p + (s / |v|_e) v

Relative kinematics in the cone's plane (paper eq. 14-16): each obstacle n
has a constant projection P_n (2 x d) onto its plane, translates at c_dot_n,
and the robot's reference point moves with r_dot and r_ddot = drift + B u, so
p_dot = v and::

    v = P_n (c_dot_n - r_dot),     v_dot = a + B_n u,   a = -P_n drift,   B_n = -P_n B

With these the CBF condition's terms are (paper eq. 2)::

    Lf h = <dh/dp, v> + <dh/dv, a>,     Lg h = B_n^T dh/dv

Obstacles that accelerate (other robots): the terms take c_dot_n as constant, but a
moving obstacle changes it by c_ddot_n, adding <dh/dv, P_n c_ddot_n> to h_dot.  With
|c_ddot_n| <= a_o (``obstacle_accel``) the worst case is -a_o |dh/dv|, so the robust
row uses Lf h - a_o |dh/dv| for every part that moves (``tighten_for_obstacle_accel``).
dh/dv = p + (s / |v|_e) v holds for every cone model here: the horizon term does not
depend on v, and the bisector cone's L (u + c v / |v|_e) is the same with p = L u,
s = L c.  A part at rest is taken to stay at rest, as everywhere else in the filter.

Velocities that are estimated (tracked scans, marker poses): the true c_dot_n is the
estimate plus an error delta with |delta| <= e (``obstacle_velocity_error``).  h is convex
in v wherever s >= 0 (a linear term plus |v|_e s), so the true h >= h - e |dh/dv|, and to
first order the error moves h_dot by <dh/dp, delta>, at least -e |dh/dp|.  The row
Lf h + Lg h u + gamma h >= m then holds for every such delta when Lf h is lowered by
e (|dh/dp| + gamma |dh/dv|) as well, with dh/dp = v + |v|_e ds/dp (the cone's part; the
horizon term's own gradient, of order d / tau, does not depend on the velocity).
"""
import math
from dataclasses import dataclass

import numpy as np

from polyc2bf_ros.core.kernels.jit import F1, F2, F3, kernel, signature


@dataclass(slots=True)
class BarrierTerms:
    """h (N,), Lf h (N,) and Lg h (m, N) for N cones (obstacle index last)."""

    h: np.ndarray
    lf_h: np.ndarray
    lg_h: np.ndarray

    @classmethod
    def from_block(cls, block):
        """Return terms viewing a (2 + m, N) block: rows h, Lf h, Lg h (no copy)."""
        return cls(h=block[0], lf_h=block[1], lg_h=block[2:])


@kernel
def plane_motion(projections, velocities, position_rate, drift, n):
    """Return (vx, vy, ax, ay): obstacle n's v = P_n (c_dot_n - r_dot) and a = -P_n drift."""
    vx = vy = ax = ay = 0.0
    for d in range(position_rate.shape[0]):
        rate = velocities[n, d] - position_rate[d]
        vx += projections[n, 0, d] * rate
        vy += projections[n, 1, d] * rate
        ax -= projections[n, 0, d] * drift[d]
        ay -= projections[n, 1, d] * drift[d]
    return vx, vy, ax, ay


@kernel
def store_input_column(projections, input_matrix, dh_dvx, dh_dvy, out, first, n):
    """Write Lg h = B_n^T dh/dv = -(P_n B)^T dh/dv into rows ``first``... of column ``n``."""
    dim, inputs = input_matrix.shape
    for j in range(inputs):
        bx = by = 0.0
        for d in range(dim):
            bx += projections[n, 0, d] * input_matrix[d, j]
            by += projections[n, 1, d] * input_matrix[d, j]
        out[first + j, n] = -(bx * dh_dvx + by * dh_dvy)


@kernel
def barrier_column(px, py, shape, ds_dpx, ds_dpy, projections, velocities, position_rate,
                   drift, input_matrix, eps_sq, out, first, n):
    """Write h, Lf h, Lg h of one cone into rows ``first``... of column ``n`` of ``out``.

    The cone of obstacle n is given by p = (px, py), s = ``shape`` and ds/dp, the obstacles'
    projections P (N, 2, d) and velocities c_dot (N, d) (see the module docstring).
    Return (vx, vy), the relative velocity v.
    """
    vx, vy, ax, ay = plane_motion(projections, velocities, position_rate, drift, n)
    speed = math.sqrt(vx * vx + vy * vy + eps_sq)
    dh_dpx, dh_dpy = vx + speed * ds_dpx, vy + speed * ds_dpy
    dh_dvx, dh_dvy = px + (shape / speed) * vx, py + (shape / speed) * vy
    out[first, n] = px * vx + py * vy + speed * shape
    out[first + 1, n] = dh_dpx * vx + dh_dpy * vy + (dh_dvx * ax + dh_dvy * ay)
    store_input_column(projections, input_matrix, dh_dvx, dh_dvy, out, first + 2, n)
    return vx, vy


@kernel(signature('void', F2, 'i8', F3, F2, F1, 'f8', 'f8', 'f8', 'f8'))
def tighten_for_obstacle_accel(block, first, projections, velocities, position_rate, eps_sq,
                               accel, velocity_error, gamma):
    """Make the rows of every moving part robust to its acceleration and velocity error.

    Lf h (row ``first`` + 1) loses ``accel`` |dh/dv| + ``velocity_error`` (|dh/dp| +
    ``gamma`` |dh/dv|) (module docstring).  ``block`` is a plane block with p in rows 2-3,
    s in row 6 and ds/dp in rows 7-8 (``cones.PLANE_ROWS`` layout); v = P_n (c_dot_n -
    r_dot) as in ``plane_motion``.
    """
    for n in range(block.shape[1]):
        moving = False
        for d in range(velocities.shape[1]):
            moving = moving or velocities[n, d] != 0.0
        if not moving:
            continue
        # Only v is needed: the drift argument (position_rate again) is ignored.
        vx, vy, _, _ = plane_motion(projections, velocities, position_rate, position_rate, n)
        speed = math.sqrt(vx * vx + vy * vy + eps_sq)
        scale = block[6, n] / speed
        gx, gy = block[2, n] + scale * vx, block[3, n] + scale * vy
        dh_dv = math.sqrt(gx * gx + gy * gy)
        px, py = vx + speed * block[7, n], vy + speed * block[8, n]
        dh_dp = math.sqrt(px * px + py * py)
        block[first + 1, n] -= accel * dh_dv + velocity_error * (dh_dp + gamma * dh_dv)
