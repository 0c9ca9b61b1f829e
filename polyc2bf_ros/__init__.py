"""PolyC2BF safety filter for ROS 2: a numpy core plus a thin rclpy shell."""
