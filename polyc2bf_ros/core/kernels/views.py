"""Kernels of ``geometry.views``, whose docstring has the math.

The math in compiled form; every kernel lives in ``core/kernels`` (``jit.kernel_sources``).
"""
import math

from polyc2bf_ros.core.kernels.jit import B1, F1, F2, F3, kernel, signature


@kernel
def viewpoint(projections, position, velocities, offsets, age, n):
    """Return (x, y) = P_n (r - age c_dot_n - o_n): the robot seen from obstacle n's frame."""
    x = y = 0.0
    for d in range(position.shape[0]):
        offset = position[d] - age * velocities[n, d] - offsets[n, d]
        x += projections[n, 0, d] * offset
        y += projections[n, 1, d] * offset
    return x, y



@kernel(signature('void', F3, F1, F2, F2, 'f8', F2))
def _viewpoints(projections, position, velocities, offsets, age, out):
    """Write every obstacle's ``viewpoint`` into the columns of ``out`` (2, N)."""
    for n in range(projections.shape[0]):
        out[0, n], out[1, n] = viewpoint(projections, position, velocities, offsets, age, n)



@kernel(signature('void', B1, F2, B1, F2, B1, F2, F2, F1, F2, F2, 'f8', B1, B1))
def _choose_planes(valid_h, k_h, valid_v, k_v, enabled_v, long_axes, band, position,
                   velocities, offsets, age, vertical, usable):
    """Per obstacle: is the vertical plane used, and is any cone usable (module docstring)."""
    for n in range(valid_h.shape[0]):
        along = (long_axes[n, 0] * (position[0] - age * velocities[n, 0] - offsets[n, 0])
                 + long_axes[n, 1] * (position[1] - age * velocities[n, 1] - offsets[n, 1]))
        candidate = valid_v[n] and enabled_v[n] and (
            not valid_h[n] or band[n, 0] <= along <= band[n, 1])
        rank_h = math.hypot(k_h[0, n], k_h[1, n]) if valid_h[n] else math.inf
        rank_v = math.hypot(k_v[0, n], k_v[1, n]) if candidate else math.inf
        vertical[n] = rank_v < rank_h
        usable[n] = valid_h[n] or candidate
