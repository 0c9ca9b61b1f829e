"""The bridge's hand-written odometry CDR is rclpy's, byte for byte; tf reads back in rosbags.

rclpy (Fast CDR) leaves alignment padding unset, so its padding bytes vary from
call to call; every other byte must equal ``serialize_message``'s, and the
padding is zero, which makes the whole message equal rosbags' serialization.
The readers themselves (``conversions.read_odometry``, ``SerializedCommand``)
are tested against rclpy in test/node/test_node_conversions.py.
"""
import numpy as np
import pytest
from nav_msgs.msg import Odometry
from rclpy.serialization import deserialize_message, serialize_message
from rosbags.typesys import get_typestore, Stores

from polyc2bf_ros.conversions import read_odometry
from sim_bridge.cdr import OdometryCdr, tf_message_cdr

JAZZY = get_typestore(Stores.ROS2_JAZZY)
# Frame ids of every length mod 8, so each padding case of the float64 block occurs.
FRAMES = [('world', 'a1/base_link'), ('map', 'r'), ('odom', 'robot_7/base_footprint'),
          ('w', ''), ('frame12', 'abcdefgh/base_link'), ('x' * 13, 'y' * 6)]


def _odometry(rng, frame_id, child_frame_id):
    """Return an Odometry with random stamp, pose and twist, zero covariances."""
    msg = Odometry()
    msg.header.stamp.sec, msg.header.stamp.nanosec = int(rng.integers(0, 2 ** 31)), 999_999_999
    msg.header.frame_id, msg.child_frame_id = frame_id, child_frame_id
    pose, twist = rng.normal(size=7), rng.normal(size=6)
    p, q = msg.pose.pose.position, msg.pose.pose.orientation
    p.x, p.y, p.z, q.x, q.y, q.z, q.w = pose.tolist()
    v, w = msg.twist.twist.linear, msg.twist.twist.angular
    v.x, v.y, v.z, w.x, w.y, w.z = twist.tolist()
    return msg, pose, twist


def _padding(frame_id, child_frame_id):
    """Return the byte offsets CDR pads in an Odometry with these frame ids.

    After the 4-byte header: stamp (8), frame_id (uint32 length, bytes, NUL),
    padding to 4, child_frame_id, padding to 8 before the float64 block;
    alignment counts from the end of the header.
    """
    end = 8 + 4 + len(frame_id) + 1
    child = end + -end % 4
    floats_end = child + 4 + len(child_frame_id) + 1
    floats = floats_end + -floats_end % 8
    return {4 + k for k in [*range(end, child), *range(floats_end, floats)]}


def _unpadded(data, padding):
    """Return ``data`` without the bytes at the ``padding`` offsets."""
    return bytes(byte for k, byte in enumerate(data) if k not in padding)


@pytest.mark.parametrize('frames', FRAMES)
def test_odometry_bytes_equal_rclpy(frames):
    """OdometryCdr.pack is serialize_message's bytes but for zero padding, and reads back."""
    rng = np.random.default_rng(len(frames[0]) + 10 * len(frames[1]))
    msg, pose, twist = _odometry(rng, *frames)
    stamp = msg.header.stamp
    data = OdometryCdr(*frames).pack(stamp.sec, stamp.nanosec, pose, twist)
    reference = serialize_message(msg)
    padding = _padding(*frames)
    assert len(data) == len(reference)
    assert _unpadded(data, padding) == _unpadded(reference, padding)
    assert all(data[k] == 0 for k in padding)
    assert data == bytes(JAZZY.serialize_cdr(
        JAZZY.deserialize_cdr(reference, 'nav_msgs/msg/Odometry'), 'nav_msgs/msg/Odometry'))
    assert deserialize_message(data, Odometry) == msg
    odom = read_odometry(data)
    assert (odom.sec, odom.nanosec) == (stamp.sec, stamp.nanosec)
    assert (odom.frame.decode(), odom.child_frame.decode()) == frames
    assert odom.pose == tuple(pose) and odom.twist == tuple(twist)
    assert read_odometry(reference) == odom


def test_tf_message_reads_in_rosbags():
    """TFMessage (tf2_msgs is not installed here) carries each transform's fields in order."""
    transforms = [(3, 500, 'world', 'a1/base_link', [1.0, 2.0, 0.3], [0.0, 0.0, 0.6, 0.8]),
                  (3, 500, 'world', 'cf_long_name/base_link', [4.0, 5.0, 1.0], [0, 0, 0, 1.0])]
    msg = JAZZY.deserialize_cdr(tf_message_cdr(transforms), 'tf2_msgs/msg/TFMessage')
    assert [t.child_frame_id for t in msg.transforms] == ['a1/base_link', 'cf_long_name/base_link']
    second = msg.transforms[1]
    assert (second.header.stamp.sec, second.header.stamp.nanosec) == (3, 500)
    assert second.header.frame_id == 'world'
    translation, rotation = second.transform.translation, second.transform.rotation
    assert [translation.x, translation.y, translation.z] == [4.0, 5.0, 1.0]
    assert [rotation.x, rotation.y, rotation.z, rotation.w] == [0.0, 0.0, 0.0, 1.0]
