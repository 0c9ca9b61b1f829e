"""Compiled kernels: ``jit`` (ahead of time or numba ``njit``), ``build`` and the kernels.

Every kernel of the core lives here, one module per concept (``cones``, ``barrier``,
``horizon``, ``braking``, ``geometry_batch``, ``views``, ``tracking``, ``obstacle_set``,
``filter_rows``, ``qp``, ``route``, ``scan`` and one per robot model), and the ahead-of-time
build's digest covers this folder only.  Imports nothing else of the core: a kernels
module imports ``kernels.jit``, numpy, math and other kernels modules; every other
core folder imports the kernels it calls.
"""
