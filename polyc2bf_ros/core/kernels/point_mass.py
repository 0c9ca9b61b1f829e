"""Kernels of ``models.point_mass``, whose docstring has the math.

The math in compiled form; every kernel lives in ``core/kernels`` (``jit.kernel_sources``).
"""
from polyc2bf_ros.core.kernels.jit import F1, F2, kernel, signature


@kernel(signature('i8', F1, 'f8', 'f8', 'f8', F2))
def _braking_path(x, limit, time_constant, period, out):
    """Write positions, then velocities along the per-axis damped brake into ``out``.

    Return the rows.

    Each period holds the brake's acceleration, as the node holds its input: exact steps.
    """
    dim = out.shape[1] // 2
    position, velocity = x[:dim].copy(), x[dim:].copy()
    rows = 0
    for k in range(out.shape[0]):
        moving = False
        for d in range(dim):
            accel = min(max(-velocity[d] / time_constant, -limit), limit)
            position[d] += period * (velocity[d] + 0.5 * period * accel)  # exact, a held
            velocity[d] += period * accel
            moving = moving or abs(velocity[d]) >= 1e-4  # then < 1e-4 time_constant to go
            out[k, d], out[k, dim + d] = position[d], velocity[d]
        rows = k + 1
        if not moving:
            break
    return rows
