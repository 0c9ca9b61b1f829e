"""``nominal_controller``: a reference controller per robot; it ignores obstacles.

One node per robot namespace.  On every ``odom`` (nav_msgs/Odometry, read from
its CDR bytes by ``polyc2bf_ros.conversions.read_odometry``, as the safety filter
does: rclpy's deserializer costs more than the controller) it answers at once
with the command of ``sim_bridge.nominal``:

- ``robot_type: quadruped`` or ``diff_drive``: ``cmd_vel_in``
  (geometry_msgs/TwistStamped), ``linear.x = v``, ``angular.z = omega`` from
  ``UnicycleGoalController.velocity_command`` to ``goal`` (``controller:
  goal``), or from ``UnicyclePathController`` following the last
  ``nav_msgs/Path`` received on ``plan`` (``controller: path``, Nav2's topic;
  poses in the odometry frame; a new plan restarts from its beginning; zero
  velocity until the first plan, and for an empty one);
- ``robot_type: crazyflie``: ``wrench_in`` (geometry_msgs/WrenchStamped),
  collective thrust on ``force.z`` and body torques from
  ``QuadrotorGoalController.wrench`` (gravity compensated; ``controller: goal``).

The command's header stamp is the stamp of the odometry it answers (the
bridge's lockstep mode matches commands to periods by it) and its frame the
odometry's ``child_frame_id``.  Without a filter, remap the output straight to
the robot: ``-r cmd_vel_in:=cmd_vel_out``.  Gains are ``gains.<field>`` of the
controller dataclass.
"""
import dataclasses
import sys

import numpy as np
from nav_msgs.msg import Odometry, Path
from rcl_interfaces.msg import FloatingPointRange, ParameterDescriptor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy

from polyc2bf_ros import conversions
from polyc2bf_ros.loop_log import LoopLogger
from polyc2bf_ros.node_main import run_node
from sim_bridge.bag_reader import message_class
from sim_bridge.nominal import ReferencePath, UnicyclePathController
from sim_bridge.robots import ROBOT_TYPES

CONTROLLERS = ('goal', 'path')
COMMAND_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE)
ODOM_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT)
# Reliable and volatile: matches a planner's plan publisher, latched or not.
PLAN_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE)


class NominalControllerNode(Node):
    """Answer each odometry message with the reference controller's command."""

    def __init__(self, **kwargs):
        """Declare ``robot_type``, ``controller``, ``goal`` and ``gains.*``; wire the topics."""
        super().__init__('nominal_controller', **kwargs)
        self._log = LoopLogger(self.get_logger())  # for the loop (loop_log)
        robot_type = self.declare_parameter('robot_type', 'quadruped', ParameterDescriptor(
            description='a sim_bridge.robots type: quadruped, diff_drive or jackal (TwistStamped '
            'on cmd_vel_in) or crazyflie (WrenchStamped on wrench_in)', read_only=True)).value
        if robot_type not in ROBOT_TYPES:
            raise ValueError(f"parameter 'robot_type' must be one of {', '.join(ROBOT_TYPES)}, "
                             f'got {robot_type!r}')
        robot = ROBOT_TYPES[robot_type]
        kind = self.declare_parameter('controller', 'goal', ParameterDescriptor(
            description="'goal': go to the goal parameter; 'path': pure pursuit along the "
            'nav_msgs/Path on plan (unicycle robot types)', read_only=True)).value
        if kind not in CONTROLLERS or (kind == 'path' and not robot.unicycle):
            raise ValueError(f"parameter 'controller' must be 'goal', or 'path' for a "
                             f'unicycle robot type, got {kind!r} for a {robot_type}')
        controller_class, self._model, goal_size = (robot.goal_controller, robot.model,
                                                    robot.goal_size)
        if kind == 'path':
            controller_class = UnicyclePathController
        goal = self.declare_parameter('goal', [0.0] * goal_size, ParameterDescriptor(
            description=f'goal position, {goal_size} numbers [m] in the odometry frame')).value
        self._goal = np.array(goal, dtype=float)
        if self._goal.shape != (goal_size,) or not np.isfinite(self._goal).all():
            raise ValueError(f"parameter 'goal' must be {goal_size} finite numbers for a "
                             f'{robot_type}, got {list(goal)}')
        gains = {}
        for field in dataclasses.fields(controller_class):
            gains[field.name] = self.declare_parameter(
                f'gains.{field.name}', float(field.default), ParameterDescriptor(
                    description=f'{controller_class.__name__}.{field.name}', read_only=True,
                    floating_point_range=[FloatingPointRange(from_value=0.0,
                                                             to_value=1000.0)])).value
        self._controller = controller_class(**gains)
        self._target = self._goal
        self._state = np.zeros(robot.state_size)
        if kind == 'path':
            self._target = None  # no plan yet: stand still
            self.create_subscription(Path, 'plan', self._on_plan, PLAN_QOS)
        command_type = message_class(robot.command_type)
        self._out = command_type()
        self._publisher = self.create_publisher(command_type, robot.nominal_topic, COMMAND_QOS)
        self._fill = self._fill_twist if robot.command_kind == 'velocity' else self._fill_wrench
        self.create_subscription(Odometry, 'odom', self._on_odom, ODOM_QOS, raw=True)
        self.get_logger().info(f'{robot_type} following the plan' if kind == 'path'
                               else f'{robot_type} to goal {self._goal.tolist()}')

    def _on_plan(self, msg):
        """Follow ``msg`` (nav_msgs/Path) from its beginning; an empty one stops the robot."""
        points = [(p.pose.position.x, p.pose.position.y) for p in msg.poses]
        try:
            self._target = ReferencePath(points) if points else None
        except ValueError as exc:  # NaN/Inf
            self._log.error(f'plan dropped: {exc}', throttle_s=1.0)
            self._target = None

    def _on_odom(self, data):
        """Publish the command for this odometry (CDR ``data``), stamped with its stamp."""
        try:
            odom = conversions.read_odometry(data)
        except ValueError as exc:
            self._log.error(f'odometry dropped: {exc}', throttle_s=1.0)
            return
        result = conversions.state_from_odometry(self._model, odom.pose, odom.twist)
        if result is None:  # NaN/Inf
            return
        self._state[:] = result[0]
        self._fill()
        header = self._out.header
        header.stamp.sec, header.stamp.nanosec = odom.sec, odom.nanosec
        header.frame_id = odom.child_frame.decode(errors='replace')
        self._publisher.publish(self._out)

    def _fill_twist(self):
        """Velocity command [v, omega] of the unicycle law (zero without a plan to follow)."""
        command = (np.zeros(2) if self._target is None
                   else self._controller.velocity_command(self._state, self._target))
        conversions.fill_twist(self._out.twist, 'unicycle', command, 0.0)

    def _fill_wrench(self):
        """Wrench [T, tau] of the quadrotor position/attitude PD."""
        thrust, tx, ty, tz = self._controller.wrench(self._state, self._target).tolist()
        wrench = self._out.wrench
        wrench.force.z = thrust
        wrench.torque.x, wrench.torque.y, wrench.torque.z = tx, ty, tz


def main(args=None):
    """Run the controller until shutdown; exit status 1 on a configuration error."""
    return run_node(NominalControllerNode, 'nominal_controller', args)


if __name__ == '__main__':
    sys.exit(main())
