"""Hand-written CDR of ``tf2_msgs/msg/TFMessage``, to record ``/tf`` without tf2_msgs installed.

The PyPI ROS wheels this project uses lack ``tf2_msgs``, so rclpy can neither
publish nor serialize a TFMessage here.  ``tf_message_cdr`` builds the bytes
rclpy would (little-endian CDR with its 4-byte encapsulation header; alignment
counted from the end of that header), and ``TF_MESSAGE_DEFINITION`` is the
type's ``.msg`` text for the bag's schema (its dependency,
``geometry_msgs/TransformStamped``, is installed).
"""
import struct

TF_MESSAGE_TYPE = 'tf2_msgs/msg/TFMessage'
TF_MESSAGE_DEFINITION = 'geometry_msgs/TransformStamped[] transforms\n'
_ENCAPSULATION = b'\x00\x01\x00\x00'  # CDR_LE, no options


def _string(text, offset):
    """Return the CDR of a string at payload ``offset`` (4-aligned length, bytes, NUL)."""
    data = text.encode() + b'\x00'
    pad = -offset % 4
    return b'\x00' * pad + struct.pack('<I', len(data)) + data


def tf_message_cdr(transforms):
    """Return the serialized TFMessage of ``transforms``.

    Each transform is ``(sec, nanosec, frame_id, child_frame_id, translation (3),
    rotation (4, x y z w))``.
    """
    parts = [struct.pack('<I', len(transforms))]
    offset = 4
    for sec, nanosec, frame_id, child_frame_id, translation, rotation in transforms:
        chunk = b'\x00' * (-offset % 4) + struct.pack('<iI', sec, nanosec)
        chunk += _string(frame_id, offset + len(chunk))
        chunk += _string(child_frame_id, offset + len(chunk))
        chunk += b'\x00' * (-(offset + len(chunk)) % 8)
        chunk += struct.pack('<7d', *translation, *rotation)
        parts.append(chunk)
        offset += len(chunk)
    return _ENCAPSULATION + b''.join(parts)
