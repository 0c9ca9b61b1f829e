"""PolyC2BF core in numpy and numba: geometry, cones, barriers, models, QP, filter.

Nothing below this package imports rclpy.  The per-step hot path runs as a few
compiled kernels (``polyc2bf_ros.core.jit``).
"""
