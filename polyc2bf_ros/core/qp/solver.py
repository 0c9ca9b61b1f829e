"""Tiny dense QPs of the safety filter: a weighted projection onto a polyhedron inside a box.

Every backend solves, for n = 2..6 variables and m = 0..~200 rows::

    minimise    sum_i w_i (x_i - x_ref_i)^2      (w_i > 0)
    subject to  A x >= b                         (m rows)
                lower <= x <= upper              (entries may be +-inf)

``QPSolver.solve`` does the work the backends share: shape and weight checks, the exact fast
path (``x_ref`` feasible => it is the unconstrained minimiser), all-zero rows (dropped if
``b <= 0``, infeasible if ``b > 0``, to ``FAST_PATH_TOL``), ``m = 0`` (the minimiser is
``clip(x_ref, lower, upper)`` because the weights are diagonal), the one-constraint shortcut
(``_single_active``) and a final primal check of every answer reported optimal (finite, rows
and bounds to ``FEASIBILITY_TOL``).  Non-optimal results carry ``x = clip(x_ref, lower,
upper)`` with NaN replaced, never NaN.

A backend subclasses ``QPSolver`` and implements ``_solve``; ``qp_backends`` lists them by
name.  ``DaqpSolver`` here (dual active set, exact; the default, one persistent ``daqp.Model``
per problem size); ``qp_proxsuite.ProxsuiteSolver`` (dense proximal ALM with the duality-gap
test on, then polished to an exact, KKT-certified optimum).
"""
import abc
import enum
import math
from dataclasses import dataclass

import daqp
import numpy as np

from polyc2bf_ros.core.kernels.qp import (
    _ANSWERED,
    _EMPTY_BOX,
    _front_end,
    _single_active,
    _ZERO_ROW,
    FAST_PATH_TOL,
    row_residuals,
)

FEASIBILITY_TOL = 1e-9
"""An optimal answer satisfies every row and bound to this absolute tolerance."""

_DAQP_SETTINGS = {'primal_tol': 1e-11, 'eps_prox': 0.0, 'iter_limit': 1000}
_DAQP_OPTIMAL, _DAQP_INFEASIBLE = 1, -1


class QPStatus(str, enum.Enum):
    """Outcome of a QP solve."""

    OPTIMAL = 'optimal'
    INFEASIBLE = 'infeasible'
    FAILED = 'failed'


@dataclass
class QPResult:
    """Solution ``x`` (``x_ref`` clipped to the box unless optimal; never NaN) and its status."""

    x: np.ndarray
    status: QPStatus
    iterations: int


def _fallback(x_ref, lower, upper):
    """Return ``x_ref`` clipped to the box, NaN entries first set to 0; never NaN or inf."""
    x = np.clip(np.where(np.isnan(x_ref), 0.0, x_ref), lower, upper)
    x[~np.isfinite(x)] = 0.0  # an infinite x_ref on an open side, or NaN bounds
    return x


def _feasible(x, A, b, lower, upper):
    """Check that x is finite and meets rows and box to ``FEASIBILITY_TOL``; clip x to the box."""
    clip = False
    for value, low, high in zip(x.tolist(), lower.tolist(), upper.tolist()):
        if not (math.isfinite(value) and low - FEASIBILITY_TOL <= value <= high + FEASIBILITY_TOL):
            return False
        clip = clip or value < low or value > high
    if clip:
        np.minimum(np.maximum(x, lower, out=x), upper, out=x)
    return row_residuals(A, x, b, np.empty(b.shape[0])) >= -FEASIBILITY_TOL


