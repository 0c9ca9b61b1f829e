"""Kernels of ``qp.solver``, whose docstring has the math.

The math in compiled form; every kernel lives in ``core/kernels`` (``jit.kernel_sources``).
"""
import math

import numpy as np

from polyc2bf_ros.core.kernels.jit import F1, F2, kernel, signature

FAST_PATH_TOL = 1e-12
"""``x_ref`` is returned as is when ``A x_ref >= b - FAST_PATH_TOL`` and it lies in the box."""
PAIR_POOL = 8
"""``_single_active`` tries all pairs of at most this many rows violated at clip(x_ref)."""
_ANSWERED, _EMPTY_BOX, _ZERO_ROW, _GENERAL = range(4)
"""What ``_front_end`` found: x is the optimum; an empty box; an all-zero row; neither."""


@kernel
def row_residual(A, x, b, i):
    """Return a_i x - b_i, the products summed first (so all its callers round alike)."""
    value = 0.0
    for j in range(x.shape[0]):
        value += A[i, j] * x[j]
    return value - b[i]



@kernel(signature('f8', F2, F1, F1, F1))
def row_residuals(A, x, b, out):
    """Write ``A x - b`` into ``out``; return its smallest entry (inf without rows, NaN if any)."""
    smallest = math.inf
    for i in range(b.shape[0]):
        out[i] = row_residual(A, x, b, i)
        if out[i] < smallest or out[i] != out[i]:
            smallest = out[i]
    return smallest



@kernel(signature('b1', F1, F1, F2, F1, F1, F1, F1))
def _single_active(x_ref, weights, A, b, lower, upper, x):
    """Try the optima with few active constraints; True if ``x`` is the optimum.

    For this strictly convex problem a point meeting the KKT conditions is the optimum.
    Candidates, in turn: the bounds S that x_ref violates held at their values plus at
    most one row; no bound and one row; no bound and two rows.  A row is made active
    when it is the one violated farthest in the W-norm (over the free coordinates F)::

        one row i:   x_F = x_ref_F + lam W_F^-1 a_iF,   lam = (b_i - a_i x) / (a_iF W_F^-1 a_iF')
        rows i, j:   x = x_ref + W^-1 A_S' lam,   (A_S W^-1 A_S') lam = b_S - A_S x_ref

    (j is the row violated farthest after projecting onto i), and then every pair of
    the rows violated at clip(x_ref) when there are at most ``PAIR_POOL`` of them
    (the two rows the farthest-violation rule picks are often not the active pair
    when x_ref lies far outside the box).  A candidate is the
    optimum when every row holds (to ``FAST_PATH_TOL``), x lies in the box and the
    multipliers are >= 0: lam, and mu_j = +-(w_j (x_j - x_ref_j) - lam a_ij) for a held
    bound (+ at a lower, - at an upper one).  The usual filter step (one or two active
    obstacles, the nominal input perhaps beyond its bounds) then needs no backend solve.
    """
    clipped = False
    for j in range(x_ref.shape[0]):
        if not (math.isfinite(x_ref[j]) and lower[j] <= upper[j]):
            return False  # NaN, inf or an empty box: the general path decides
        clipped = clipped or not lower[j] <= x_ref[j] <= upper[j]
    if _one_row_candidate(x_ref, weights, A, b, lower, upper, True, x):
        return True
    if clipped and _one_row_candidate(x_ref, weights, A, b, lower, upper, False, x):
        return True
    if _two_row_candidate(x_ref, weights, A, b, lower, upper, x):
        return True
    return _violated_pairs(x_ref, weights, A, b, lower, upper, x)



@kernel
def _farthest_row(point, x_ref, weights, A, b, skip):
    """Return (row, lam) of the row violated farthest at ``point`` in the W-norm, or -1.

    Only coordinates where ``point`` equals ``x_ref`` are free to move; lam is the step
    (b_i - a_i point) / (a_iF W_F^-1 a_iF') onto the row.
    """
    best, row, lam = 0.0, -1, 0.0
    for i in range(b.shape[0]):
        gap, norm_sq = b[i], 0.0
        for j in range(point.shape[0]):
            gap -= A[i, j] * point[j]
            if point[j] == x_ref[j]:
                norm_sq += A[i, j] * A[i, j] / weights[j]
        if i != skip and gap > FAST_PATH_TOL and norm_sq > 0.0 and gap / math.sqrt(
                norm_sq) > best:
            best, row, lam = gap / math.sqrt(norm_sq), i, gap / norm_sq
    return row, lam



@kernel
def _meets_rows(A, b, x):
    """Return True when every row holds at x to ``FAST_PATH_TOL``."""
    for i in range(b.shape[0]):
        value = -b[i]
        for j in range(x.shape[0]):
            value += A[i, j] * x[j]
        if not value >= -FAST_PATH_TOL:
            return False
    return True



