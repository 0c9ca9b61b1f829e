"""Kernels of ``models.unicycle``, whose docstring has the math.

The math in compiled form; every kernel lives in ``core/kernels`` (``jit.kernel_sources``).
"""
import math

from polyc2bf_ros.core.kernels.braking import product_range
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
    px, py, theta, v, omega = _one_period(x, u, period)
    _point_row(px, py, theta, v, omega, offset, out[0])
    capacity = _stop_rows(v, omega, limits, time_constant, period)
    if capacity + 1 > out.shape[0]:
        return -(capacity + 1)
    px, py, theta, v, omega = _coast(px, py, theta, v, omega, coast)
    return 1 + _brake(px, py, theta, v, omega, offset, limits, time_constant, period, out, 1,
                      capacity)



@kernel
def _one_period(x, u, period):
    """Return x+ = (x, y, theta, v, omega) after holding ``u`` for ``period`` (midpoint rule).

    middle = x + (T / 2) x_dot(x, u), x+ = x + T x_dot(middle, u), as
    ``RobotModel.one_period`` computes it, operation for operation.
    """
    px, py, theta, v, omega = x[0], x[1], x[2], x[3], x[4]
    half = 0.5 * period
    mid_theta, mid_v = theta + half * omega, v + half * u[0]
    mid_omega = omega + half * u[1]
    px = px + period * (mid_v * math.cos(mid_theta))
    py = py + period * (mid_v * math.sin(mid_theta))
    return px, py, theta + period * mid_omega, v + period * u[0], omega + period * u[1]



@kernel
def _stop_rows(v, omega, limits, time_constant, period):
    """Return how many rows ``_brake`` may write from speed v and turn rate omega."""
    stop = abs(v) / limits[0] + abs(omega) / limits[1]
    return int(stop / period) + int(8 * time_constant / period) + 2



