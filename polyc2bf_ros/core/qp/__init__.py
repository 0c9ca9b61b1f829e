"""The safety filter's small dense QPs and their backends.

``solver``: the projection QP; ``backends`` and ``proxsuite_backend``: solvers by name.

Imports only ``kernels``.
"""
