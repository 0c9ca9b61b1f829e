"""Hand-written CDR reads back in rclpy and rosbags as the message, and reads what rclpy wrote.

Byte equality with ``serialize_message`` holds except in alignment padding,
which Fast CDR leaves unset (it is zero here).
"""
import numpy as np
import pytest
from geometry_msgs.msg import TwistStamped, WrenchStamped
from nav_msgs.msg import Odometry
from rclpy.serialization import deserialize_message, serialize_message
from rosbags.typesys import get_typestore, Stores
from rosgraph_msgs.msg import Clock

from sim_bridge.cdr import (
    clock_cdr,
    OdometryCdr,
    read_odometry,
    read_stamped_six,
    tf_message_cdr,
)

# Frame ids of every length mod 8, so each padding case of the float64 block occurs.
FRAMES = [('world', 'a1/base_link'), ('map', 'r'), ('odom', 'robot_7/base_footprint'),
          ('w', ''), ('frame12', 'abcdefgh/base_link')]


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


@pytest.mark.parametrize('frames', FRAMES)
def test_odometry_bytes_equal_rclpy(frames):
    """OdometryCdr.pack deserializes to the message (rclpy, rosbags); read_odometry inverts it."""
    rng = np.random.default_rng(len(frames[0]) + 10 * len(frames[1]))
    msg, pose, twist = _odometry(rng, *frames)
    stamp = msg.header.stamp
    data = OdometryCdr(*frames).pack(stamp.sec, stamp.nanosec, pose, twist)
    reference = serialize_message(msg)
    assert len(data) == len(reference)
    assert deserialize_message(data, Odometry) == msg
    other = get_typestore(Stores.ROS2_JAZZY).deserialize_cdr(data, 'nav_msgs/msg/Odometry')
    assert other.child_frame_id == frames[1] and other.twist.twist.angular.z == twist[5]
    assert read_odometry(reference, Odometry()) == msg


def test_read_odometry_keeps_nonzero_covariances_out_and_rejects_bad_data():
    """Covariances sent by someone else do not shift the twist; bad bytes raise ValueError."""
    msg, _, _ = _odometry(np.random.default_rng(1), 'world', 'x/base_link')
    msg.pose.covariance[:] = np.arange(36.0)
    msg.twist.covariance[:] = -np.arange(36.0)
    back = read_odometry(serialize_message(msg), Odometry())
    assert back.twist.twist == msg.twist.twist and back.pose.pose == msg.pose.pose
    assert back.header == msg.header and back.child_frame_id == msg.child_frame_id
    with pytest.raises(ValueError, match='truncated'):
        read_odometry(serialize_message(msg)[:100], Odometry())
    with pytest.raises(ValueError, match='little-endian'):
        read_odometry(b'\x00\x00\x00\x00' + serialize_message(msg)[4:], Odometry())


@pytest.mark.parametrize('frame', ['', 'a', 'a1/base_link', 'abcdefg'])
def test_stamped_commands_read_back(frame):
    """read_stamped_six gives the stamp in ns and the six numbers rclpy serialized."""
    twist, wrench = TwistStamped(), WrenchStamped()
    for msg in (twist, wrench):
        msg.header.stamp.sec, msg.header.stamp.nanosec = 7, 8_333_333
        msg.header.frame_id = frame
    twist.twist.linear.x, twist.twist.angular.z = 0.75, -0.5
    wrench.wrench.force.z, wrench.wrench.torque.y = 0.26, 1e-5
    assert read_stamped_six(serialize_message(twist)) == (
        7_008_333_333, (0.75, 0.0, 0.0, 0.0, 0.0, -0.5))
    assert read_stamped_six(serialize_message(wrench)) == (
        7_008_333_333, (0.0, 0.0, 0.26, 0.0, 1e-5, 0.0))
    with pytest.raises(ValueError, match='truncated'):
        read_stamped_six(serialize_message(twist)[:-8])


def test_clock_bytes_equal_rclpy():
    """clock_cdr gives serialize_message's bytes (no padding in a Clock)."""
    msg = Clock()
    msg.clock.sec, msg.clock.nanosec = 12, 345_678_901
    assert clock_cdr(12, 345_678_901) == serialize_message(msg)


def test_tf_message_reads_in_rosbags():
    """TFMessage (tf2_msgs is not installed here) deserializes with rosbags' Jazzy types."""
    transforms = [(3, 500, 'world', 'a1/base_link', [1.0, 2.0, 0.3], [0.0, 0.0, 0.6, 0.8]),
                  (3, 500, 'world', 'cf_long_name/base_link', [4.0, 5.0, 1.0], [0, 0, 0, 1.0])]
    store = get_typestore(Stores.ROS2_JAZZY)
    msg = store.deserialize_cdr(tf_message_cdr(transforms), 'tf2_msgs/msg/TFMessage')
    assert [t.child_frame_id for t in msg.transforms] == ['a1/base_link', 'cf_long_name/base_link']
    second = msg.transforms[1]
    assert (second.header.stamp.sec, second.header.stamp.nanosec) == (3, 500)
    assert second.header.frame_id == 'world'
    assert [second.transform.translation.x, second.transform.rotation.w] == [4.0, 1.0]

