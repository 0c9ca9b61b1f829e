"""The collision-cone barrier h and its Lie derivatives, for any cone model.

For relative position p (cone axis) and relative velocity v (paper eq. 9)::

    h = <p, v> + |v|_e s(p),        |v|_e = sqrt(|v|^2 + eps^2)

``|v|`` is not differentiable at v = 0, so the smooth norm |v|_e replaces it
(eps = ``velocity_epsilon``).  Since |v| <= |v|_e <= |v| + eps, the smoothed h
exceeds the paper's h by at most eps * s <= eps |p|: negligible once the
robot moves faster than eps, and at rest it lets the robot start moving.

Partial derivatives::

    dh/dp = v + |v|_e ds/dp
    dh/dv = p + (s / |v|_e) v

With p_dot = v and v_dot = a_drift + B u (both relative, projected into the
cone's plane), the CBF condition's terms are (paper eq. 2)::

    Lf h = <dh/dp, v> + <dh/dv, a_drift>,     Lg h = (dh/dv)^T B
"""
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class BarrierTerms:
    """h (N,), Lf h (N,) and Lg h (N, m) for N cones."""

    h: np.ndarray
    lf_h: np.ndarray
    lg_h: np.ndarray


def barrier_terms(cones, v_rel, a_drift, b_rel, velocity_epsilon) -> BarrierTerms:
    """Evaluate h, Lf h, Lg h for cones given v_rel (N,2), a_drift (N,2), b_rel (N,2,m)."""
    speed = np.sqrt(np.einsum('ij,ij->i', v_rel, v_rel) + velocity_epsilon ** 2)
    h = np.einsum('ij,ij->i', cones.p, v_rel) + speed * cones.s
    dh_dp = v_rel + speed[:, None] * cones.ds_dp
    dh_dv = cones.p + (cones.s / speed)[:, None] * v_rel
    lf_h = np.einsum('ij,ij->i', dh_dp, v_rel) + np.einsum('ij,ij->i', dh_dv, a_drift)
    lg_h = np.einsum('ij,ijk->ik', dh_dv, b_rel)
    return BarrierTerms(h=h, lf_h=lf_h, lg_h=lg_h)
