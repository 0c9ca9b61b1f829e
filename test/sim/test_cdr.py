"""Hand-written CDR reads back in rclpy and rosbags as the message, and in the filter's reader.

Byte equality with ``serialize_message`` holds except in alignment padding,
which Fast CDR leaves unset (it is zero here).  The readers themselves
(``conversions.read_odometry``, ``SerializedCommand``) are tested against
rclpy in test/node/test_node_conversions.py.
"""
import numpy as np
import pytest
from nav_msgs.msg import Odometry
from rclpy.serialization import deserialize_message, serialize_message
from rosbags.typesys import get_typestore, Stores
from rosgraph_msgs.msg import Clock

from polyc2bf_ros.conversions import read_odometry
from sim_bridge.cdr import clock_cdr, OdometryCdr, tf_message_cdr

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
    """OdometryCdr.pack deserializes to the message (rclpy, rosbags) and reads back exactly."""
    rng = np.random.default_rng(len(frames[0]) + 10 * len(frames[1]))
    msg, pose, twist = _odometry(rng, *frames)
    stamp = msg.header.stamp
    data = OdometryCdr(*frames).pack(stamp.sec, stamp.nanosec, pose, twist)
    reference = serialize_message(msg)
    assert len(data) == len(reference)
    assert deserialize_message(data, Odometry) == msg
    other = get_typestore(Stores.ROS2_JAZZY).deserialize_cdr(data, 'nav_msgs/msg/Odometry')
    assert other.child_frame_id == frames[1] and other.twist.twist.angular.z == twist[5]
    odom = read_odometry(data)
    assert (odom.sec, odom.nanosec) == (stamp.sec, stamp.nanosec)
    assert (odom.frame.decode(), odom.child_frame.decode()) == frames
    assert odom.pose == tuple(pose) and odom.twist == tuple(twist)
    assert read_odometry(reference) == odom


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

