"""ROS messages <-> numpy for the safety filter node: odometry and commands.

Odometry -> model state.  ``nav_msgs/Odometry`` gives the pose in
``header.frame_id`` (the world/odometry frame) and the twist in
``child_frame_id`` (the body frame).  With ``R`` the body-to-world rotation of
the pose quaternion and ``(roll, pitch, yaw)`` its ZYX Euler angles
(``R = Rz(yaw) Ry(pitch) Rx(roll)``)::

    unicycle       [x, y, yaw, v, omega]        v = twist.linear.x, omega = twist.angular.z
    point_mass_2d  [x, y, vx, vy]               [vx, vy, .] = R twist.linear
    point_mass_3d  [x, y, z, vx, vy, vz]        [vx, vy, vz] = R twist.linear
    quadrotor      [x, y, z, R twist.linear, roll, pitch, yaw, twist.angular]

A non-unit quaternion is normalised; an all-zero one is read as identity (as
RViz does).  Non-finite input is refused (``None`` / NaN), never normalised away.

Commands.  ``core.command_filter`` works on command vectors; a Twist or Wrench
carries them in its six numbers ``(linear|force xyz, angular|torque xyz)``::

    unicycle       [v, omega]       = linear.x, angular.z
    point_mass_2d  [vx, vy]         = linear.x, linear.y        (angular.z passed through)
    point_mass_3d  [vx, vy, vz]     = linear.x, .y, .z          (angular.z passed through)
    quadrotor      [T, tx, ty, tz]  = force.z, torque.x, .y, .z

On the node's hot path odometry and commands stay serialized (CDR): see
``read_odometry`` and ``SerializedCommand`` below.  Obstacle markers are
``marker_obstacles``.
"""
import math
import struct
from typing import NamedTuple

import numpy as np

from polyc2bf_ros.cdr_reader import aligned, layout_of, read_header, read_string

# -- odometry -> state ------------------------------------------------------------------------

def rotation(qx, qy, qz, qw):
    """Row-major rotation matrix ``(r00, r01, ..., r22)`` of a quaternion, normalised.

    An all-zero quaternion reads as identity.  Plain floats: this runs per
    odometry message, where numpy's per-call overhead would dominate.
    """
    norm_sq = qx * qx + qy * qy + qz * qz + qw * qw
    if norm_sq == 0.0:
        return 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0
    s = 2.0 / norm_sq
    return (1.0 - s * (qy * qy + qz * qz), s * (qx * qy - qz * qw), s * (qx * qz + qy * qw),
            s * (qx * qy + qz * qw), 1.0 - s * (qx * qx + qz * qz), s * (qy * qz - qx * qw),
            s * (qx * qz - qy * qw), s * (qy * qz + qx * qw), 1.0 - s * (qx * qx + qy * qy))


def state_from_odometry(model_name, pose, twist):
    """``(state tuple, yaw)`` of ``model_name`` from Odometry numbers; ``None`` if non-finite.

    ``pose`` = (x, y, z, qx, qy, qz, qw) in the odometry frame, ``twist`` =
    (vx, vy, vz, wx, wy, wz) in the body frame (the layout of the messages).
    The yaw (of the body x axis in the odometry frame) rotates body-frame
    velocity commands into the odometry frame.  Every input number is checked,
    so a non-finite quaternion cannot hide behind the normalisation.
    """
    if not all(map(math.isfinite, pose)) or not all(map(math.isfinite, twist)):
        return None
    x, y, z, qx, qy, qz, qw = pose
    vx, vy, vz, wx, wy, wz = twist
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = rotation(qx, qy, qz, qw)
    yaw = math.atan2(r10, r00)
    if model_name == 'unicycle':
        return (x, y, yaw, vx, wz), yaw
    world_vx = r00 * vx + r01 * vy + r02 * vz
    world_vy = r10 * vx + r11 * vy + r12 * vz
    if model_name == 'point_mass_2d':
        return (x, y, world_vx, world_vy), yaw
    world_vz = r20 * vx + r21 * vy + r22 * vz
    if model_name == 'point_mass_3d':
        return (x, y, z, world_vx, world_vy, world_vz), yaw
    roll = math.atan2(r21, r22)
    pitch = math.asin(max(-1.0, min(1.0, -r20)))
    return (x, y, z, world_vx, world_vy, world_vz, roll, pitch, yaw, wx, wy, wz), yaw


def _vector(v):
    return v.x, v.y, v.z


def odometry_to_state(msg, model_name, out):
    """Fill ``out`` with the state of ``model_name`` from ``nav_msgs/Odometry``; return the yaw.

    Non-finite input fills ``out`` with NaN and returns NaN, for the caller to refuse.
    """
    pose, twist = msg.pose.pose, msg.twist.twist
    q = pose.orientation
    result = state_from_odometry(model_name, (*_vector(pose.position), q.x, q.y, q.z, q.w),
                                 (*_vector(twist.linear), *_vector(twist.angular)))
    if result is None:
        out[:] = math.nan
        return math.nan
    out[:] = result[0]
    return result[1]


# -- commands: the six numbers of a Twist or Wrench <-> the CommandFilter's vector -----------

