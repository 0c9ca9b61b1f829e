r"""Crazyflie 2.1 constants, rotor layout and mixer: the one place for them.

Shared by the filter's quadrotor model and the PyBullet plant, so both agree
on which rotor rolls the vehicle which way.

Public Crazyflie 2.x parameters: mass 0.027 kg, arm 0.0397 m (centre to
rotor), Ixx = Iyy = 1.4e-5, Izz = 2.17e-5 kg m^2, kf = 3.16e-10 N/rpm^2,
km = 7.94e-12 N m/rpm^2, thrust-to-weight ratio 2.25.

Rotor layout ("X" configuration, body x forward, y left, z up), numbered
clockwise seen from above, starting front-right::

        4 (+x,+y)   1 (+x,-y)
              \   /
               [ ]          rotors 1 and 3 spin clockwise, 2 and 4 counter-clockwise
              /   \
        3 (-x,+y)   2 (-x,-y)

A rotor spinning clockwise (seen from above) pushes the body
counter-clockwise, so its yaw reaction torque is ``+c_tau f``.

Mixer (the input matrix of paper eq. 13, generalised from its "+" layout to the X
layout)::

    [T, tau_x, tau_y, tau_z]^T = M f,   M = [[1,     1,     1,     1    ],
                                             [y_1,   y_2,   y_3,   y_4  ],
                                             [-x_1, -x_2,  -x_3,  -x_4  ],
                                             [s_1 c, s_2 c, s_3 c, s_4 c]]

with rotor positions (x_i, y_i), spin signs s_i and c = km / kf [m].
"""
import numpy as np

GRAVITY = 9.81
MASS = 0.027
ARM = 0.0397
INERTIA = np.diag([1.4e-5, 1.4e-5, 2.17e-5])
KF = 3.16e-10
KM = 7.94e-12
THRUST_TO_WEIGHT = 2.25
TORQUE_PER_THRUST = KM / KF
MAX_ROTOR_THRUST = THRUST_TO_WEIGHT * MASS * GRAVITY / 4.0
HOVER_ROTOR_THRUST = MASS * GRAVITY / 4.0
# Collision radius of the airframe (rotor tip to centre), used as robot radius.
BODY_RADIUS = 0.065

_half = ARM / np.sqrt(2.0)
ROTOR_POSITIONS = np.array([
    [_half, -_half, 0.0],
    [-_half, -_half, 0.0],
    [-_half, _half, 0.0],
    [_half, _half, 0.0],
])
ROTOR_SPIN = np.array([1.0, -1.0, 1.0, -1.0])

MIXER = np.vstack([
    np.ones(4),
    ROTOR_POSITIONS[:, 1],
    -ROTOR_POSITIONS[:, 0],
    ROTOR_SPIN * TORQUE_PER_THRUST,
])
MIXER_INVERSE = np.linalg.inv(MIXER)


def wrench_from_thrusts(thrusts):
    """Map rotor thrusts f (4,) [N] to [T, tau_x, tau_y, tau_z] = M f."""
    return MIXER @ np.asarray(thrusts, dtype=float)


def thrusts_from_wrench(wrench):
    """Map [T, tau_x, tau_y, tau_z] to rotor thrusts f = M^-1 w (not clipped)."""
    return MIXER_INVERSE @ np.asarray(wrench, dtype=float)
