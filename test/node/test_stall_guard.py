"""The independent stop: the guard's rule on a given clock, and a stuck node step in process."""
import threading
import time

import pytest
import rclpy
from geometry_msgs.msg import Twist
from rclpy.parameter import Parameter
from rclpy.serialization import deserialize_message, serialize_message

from node_harness import markers, odometry, twist
from polyc2bf_ros.safety_filter_node import SafetyFilterNode
from polyc2bf_ros.stall_guard import StallGuard


def test_the_guard_acts_only_after_the_timeout_and_counts_each_stall_once():
    """Armed by a beat; silent >= timeout: ``on_stall`` per check; a beat ends the stall."""
    calls = []
    guard = StallGuard(0.2, calls.append, clock=lambda: 0.0)
    assert not guard.check(100.0)  # not armed before the first beat
    guard.beat(10.0)
    assert not guard.check(10.19) and calls == []
    assert guard.check(10.25) and guard.check(10.5)
    assert calls == pytest.approx([0.25, 0.5]) and guard.stalls == 1 and guard.stalled
    guard.beat(10.6)
    assert not guard.check(10.7) and not guard.stalled
    assert guard.check(11.0) and guard.stalls == 2


def test_a_non_positive_timeout_is_refused():
    """A guard that could never wait is a configuration error."""
    with pytest.raises(ValueError, match='positive'):
        StallGuard(0.0, print)


def test_a_stuck_step_gets_a_stop_from_the_guard_thread():
    """The step blocks for 4 s: the guard's thread publishes a zero twist meanwhile, one stall.

    Answers are told apart by the thread that published them.
    """
    context = rclpy.Context()
    rclpy.init(context=context)
    node = SafetyFilterNode(context=context, parameter_overrides=[
        Parameter('trigger', value='command'), Parameter('obstacles_timeout', value=0.0),
        Parameter('stall_timeout', value=1.0), Parameter('odom_timeout', value=10.0),
        Parameter('cmd_timeout', value=10.0)])
    answers, lock = [], threading.Lock()

    def record(data):
        with lock:
            answers.append((threading.current_thread().name,
                            deserialize_message(data, Twist).linear.x))

    node._publish = record  # the serialized answers, instead of DDS
    real_filter = node._filter.filter
    try:
        node._on_obstacles(serialize_message(markers()))
        node._on_odom(serialize_message(odometry(v=0.5)))
        node._intake.process()
        node._on_odom(serialize_message(odometry(v=0.5)))  # fresh after the wait
        node._on_command(serialize_message(twist(0.5)))
        with lock:
            assert [v for name, v in answers if name != 'stall_guard'][-1] > 0.4

        def stuck(*args):
            time.sleep(4.0)
            return real_filter(*args)

        node._filter.filter = stuck
        node._stall_guard.beat()
        time.sleep(0.3)  # the guard sees the beat: not stalled when the step starts
        before = node._stall_guard.stalls
        with lock:
            count = len(answers)
        node._on_command(serialize_message(twist(0.5)))
        with lock:
            during = answers[count:]
        assert during[-1][0] != 'stall_guard' and during[-1][1] > 0.4  # the step's own answer
        guard = [v for name, v in during if name == 'stall_guard']
        assert guard and set(guard) == {0.0}, during
        assert node._stall_guard.stalls == before + 1
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=context)
