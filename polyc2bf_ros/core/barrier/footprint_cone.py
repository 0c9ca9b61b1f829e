"""The horizon cone of a footprint polygon that turns with the robot (design.md 3.11).

For a model whose footprint turns with its heading (``RobotModel.turns_footprint``: the
unicycle [x, y, theta, v, omega]) and a ``FilterConfig.footprint``, the filter guards the
polygon itself instead of a disc that covers it.  The footprint F (convex, CCW, body frame
about the axle c) at heading theta overlaps the obstacle part O (convex, CCW, translating
at o_dot) exactly when c lies inside the configuration polygon

    C(theta) = O + (-R(theta) F),     vertices V_k = o_i(k) - R f_j(k)

(``kernels.footprint.configuration_polygon``: the two edge sequences merged by angle, n + m
vertices at most).  So the bisector horizon cone of ``horizon_cone`` is taken on C(theta)
seen from c, with its vertices relative to c, P_k = V_k - c.  Unlike an inflated polygon's
they do not move alike when the robot turns:

    P_k_dot = o_dot - c_dot - omega J R f_j(k) = v + omega J R (f* - f_j(k)),
    v = o_dot - c_dot - omega J R f*,

v the relative velocity of the touching points: f* is the footprint point behind C's
boundary point nearest c, w = (1 - t) P_k + t P_k+1 = o* - (c + R f*), f* = (1 - t) f_j(k)
+ t f_j(k+1).  The barrier is ``horizon_cone``'s with the turning share of v faded out
over the covering radius r:

    h = L [<u, v_s> + |v_s|_e cc + (d / tau)(1 - cc)],    d = |w|,
    v_s = o_dot - c_dot - s omega J R f*,    s = max(0, 1 - d / r),

m = a_hat + b_hat over the silhouette rays a, b, u = m / |m|, cc = |m| / 2, L = |g|, g the
mean of the P_k.  (With s = 1 everywhere, measured on BARN with a Jackal, a turn made
every far part's row swing: the filter spun the box at its turn-rate limit and its QP
turned infeasible.  A part farther than r from the body cannot be reached by turning in
place.)  Its rate is

    h_dot = sum_k dh/dP_k . P_k_dot + dh/dv . v_s_dot,
    v_s_dot = -(a e + v omega J e) + s (-alpha J R f* + omega^2 R f* - omega J R f*_dot)
              - s_dot omega J R f*,

e = (cos theta, sin theta); f*_dot = t_dot (f_j(k+1) - f_j(k)) while t is inside (0, 1), 0
at a vertex; s_dot = -d_dot / r inside (0, r), d_dot = <w, v> / d (the nearest point moves
with the touching points).  dh/dP_k is inner g_hat / count for every vertex (through L),
plus, at the silhouette vertices, (I - a_hat a_hat^T) / |a| dh/dm, and at the nearest
edge's ends (1 - t) and t times L (1 - cc) w / (tau d) (through d).  alpha enters through
v_s: Lg h's steering column is -s dh/dv . J R f*, nonzero near a part wherever the touching
point is off the heading's line through c, so the filter may turn the body away as well
as brake.

Why h >= 0 excludes contact: the bodies touch first when c reaches C's boundary (d = 0).
There s = 1 and h = L [<u, v> + |v|_e cc] is eq. 7 with v the velocity of the touching body
point relative to the obstacle's, so h >= 0 forbids every such velocity into C (its silhouette
rays bound the tangent cone of C at the touching point), as in ``horizon_cone``.  Turning
is accounted for: a corner that sweeps towards a post is a touching point whose velocity
omega J R f* is in v.  A non-convex footprint is guarded by its convex hull
(``geometry.footprint``).

The braking check measures the footprint along the brake the same way: the signed
distance of the axle to C(theta_k) at each row is the bodies' distance
(``kernels.braking.path_clearance`` with a footprint), and its barrier test takes this h
at each row (``kernels.footprint_path.footprint_min_h_along``).  The moving parts' rows
are made robust to ``obstacle_accel`` and ``obstacle_velocity_error`` in the same pass, with
dh/do (rows 7-8 of the block: every vertex moved alike) in place of ``cone_barrier``'s dh/dp.
"""
import numpy as np

