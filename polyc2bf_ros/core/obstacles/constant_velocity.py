"""Constant-velocity Kalman filter in the plane: state ``[x, y, vx, vy]``, position measured.

numpy only, written here: the matrices are 4 x 4 (6 x 6 with a clone) and the equations
below are the whole filter, so a Kalman-filter library (none is in the project's pins) would
cost a dependency and per-call overhead for no gain.  Used per key (``initial``,
``predict``, ``update`` on one state) and for many tracks at once: the compiled helpers
``predict_one``, ``update_one``, ``reclone_one`` run the same equations in place inside other
kernels, and ``predict_all``, ``update_rows`` run them over arrays of tracks.

Model (white-noise acceleration: the acceleration is white noise of spectral density
``q = accel_std^2`` [m^2 s^-3] on each axis, independently)::

    x_k = F x_{k-1} + w,   F = [[I, dt I], [0, I]],   w ~ N(0, Q),
    Q = q [[dt^3 / 3 I, dt^2 / 2 I], [dt^2 / 2 I, dt I]]       (I: the 2 x 2 identity)

so over a time ``dt`` the velocity's variance grows by ``q dt`` per axis.  Measurement
``z = H x + v``, ``H = [I, 0]``, ``v ~ N(0, R)`` with R the 2 x 2 position covariance.

- ``predict``: ``x <- F x``, ``P <- F P F^T + Q`` (dt >= 0).
- ``update``: innovation ``y = z - H x``, ``S = H P H^T + R``, gain ``K = P H^T S^-1``,
  ``x <- x + K y``, ``P <- (I - K H) P (I - K H)^T + K R K^T`` (Joseph form: symmetric and
  positive definite in floating point whenever P and R are), then symmetrised.
- ``initial``: ``x = [z, 0, 0]``, ``P = diag(R, speed_std^2 I)``: the position as measured,
  the velocity unknown with standard deviation ``speed_std`` per axis.

Displacements (stochastic cloning).  A sensor that measures how far an object moved since
an earlier time t0, ``d = p(t) - p(t0) + v``, not where it is, measures the difference of
two states.  The state is augmented with a clone c of the position at t0, ``[x, y, vx, vy,
cx, cy]``: ``clone`` makes it (``c = p``, with P's position rows and columns copied, so c
and p are fully correlated); ``predict`` moves p and v only (F and Q act on the first four
entries, c stays); ``update_relative`` is ``update`` with ``H = [I, 0, -I]``; after it
``reclone`` sets ``c = p`` again for the next displacement.  Feeding ``p(t0)_estimate + d``
to ``update`` as if it were a position instead would count the earlier estimate's error as
new information: where d measures one direction only (a wall seen from the side), a
slight turn of that direction between scans then lets the filter "explain" an innovation by
moving the unmeasured position, and its velocity with it.

One direction only (consider update).  A displacement measured along one direction n
only (R huge along the other, w) still moves the estimate along w when n turns slightly from
one measurement to the next, through the correlations in P: the filter would read the
along-face velocity of a box seen face-on from the noise in its face's estimated normal.
``update_relative(..., free=w)`` zeroes the gain's component along w in each of p, v and c
(a Schmidt, or consider, update: ``K <- (I - W) K`` with ``W`` the projection on w in each
pair), so the state moves along n only; the Joseph form stays the exact covariance for any
gain.

``velocity_std``: the square root of the largest eigenvalue of the velocity block
``P_vv = [[a, b], [b, c]]``, ``(a + c) / 2 + sqrt(((a - c) / 2)^2 + b^2)``: the standard
deviation of the velocity along its worst-known axis.
"""
import math

import numpy as np


def _check_time_step(dt, accel_std):
    """Raise ValueError unless ``dt >= 0`` and ``accel_std >= 0`` are finite."""
    if not (math.isfinite(dt) and dt >= 0):
        raise ValueError(f'dt must be a finite number >= 0, got {dt!r}')
    if not (math.isfinite(accel_std) and accel_std >= 0):
        raise ValueError(f'accel_std must be a finite number >= 0, got {accel_std!r}')


