"""Kernels of ``models.unicycle``, whose docstring has the math.

The math in compiled form; every kernel lives in ``core/kernels`` (``jit.kernel_sources``).
"""
import math

from polyc2bf_ros.core.kernels.jit import F1, F2, kernel, signature


@kernel(signature('void', F1, 'f8', F1, F1, F1, F2))
def _offset_point(x, offset, position, velocity, drift, input_matrix):
    """Write r, r_dot, drift and B of the point ``offset`` ahead of the axle (module docstring)."""
    px, py, theta, v, omega = x[0], x[1], x[2], x[3], x[4]
    c, s = math.cos(theta), math.sin(theta)
    position[0], position[1] = px + offset * c, py + offset * s
    velocity[0] = v * c - offset * omega * s
    velocity[1] = v * s + offset * omega * c
    drift[0] = -v * omega * s - offset * omega ** 2 * c
    drift[1] = v * omega * c - offset * omega ** 2 * s
    input_matrix[0, 0], input_matrix[0, 1] = c, -offset * s
    input_matrix[1, 0], input_matrix[1, 1] = s, offset * c



@kernel(signature('i8', F1, 'f8', F1, 'f8', 'f8', 'f8', F2))
def _braking_path(x, offset, limits, time_constant, coast, period, out):
    """Write the reference point's [x, y, vx, vy] along the brake into ``out``; return the rows.

    ``_brake`` from x, coasted ``coast`` s first (``_coast``), as many rows as ``out`` holds.
    """
    px, py, theta, v, omega = _coast(x[0], x[1], x[2], x[3], x[4], coast)
    return _brake(px, py, theta, v, omega, offset, limits, time_constant, period, out, 0,
                  out.shape[0])



@kernel(signature('i8', F1, F1, 'f8', F1, 'f8', 'f8', 'f8', F2))
def _braking_after(x, u, offset, limits, time_constant, coast, period, out):
    """Write the point at x+ and then along the brake from x+ into ``out``; return the rows.

    Or minus the rows needed, writing nothing past row 0, when ``out`` is shorter.

    x+ is x after holding ``u`` for ``period`` by the midpoint rule on x_dot (module
    docstring), as ``RobotModel.one_period`` computes it, operation for operation:
    middle = x + (T / 2) x_dot(x, u), x+ = x + T x_dot(middle, u).  Row 0 is the point at x+
    (``RobotModel.point_row``), rows 1.. ``_brake`` from x+ coasted ``coast`` s with as many
    rows as ``Unicycle.braking_path`` gives x+.
    """
    px, py, theta, v, omega = x[0], x[1], x[2], x[3], x[4]
    half = 0.5 * period
    mid_theta, mid_v = theta + half * omega, v + half * u[0]
    mid_omega = omega + half * u[1]
    px = px + period * (mid_v * math.cos(mid_theta))
    py = py + period * (mid_v * math.sin(mid_theta))
    theta, v, omega = theta + period * mid_omega, v + period * u[0], omega + period * u[1]
    _point_row(px, py, theta, v, omega, offset, out[0])
    stop = abs(v) / limits[0] + abs(omega) / limits[1]
    capacity = int(stop / period) + int(8 * time_constant / period) + 2
    if capacity + 1 > out.shape[0]:
        return -(capacity + 1)
    px, py, theta, v, omega = _coast(px, py, theta, v, omega, coast)
    return 1 + _brake(px, py, theta, v, omega, offset, limits, time_constant, period, out, 1,
                      capacity)



@kernel
def _coast(px, py, theta, v, omega, duration):
    """Return the state ``duration`` s on at constant v and omega (none for 0).

    The braking check's coast before each stop (``RobotModel.plan_braking``): ``_held_step``
    with no input, skipped at 0 so that a plan without one computes what it did before.
    """
    if duration > 0.0:
        return _held_step(px, py, theta, v, omega, 0.0, 0.0, duration)
    return px, py, theta, v, omega



@kernel
def _brake(px, py, theta, v, omega, offset, limits, time_constant, period, out, first,
           capacity):
    """Write the point's rows along the brake from a state to ``out[first:]``; return them.

    One midpoint step of the dynamics per period, the damped brake held over it
    (``damped_brake``; exact for a straight stop); ends at rest (|v|, |omega| < 1e-4)
    or after ``capacity`` rows.
    """
    rows = 0
    for k in range(capacity):
        a = min(max(-v / time_constant, -limits[0]), limits[0])
        alpha = min(max(-omega / time_constant, -limits[1]), limits[1])
        px, py, theta, v, omega = _held_step(px, py, theta, v, omega, a, alpha, period)
        _point_row(px, py, theta, v, omega, offset, out[first + k])
        rows = k + 1
        if abs(v) < 1e-4 and abs(omega) < 1e-4:
            break  # the rest of the damped stop moves the point by < 1e-4 time_constant
    return rows



@kernel
def _held_step(px, py, theta, v, omega, a, alpha, period):
    """Return the state one ``period`` on with (a, alpha) held.

    The midpoint rule, second order in T (exact for a straight stop).
    """
    heading = theta + 0.5 * period * (omega + 0.25 * period * alpha)
    travel = period * (v + 0.5 * period * a)
    return (px + travel * math.cos(heading), py + travel * math.sin(heading),
            theta + period * (omega + 0.5 * period * alpha), v + period * a,
            omega + period * alpha)



@kernel
def _point_row(px, py, theta, v, omega, offset, row):
    """Write the reference point's [x, y, vx, vy] at state (px, py, theta, v, omega) to ``row``.

    A longer row also gets theta, then omega (``unicycle.AxlePaths``).
    """
    c, s = math.cos(theta), math.sin(theta)
    row[0], row[1] = px + offset * c, py + offset * s
    row[2], row[3] = v * c - offset * omega * s, v * s + offset * omega * c
    if row.shape[0] > 5:
        row[4], row[5] = theta, omega



@kernel(signature('void', F1, 'f8', F1, 'f8', F2, F1))
def _held_path(x, offset, u, step, out, end):
    """Write the reference point's [x, y, vx, vy] with ``u`` held, one row per ``step``.

    And the state after the last row to ``end``.
    """
    px, py, theta, v, omega = x[0], x[1], x[2], x[3], x[4]
    for k in range(out.shape[0]):
        px, py, theta, v, omega = _held_step(px, py, theta, v, omega, u[0], u[1], step)
        _point_row(px, py, theta, v, omega, offset, out[k])
    end[0], end[1], end[2], end[3], end[4] = px, py, theta, v, omega
