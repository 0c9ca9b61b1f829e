"""Kernels of ``safety_filter``, whose docstring has the math.

The math in compiled form; every kernel lives in ``core/kernels`` (``jit.kernel_sources``).
"""
import math

from polyc2bf_ros.core.kernels.jit import B1, F1, F2, I1, kernel, signature
from polyc2bf_ros.core.kernels.qp import front_end_answers, row_residual

ACTIVE_TOLERANCE = 1e-7
_MIN_ROW_NORM = 1e-12


@kernel(signature('i8', F2, F1, F1, I1, 'f8', I1))
def _active_parts(rows_a, x, rows_b, index, tolerance, out):
    """Write the obstacle ``index`` of every row with a_i x - b_i <= ``tolerance``; count them."""
    active = 0
    for i in range(rows_b.shape[0]):
        if row_residual(rows_a, x, rows_b, i) <= tolerance:
            out[active] = index[i]
            active += 1
    return active



@kernel(signature('Tuple((i8, i8, f8))', F2, B1, 'f8', 'f8', F1, F1, 'b1', F2, F1, I1, F1))
def _assemble_rows(terms, usable, margin, gamma, lower, upper, prune, rows_a, rows_b, index,
                   h_out):
    """Write the unit-norm QP rows of the needed obstacle parts.

    Return (rows, unusable parts, smallest h of the usable parts or +inf).

    ``terms`` (2 + m, N) holds rows h, Lf h, Lg h.  Row of part n: Lg h_n u >= b_n =
    m - Lf h_n - gamma h_n, divided by |Lg h_n| (the same feasible set, but a
    well-scaled QP: row norms span 1e1..1e4 for the quadrotor, and a slack measured in
    input units).  With ``prune``, a row that holds for every u in the box,
    sum_j min(a_j lower_j, a_j upper_j) >= b_n, is dropped.  ``h_out`` gets h, NaN where
    no cone is usable (the part is left out: the escape input handles it).
    """
    h, lf_h, lg_h = terms[0], terms[1], terms[2:]
    count = inside = 0
    min_h = math.inf
    for n in range(h.shape[0]):
        if not usable[n]:
            h_out[n] = math.nan
            inside += 1
            continue
        h_out[n] = h[n]
        min_h = min(min_h, h[n])
        b = margin - lf_h[n] - gamma * h[n]
        if prune:
            worst = 0.0
            for j in range(lower.shape[0]):
                if lg_h[j, n] != 0.0:
                    worst += min(lg_h[j, n] * lower[j], lg_h[j, n] * upper[j])
            if worst >= b:
                continue
        norm_sq = 0.0
        for j in range(lower.shape[0]):
            norm_sq += lg_h[j, n] * lg_h[j, n]
        scale = 1.0 / max(math.sqrt(norm_sq), _MIN_ROW_NORM)
        for j in range(lower.shape[0]):
            rows_a[count, j] = lg_h[j, n] * scale
        rows_b[count] = b * scale
        index[count] = n
        count += 1
    return count, inside, min_h



@kernel(signature('Tuple((i8, i8, f8, i8))', F2, B1, 'f8', 'f8', F1, F1, 'b1', F2, F1, I1, F1,
                  F1, F1, 'b1', F1, I1))
def _rows_and_answer(terms, usable, margin, gamma, lower, upper, prune, rows_a, rows_b, index,
                     h_out, u_nom, weights, shortcut, x, active):
    """``_assemble_rows``, then the QP's front end on u_nom and the active parts of its answer.

    One compiled pass for the common step.  Return (rows, unusable parts, smallest h,
    active parts), the last -1 when there is no answer yet: a part is unusable (u_ref is
    then the escape input) or the QP needs the solver (``qp.front_end_answers``).
    Otherwise ``x`` holds u_safe, exactly ``QPSolver.solve_checked``'s answer, and
    ``active`` the parts whose rows hold with equality to ``ACTIVE_TOLERANCE``.
    """
    count, inside, min_h = _assemble_rows(terms, usable, margin, gamma, lower, upper, prune,
                                          rows_a, rows_b, index, h_out)
    if inside:
        return count, inside, min_h, -1
    rows_a, rows_b = rows_a[:count], rows_b[:count]
    if not front_end_answers(u_nom, weights, rows_a, rows_b, lower, upper, shortcut, x):
        return count, inside, min_h, -1
    return count, inside, min_h, _active_parts(rows_a, x, rows_b, index, ACTIVE_TOLERANCE,
                                               active)