# Positions in (linear|force x, y, z, angular|torque x, y, z) of the command vector of each
# model (core.command_filter), and of the numbers passed through from the nominal command:
# point masses have no heading, so their nominal yaw rate passes unchanged (a holonomic base
# turning in place does not move its centre).  Every other number of a safe command is 0.
COMMAND_FIELDS = {
    'unicycle': (0, 5),
    'point_mass_2d': (0, 1),
    'point_mass_3d': (0, 1, 2),
    'quadrotor': (2, 3, 4, 5),
}
KEPT_FIELDS = {'point_mass_2d': (5,), 'point_mass_3d': (5,)}


def command_from_values(values, model_name):
    """Pick the command vector of ``model_name`` out of the six numbers of a Twist or Wrench."""
    return tuple(values[i] for i in COMMAND_FIELDS[model_name])


def six_values(msg):
    """Return the six numbers of a Twist / TwistStamped or Wrench / WrenchStamped message."""
    body = getattr(msg, 'twist', None) or getattr(msg, 'wrench', None) or msg
    first, second = ((body.linear, body.angular) if hasattr(body, 'linear')
                     else (body.force, body.torque))
    return first.x, first.y, first.z, second.x, second.y, second.z


def twist_to_command(msg, model_name):
    """Command vector of ``model_name`` from a (stamped) Twist, or Wrench for the quadrotor."""
    return command_from_values(six_values(msg), model_name)


def values_from_command(command, model_name, nominal=None):
    """Six numbers of the Twist/Wrench carrying ``command``; kept ones copied from ``nominal``."""
    values = [0.0] * 6
    if nominal is not None:
        for i in KEPT_FIELDS.get(model_name, ()):
            values[i] = nominal[i]
    if isinstance(command, np.ndarray):
        command = command.tolist()  # floats at once, not one numpy scalar each
    for i, value in zip(COMMAND_FIELDS[model_name], command):
        values[i] = float(value)
    return values


def fill_twist(out, model_name, command, yaw_rate=0.0):
    """Write ``command`` into Twist ``out``; point masses get ``yaw_rate`` on angular.z."""
    values = values_from_command(command, model_name, (0.0,) * 5 + (float(yaw_rate),))
    out.linear.x, out.linear.y, out.linear.z, out.angular.x, out.angular.y, out.angular.z = values


# -- serialized odometry and commands on the node's hot path ----------------------------------
#
# rclpy turns every received message into Python objects field by field; for an Odometry
# (two 36-double covariances) that costs more than the safety filter step.  The node takes
# odometry and commands serialized and reads only the numbers it uses, and answers a command
# by replacing the six numbers in a copy of its bytes, which copies the header for free.
# The CDR layout is in ``cdr_reader``.

class OdometryView(NamedTuple):
    """The numbers of a serialized Odometry that are read (see ``read_odometry``)."""

    sec: int
    nanosec: int
    frame: bytes
    child_frame: bytes
    pose: tuple
    twist: tuple

    @property
    def stamp(self):
        """Header stamp [s]."""
        return self.sec + 1e-9 * self.nanosec


def read_odometry(data):
    """``OdometryView`` (stamp, frame ids, pose (7,), twist (6,)) of a serialized Odometry.

    The covariances are skipped, not read.  Raises ``ValueError`` for a malformed message.
    """
    layout = layout_of(data)
    try:
        sec, nanosec, frame, end = read_header(data, layout)
        child_frame, end = read_string(data, layout, end)
        pose_at = aligned(end, 8)
        pose = layout.pose.unpack_from(data, pose_at)
        twist = layout.six.unpack_from(data, pose_at + 8 * (7 + 36))
    except struct.error as exc:
        raise ValueError(f'truncated Odometry: {exc}') from None
    return OdometryView(sec, nanosec, frame, child_frame, pose, twist)


class SerializedCommand:
    """A received serialized Twist, TwistStamped or WrenchStamped and its six numbers.

    ``stamp`` [s] and ``stamp_ns`` (exact, for matching stamps) are 0 without a header.
    """

    __slots__ = ('data', 'layout', 'at', 'values', 'stamp', 'stamp_ns', 'finite')

    def __init__(self, data, stamped):
        """Parse ``data``; ``stamped``: it starts with a Header.  ``ValueError`` if malformed."""
        self.data = data
        self.layout = layout_of(data)
        self.stamp, self.stamp_ns, self.at = 0.0, 0, 4
        try:
            if stamped:
                sec, nanosec, _, end = read_header(data, self.layout)
                self.stamp, self.stamp_ns = sec + 1e-9 * nanosec, sec * 1_000_000_000 + nanosec
                self.at = aligned(end, 8)
            self.values = self.layout.six.unpack_from(data, self.at)
        except struct.error as exc:
            raise ValueError(f'truncated command: {exc}') from None
        self.finite = all(map(math.isfinite, self.values))

    def replaced(self, values, stamp=None):
        """Return a copy of the bytes with the six numbers (and the stamp (sec, nanosec)) set."""
        at, layout = self.at, self.layout
        head = self.data[:at] if stamp is None else (
            self.data[:4] + layout.stamp.pack(*stamp) + self.data[12:at])
        return head + layout.six.pack(*values) + self.data[at + 48:]


# -- markers -> obstacles ---------------------------------------------------------------------
