"""Pure-numpy PolyC2BF core: geometry, cones, barriers, models, QP, filter.

Nothing below this package imports rclpy.
"""