class QPSolver(abc.ABC):
    """Backend-independent front end; subclasses implement ``_solve``."""

    name: str
    shortcut = True
    """Try ``_single_active`` before the backend (off for the reference, the tests' oracle)."""

    def solve(self, x_ref, weights, A, b, lower, upper) -> QPResult:
        """Minimise ``sum w (x - x_ref)^2`` s.t. ``A x >= b``, ``lower <= x <= upper``.

        Raise ``ValueError`` on inconsistent shapes or weights that are not positive and finite.
        NaN in the data gives ``FAILED`` (or ``INFEASIBLE``), never a NaN answer.
        """
        x_ref = np.asarray(x_ref, dtype=np.float64)
        weights = np.asarray(weights, dtype=np.float64)
        A = np.ascontiguousarray(A, dtype=np.float64)
        b = np.ascontiguousarray(b, dtype=np.float64)
        lower = np.asarray(lower, dtype=np.float64)
        upper = np.asarray(upper, dtype=np.float64)
        n = x_ref.shape[0] if x_ref.ndim == 1 else 0
        if A.size == 0 and b.size == 0:
            A = np.empty((0, n))
        m = A.shape[0]
        if (n == 0 or A.shape != (m, n) or b.shape != (m,) or weights.shape != (n,)
                or lower.shape != (n,) or upper.shape != (n,)):
            raise ValueError(
                f'inconsistent QP shapes: x_ref {x_ref.shape}, weights {weights.shape}, '
                f'A {A.shape}, b {b.shape}, lower {lower.shape}, upper {upper.shape}')
        for w in weights.tolist():
            if not 0.0 < w < math.inf:
                raise ValueError(f'weights must be positive and finite, got {weights}')
        return self.solve_checked(np.ascontiguousarray(x_ref), weights, A, b,
                                  np.ascontiguousarray(lower), np.ascontiguousarray(upper))

    def solve_checked(self, x_ref, weights, A, b, lower, upper) -> QPResult:
        """``solve`` for arguments it would accept as they are, without checking them again.

        That is: C-contiguous float64 arrays of consistent shapes, weights positive and
        finite.  The safety filter calls this on every step.
        """
        x = np.empty(x_ref.shape[0])
        found = _front_end(x_ref, weights, A, b, lower, upper, self.shortcut, x)
        if found == _ANSWERED:
            return QPResult(x, QPStatus.OPTIMAL, 0)
        if found == _EMPTY_BOX:
            return QPResult(_fallback(x_ref, lower, upper), QPStatus.INFEASIBLE, 0)
        if found == _ZERO_ROW:
            nonzero = A.any(axis=1)
            if not (b[~nonzero] <= FAST_PATH_TOL).all():
                status = QPStatus.FAILED if np.isnan(b).any() else QPStatus.INFEASIBLE
                return QPResult(_fallback(x_ref, lower, upper), status, 0)
            A, b = A[nonzero], b[nonzero]
            if self.shortcut and _single_active(x_ref, weights, A, b, lower, upper, x):
                return QPResult(x, QPStatus.OPTIMAL, 0)
        if b.shape[0] == 0:
            x, status, iterations = np.minimum(np.maximum(x_ref, lower), upper), \
                QPStatus.OPTIMAL, 0
        else:
            x, status, iterations = self._solve(x_ref, weights, A, b, lower, upper)
        if status is QPStatus.OPTIMAL and not _feasible(x, A, b, lower, upper):
            status = QPStatus.FAILED
        if status is not QPStatus.OPTIMAL:
            x = _fallback(x_ref, lower, upper)
        return QPResult(x, status, iterations)

    @abc.abstractmethod
    def _solve(self, x_ref, weights, A, b, lower, upper) -> tuple[np.ndarray, QPStatus, int]:
        """Solve a problem with m >= 1 nonzero rows; return (x, status, iterations).

        ``x`` is the backend's answer; ``solve`` checks it and replaces it unless optimal.
        """


