"""Kernels of ``barrier.cone_barrier``, whose docstring has the math.

The math in compiled form; every kernel lives in ``core/kernels`` (``jit.kernel_sources``).
"""
import math

from polyc2bf_ros.core.kernels.jit import F1, F2, F3, kernel, signature


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
