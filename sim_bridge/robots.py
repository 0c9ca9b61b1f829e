"""The simulated robot types: one ``RobotType`` each, in ``ROBOT_TYPES``.

The scenario loader, launcher, bridge, world, in-process loop and nominal
controller read their per-type facts here; a new type is one entry plus its
plant in ``sim_bridge.plants.PLANTS``.
"""
import dataclasses
import math
from types import MappingProxyType

from polyc2bf_ros.core.models import crazyflie as cf
from sim_bridge.nominal import QuadrotorGoalController, UnicycleGoalController


@dataclasses.dataclass(frozen=True)
class RobotType:
    """What one robot type is to the simulation, its filter and its nominal controller.

    ``model``: the filter's (and odometry state's) model name; ``params_file``: the
    filter parameters under ``config/``; ``command_kind``: what the world is sent
    ('velocity' [v, omega] or 'wrench' [T, tau]) as ``command_type`` on the filter's
    ``nominal_topic`` (in) and ``safe_topic`` (out), with ``filter_parameters`` added;
    ``radius``: default footprint radius [m]; ``start_fields`` / ``goal_fields``: the
    scenario layouts; ``yaw_index``: the yaw's place in the state; ``disc_body``:
    the body is a disc of the scenario's ``radius`` (its ``filter.robot_radius``);
    ``input_units``: what the filter's input u is, for the evaluation's intervention
    column; ``lidar``: its lidar's ``LidarSettings`` fields in scan mode (none: the
    defaults).
    """

    name: str
    model: str
    params_file: str
    command_kind: str
    command_type: str
    safe_topic: str
    nominal_topic: str
    radius: float
    start_fields: str
    goal_fields: str
    goal_controller: type
    state_size: int
    yaw_index: int
    input_units: str
    filter_parameters: MappingProxyType = dataclasses.field(
        default_factory=lambda: MappingProxyType({}))
    disc_body: bool = False
    lidar: MappingProxyType = dataclasses.field(default_factory=lambda: MappingProxyType({}))

    @property
    def unicycle(self):
        """Return True for a ground robot with the unicycle state [x, y, theta, v, omega]."""
        return self.model == 'unicycle'

    @property
    def aerial(self):
        """Return True for a flying robot (positions [x, y, z])."""
        return self.goal_size == 3

    @property
    def goal_size(self):
        """Return the number of goal coordinates (the start adds the yaw)."""
        return len(self.goal_fields.split(','))


_TWIST = dict(model='unicycle', command_kind='velocity',
              command_type='geometry_msgs/msg/TwistStamped', safe_topic='cmd_vel_out',
              nominal_topic='cmd_vel_in', start_fields='[x, y, yaw]', goal_fields='[x, y]',
              goal_controller=UnicycleGoalController, state_size=5, yaw_index=2,
              input_units='unicycle [a m/s^2, alpha rad/s^2]',
              filter_parameters=MappingProxyType({'stamped': True}))

# Footprint circle radius [m] around the base: the standing A1 reaches 0.378 m (its rear
# knees stick out 0.354 m behind the base), a diff-drive base is a disc of
# DIFF_DRIVE_RADIUS, the Crazyflie its rotor tips.
DIFF_DRIVE_RADIUS = 0.2  # m: BARN's reference paths keep >= 0.225 m from 99 % of its worlds
# Clearpath Jackal: 0.508 x 0.430 x 0.250 m outside (Clearpath's specification; the
# chassis alone is 0.42 x 0.31 m, jackal_description/urdf/jackal.urdf.xacro); its radius is
# from the box's centre to a corner.
JACKAL_SIZE = (0.508, 0.430, 0.250)   # m: length, width, height
JACKAL_RADIUS = 0.5 * math.hypot(*JACKAL_SIZE[:2])
# BARN's Jackal carries a Hokuyo UST-10 on its front mount (Daffan/the-barn-challenge run.py:
# JACKAL_LASER_MODEL=ust10, JACKAL_LASER_OFFSET="-0.065 0 0.01"; jackal_description
# accessories/hokuyo_ust10.urdf.xacro): 720 beams over 270 deg, 0.1-30 m, 1 mm noise, 50 Hz,
# 0.055 m ahead of base_link and 0.24 m up.  Here at 48 Hz, the rate nearest 50 that divides
# the default physics rate (240 Hz), its plane 0.24 m above the ground (the box's centre,
# where the plant's base sits, is 0.125 m up).
JACKAL_LIDAR = MappingProxyType({
    'beams': 720, 'field_of_view': 1.5 * math.pi, 'range_min': 0.1, 'range_max': 30.0,
    'rate': 48.0, 'noise_std': 0.001, 'height': 0.24 - 0.5 * JACKAL_SIZE[2],
    'mount': (0.055, 0.0, 0.0)})
ROBOT_TYPES = MappingProxyType({robot.name: robot for robot in (
    RobotType('quadruped', params_file='quadruped.yaml', radius=0.4, **_TWIST),
    RobotType('diff_drive', params_file='diff_drive.yaml', radius=DIFF_DRIVE_RADIUS,
              disc_body=True, **_TWIST),
    RobotType('jackal', params_file='jackal.yaml', radius=JACKAL_RADIUS, lidar=JACKAL_LIDAR,
              **_TWIST),
    RobotType('crazyflie', model='quadrotor', params_file='crazyflie_thrust.yaml',
              command_kind='wrench', command_type='geometry_msgs/msg/WrenchStamped',
              safe_topic='wrench_out', nominal_topic='wrench_in', radius=cf.BODY_RADIUS,
              start_fields='[x, y, z, yaw]', goal_fields='[x, y, z]',
              goal_controller=QuadrotorGoalController, state_size=12, yaw_index=8,
              input_units='rotor thrusts [N]'),
)})


def robot_type(name):
    """Return the RobotType called ``name``; ValueError naming the valid types."""
    try:
        return ROBOT_TYPES[name]
    except (KeyError, TypeError):
        raise ValueError(f'expected one of {", ".join(ROBOT_TYPES)}, got {name!r}') from None