from polyc2bf_ros.core.barrier.cones import InflatedCone
from polyc2bf_ros.core.geometry.footprint import covering_radius
from polyc2bf_ros.core.kernels.footprint import _footprint_exits, _footprint_plane
from polyc2bf_ros.core.kernels.footprint_path import footprint_min_h_along, stop_sweeps_past


class FootprintCone(InflatedCone):
    """The bisector horizon cone of a turning footprint polygon (module docstring).

    ``footprint`` (m, 2) CCW about the axle, ``horizon`` tau; ``obstacle_accel``,
    ``velocity_error`` and ``gamma`` as ``FilterConfig``'s.  The prepared polygons are the
    parts themselves; ``exits`` are those of C(theta) at the heading of the last
    ``fill_plane`` (the escape of the same step): the axle's shortest way out of the
    region where the bodies overlap.  (Measured: taken from the part alone, seen from an
    axle outside it, the way out pointed at the part, and a box whose nose overlapped a
    scan obstacle drove on into the cylinders behind it, BARN from the laser.)
    """

    name = 'polyc2bf_footprint'

    def __init__(self, footprint, horizon=1.0, obstacle_accel=0.0, velocity_error=0.0,
                 gamma=1.0):
        """Keep the polygon (as pairs: the settings key the prepared views) and tau."""
        super().__init__(0.0)
        if not horizon > 0.0:
            raise ValueError(f'horizon must be positive (math.inf: none), got {horizon!r}')
        self.footprint = tuple((float(x), float(y)) for x, y in footprint)
        self.horizon, self.obstacle_accel = float(horizon), float(obstacle_accel)
        self.velocity_error, self.gamma = float(velocity_error), float(gamma)
        self._points = np.ascontiguousarray(np.array(self.footprint).T)
        self._cover = covering_radius(footprint)
        self._heading = 0.0  # of the last fill_plane: the escape's C(theta)

    @property
    def points(self):
        """Return the footprint as a (2, m) C-contiguous array (the kernels' layout)."""
        return self._points

    def fill_plane(self, prepared, projections, velocities, offsets, age, reference,
                   velocity_epsilon, block, valid, checked):
        """Run the footprint kernel at the state the reference was computed at."""
        self._heading = float(reference.state[2])
        kernel = _footprint_plane if checked else _footprint_plane.unchecked
        kernel(prepared.x, prepared.y, prepared.counts, self._points, reference.state,
               velocities, offsets, age, 1.0 / self.horizon,
               velocity_epsilon * velocity_epsilon, self.obstacle_accel, self.velocity_error,
               self.gamma, block, valid)

    def fill_exits(self, prepared, viewpoints, out):
        """Run the exit kernel on C(theta) (class docstring)."""
        _footprint_exits(prepared.x, prepared.y, prepared.counts, self._points, self._heading,
                         viewpoints, out)

    def stop_skipped(self, prepared, velocities, offsets, first_time, last_time, bands):
        """Return ``stop_sweeps_past`` (the kernel) on the axle's ``bands``."""
        return stop_sweeps_past.unchecked(bands, float(first_time), float(last_time),
                                          prepared.boxes, velocities, offsets, self._cover,
                                          1.0 / self.horizon)

    def min_h_along(self, prepared, velocities, offsets, age, start, path, period,
                    velocity_epsilon, checked=True):
        """Return h's minimum along an axle's braking path (``footprint_min_h_along``)."""
        kernel = footprint_min_h_along if checked else footprint_min_h_along.unchecked
        return kernel(prepared.x, prepared.y, prepared.counts, prepared.boxes, self._points,
                      self._cover, 1.0 / self.horizon, velocity_epsilon * velocity_epsilon,
                      velocities, offsets, float(age), start, path, float(period))