@kernel
def _one_row_candidate(x_ref, weights, A, b, lower, upper, hold, x):
    """Build and check a held-bounds-plus-one-row candidate of ``_single_active``."""
    for j in range(x_ref.shape[0]):
        x[j] = min(max(x_ref[j], lower[j]), upper[j]) if hold else x_ref[j]
    row, lam = _farthest_row(x, x_ref, weights, A, b, -1)
    for j in range(x_ref.shape[0]):
        if x[j] != x_ref[j]:  # held: its multiplier must have the right sign
            if row >= 0 and not (x[j] - x_ref[j]) * (
                    weights[j] * (x[j] - x_ref[j]) - lam * A[row, j]) >= 0.0:
                return False
        elif row >= 0:
            x[j] = x_ref[j] + lam * A[row, j] / weights[j]
        if not lower[j] <= x[j] <= upper[j]:
            return False
    return _meets_rows(A, b, x)



@kernel
def _pair_candidate(x_ref, weights, A, b, lower, upper, first, second, x):
    """Build and check the candidate with rows ``first`` and ``second`` active and no bound."""
    n = x_ref.shape[0]
    g11 = g12 = g22 = 0.0
    r1, r2 = b[first], b[second]
    for j in range(n):
        g11 += A[first, j] * A[first, j] / weights[j]
        g12 += A[first, j] * A[second, j] / weights[j]
        g22 += A[second, j] * A[second, j] / weights[j]
        r1 -= A[first, j] * x_ref[j]
        r2 -= A[second, j] * x_ref[j]
    det = g11 * g22 - g12 * g12
    if not det > 1e-9 * g11 * g22:
        return False  # (nearly) parallel rows: leave them to the backend
    lam1, lam2 = (g22 * r1 - g12 * r2) / det, (g11 * r2 - g12 * r1) / det
    if not (lam1 >= 0.0 and lam2 >= 0.0):
        return False
    for j in range(n):
        x[j] = x_ref[j] + (lam1 * A[first, j] + lam2 * A[second, j]) / weights[j]
        if not lower[j] <= x[j] <= upper[j]:
            return False
    return _meets_rows(A, b, x)



@kernel
def _two_row_candidate(x_ref, weights, A, b, lower, upper, x):
    """Try the pair: the row violated farthest at x_ref, then farthest after projecting."""
    first, lam = _farthest_row(x_ref, x_ref, weights, A, b, -1)
    if first < 0:
        return False
    for j in range(x_ref.shape[0]):
        x[j] = x_ref[j] + lam * A[first, j] / weights[j]
    second, _ = _farthest_row(x, x, weights, A, b, first)
    if second < 0:
        return False
    return _pair_candidate(x_ref, weights, A, b, lower, upper, first, second, x)



@kernel
def _violated_pairs(x_ref, weights, A, b, lower, upper, x):
    """Try every pair among the rows violated at clip(x_ref), if there are at most PAIR_POOL."""
    pool = np.empty(PAIR_POOL, dtype=np.int64)
    count = 0
    for i in range(b.shape[0]):
        value = -b[i]
        for j in range(x_ref.shape[0]):
            value += A[i, j] * min(max(x_ref[j], lower[j]), upper[j])
        if value < -FAST_PATH_TOL:
            if count == PAIR_POOL:
                return False
            pool[count] = i
            count += 1
    for first in range(count):
        for second in range(first + 1, count):
            if _pair_candidate(x_ref, weights, A, b, lower, upper, pool[first], pool[second],
                               x):
                return True
    return False



@kernel(signature('i8', F1, F1, F2, F1, F1, F1, 'b1', F1))
def _front_end(x_ref, weights, A, b, lower, upper, shortcut, x):
    """Run the checks every solve starts with, in one pass; ``_ANSWERED``: x is the optimum.

    In order: x_ref itself when it lies in the box and meets every row to
    ``FAST_PATH_TOL`` (``row_residual``); else ``_EMPTY_BOX`` when some
    lower > upper; ``_ZERO_ROW`` when a row of A is all zero (``solve_checked`` drops or
    refuses it, then tries the shortcut); else ``_single_active`` if ``shortcut``.
    NaN fails every comparison, so it ends in ``_GENERAL`` or ``_ZERO_ROW``.
    """
    n, m = x_ref.shape[0], b.shape[0]
    inside = True
    for j in range(n):
        inside = inside and lower[j] <= x_ref[j] <= upper[j]
    if inside:
        holds = True
        for i in range(m):
            holds = holds and row_residual(A, x_ref, b, i) >= -FAST_PATH_TOL
        if holds:
            for j in range(n):
                x[j] = x_ref[j]
            return _ANSWERED
    else:
        for j in range(n):
            if lower[j] > upper[j]:
                return _EMPTY_BOX
    for i in range(m):
        zero = True
        for j in range(n):
            zero = zero and A[i, j] == 0.0
        if zero:
            return _ZERO_ROW
    if shortcut and _single_active(x_ref, weights, A, b, lower, upper, x):
        return _ANSWERED
    return _GENERAL



@kernel
def front_end_answers(x_ref, weights, A, b, lower, upper, shortcut, x):
    """Return True when the front end (``_front_end``) leaves the optimum in ``x``.

    For a kernel that runs the front end in its own pass (the safety filter's
    rows); when this returns False, ``QPSolver.solve_checked`` does the rest,
    running the front end again (a pass over the rows, small beside the backend
    solve that follows).
    """
    return _front_end(x_ref, weights, A, b, lower, upper, shortcut, x) == _ANSWERED
