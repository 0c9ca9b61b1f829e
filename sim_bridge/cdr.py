"""CDR of the bridge's per-period odometry (hand-written) and ``/tf`` (rosbags).

``OdometryCdr`` is the one hand-written serializer left: it is on the lockstep
bridge's per-period path, once per robot.  Building an rclpy ``Odometry`` and
``serialize_message`` took 36-110 us here, ``OdometryCdr.pack`` 0.6-1.4 us
(rosbags' type store 21-26 us; best of 5 x 5000 calls, timeit, over runs from
an idle to a loaded machine).  The lockstep bridge runs its periods back to
back, ~725 us each with one robot and no filter (bench/results/sim.json,
quadruped_50_obstacles_no_filter: real-time factor 11.5 at 120 Hz), so rclpy
would add 5-15% per robot.  The bytes are rclpy's except in alignment
padding, which Fast CDR leaves unset and this writes as zeros (little-endian
CDR after the 4-byte encapsulation header, alignment counted from the end of
that header); test/sim/test_cdr.py compares them byte for byte with
``serialize_message`` and rosbags.

``tf_message_cdr`` serializes ``tf2_msgs/msg/TFMessage`` with rosbags' Jazzy
type store, as the PyPI ROS wheels lack ``tf2_msgs`` (rclpy cannot serialize
one here): 8.5-23 us for one transform against 2-4.5 us by hand, 1-2.5% of
that period per robot.  ``/clock`` goes through rclpy (7-17 us, 1-2.5%).

The readers (odometry, stamped commands) are the safety filter's own:
``polyc2bf_ros.conversions.read_odometry`` and ``SerializedCommand``.
"""
import struct

from rosbags.typesys import get_typestore, Stores

TF_MESSAGE_TYPE = 'tf2_msgs/msg/TFMessage'
_TYPES = get_typestore(Stores.ROS2_JAZZY)
_ENCAPSULATION = b'\x00\x01\x00\x00'  # CDR_LE, no options
_STAMP = struct.Struct('<iI')
_UINT32 = struct.Struct('<I')
# Odometry after the frame ids: position (3), orientation (4), covariance (36), linear (3),
# angular (3), covariance (36); all float64, contiguous from one 8-aligned offset.
_POSE = struct.Struct('<7d')
_TWIST = struct.Struct('<6d')
_COVARIANCE = bytes(36 * 8)


def _string(text, offset):
    """Return the CDR of a string at payload ``offset`` (4-aligned length, bytes, NUL)."""
    data = text.encode() + b'\x00'
    pad = -offset % 4
    return b'\x00' * pad + _UINT32.pack(len(data)) + data


def tf_message_cdr(transforms):
    """Return the serialized TFMessage of ``transforms``.

    Each transform is ``(sec, nanosec, frame_id, child_frame_id, translation (3),
    rotation (4, x y z w))``.
    """
    types = _TYPES.types
    message = types[TF_MESSAGE_TYPE](transforms=[
        types['geometry_msgs/msg/TransformStamped'](
            header=types['std_msgs/msg/Header'](
                stamp=types['builtin_interfaces/msg/Time'](sec=sec, nanosec=nanosec),
                frame_id=frame_id),
            child_frame_id=child_frame_id,
            transform=types['geometry_msgs/msg/Transform'](
                translation=types['geometry_msgs/msg/Vector3'](*translation),
                rotation=types['geometry_msgs/msg/Quaternion'](*rotation)))
        for sec, nanosec, frame_id, child_frame_id, translation, rotation in transforms])
    return bytes(_TYPES.serialize_cdr(message, TF_MESSAGE_TYPE))


class OdometryCdr:
    """Serializer of one robot's Odometry: frames fixed, covariances zero.

    ``pack(sec, nanosec, pose, twist)`` with pose = position (3) + quaternion
    (x, y, z, w) and twist = linear (3) + angular (3) in the child frame.
    """

    def __init__(self, frame_id, child_frame_id):
        """Precompute the frame ids and the padding to the 8-aligned float64 block."""
        frames = _string(frame_id, 8)
        frames += _string(child_frame_id, 8 + len(frames))
        frames += b'\x00' * (-(8 + len(frames)) % 8)
        self._frames = frames

    def pack(self, sec, nanosec, pose, twist):
        """Return the CDR bytes of the odometry message."""
        return b''.join((_ENCAPSULATION, _STAMP.pack(sec, nanosec), self._frames,
                         _POSE.pack(*pose), _COVARIANCE, _TWIST.pack(*twist), _COVARIANCE))