def transition(dt, size=4):
    """Return F (size, size): positions advance by ``dt`` times the velocities, the rest stays."""
    matrix = np.eye(size)
    matrix[0, 2] = matrix[1, 3] = dt
    return matrix


def process_noise(dt, accel_std, size=4):
    """Return Q (size, size) of white-noise acceleration, ``q = accel_std^2``, on [p, v]."""
    q = accel_std * accel_std
    noise = np.zeros((size, size))
    block = q * np.array([[dt ** 3 / 3.0, dt ** 2 / 2.0], [dt ** 2 / 2.0, dt]])
    noise[:4, :4] = np.kron(block, np.eye(2))
    return noise


def initial(z, R, speed_std):
    """Return (x, P) of a track first measured at ``z`` (2,) with covariance ``R`` (2, 2)."""
    state = np.zeros(4)
    state[:2] = z
    covariance = np.zeros((4, 4))
    covariance[:2, :2] = R
    covariance[2, 2] = covariance[3, 3] = speed_std * speed_std
    return state, covariance


def predict(x, P, dt, accel_std):
    """Return (F x, F P F^T + Q) after ``dt`` >= 0 seconds (4 entries, or 6 with a clone)."""
    _check_time_step(dt, accel_std)
    size = len(x)
    transition_matrix = transition(dt, size)
    covariance = (transition_matrix @ P @ transition_matrix.T
                  + process_noise(dt, accel_std, size))
    return transition_matrix @ x, 0.5 * (covariance + covariance.T)


def _linear_update(x, P, H, z, R, free=None):
    """Return (x, P) after measuring ``z = H x + v``, ``v ~ N(0, R)`` (Joseph form).

    ``free``: a unit direction w the gain must not move any (x, y) pair of the state along.
    """
    x, P = np.asarray(x, dtype=float), np.asarray(P, dtype=float)
    innovation = np.asarray(z, dtype=float) - H @ x
    S = H @ P @ H.T + R
    gain = np.linalg.solve(S, H @ P).T  # P H^T S^-1, with S and P symmetric
    if free is not None:
        w = np.asarray(free, dtype=float)
        keep = np.kron(np.eye(len(x) // 2), np.eye(2) - np.outer(w, w))
        gain = keep @ gain
    reduce = np.eye(len(x)) - gain @ H
    covariance = reduce @ P @ reduce.T + gain @ R @ gain.T
    return x + gain @ innovation, 0.5 * (covariance + covariance.T)


def update(x, P, z, R):
    """Return (x, P) after measuring position ``z`` (2,) with covariance ``R`` (Joseph form)."""
    H = np.zeros((2, len(x)))
    H[0, 0] = H[1, 1] = 1.0
    return _linear_update(x, P, H, z, R)


def clone(x, P):
    """Return the 6-entry (x, P) with a clone c of the position appended (module docstring)."""
    rows = [0, 1, 2, 3, 0, 1]
    return np.asarray(x, dtype=float)[rows], np.asarray(P, dtype=float)[np.ix_(rows, rows)]


def reclone(x, P):
    """Return the 6-entry (x, P) with its clone set to the current position again."""
    return clone(np.asarray(x)[:4], np.asarray(P)[:4, :4])


def update_relative(x, P, d, R, free=None):
    """Return the 6-entry (x, P) after measuring the displacement ``d = p - c`` (cov. R).

    ``free``: the unit direction w that d does not measure (module docstring), or None.
    """
    H = np.zeros((2, 6))
    H[0, 0] = H[1, 1] = 1.0
    H[0, 4] = H[1, 5] = -1.0
    return _linear_update(x, P, H, d, R, free)


def velocity_std(P):
    """Return the standard deviation of the velocity along its worst axis (module docstring)."""
    a, b, c = P[2, 2], P[2, 3], P[3, 3]
    return math.sqrt(max(0.5 * (a + c) + math.hypot(0.5 * (a - c), b), 0.0))
