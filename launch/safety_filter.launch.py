"""Start the PolyC2BF safety filter: ``ros2 launch polyc2bf_ros safety_filter.launch.py``.

Arguments: ``params_file`` (default: the package's ``config/quadruped.yaml``) and
``namespace`` (default: none), e.g.
``ros2 launch polyc2bf_ros safety_filter.launch.py namespace:=robot1``.
Topics are relative (``odom``, ``obstacles``, ``cmd_vel_in``, ``cmd_vel_out``), so
a namespace moves them all; remap further by copying this file.
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def generate_launch_description():
    """Return a launch description with one ``safety_filter`` node."""
    default_params = os.path.join(
        get_package_share_directory('polyc2bf_ros'), 'config', 'quadruped.yaml')
    return LaunchDescription([
        DeclareLaunchArgument(
            'params_file', default_value=default_params,
            description='YAML parameter file for the safety_filter node'),
        DeclareLaunchArgument(
            'namespace', default_value='',
            description='namespace for the node and its relative topics'),
        Node(
            package='polyc2bf_ros',
            executable='safety_filter',
            name='safety_filter',
            namespace=LaunchConfiguration('namespace'),
            parameters=[LaunchConfiguration('params_file')],
            output='screen',
            emulate_tty=True,
        ),
    ])
