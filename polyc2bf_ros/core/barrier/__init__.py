"""The barrier: collision cones, h and its derivatives, and the braking check.

``cones`` and ``cone_models`` build the cones, ``cone_barrier`` h and its Lie
derivatives, ``horizon_cone`` the horizon-aware cone, ``braking_check`` the check on
the input, ``obstacle_geometry`` the views prepared once per obstacle set.

Imports ``kernels``, ``geometry`` and ``obstacles``.
"""
