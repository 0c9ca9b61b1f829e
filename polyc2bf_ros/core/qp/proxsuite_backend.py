"""The proxsuite backend of ``qp.QPSolver``: its dense solver, polished to an exact optimum.

See ``ProxsuiteSolver``.  ``_polish`` and its active-set projections (``_projections``) turn
proxsuite's approximate answer into the KKT-certified optimum, or the solve is not optimal.
"""
import itertools

import numpy as np
from proxsuite import proxqp

from polyc2bf_ros.core.qp.solver import QPSolver, QPStatus

_PROXSUITE_EPS = 1e-10  # residuals and duality gap, absolute
_PROXSUITE_EPS_INFEASIBLE = 0.0  # off: its test misfires on feasible problems (phase 1 decides)
_PROXSUITE_MAX_ITER = 100  # outer (ALM) iterations; they bound the time spent on an infeasible
_PROXSUITE_MAX_ITER_IN = 50  # problem (inner: semismooth Newton steps per outer iteration)
_PHASE1_PROXIMAL = 1e-6  # curvature on x in the phase-1 problem (see ProxsuiteSolver)
_POLISH_GAP = 1e-4  # constraints this close to active at proxsuite's answer may be active
_POLISH_POOL = 12  # at most this many candidates (the closest to active) are tried
_MULTIPLIER_TOL = 1e-9  # a certifying multiplier is >= -_MULTIPLIER_TOL (1 + max|w x_ref|)
_INFEASIBILITY_TOL = 1e-8  # phase-1 minimax row violation above which a problem is infeasible
_RANK_TOL = 1e-10  # smallest / largest eigenvalue of an admissible Gram matrix
_CANDIDATE_TOL = 1e-12  # enumerated points are feasible if G x >= h - _CANDIDATE_TOL (1 + |h|)


def _proxsuite_qp(n, m):
    """Return a dense proxsuite QP with n variables, m inequality rows, a box and our settings.

    A fresh object per solve costs a few microseconds against ~100 us for the solve; cached ones
    outlive the interpreter's cleanup and make nanobind report leaks at exit.
    """
    qp = proxqp.dense.QP(n, 0, m, True)
    settings = qp.settings
    settings.eps_abs = _PROXSUITE_EPS
    settings.eps_rel = 0.0
    settings.check_duality_gap = True
    settings.eps_duality_gap_abs = _PROXSUITE_EPS
    settings.eps_duality_gap_rel = 0.0
    settings.eps_primal_inf = settings.eps_dual_inf = _PROXSUITE_EPS_INFEASIBLE
    settings.max_iter = _PROXSUITE_MAX_ITER
    settings.max_iter_in = _PROXSUITE_MAX_ITER_IN
    settings.initial_guess = proxqp.InitialGuess.EQUALITY_CONSTRAINED_INITIAL_GUESS
    return qp


def _constraints(A, b, lower, upper):
    """Return ``G, h`` with every constraint as a row of ``G x >= h``: rows, finite bounds."""
    eye = np.eye(lower.shape[0])
    has_lower, has_upper = np.isfinite(lower), np.isfinite(upper)
    return (np.vstack([A, eye[has_lower], -eye[has_upper]]),
            np.concatenate([b, lower[has_lower], -upper[has_upper]]))


def _projections(x_ref, weights, G, h, pool, k):
    """Project ``x_ref`` onto ``{G_S x = h_S}`` for each k-subset S of ``pool``, in the W-norm.

    Subsets with dependent rows are skipped (their affine set, if consistent, is that of a
    smaller independent subset).  Return the points ``X`` (N, n) and multipliers ``lam`` (N, k)::

        x = x_ref + W^-1 G_S' lam,   (G_S W^-1 G_S') lam = h_S - G_S x_ref

    One step of iterative refinement makes ``G_S x = h_S`` hold to rounding error even when the
    weights make the Gram matrix ill-conditioned.
    """
    if k == 0:
        return x_ref[None, :], np.zeros((1, 0))
    subsets = np.array(list(itertools.combinations(pool, k)), dtype=np.intp)
    G_s = G[subsets]  # (N, k, n)
    G_s_inv_w = G_s.transpose(0, 2, 1) / weights[:, None]  # W^-1 G_S', (N, n, k)
    gram = G_s @ G_s_inv_w
    eigenvalues = np.linalg.eigvalsh(gram)
    independent = eigenvalues[:, 0] > _RANK_TOL * eigenvalues[:, -1]
    G_s, G_s_inv_w, gram = G_s[independent], G_s_inv_w[independent], gram[independent]
    h_s = h[subsets[independent]][..., None]
    X = np.broadcast_to(x_ref[:, None], (G_s.shape[0], x_ref.shape[0], 1))
    lam = np.zeros_like(h_s)
    for _ in range(2):
        step = np.linalg.solve(gram, h_s - G_s @ X)
        lam = lam + step
        X = X + G_s_inv_w @ step
    return X[..., 0], lam[..., 0]


def _satisfies(X, G, h):
    """Tell which rows of X satisfy ``G x >= h`` up to rounding (``_CANDIDATE_TOL``).

    Looser would be wrong: a point that violates a row by 1e-10 can undercut the optimum.
    """
    return (X @ G.T - h >= -_CANDIDATE_TOL * (1.0 + np.abs(h))).all(axis=1)


