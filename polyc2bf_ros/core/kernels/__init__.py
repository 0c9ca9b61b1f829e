"""Compiled kernels: ``jit`` (ahead of time or numba ``njit``) and ``build`` (the AOT build).

Imports nothing else of the core; every other core folder imports ``kernels.jit``.
"""
