"""The safety filter in a Nav2 chain: ``ros2 launch polyc2bf_ros nav2_safety_filter.launch.py``.

Include it beside Nav2's bringup (doc/nav2.md)::

    controller_server --cmd_vel_nav--> safety_filter --cmd_vel--> base
                        odom, scan ----^

Its arguments:

- ``namespace`` (default none) and ``use_sim_time`` (default false): as Nav2's bringup's;
- ``params_file``: default the package's ``config/nav2_safety_filter.yaml``;
- ``cmd_vel_in_topic`` (default ``cmd_vel_nav``; ``cmd_vel_smoothed`` behind the velocity
  smoother) and ``cmd_vel_out_topic`` (default ``cmd_vel``), named as the collision
  monitor's parameters, remapped onto the node's ``cmd_vel_in`` / ``cmd_vel_out``;
- ``use_lifecycle`` (default false): true starts the executable ``safety_filter_lifecycle``
  instead of ``safety_filter``, with the same name, parameters and remappings, for Nav2's
  lifecycle manager to configure and activate.  That variant may not be installed yet: the
  launch description is valid either way, but starting it fails until it is.

The shipped parameters take every obstacle from ``scan`` (``use_markers: false``): no
MarkerArray is needed.  For obstacle markers on ``obstacles`` as well, use a parameter file
with ``use_markers: true``.
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition, UnlessCondition
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue


def _filter_node(executable, condition):
    """Return the filter's ``Node`` action for ``executable``, started under ``condition``."""
    return Node(
        package='polyc2bf_ros',
        executable=executable,
        name='safety_filter',
        namespace=LaunchConfiguration('namespace'),
        parameters=[LaunchConfiguration('params_file'),
                    {'use_sim_time': ParameterValue(LaunchConfiguration('use_sim_time'),
                                                    value_type=bool)}],
        remappings=[('cmd_vel_in', LaunchConfiguration('cmd_vel_in_topic')),
                    ('cmd_vel_out', LaunchConfiguration('cmd_vel_out_topic'))],
        condition=condition,
        output='screen',
        emulate_tty=True,
    )


def generate_launch_description():
    """Return the safety filter, plain or lifecycle (``use_lifecycle``)."""
    default_params = os.path.join(
        get_package_share_directory('polyc2bf_ros'), 'config', 'nav2_safety_filter.yaml')
    use_lifecycle = LaunchConfiguration('use_lifecycle')
    return LaunchDescription([
        DeclareLaunchArgument(
            'namespace', default_value='',
            description='namespace for the node and its relative topics (as Nav2 bringup)'),
        DeclareLaunchArgument(
            'params_file', default_value=default_params,
            description='YAML parameter file for the safety_filter node'),
        DeclareLaunchArgument(
            'use_sim_time', default_value='false',
            description='ROS clock from /clock (the watchdogs use the steady clock)'),
        DeclareLaunchArgument(
            'use_lifecycle', default_value='false',
            description='start safety_filter_lifecycle instead of safety_filter'),
        DeclareLaunchArgument(
            'cmd_vel_in_topic', default_value='cmd_vel_nav',
            description='nominal command: the controller (or cmd_vel_smoothed)'),
        DeclareLaunchArgument(
            'cmd_vel_out_topic', default_value='cmd_vel',
            description='safe command: the base'),
        _filter_node('safety_filter', UnlessCondition(use_lifecycle)),
        _filter_node('safety_filter_lifecycle', IfCondition(use_lifecycle)),
    ])
