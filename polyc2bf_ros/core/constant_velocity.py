"""Constant-velocity Kalman filter in the plane: state ``[x, y, vx, vy]``, position measured.

numpy only, written here: the matrices are 4 x 4 and the equations below are the whole
filter, so a Kalman-filter library (none is in the project's pins) would cost a dependency
and per-call overhead for no gain.  Used per key (``predict``, ``update``, ``initial`` on one
state) and for many tracks at once (``predict_all``, ``update_rows``: compiled kernels, the
same equations, state arrays changed in place).

Model (white-noise acceleration: the acceleration is white noise of spectral density
``q = accel_std^2`` [m^2 s^-3] on each axis, independently)::

    x_k = F x_{k-1} + w,   F = [[I, dt I], [0, I]],   w ~ N(0, Q),
    Q = q [[dt^3 / 3 I, dt^2 / 2 I], [dt^2 / 2 I, dt I]]       (I: the 2 x 2 identity)

so over a time ``dt`` the velocity's variance grows by ``q dt`` per axis: a velocity that
really changes at ``a`` [m/s^2] is followed with a lag of about ``a / accel_std`` seconds'
worth of change when measurements are precise.  Measurement ``z = H x + v``, ``H = [I, 0]``,
``v ~ N(0, R)`` with R the 2 x 2 position covariance.

- ``predict``: ``x <- F x``, ``P <- F P F^T + Q`` (dt >= 0).
- ``update``: innovation ``y = z - H x``, ``S = H P H^T + R``, gain ``K = P H^T S^-1``,
  ``x <- x + K y``, ``P <- (I - K H) P (I - K H)^T + K R K^T`` (Joseph form: symmetric and
  positive definite in floating point whenever P and R are), then symmetrised.
- ``initial``: ``x = [z, 0, 0]``, ``P = diag(R, speed_std^2 I)``: the position as measured,
  the velocity unknown with standard deviation ``speed_std`` per axis.

``velocity_std``: the square root of the largest eigenvalue of the velocity block
``P_vv = [[a, b], [b, c]]``, ``(a + c) / 2 + sqrt(((a - c) / 2)^2 + b^2)``: the standard
deviation of the velocity along its worst-known axis.
"""
import math

import numpy as np

from polyc2bf_ros.core.jit import F2, F3, I1, kernel, signature


def _check_time_step(dt, accel_std):
    """Raise ValueError unless ``dt >= 0`` and ``accel_std >= 0`` are finite."""
    if not (math.isfinite(dt) and dt >= 0):
        raise ValueError(f'dt must be a finite number >= 0, got {dt!r}')
    if not (math.isfinite(accel_std) and accel_std >= 0):
        raise ValueError(f'accel_std must be a finite number >= 0, got {accel_std!r}')


def transition(dt):
    """Return F (4, 4): positions advance by ``dt`` times the velocities."""
    matrix = np.eye(4)
    matrix[0, 2] = matrix[1, 3] = dt
    return matrix


def process_noise(dt, accel_std):
    """Return Q (4, 4) of white-noise acceleration with ``q = accel_std^2`` (module docstring)."""
    q = accel_std * accel_std
    block = q * np.array([[dt ** 3 / 3.0, dt ** 2 / 2.0], [dt ** 2 / 2.0, dt]])
    return np.kron(block, np.eye(2))


def initial(z, R, speed_std):
    """Return (x, P) of a track first measured at ``z`` (2,) with covariance ``R`` (2, 2)."""
    state = np.zeros(4)
    state[:2] = z
    covariance = np.zeros((4, 4))
    covariance[:2, :2] = R
    covariance[2, 2] = covariance[3, 3] = speed_std * speed_std
    return state, covariance


def predict(x, P, dt, accel_std):
    """Return (F x, F P F^T + Q) after ``dt`` >= 0 seconds (module docstring)."""
    _check_time_step(dt, accel_std)
    transition_matrix = transition(dt)
    covariance = transition_matrix @ P @ transition_matrix.T + process_noise(dt, accel_std)
    return transition_matrix @ x, 0.5 * (covariance + covariance.T)


