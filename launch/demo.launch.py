"""The closed-loop demo on a full ROS 2 install: ``ros2 launch polyc2bf_ros demo.launch.py``.

Arguments: ``scenario`` (a shipped name such as ``long_wall`` or a YAML path),
``filter`` (``default``: each robot type's shipped barrier; ``polyc2bf_horizon``,
``polyc2bf_inflated``, ``polyc2bf_paper``, ``c3bf`` or ``none``),
``duration`` (sim seconds, -1 = the scenario's) and ``bag_path`` (empty =
``runs/<timestamp>/run``), e.g.
``ros2 launch polyc2bf_ros demo.launch.py scenario:=quadrotor_wall filter:=c3bf``.

Starts the processes of ``sim_bridge.launcher.closed_loop_plan``, the plan the
``demo`` command runs: ``sim_bridge`` (lockstep, recording), and per robot of
the scenario, in its namespace, ``nominal_controller`` and (unless ``filter`` is
``none``) ``safety_filter`` with the robot type's parameter file and the lockstep
overrides.  The bridge exits at the end of the scenario; stop the rest with Ctrl-C.
"""
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from sim_bridge.launcher import closed_loop_plan, FILTER_CHOICES


def _nodes(context):
    """Return one Node action per process of the plan for the chosen arguments."""
    bridge = {'record': True}
    duration = float(LaunchConfiguration('duration').perform(context))
    if duration > 0:
        bridge['duration'] = duration
    bag_path = LaunchConfiguration('bag_path').perform(context)
    if bag_path:
        bridge['bag_path'] = bag_path
    plan = closed_loop_plan(LaunchConfiguration('scenario').perform(context),
                            LaunchConfiguration('filter').perform(context), bridge)
    return [Node(package='polyc2bf_ros', executable=spec.executable,
                 namespace=spec.namespace or None,
                 parameters=([str(spec.params_file)] if spec.params_file else [])
                 + [spec.parameters],
                 remappings=list(spec.remappings), output='screen', emulate_tty=True)
            for spec in plan]


def generate_launch_description():
    """Return the demo's launch description."""
    return LaunchDescription([
        DeclareLaunchArgument('scenario', default_value='long_wall',
                              description='shipped scenario name or scenario YAML path'),
        DeclareLaunchArgument('filter', default_value='default',
                              choices=[*FILTER_CHOICES, 'default'],
                              description='safety filter barrier, or none'),
        DeclareLaunchArgument('duration', default_value='-1.0',
                              description="sim seconds; -1 = the scenario's"),
        DeclareLaunchArgument('bag_path', default_value='',
                              description='bag directory; empty = runs/<timestamp>/run'),
        OpaqueFunction(function=_nodes),
    ])
