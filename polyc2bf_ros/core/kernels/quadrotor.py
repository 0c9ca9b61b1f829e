"""Kernels of ``models.quadrotor``, whose docstring has the math.

The math in compiled form; every kernel lives in ``core/kernels`` (``jit.kernel_sources``).
"""
import math

import numpy as np

from polyc2bf_ros.core.kernels.jit import F1, F2, kernel, signature


@kernel(signature(F2, 'f8', 'f8', 'f8'))
def rotation_matrix(roll, pitch, yaw):
    """Return R = Rz(yaw) Ry(pitch) Rx(roll), body to world."""
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    rot = np.empty((3, 3))
    rot[0, 0], rot[0, 1], rot[0, 2] = cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr
    rot[1, 0], rot[1, 1], rot[1, 2] = sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr
    rot[2, 0], rot[2, 1], rot[2, 2] = -sp, cp * sr, cp * cr
    return rot



@kernel
def _cross(a, b):
    """Return a x b for 3-tuples."""
    return a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]



@kernel
def _times(matrix, v):
    """Return matrix @ v for a 3 x 3 array and a 3-tuple, as a tuple."""
    return (matrix[0, 0] * v[0] + matrix[0, 1] * v[1] + matrix[0, 2] * v[2],
            matrix[1, 0] * v[0] + matrix[1, 1] * v[1] + matrix[1, 2] * v[2],
            matrix[2, 0] * v[0] + matrix[2, 1] * v[1] + matrix[2, 2] * v[2])



@kernel(signature('void', F1, F1, F2, F2, F2, 'f8', 'f8', F1, F1, F1, F2))
def _body_point(x, b, inertia, inertia_inv, torque_map, mass, gravity, position, velocity,
                drift, input_matrix):
    """Write r, r_dot, drift and B of the body point b (module docstring) into the outputs."""
    rot = rotation_matrix(x[6], x[7], x[8])
    w, b = (x[9], x[10], x[11]), (b[0], b[1], b[2])
    w_b = _cross(w, b)
    gyro = _times(inertia_inv, _cross(w, _times(inertia, w)))
    spin, tilt = _cross(w, w_b), _cross(b, gyro)
    offset, offset_rate = _times(rot, b), _times(rot, w_b)
    acceleration = _times(rot, (spin[0] + tilt[0], spin[1] + tilt[1], spin[2] + tilt[2]))
    for i in range(3):
        position[i] = x[i] + offset[i]
        velocity[i] = x[3 + i] + offset_rate[i]
        drift[i] = acceleration[i]
    drift[2] -= gravity
    for j in range(torque_map.shape[1]):
        arm = _times(rot, _cross(b, (torque_map[0, j], torque_map[1, j], torque_map[2, j])))
        for i in range(3):
            input_matrix[i, j] = rot[i, 2] / mass - arm[i]
