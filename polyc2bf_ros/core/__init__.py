"""PolyC2BF core in numpy and numba: (state, obstacles, nominal input) -> safe input.

Nothing below this package imports rclpy.  Its folders, each one concept, from the
bottom up (a folder imports only those above it in this list):

- ``kernels``: the compiled hot path: its machinery (``kernels.jit``), its build and
  every kernel, one module per concept;
- ``geometry``: planar polygons, views and size limits;
- ``obstacles``: obstacle sets, marker and scan tracking, scan -> polygons, the ground;
- ``barrier``: collision cones, the barrier h and its derivatives, the horizon cone,
  the braking check and the geometry prepared per obstacle set;
- ``models``, ``qp``, ``actuation``: robot models, the QP solvers, commands in flight
  and lagging actuators;
- ``safety_filter``: the filter (the QP of paper eq. 7 and its variants);
- ``liveness``: deadlock detection and resolution around the filter;
- ``command_filter`` and ``decision``: what the node decides per step, shared by
  the node, offline replay and the evaluation; ``watchdog`` and ``stats`` serve them.
"""