def update(x, P, z, R):
    """Return (x, P) after measuring position ``z`` (2,) with covariance ``R`` (Joseph form)."""
    x, P = np.asarray(x, dtype=float), np.asarray(P, dtype=float)
    innovation = np.asarray(z, dtype=float) - x[:2]
    S = P[:2, :2] + R
    gain = np.linalg.solve(S, P[:2, :]).T  # P H^T S^-1, with S and P symmetric
    state = x + gain @ innovation
    reduce = np.eye(4)
    reduce[:, :2] -= gain
    covariance = reduce @ P @ reduce.T + gain @ R @ gain.T
    return state, 0.5 * (covariance + covariance.T)


def velocity_std(P):
    """Return the standard deviation of the velocity along its worst axis (module docstring)."""
    a, b, c = P[2, 2], P[2, 3], P[3, 3]
    return math.sqrt(max(0.5 * (a + c) + math.hypot(0.5 * (a - c), b), 0.0))


@kernel(signature('void', F2, F3, 'f8', 'f8'))
def predict_all(states, covariances, dt, accel_std):
    """Predict every track (rows of ``states`` (T, 4), ``covariances`` (T, 4, 4)) in place.

    ``P <- F P F^T + Q`` by blocks: ``P_pp += dt (P_pv + P_vp) + dt^2 P_vv + q dt^3 / 3 I``,
    ``P_pv += dt P_vv + q dt^2 / 2 I``, ``P_vv += q dt I`` (right-hand sides: the old P).
    """
    q = accel_std * accel_std
    for t in range(states.shape[0]):
        state, P = states[t], covariances[t]
        state[0] += dt * state[2]
        state[1] += dt * state[3]
        for i in range(2):
            for j in range(2):
                P[i, j] += dt * (P[i, 2 + j] + P[2 + i, j]) + dt * dt * P[2 + i, 2 + j]
        for i in range(2):
            for j in range(2):
                P[i, 2 + j] += dt * P[2 + i, 2 + j]
                P[2 + j, i] = P[i, 2 + j]
        for i in range(2):
            P[i, i] += q * dt * dt * dt / 3.0
            P[i, 2 + i] += q * dt * dt / 2.0
            P[2 + i, i] += q * dt * dt / 2.0
            P[2 + i, 2 + i] += q * dt


@kernel(signature('void', F2, F3, I1, F2, F3))
def update_rows(states, covariances, rows, measurements, noises):
    """Update track ``rows[m]`` with position ``measurements[m]``, covariance ``noises[m]``.

    In place, as ``update`` (Joseph form, symmetrised); ``S^-1`` is the closed-form inverse
    of the 2 x 2 ``S = P_pp + R``.
    """
    gain = np.empty((4, 2))
    reduce = np.empty((4, 4))
    product = np.empty((4, 4))
    for m in range(rows.shape[0]):
        state, P, R = states[rows[m]], covariances[rows[m]], noises[m]
        s00, s01, s11 = P[0, 0] + R[0, 0], 0.5 * (P[0, 1] + P[1, 0] + R[0, 1] + R[1, 0]), \
            P[1, 1] + R[1, 1]
        det = s00 * s11 - s01 * s01
        i00, i01, i11 = s11 / det, -s01 / det, s00 / det
        for i in range(4):
            gain[i, 0] = P[i, 0] * i00 + P[i, 1] * i01
            gain[i, 1] = P[i, 0] * i01 + P[i, 1] * i11
        y0, y1 = measurements[m, 0] - state[0], measurements[m, 1] - state[1]
        for i in range(4):
            state[i] += gain[i, 0] * y0 + gain[i, 1] * y1
            for j in range(4):
                reduce[i, j] = (1.0 if i == j else 0.0) - (gain[i, j] if j < 2 else 0.0)
        for i in range(4):
            for j in range(4):
                total = 0.0
                for k in range(4):
                    total += reduce[i, k] * P[k, j]
                product[i, j] = total
        for i in range(4):
            for j in range(i, 4):
                total = 0.0
                for k in range(4):
                    total += product[i, k] * reduce[j, k]
                for k in range(2):
                    for n in range(2):
                        total += gain[i, k] * R[k, n] * gain[j, n]
                P[i, j] = total
        for i in range(4):
            for j in range(i):
                P[i, j] = P[j, i]