class _DaqpWorkspace:
    """A ``daqp.Model`` and the buffers it reads, for one problem size (n, m).

    DAQP's form is ``min 1/2 x'Hx + f'x`` s.t. ``blower <= [I; A] x <= bupper`` (the first n
    entries of the bound vectors are simple bounds), so ``H = diag(w)``, ``f = -w x_ref``.
    ``Model.setup`` keeps pointers to contiguous float64 (intc) arrays instead of copying them, so
    a solve writes the new data into these buffers and calls ``update(H, sense)``: the H flag
    makes DAQP rebuild everything from the buffers, and the all-zero ``sense`` a cold start.
    This saves ~4 us per call over passing every array to ``update``.
    """

    def __init__(self, n, m):
        self.weights = None
        self.H = np.zeros((n, n))
        self.neg_w = np.zeros(n)
        self.f = np.zeros(n)
        self.A = np.zeros((m, n))
        self.bupper = np.full(n + m, np.inf)
        self.blower = np.full(n + m, -np.inf)
        self.sense = np.zeros(n + m, dtype=np.intc)
        self.model = None

    def solve(self, x_ref, weights, A, b, lower, upper):
        """Solve; return DAQP's ``(x, fval, exitflag, info)``."""
        n = x_ref.shape[0]
        weight_list = weights.tolist()
        if weight_list != self.weights:
            self.weights = weight_list
            np.fill_diagonal(self.H, weights)
            np.negative(weights, out=self.neg_w)
        np.multiply(self.neg_w, x_ref, out=self.f)
        self.A[...] = A
        self.bupper[:n] = upper
        self.blower[:n] = lower
        self.blower[n:] = b
        if self.model is None:
            self.model = daqp.Model()
            self.model.setup(self.H, self.f, self.A, self.bupper, self.blower, self.sense)
            self.model.settings = _DAQP_SETTINGS
        else:
            self.model.update(H=self.H, sense=self.sense)
        return self.model.solve()


class DaqpSolver(QPSolver):
    """DAQP backend: exact dual active-set solves on a cached ``daqp.Model`` per (n, m).

    Every solve is a cold start, so answers do not depend on earlier calls.  An instance holds
    mutable buffers: use one per thread.
    """

    name = 'daqp'

    def __init__(self):
        """Start with no cached models."""
        self._workspaces = {}

    def _solve(self, x_ref, weights, A, b, lower, upper):
        """Solve with DAQP; exit flag 1 is optimal, -1 infeasible, anything else failed."""
        key = (x_ref.shape[0], b.shape[0])
        workspace = self._workspaces.get(key)
        if workspace is None:
            workspace = self._workspaces[key] = _DaqpWorkspace(*key)
        x, _, flag, info = workspace.solve(x_ref, weights, A, b, lower, upper)
        if flag == _DAQP_OPTIMAL:
            status = QPStatus.OPTIMAL
        elif flag == _DAQP_INFEASIBLE:
            status = QPStatus.INFEASIBLE
        else:
            status = QPStatus.FAILED
        return x, status, info['iterations']


def solve_with_shared_slack(solver, x_ref, weights, A, b, lower, upper, slack_weight, *,
                            plain=None) -> tuple[np.ndarray, float, QPResult]:
    """Solve the QP; if that is not optimal, relax every row by one shared slack s >= 0.

    The relaxed problem keeps the bounds hard and is feasible whenever the box is non-empty::

        minimise  sum w (x - x_ref)^2 + slack_weight s^2   s.t.  A x + s >= b,  s >= 0

    ``plain`` is the plain problem's result if the caller already has it.  Return ``(x, s,
    result)``: ``s = 0`` and the plain result when the plain QP is optimal, otherwise the relaxed
    solve's ``x`` and ``s`` (both from the fallback if it is not optimal) and a result with its
    status and the iterations of both solves.
    """
    if plain is None:
        plain = solver.solve(x_ref, weights, A, b, lower, upper)
    if plain.status is QPStatus.OPTIMAL:
        return plain.x, 0.0, plain
    x_ref = np.asarray(x_ref, dtype=np.float64)
    n = x_ref.shape[0]
    A = np.asarray(A, dtype=np.float64).reshape(-1, n)
    relaxed = solver.solve(
        np.append(x_ref, 0.0), np.append(weights, slack_weight),
        np.hstack([A, np.ones((A.shape[0], 1))]), b,
        np.append(lower, 0.0), np.append(upper, np.inf))
    x = relaxed.x[:n].copy()
    return x, float(relaxed.x[n]), QPResult(x, relaxed.status,
                                             plain.iterations + relaxed.iterations)
