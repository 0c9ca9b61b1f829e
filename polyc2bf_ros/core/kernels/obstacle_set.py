"""Kernels of ``obstacles.obstacle_set``, whose docstring has the math.

The math in compiled form; every kernel lives in ``core/kernels`` (``jit.kernel_sources``).
"""
import math

from polyc2bf_ros.core.kernels.jit import F2, F3, kernel, signature


@kernel(signature('b1', F3, 'f8[:, :]', F2))
def _finite(vertices, velocities, z_ranges):
    """Return True when vertices and velocities are finite and no z bound is NaN."""
    for value in vertices.ravel():
        if not math.isfinite(value):
            return False
    for value in velocities.ravel():
        if not math.isfinite(value):
            return False
    for value in z_ranges.ravel():
        if math.isnan(value):
            return False
    return True
