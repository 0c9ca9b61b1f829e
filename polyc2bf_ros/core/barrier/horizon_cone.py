"""Horizon-aware PolyC2BF: only what the robot could reach within a horizon tau constrains it.

The paper's barrier (eq. 7) forbids every relative velocity inside an obstacle's cone,
however far the obstacle is: in clutter the union of far cones closes every direction.
This model adds a term that vanishes on the obstacle's boundary and grows with the
distance d from the viewpoint q to the (inflated) polygon::

    h_tau = <p, v> + |v|_e s + (d / tau) (|p| - s)

with the cone's axis p, shape s = <p, k_hat> = |p| cos(phi) and relative velocity v
(``polyc2bf_ros.core.barrier.cone_barrier``).  Properties:

* **tau = inf gives eq. 7 exactly** (the term is 0 * finite = 0, bit for bit).
* **Time-to-contact reading.** Head on, v = -c p_hat (closing at speed c):
  h_tau = (|p| - s)(d / tau - c), so h_tau >= 0 iff d / c >= tau: a closing velocity is
  allowed exactly when contact is more than tau away, the velocity-obstacle truncation of
  ORCA.  Off axis the allowed closing speed grows towards the cone's boundary, where every
  speed is allowed, as in eq. 7.
* **h_tau >= 0 still excludes contact.** |p| - s >= 0 and d >= 0 outside, so the term is
  >= 0 and h_tau >= h; it vanishes as d -> 0.  At a first contact time t* (d = 0) we have
  h_tau = h >= 0, which forbids every velocity strictly into the obstacle (every such
  velocity lies inside the cone, whose rays then bound the tangent cone of the boundary):
  the reference point cannot cross into the inflated polygon, exactly as with eq. 7.
  Near the boundary the allowed closing speed is about d / tau, so d decays at most
  exponentially, d(t) >= d(0) exp(-t / tau), as long as h_tau >= 0 holds.
* **Braking.**  That speed profile needs a deceleration of only c^2 / d = d / tau^2 to
  follow, at most ``max_accel`` for d <= max_accel tau^2 (2 m for 2 m/s^2 and tau = 1 s).

d is the distance to the inflated polygon (``cones.nearest_edge``); with o = q - c(q) its
offset from the nearest point and x the obstacle's position relative to q (x_dot = v),
grad_x d = -o / |o|.  So, with the cone's own gradient ds/dx::

    grad_x h_tau = grad_x h + [(|p| - s) grad_x d + d (grad_x |p| - ds/dx)] / tau

and the term adds only to Lf h (it does not depend on v).

Two cone axes (``axis``), both on the inflated polygon (``cones.InflatedCone``):

* ``midpoint``: the paper's cone, p from q to the silhouette segment's midpoint, the
  half-angle to the closer vertex (``cones.midpoint_cone``).  It covers past the far
  vertex: near one end of a long wall it forbids sliding along it towards the other end.
  p jumps when the silhouette vertex pair switches, and h with it.
* ``bisector``: the tightest cone, the exact silhouette.  In the plane a cone is fixed by
  its two rays a = A - q, b = B - q and is symmetric about their bisector:
  u = m / |m|, m = a_hat + b_hat, half-angle cos = c = |m| / 2.  The axis is scaled by
  L = |g|, the distance from q to the polygon's vertex mean g (inside the polygon):
  p = L u, s = L c.  Rays, u, c and L are continuous in q (a silhouette switch swaps
  vertices on the same ray), so h is continuous too, unlike the midpoint cone's.
  With M = (I - a_hat a_hat^T) / |a| + (I - b_hat b_hat^T) / |b| = dm/dx::

      h = L [<u, v> + |v|_e c + (d / tau)(1 - c)]
      grad_x h = g_hat (h / L) + L [M (I - u u^T) v / |m| + |v|_e M u / 2
                                    + ((1 - c) grad_x d - d M u / 2) / tau]
      dh/dv = L (u + c v / |v|_e)

  The cone rows hold p = L u, k = the closer of a, b, s = L c and, in place of ds/dp,
  ds/dx = c g_hat + L M u / 2.
"""

from polyc2bf_ros.core.barrier.cones import InflatedCone
from polyc2bf_ros.core.kernels.horizon import (
    _horizon_cones,
    _horizon_plane,
    min_h_along,
    stop_heads_past,
)

AXES = ('midpoint', 'bisector')


class HorizonCone(InflatedCone):
    """Horizon-aware PolyC2BF on the inflated polygon (module docstring).

    ``horizon`` tau in seconds (``math.inf``: the paper's eq. 7 on the inflated polygon),
    ``axis`` one of ``AXES``.
    """

    name = 'polyc2bf_horizon'

    def __init__(self, robot_radius, segments=16, horizon=1.0, axis='bisector'):
        """Inflate by ``robot_radius`` (``segments``-gon); keep tau and the axis."""
        super().__init__(robot_radius, segments)
        if not horizon > 0.0:
            raise ValueError(f'horizon must be positive (math.inf: none), got {horizon!r}')
        if axis not in AXES:
            raise ValueError(f'cone axis must be one of {AXES}, got {axis!r}')
        self.horizon, self.axis = float(horizon), axis

    def fill(self, prepared, viewpoints, block, valid):
        """Run the cone kernel of the chosen axis."""
        _horizon_cones(prepared.x, prepared.y, prepared.edge_x, prepared.edge_y,
                       prepared.inv_sq, prepared.counts, viewpoints, self.axis == 'bisector',
                       block, valid)

    def min_h_along(self, prepared, velocities, offsets, age, start, path, period,
                    velocity_epsilon, checked=True):
        """Return h_tau's minimum along a braking path (``min_h_along``, the kernel)."""
        kernel = min_h_along if checked else min_h_along.unchecked
        return kernel(prepared.x, prepared.y, prepared.edge_x, prepared.edge_y,
                      prepared.inv_sq, prepared.counts, prepared.boxes, 1.0 / self.horizon,
                      self.axis == 'bisector', velocities, offsets, float(age), start, path,
                      float(period), velocity_epsilon * velocity_epsilon)

    def stop_skipped(self, prepared, velocities, offsets, first_time, last_time, bands):
        """Return ``stop_heads_past`` (the kernel); False on the midpoint axis (no pruning)."""
        return self.axis == 'bisector' and stop_heads_past.unchecked(
            bands, float(first_time), float(last_time), prepared.boxes, velocities, offsets,
            1.0 / self.horizon)

    def fill_plane(self, prepared, projections, velocities, offsets, age, reference,
                   velocity_epsilon, block, valid, checked):
        """Run the fused horizon kernel."""
        kernel = _horizon_plane if checked else _horizon_plane.unchecked
        kernel(prepared.x, prepared.y, prepared.edge_x, prepared.edge_y, prepared.inv_sq,
               prepared.counts, prepared.hints, 1.0 / self.horizon, self.axis == 'bisector',
               projections, reference.position, velocities, offsets, age, reference.velocity,
               reference.drift, reference.input_matrix, velocity_epsilon, block, valid)