@kernel(signature('i8', F1, F1, 'f8', F1, 'f8', 'f8', 'f8', F2))
def _stop_bands(x, u, offset, limits, time_constant, coast, period, out):
    """Write bounds of every row ``_braking_after`` writes into ``out``; return their count.

    Without computing a row (``RobotModel.stop_bands``).  From x+ = (p, theta, v, omega)
    (``_one_period``) the coast and the brake keep the signs of v and omega and shrink
    them (T <= tau: ``_brake`` never overshoots), so every row has |v_k| <= |v| = V and
    |omega_k| <= |omega| = W.  Each step moves the axle T (v_k + v_k+1) / 2 along a
    heading between theta_k and theta_k+1: at the limit a the steps telescope to
    (v_k^2 - v_k+1^2) / (2 a), and once |v| <= a tau they shrink geometrically by
    1 - T / tau, so the axle travels at most D = V c + V^2 / (2 a) + min(V, a tau) tau
    (c the coast) and turns at most Th, the same with W and alpha, all one way.  So
    every heading lies in I = [theta, theta + sign(omega) Th], the axle within
    sign(v) [0, D] {(cos h, sin h): h in I} of p's box, the point ``offset`` l
    ahead l (cos I, sin I) further, and its velocity v_k (cos, sin) + l omega_k (-sin,
    cos) in the products of those ranges.  Row b of ``out`` (``path_groups``' columns):
    that position box and the velocity box of the rows whose |v_k| lies in
    [V / 2^(b+1), V / 2^b] (the last row: [0, V / 2^b]); a bound of the largest |v|^2 in
    column 8, and of |omega| in column 9.  Every bound is widened by 1e-9 of its scale,
    far above the rounding of rows computed over 10^5 steps.
    """
    px, py, theta, v, omega = _one_period(x, u, period)
    speed, turn = abs(v), abs(omega)
    rows = 1 + _stop_rows(v, omega, limits, time_constant, period)
    travel = speed * coast + speed * speed / (2.0 * limits[0]) \
        + min(speed, limits[0] * time_constant) * time_constant
    swing = turn * coast + turn * turn / (2.0 * limits[1]) \
        + min(turn, limits[1] * time_constant) * time_constant
    travel, swing = travel * (1.0 + 1e-9) + 1e-12, swing * (1.0 + 1e-9) + 1e-12
    first, last = (theta, theta + swing) if omega >= 0.0 else (theta - swing, theta)
    low_c, high_c, low_s, high_s = _cos_sin_ranges(first, last)
    way = travel if v >= 0.0 else -travel
    low_dx, high_dx = min(0.0, way * low_c, way * high_c), max(0.0, way * low_c, way * high_c)
    low_dy, high_dy = min(0.0, way * low_s, way * high_s), max(0.0, way * low_s, way * high_s)
    low_ox, high_ox = min(offset * low_c, offset * high_c), max(offset * low_c, offset * high_c)
    low_oy, high_oy = min(offset * low_s, offset * high_s), max(offset * low_s, offset * high_s)
    widen = 1e-9 * (1.0 + abs(px) + abs(py) + travel + abs(offset))
    low_x, high_x = px + low_dx + low_ox - widen, px + high_dx + high_ox + widen
    low_y, high_y = py + low_dy + low_oy - widen, py + high_dy + high_oy + widen
    spin = (0.0, offset * omega) if offset * omega >= 0.0 else (offset * omega, 0.0)
    spin_c = product_range(spin[0], spin[1], low_c, high_c)
    spin_s = product_range(spin[0], spin[1], low_s, high_s)
    blur = 1e-9 * (1.0 + speed + abs(offset) * turn)
    bands = out.shape[0]
    for b in range(bands):
        top = speed * 0.5 ** b
        bottom = 0.0 if b == bands - 1 else 0.5 * top
        drive = (bottom, top) if v >= 0.0 else (-top, -bottom)
        drive_c = product_range(drive[0], drive[1], low_c, high_c)
        drive_s = product_range(drive[0], drive[1], low_s, high_s)
        low_vx, high_vx = drive_c[0] - spin_s[1] - blur, drive_c[1] - spin_s[0] + blur
        low_vy, high_vy = drive_s[0] + spin_c[0] - blur, drive_s[1] + spin_c[1] + blur
        out[b, 0], out[b, 1], out[b, 2], out[b, 3] = low_x, high_x, low_y, high_y
        out[b, 4], out[b, 5], out[b, 6], out[b, 7] = low_vx, high_vx, low_vy, high_vy
        out[b, 8] = max(low_vx * low_vx, high_vx * high_vx) \
            + max(low_vy * low_vy, high_vy * high_vy)
        out[b, 9] = turn * (1.0 + 1e-9)
    return rows



@kernel
def _cos_sin_ranges(first, last):
    """Return (low cos, high cos, low sin, high sin) over headings in [first, last].

    The ends' values, and +-1 where the range holds an extreme (tested on the range
    widened by 1e-9 rad); widened by 1e-12 for the rounding of cos and sin.
    """
    if last - first >= 2.0 * math.pi:
        return -1.0, 1.0, -1.0, 1.0
    c0, c1, s0, s1 = math.cos(first), math.cos(last), math.sin(first), math.sin(last)
    low_c, high_c = min(c0, c1) - 1e-12, max(c0, c1) + 1e-12
    low_s, high_s = min(s0, s1) - 1e-12, max(s0, s1) + 1e-12
    if _holds_angle(first, last, 0.0):
        high_c = 1.0
    if _holds_angle(first, last, math.pi):
        low_c = -1.0
    if _holds_angle(first, last, 0.5 * math.pi):
        high_s = 1.0
    if _holds_angle(first, last, -0.5 * math.pi):
        low_s = -1.0
    return max(low_c, -1.0), min(high_c, 1.0), max(low_s, -1.0), min(high_s, 1.0)



@kernel
def _holds_angle(first, last, angle):
    """Return True when [first - 1e-9, last + 1e-9] holds angle + 2 pi k for some k."""
    turns = math.ceil((first - 1e-9 - angle) / (2.0 * math.pi))
    return angle + 2.0 * math.pi * turns <= last + 1e-9



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
