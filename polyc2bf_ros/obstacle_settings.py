"""How obstacle messages become obstacles: the node parameters of the obstacle intake.

Shared by the node (``filter_parameters.build_settings``), the worker process and the
offline pipelines (``sim_bridge``), so every path takes the same values.
"""
from typing import NamedTuple

from polyc2bf_ros.core.geometry.polygon_limits import MAX_PARTS, MAX_VERTICES

MAX_OBSTACLES = 1000


class IntakeSettings(NamedTuple):
    """How markers become obstacles (node parameters of the same names)."""

    wall_thickness: float = 0.05
    cylinder_sides: int = 12
    max_vertices: int = MAX_VERTICES
    max_parts: int = MAX_PARTS
    max_obstacles: int = MAX_OBSTACLES
    sensor_pose: tuple = (0.0, 0.0, 0.0)
    scan_cluster_tolerance: float = 0.15
    scan_footprint_radius: float = -1.0  # negative: the filter's robot_radius
    scan_obstacle_depth: float = 0.10
    scan_split_tolerance: float = 0.05
    scan_tracking: bool = True
    scan_unknown_speed: float = 2.0
    scan_hidden_speed: float = 1.0
    scan_memory_time: float = 10.0
    scan_memory_range: float = 1.5
    odom_position_std: float = 0.0
    odom_heading_std: float = 0.0