def _polish(x, z, x_ref, weights, A, b, lower, upper):
    """Return the exact optimum near an approximate one, certified by the KKT conditions, or None.

    The candidate active set is every constraint within ``_POLISH_GAP`` of active at ``x`` or
    with a multiplier of the right sign in proxsuite's ``z = [z_rows, z_box]`` (``z < 0`` at a
    row or lower bound, ``z > 0`` at an upper bound).  Among its subsets, look for one whose
    projection (``_projections``) satisfies every constraint (``_satisfies``) and has
    multipliers ``lam >= 0``: that point meets all KKT conditions (stationarity and
    complementarity hold by construction), so it is the unique optimum.
    """
    G, h = _constraints(A, b, lower, upper)
    m = b.shape[0]
    z_rows, z_box = z[:m], z[m:]
    pushing = np.concatenate([z_rows < 0.0, z_box[np.isfinite(lower)] < 0.0,
                              z_box[np.isfinite(upper)] > 0.0])
    gap = G @ x - h
    pool = np.flatnonzero((gap <= _POLISH_GAP) | pushing)
    pool = pool[np.argsort(gap[pool])][:_POLISH_POOL]
    min_multiplier = -_MULTIPLIER_TOL * (1.0 + np.abs(weights * x_ref).max())
    for k in range(min(x_ref.shape[0], pool.shape[0]) + 1):
        X, lam = _projections(x_ref, weights, G, h, pool, k)
        certified = _satisfies(X, G, h) & (lam >= min_multiplier).all(axis=1)
        if certified.any():
            return X[certified.argmax()].copy()
    return None


class ProxsuiteSolver(QPSolver):
    """proxsuite dense backend, made trustworthy for these problems.

    With default settings proxsuite stops on primal and dual residuals alone and reports wrong
    answers as solved (errors > 0.5 on 2-variable problems); here the duality gap is checked too
    and tolerances are 1e-10.  Even so its answers can be off by 1e-6 and it sometimes stalls,
    so its answer only serves to guess the active set: ``_polish`` turns the guess into the exact
    optimum and verifies the KKT conditions, or the solve is not optimal.  proxsuite's own
    infeasibility test rarely fires on infeasible problems and does fire on badly scaled feasible
    ones, so it is off, and a phase-1 problem decides between INFEASIBLE and FAILED::

        minimise t + t^2 / 2  s.t.  A x + t >= b,  lower <= x <= upper,  t >= 0

    is always feasible, and the problem is infeasible iff ``t* > _INFEASIBILITY_TOL``.  x has
    no curvature there and can drift along recession directions; when proxsuite stalls on it,
    a second attempt scales the rows to unit norm (the same feasible set) and adds a small
    proximal term rho |x - x_ref|^2 / 2 (rho = ``_PHASE1_PROXIMAL``), which makes it strongly
    convex.  The term only raises t*, so an infeasible problem is never reported feasible; a
    feasible one on which the main solve failed may be reported infeasible (t* <=
    rho |x_feasible - x_ref|^2 / 2) rather than failed, which callers treat alike.
    """

    name = 'proxsuite'

    def _solve(self, x_ref, weights, A, b, lower, upper):
        """Solve with ``H = diag(w)``, ``g = -w x_ref``, polish; classify failures by phase 1."""
        n, m = x_ref.shape[0], b.shape[0]
        row_upper = np.full(m, np.inf)
        qp = _proxsuite_qp(n, m)
        qp.init(np.diag(weights), -weights * x_ref, None, None, A, b, row_upper,
                l_box=lower, u_box=upper)
        qp.solve()
        iterations = qp.results.info.iter
        x = _polish(qp.results.x, qp.results.z, x_ref, weights, A, b, lower, upper)
        if x is not None:
            return x, QPStatus.OPTIMAL, iterations

        for proximal in (0.0, _PHASE1_PROXIMAL):
            solved, t, steps = _phase1(x_ref, A, b, lower, upper, proximal)
            iterations += steps
            if solved:
                status = QPStatus.INFEASIBLE if t > _INFEASIBILITY_TOL else QPStatus.FAILED
                return x_ref, status, iterations
        return x_ref, QPStatus.FAILED, iterations


def _phase1(x_ref, A, b, lower, upper, proximal):
    """Solve the phase-1 problem (``ProxsuiteSolver``); return (solved, t*, iterations).

    With ``proximal`` > 0 the rows are scaled to unit norm and x gets that curvature.
    """
    n, m = x_ref.shape[0], b.shape[0]
    if proximal:
        scale = 1.0 / np.linalg.norm(A, axis=1)  # the front end dropped all-zero rows
        A, b = A * scale[:, None], b * scale
    phase1 = _proxsuite_qp(n + 1, m)
    phase1.init(np.diag(np.append(np.full(n, proximal), 1.0)),
                np.append(-proximal * x_ref, 1.0), None, None, np.hstack([A, np.ones((m, 1))]),
                b, np.full(m, np.inf), l_box=np.append(lower, 0.0),
                u_box=np.append(upper, np.inf))
    phase1.solve()
    result = phase1.results
    return result.info.status == proxqp.PROXQP_SOLVED, result.x[n], result.info.iter
