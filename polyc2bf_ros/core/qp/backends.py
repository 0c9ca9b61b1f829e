"""The QP backends by name: ``SOLVERS`` and ``make_solver``.

A backend is a ``qp.QPSolver`` subclass in a module of its own, listed here.
"""
from polyc2bf_ros.core.qp.proxsuite_backend import ProxsuiteSolver
from polyc2bf_ros.core.qp.solver import DaqpSolver, QPSolver

SOLVERS: dict[str, type[QPSolver]] = {
    solver.name: solver for solver in (DaqpSolver, ProxsuiteSolver)}


def make_solver(name: str) -> QPSolver:
    """Return a new solver of the backend called ``name`` (a key of ``SOLVERS``)."""
    try:
        return SOLVERS[name]()
    except KeyError:
        raise ValueError(
            f'unknown QP solver {name!r}; valid names: {", ".join(sorted(SOLVERS))}') from None
