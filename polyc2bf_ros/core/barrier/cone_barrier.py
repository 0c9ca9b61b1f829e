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
from dataclasses import dataclass

import numpy as np


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
