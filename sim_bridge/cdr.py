"""Hand-written CDR of the bridge's per-period messages: /tf, odometry and clock.

rclpy serializes through Python message objects: an ``Odometry`` (two float64[36]
covariances) took ~120 us to serialize here, more than a DDS hop.  These functions
build the bytes rclpy would (little-endian CDR after the 4-byte encapsulation
header; alignment counted from the end of that header), so the bridge can
publish and record the same bytes.  They equal rclpy's output except in
alignment padding, which Fast CDR leaves unset and these write as zeros;
test/sim/test_cdr.py checks them with ``rclpy.serialization`` and ``rosbags``.

- ``tf_message_cdr``: ``tf2_msgs/msg/TFMessage``, also because the PyPI ROS
  wheels lack ``tf2_msgs`` (rclpy cannot serialize one here);
  ``TF_MESSAGE_DEFINITION`` is its ``.msg`` text for the bag's schema;
- ``clock_cdr``: ``rosgraph_msgs/msg/Clock``;
- ``OdometryCdr``: ``nav_msgs/msg/Odometry`` with fixed frame ids and zero
  covariances (what the bridge sends).

The readers (odometry, stamped commands) are the safety filter's own:
``polyc2bf_ros.conversions.read_odometry`` and ``SerializedCommand``.

(A MarkerArray writer was tried and dropped: reading the fields of rclpy
``Marker`` objects costs as much as rclpy's own serializer, ~33 us a marker.)
"""
import struct

TF_MESSAGE_TYPE = 'tf2_msgs/msg/TFMessage'
TF_MESSAGE_DEFINITION = 'geometry_msgs/TransformStamped[] transforms\n'
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
    parts = [_UINT32.pack(len(transforms))]
    offset = 4
    for sec, nanosec, frame_id, child_frame_id, translation, rotation in transforms:
        chunk = b'\x00' * (-offset % 4) + _STAMP.pack(sec, nanosec)
        chunk += _string(frame_id, offset + len(chunk))
        chunk += _string(child_frame_id, offset + len(chunk))
        chunk += b'\x00' * (-(offset + len(chunk)) % 8)
        chunk += struct.pack('<7d', *translation, *rotation)
        parts.append(chunk)
        offset += len(chunk)
    return _ENCAPSULATION + b''.join(parts)


def clock_cdr(sec, nanosec):
    """Return the serialized rosgraph_msgs/Clock of time ``sec`` + ``nanosec``."""
    return _ENCAPSULATION + _STAMP.pack(sec, nanosec)


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
