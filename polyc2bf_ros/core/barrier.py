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

from polyc2bf_ros.core.cones import dot2


@dataclass(frozen=True)
class BarrierTerms:
    """h (N,), Lf h (N,) and Lg h (m, N) for N cones (obstacle index last)."""

    h: np.ndarray
    lf_h: np.ndarray
    lg_h: np.ndarray


def barrier_terms(cones, v_rel, a_drift, b_rel, velocity_epsilon) -> BarrierTerms:
    """Evaluate h, Lf h, Lg h from planar (2, N) v_rel and a_drift and input map b_rel.

    ``a_drift`` may be (2, 1) (shared by all obstacles); ``b_rel`` is (2, m) shared,
    or (N, 2, m) per obstacle.
    """
    speed = np.sqrt(dot2(v_rel, v_rel) + velocity_epsilon ** 2)
    h = dot2(cones.p, v_rel) + speed * cones.s
    dh_dp = v_rel + speed * cones.ds_dp
    dh_dv = cones.p + (cones.s / speed) * v_rel
    lf_h = dot2(dh_dp, v_rel) + dot2(dh_dv, a_drift)
    if b_rel.ndim == 2:
        lg_h = b_rel.T @ dh_dv
    else:
        lg_h = np.einsum('in,nij->jn', dh_dv, b_rel)
    return BarrierTerms(h=h, lf_h=lf_h, lg_h=lg_h)
